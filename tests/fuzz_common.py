"""Fuzzing strategies and targets shared by tests/test_fuzz_*.py (small budgets, in CI) and
benchmarks/fuzz_counts.py (large budgets, prints the counts).

A *target* takes one generated input and returns ``"valid"`` or ``"refused"``: ``"refused"`` when
the reader raised the project's own error (a PmctlError subclass, with a location that makes
sense), ``"valid"`` when it returned a result whose every value is finite and in range. Anything
else (another exception, an accepted infinity, a value out of range) is an AssertionError or the
exception itself: a crash, which the tests report with hypothesis' minimal example.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import tempfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, event, settings
from hypothesis import strategies as st

from pmctl.core.config import CONFIG_DIR, Machine, load_machine
from pmctl.core.errors import ConfigError, InputError, PmctlError
from pmctl.core.recording import read_recording
from pmctl.motion.service_config import load_service_config
from pmctl.task.cldata import MAX_COORD_MM, parse_cl
from pmctl.task.gcode import MAX_DWELL_S, parse_gcode
from pmctl.task.job import ARC, DWELL, EVENT, LINE, RAPID, read_job_text

ROOT = Path(__file__).resolve().parents[1]
JOBS = ROOT / "examples" / "jobs"
RECORDINGS = sorted(p / "recording" for p in (ROOT / "examples" / "recordings").iterdir()
                    if (p / "recording" / "recording.json").is_file())
START = (0.0, 0.0, 100.0)
_TMP = Path(tempfile.mkdtemp(prefix="pmctl-fuzz-"))


# ---------------------------------------------------------------- generic mutation of bytes and text

_HOSTILE_TOKENS = [
    b"9" * 400, b"1" + b"0" * 400, b"1e400", b"-1e400", b"inf", b"nan", b"NaN", b"-0", b"0", b"1e-400",
    b"\xff", b"\xc3\xa9", b"\xef\xbc\x91", b"\xd9\xa1", b"\x00", b"\r", b"\n", b"\t", b" ", b",", b";",
    b"(", b")", b"(MSG, hi)", b"%", b"[", b"]", b"#1", b"O100", b"<x>", b"=", b'"', b"'", b"{", b"}",
    b"G", b"X", b"F", b"P", b"M3", b"S", b"G4 P", b"G2", b"G81", b"N", b"true", b"false", b'"no"', b"[[",
    b"0.42", b"0.0000001", b"100000000", b"-", b"+", b".", b"e", b"_", b"\\u0000", b"[" * 200,
]


@st.composite
def mutated(draw, original: bytes, max_mutations=4):
    """``original`` with a few random edits: delete, duplicate, insert hostile or random bytes,
    replace a number, swap lines, truncate."""
    data = bytearray(original)
    for _ in range(draw(st.integers(1, max_mutations))):
        n = len(data)
        op = draw(st.sampled_from(["delete", "dup", "token", "bytes", "number", "swap", "truncate"]))
        i = draw(st.integers(0, max(n - 1, 0)))
        if op == "delete" and n:
            j = min(n, i + draw(st.integers(1, 16)))
            del data[i:j]
        elif op == "dup" and n:
            j = min(n, i + draw(st.integers(1, 64)))
            data[i:i] = data[i:j]
        elif op == "token":
            data[i:i] = draw(st.sampled_from(_HOSTILE_TOKENS))
        elif op == "bytes":
            data[i:i] = draw(st.binary(min_size=1, max_size=6))
        elif op == "number":
            k = i
            while k < n and not (48 <= data[k] <= 57):
                k += 1
            e = k
            while e < n and (48 <= data[e] <= 57 or data[e] in b".eE+-"):
                e += 1
            data[k:e] = draw(st.sampled_from(_HOSTILE_TOKENS[:10] + [b"0.42", b"1e-7", b"100000000", b"-5"]))
        elif op == "swap":
            lines = bytes(data).split(b"\n")
            if len(lines) > 2:
                a, b = draw(st.integers(0, len(lines) - 1)), draw(st.integers(0, len(lines) - 1))
                lines[a], lines[b] = lines[b], lines[a]
                data = bytearray(b"\n".join(lines))
        elif op == "truncate":
            del data[i:]
    return bytes(data)


def _write(name: str, data: bytes) -> Path:
    p = _TMP / name
    p.write_bytes(data)
    return p


def _finite(*arrays):
    for a in arrays:
        assert np.all(np.isfinite(np.asarray(a, float))), a


# ---------------------------------------------------------------- G-code

_NUM = st.one_of(
    st.integers(-10**6, 10**6).map(str),
    st.floats(-1e4, 1e4, allow_nan=False).map(lambda v: f"{v:.4f}"),
    st.sampled_from(["9" * 400, "1" + "0" * 400, "0.42", "0.0000001", "100000000", "-0", ".5", "5.", "+1", "1e5",
                     "\u0661", "\uff11", "", "-", "."]))
_WORD = st.tuples(st.sampled_from(list("GXYZABIJRFSMNPQ") + ["O", "T", "K", "#", "[", "E", "W"]), _NUM) \
    .map(lambda t: t[0] + t[1])
_GLINE = st.lists(st.one_of(_WORD, st.sampled_from(["G0", "G1", "G2", "G3", "G4", "G20", "G21", "G90", "G91",
                                                    "M3", "M5", "M2", "M30", "S1000", "F600", "(MSG, hi)",
                                                    "(c)", ";x", "%", "G81", "[1+2]", "#1=2", "o100 sub"])),
                  max_size=7).map(" ".join)
GCODE_TEXT = st.one_of(
    st.text(max_size=120),
    st.text(alphabet="GXYZABIJRFSMNPQ0123456789.-+ ();%\n\t[]#", max_size=120),
    st.lists(_GLINE, max_size=12).map("\n".join),
    st.sampled_from(["cone.ngc", "spiral.ngc"]).flatmap(
        lambda n: mutated((JOBS / n).read_bytes())).map(lambda b: b.decode("utf-8", errors="replace")),
)
GCODE_BYTES = st.sampled_from(["cone.ngc", "spiral.ngc"]).flatmap(lambda n: mutated((JOBS / n).read_bytes()))


def check_job(job, source):
    assert job.source == str(source)
    for m in job.moves:
        assert m.kind in (RAPID, LINE, ARC, DWELL, EVENT)
        _finite(m.tip, m.axis, [m.feed, m.spindle_rpm, m.sweep, m.dwell, m.tool_offset, m.duration, m.tolerance])
        assert abs(np.linalg.norm(m.axis) - 1.0) < 1e-9
        assert m.line >= 0 and m.duration >= 0 and m.tolerance >= 0
        if m.kind == EVENT:
            assert m.events and all(isinstance(name, str) for name, _ in m.events)
        if m.kind in (LINE, ARC):
            assert m.feed > 0 or m.duration > 0
        if m.kind == ARC:
            _finite(m.center)
        if m.kind == DWELL:
            assert 0 <= m.dwell <= MAX_DWELL_S
    for line, text in job.messages:
        assert isinstance(text, str) and line >= 1


def _check_input_error(e: InputError, path, text=None):
    assert e.path == str(path), (e.path, path)
    if e.line is not None and text is not None:
        assert 1 <= e.line <= text.count("\n") + 1
    if e.column is not None:
        assert e.column >= 1


def gcode_target(text: str) -> str:
    try:
        job = parse_gcode(text, "f.ngc", START, (0.0, 0.0, 1.0))
    except InputError as e:
        _check_input_error(e, "f.ngc", text)
        return "refused"
    check_job(job, "f.ngc")
    return "valid"


def gcode_file_target(data: bytes) -> str:
    p = _write("f.ngc", data)
    try:
        job = parse_gcode(read_job_text(p), p, START, (0.0, 0.0, 1.0))
    except InputError as e:
        _check_input_error(e, p)
        return "refused"
    check_job(job, p)
    return "valid"


# ---------------------------------------------------------------- CL data

_CLNUM = st.one_of(st.floats(-200, 200, allow_nan=False).map(lambda v: f"{v:.3f}"),
                   st.sampled_from(["1", "0", "-1", "0.7071", "nan", "inf", "1e400", "9" * 400, "1_0",
                                    "\uff11", "", "x", "1e5", "1e-400", "0x1"]))
_CLLINE = st.tuples(*[_CLNUM] * 6, st.sampled_from(["s", "w", "e", "S", "x", ""])).map(",".join)

def _short_cl():
    """The bundled CL file cut to its header and a short first pass (every 20th point, then its 'e')."""
    lines = (JOBS / "hemisphere.cl").read_text().split("\n")
    head = [ln for ln in lines[:10] if not ln[:1].isdigit() and not ln[:1] == "-"]
    pts = [ln for ln in lines if ln.endswith((",s", ",w"))]
    end = next(ln for ln in lines if ln.endswith(",e"))
    return ("\n".join(head + pts[:200:20] + [end]) + "\n").encode()


@st.composite
def _cl_passes(draw):
    """Structurally valid passes of unit tool axes, with a hostile number now and then."""
    out = []
    for _ in range(draw(st.integers(1, 3))):
        n = draw(st.integers(1, 4))
        for k in range(n):
            th = draw(st.floats(0, 0.6))
            ph = draw(st.floats(-3.2, 3.2))
            v = [math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)]
            cells = [f"{draw(st.floats(-100, 100)):.4f}" for _ in range(3)] + [f"{x:.6f}" for x in v]
            if draw(st.integers(0, 9)) == 0:
                cells[draw(st.integers(0, 5))] = draw(_CLNUM)
            flag = "s" if k == 0 else ("e" if k == n - 1 else "w")
            out.append(",".join(cells) + "," + (flag if n > 1 or k == 0 else "s"))
        if n == 1:
            out.append(out[-1][:-1] + "e")
    return "\n".join(out)


CL_TEXT = st.one_of(
    st.text(max_size=120),
    st.lists(_CLLINE, max_size=8).map("\n".join),
    _cl_passes(),
    mutated(_short_cl()).map(lambda b: b.decode("utf-8", errors="replace")),
)


def cl_target(text: str) -> str:
    try:
        cl = parse_cl(text, "f.cl")
    except InputError as e:
        _check_input_error(e, "f.cl", text)
        return "refused"
    _finite(cl.tip, cl.axis)
    assert np.all(np.abs(cl.tip) <= MAX_COORD_MM)
    assert np.allclose(np.linalg.norm(cl.axis, axis=1), 1.0) and np.all(cl.axis[:, 2] > 0)
    assert set(cl.flag) <= {"s", "w", "e"} and len(cl) >= 1
    return "valid"


# ---------------------------------------------------------------- TOML configs

_TOML_VALUES = st.sampled_from([
    '"0.5"', "true", "false", '"no"', '""', "0", "-1", "1e300", "-1e300", "inf", "nan", "-inf", "9" * 400,
    "9" * 20, "1.5", "[]", '["0.5", true, 0]', "[1, 2]", "[1, 2, 3]", "[1, 2, 3, 4, 5]", "[[1, 2, 3]]",
    "{a = 1}", "1979-05-27", '"low"', "0.0", "1e-300", "[" * 50 + "]" * 50, "99", "100", "20000", "10"])


@st.composite
def toml_mutated(draw, original: bytes):
    """Either a byte-level mutation, or one ``key = value`` line given a hostile value, or a key or
    table renamed."""
    kind = draw(st.sampled_from(["bytes", "value", "value", "rename"]))
    if kind == "bytes":
        return draw(mutated(original))
    lines = original.decode().split("\n")
    idx = [i for i, ln in enumerate(lines) if "=" in ln and not ln.lstrip().startswith("#")]
    tab = [i for i, ln in enumerate(lines) if ln.startswith("[")]
    if kind == "value":
        i = draw(st.sampled_from(idx))
        key = lines[i].split("=", 1)[0]
        lines[i] = f"{key}= {draw(_TOML_VALUES)}"
    else:
        i = draw(st.sampled_from(idx + tab))
        ln = lines[i]
        k = draw(st.integers(1, max(1, len(ln.split("=")[0].strip()) - 1)))
        lines[i] = ln[:k] + draw(st.sampled_from(["", "x", "_mm", "s"])) + ln[k + 1:]
    return "\n".join(lines).encode()


MACHINE_TOML = toml_mutated((CONFIG_DIR / "prototype.toml").read_bytes())
SERVICE_TOML = toml_mutated((CONFIG_DIR / "service.toml").read_bytes())


def _numbers_of(obj, depth=0):
    """Every number held in a (dataclass / dict / tuple / array) value."""
    if depth > 6:
        return
    if isinstance(obj, bool) or obj is None or isinstance(obj, str):
        return
    if isinstance(obj, (int, float, np.number)):
        yield float(obj)
    elif isinstance(obj, np.ndarray):
        yield from obj.astype(float).ravel().tolist()
    elif isinstance(obj, dict):
        for v in obj.values():
            yield from _numbers_of(v, depth + 1)
    elif isinstance(obj, (list, tuple)):
        for v in obj:
            yield from _numbers_of(v, depth + 1)
    elif hasattr(obj, "__dataclass_fields__"):
        for k in obj.__dataclass_fields__:
            yield from _numbers_of(getattr(obj, k), depth + 1)


def machine_target(data: bytes) -> str:
    p = _write("m.toml", data)
    try:
        m = load_machine(p)
    except ConfigError as e:
        assert e.path == str(p)
        return "refused"
    assert isinstance(m, Machine)
    nums = list(_numbers_of(m))
    assert nums and all(math.isfinite(v) and abs(v) <= 1e10 for v in nums)
    lim = m.limits
    assert lim.chain_length[0] > 0 and all(a < b for a, b in (lim.chain_length, lim.table_x, lim.table_y))
    assert np.all(lim.joint_speed > 0) and np.all(m.resolution.pulses_per_mm > 0)
    return "valid"


def service_target(data: bytes) -> str:
    p = _write("s.toml", data)
    try:
        cfg = load_service_config(p)
    except ConfigError as e:
        assert str(p) in str(e)
        return "refused"
    assert 10 <= cfg.loop.rate_hz <= 20000 and 1 <= cfg.loop.rt_priority <= 99
    assert isinstance(cfg.loop.realtime, bool) and isinstance(cfg.loop.lock_memory, bool)
    assert cfg.nc.kv_per_s * cfg.loop.dt < 1 and cfg.nc.pulse_mode in ("multi", "single")
    assert all(math.isfinite(v) for v in _numbers_of(cfg.loop))
    assert all(math.isfinite(v) and v >= 0 for v in _numbers_of(cfg.nc))
    from pmctl.hal import validate_options
    opts = validate_options(cfg.backend, cfg.backend_options, "x")
    nums = list(_numbers_of(opts))
    assert all(math.isfinite(v) for v in nums)
    if cfg.backend == "sim":
        assert isinstance(opts.flex, bool) and isinstance(opts.seed, int) and opts.seed >= 0
        assert opts.read_timeout_s > 0 and np.all(opts.mode_damping_ratio >= 0) and np.all(opts.mode_mass_kg > 0)
    return "valid"


# ---------------------------------------------------------------- recordings

def _small(rec: Path, rows=30):
    lines = (rec / "data.csv").read_bytes().split(b"\n")
    return (rec / "recording.json").read_bytes(), b"\n".join(lines[:rows + 1]) + b"\n"


_SMALL = [_small(r) for r in RECORDINGS]


@st.composite
def recording_mutated(draw):
    meta, data = draw(st.sampled_from(_SMALL))
    which = draw(st.sampled_from(["meta", "data", "data", "both"]))
    if which in ("meta", "both"):
        meta = draw(mutated(meta))
    if which in ("data", "both"):
        data = draw(mutated(data))
    return meta, data


RECORDING = recording_mutated()


def recording_target(files) -> str:
    meta, data = files
    d = _TMP / "rec"
    d.mkdir(exist_ok=True)
    (d / "recording.json").write_bytes(meta)
    (d / "data.csv").write_bytes(data)
    try:
        rec = read_recording(d)
    except (InputError, ConfigError) as e:
        assert str(d) in str(e)
        return "refused"
    assert rec.n >= 1
    for name, col in rec.columns.items():
        assert col.shape == (rec.n,) and not np.any(np.isinf(col)), name
    assert np.all(np.isfinite(rec.t)) and np.all(np.diff(rec.t) > 0)
    sr = rec.sample_rate_hz
    assert sr is None or (math.isfinite(sr) and sr > 0)
    return "valid"


# ---------------------------------------------------------------- the command line, in process

_ARG = st.one_of(st.sampled_from(["0,0,173", "0,0,1", "1e400,0,0", "nan,0,0", "inf,1,2", "0,0", "a,b,c", "", ",,",
                                  "-5,0,173", "300,300,300,0,0", "1" * 400 + ",0,0", "\uff11,0,0", "--json",
                                  "-1e308,0,1"]),
                 st.text(max_size=12))
# Every generated job is refused before motion: G-code starts with an unreachable pose (Z 1000 mm: the
# whole program is parsed, then every pose checked), CL data ends with a bad flag.
_UNREACHABLE = b"G0 X0 Y0 Z1000\n"


@st.composite
def cli_args(draw):
    """Arguments for commands that must fail (or answer) without moving anything."""
    kind = draw(st.sampled_from(["ik", "fk", "run", "config", "junk"]))
    if kind == "ik":
        return ["kin", "ik", "--tip", draw(_ARG), "--axis", draw(_ARG)] + draw(st.sampled_from([[], ["--json"]]))
    if kind == "fk":
        return ["kin", "fk", "--joints", draw(_ARG)] + draw(st.sampled_from([[], ["--json"]]))
    if kind == "config":
        p = _write("c.toml", draw(MACHINE_TOML))
        return ["kin", "ik", "--tip", "0,0,173", "--axis", "0,0,1", "--config", str(p)]
    if kind == "run":
        suffix = draw(st.sampled_from([".ngc", ".cl", ".tap", ".xyz", ""]))
        body = draw(GCODE_BYTES) if suffix != ".cl" else draw(mutated((JOBS / "hemisphere.cl").read_bytes()[:2000]))
        p = _write("job" + suffix, _UNREACHABLE + body if suffix != ".cl" else body + b"\n1,2,3,0,0,1,q\n")
        extra = draw(st.lists(st.sampled_from([["--rate", "nan"], ["--rate", "5"], ["--feed-override", "inf"],
                                               ["--k-theta", "-1"], ["--pulse-mode", "x"], ["--backend", "nope"],
                                               ["--service", str(p)], ["--config", "nope"]]), max_size=2))
        return ["run", "--no-realtime", "--quiet", "--state", "", "--job", str(p)] + [a for e in extra for a in e]
    return draw(st.lists(st.one_of(st.sampled_from(["kin", "run", "twin", "analyze", "--help", "-x", "ik",
                                                    "--version", "--config"]), _ARG), max_size=5))


def cli_target(argv) -> str:
    from pmctl.interfaces.cli import EXIT_INTERNAL, main
    err, out = io.StringIO(), io.StringIO()
    os.environ.pop("PMCTL_DEBUG", None)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            code = main(list(argv))
    except SystemExit as e:            # argparse: usage errors exit 2, --help/--version exit 0
        assert e.code in (0, 2), e.code
        return "refused" if e.code else "valid"
    text = err.getvalue()
    assert code != EXIT_INTERNAL and "Traceback" not in text, text
    if code == 0:
        return "valid"
    if code == 2 and not text:          # no command: the help, exit 2
        assert out.getvalue().startswith("usage: pmctl")
        return "refused"
    assert code == 1 and text.count("\n") == 1 and text.startswith("pmctl: error: "), (code, text)
    return "refused"


# ---------------------------------------------------------------- the planner on absurd but legal programs

_FEED = st.sampled_from(["0.0000001", "0.42", "1", "60", "600", "6000", "999999"])
PLANNER_PROGRAM = st.lists(st.one_of(
    st.tuples(st.sampled_from(["G1", "G0"]), st.integers(-30, 30), st.integers(-30, 30), _FEED)
      .map(lambda t: f"{t[0]} X{t[1]} Y{t[2]} F{t[3]}"),
    st.tuples(st.sampled_from(["G2", "G3"]), st.integers(1, 20), st.integers(1, 1000), _FEED)
      .map(lambda t: f"G0 X{t[1]} Y0\n{t[0]} X{t[1]} Y0 I-{t[1]} J0 P{t[2]} F{t[3]}"),
    st.sampled_from(["0", "0.001", "1", "100", "3600"]).map(lambda p: f"G4 P{p}")), min_size=1, max_size=4)
PLANNER_BOUND = 30_000        # MAX_SAMPLES and MAX_GRID_POINTS while fuzzing (keeps each example fast)
_MACHINE = None


def planner_target(lines) -> str:
    global _MACHINE
    from pmctl.task import planner as P
    _MACHINE = _MACHINE or load_machine()
    job = parse_gcode("G0 X0 Y0 Z70\n" + "\n".join(lines), "p.ngc", *P.home_pose(_MACHINE))
    saved = P.MAX_SAMPLES, P.MAX_GRID_POINTS
    P.MAX_SAMPLES = P.MAX_GRID_POINTS = PLANNER_BOUND
    try:
        traj = P.plan(job, _MACHINE, 1e-3)
    except PmctlError as e:
        assert "p.ngc" in str(e)
        return "refused"
    finally:
        P.MAX_SAMPLES, P.MAX_GRID_POINTS = saved
    assert len(traj) <= PLANNER_BOUND
    _finite(traj.tip, traj.axis, traj.tip_vel, traj.axis_vel, traj.spindle_rpm)
    return "valid"


TARGETS = {
    "gcode": (GCODE_TEXT, gcode_target),
    "gcode-file": (GCODE_BYTES, gcode_file_target),
    "cldata": (CL_TEXT, cl_target),
    "machine-config": (MACHINE_TOML, machine_target),
    "service-config": (SERVICE_TOML, service_target),
    "recording": (RECORDING, recording_target),
    "cli": (cli_args(), cli_target),
    "planner": (PLANNER_PROGRAM, planner_target),
}


# ---------------------------------------------------------------- shared by the tests/test_fuzz_*.py files

FUZZ = settings(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                                      HealthCheck.filter_too_much])


def check(name, x):
    """Run target ``name`` on input x: a clean refusal or a valid result, never another exception."""
    outcome = TARGETS[name][1](x)            # raises on anything but a clean refusal or a valid result
    assert outcome in ("valid", "refused")
    event(outcome)
