#!/usr/bin/env python3
"""Mutation testing of the safety modules with mutmut (the ``[mutation]`` extra), group by group.

A group is one safety rule set: the functions that carry it (mutmut's names: ``x_<function>``,
``xǁ<Class>ǁ<method>``), in one or more modules, and the quick tests that guard them. Inside a long
function that does more than the rule (the control loop's ``run``, the NC tick, the twin's
``unexplained``) the group names *spans*: the lines between two anchor texts; only mutants that
change lines inside a span are judged, the rest of the function is out of the group's scope (said
in the table as ``out of scope``). Messages and report texts outside the rule are out of scope the
same way.

For each group the repository (the working tree, or ``--ref``) is copied into a scratch folder, its
C extensions are built there, a ``[tool.mutmut]`` table for the group is written into the copy's
pyproject.toml, mutmut generates the mutants, this script picks those in the group's scope, and
``mutmut run`` runs each one against the tests that reach its function (mutmut learns which tests
call which function in a first, traced run of the group's tests: its per-mutant test selection).
The table at the end is the kill rate per group: killed / (killed + survived + no test reaches it),
timeouts and segfaults counted as killed.

    pip install -e '.[test,mutation]'
    .venv/bin/python tools/mutation/run_mutmut.py                       # every group
    .venv/bin/python tools/mutation/run_mutmut.py --group nc,bridge      # some
    .venv/bin/python tools/mutation/run_mutmut.py --list                 # the groups, their scope and tests
    .venv/bin/python tools/mutation/run_mutmut.py --ref main --json before.json   # main's tests
    .venv/bin/python tools/mutation/run_mutmut.py --group nc --survivors  # what survived, with diffs
    .venv/bin/python tools/mutation/run_mutmut.py --group loop --work /tmp/mm --resume   # go on after a stop

Not part of CI: a group takes minutes to an hour on two cores. mutmut switches mutants inside the
test process, so code that only runs in a child process (the rt process of ``pmctl run`` and
``pmctl serve``, the console behind a pty) is out of its reach: the groups' tests drive those
functions in-process, and tools/mutation/hand_mutants.py keeps listed mutants of what only a real
process (or the C code) exercises. Survivors that are equivalent (no test can tell them from the
original) are explained in tools/mutation/EQUIVALENT.md.
"""

from __future__ import annotations

import argparse
import ast
import difflib
import fnmatch
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from hand_mutants import ROOT, _copy_tree  # noqa: E402


@dataclass(frozen=True)
class Target:
    """Functions of one module: ``funcs`` mutmut name globs judged whole; ``spans`` {name: [(first
    line's anchor text, last line's anchor text), ...]} judged only inside those lines, less the
    lines holding a ``skip`` text (bookkeeping inside a span: timing statistics)."""
    module: str
    funcs: tuple = ()
    spans: dict = field(default_factory=dict)
    skip: tuple = ()


@dataclass(frozen=True)
class Group:
    targets: tuple
    tests: tuple                 # test files (run once per mutant, those that reach its function)
    kexpr: str | None = None     # a pytest -k expression over them
    what: str = ""               # the rules, for the README's table and --list


NC, TS, LOOP, PROBE = ("src/pmctl/motion/nc.py", "src/pmctl/motion/timescale.py", "src/pmctl/motion/loop.py",
                       "src/pmctl/motion/probe.py")
GRBL = "src/pmctl/interfaces/console/grbl.py"

GROUPS = {
    "nc": Group(
        (Target(NC, ("x__stopping_violation", "x__ferror_violation", "x__nonfinite_feedback", "x__limit_rates_l",
                     "x__slew_offset"),
                {"x_nc_step": [("if state.mode in (HALTED, DONE):", "return zero, state"),
                               ("bad = _nonfinite_feedback(", "reason=fe)"),
                               ("if offset is not None and state.mode == RUN:", "off = _slew_offset("),
                               ("if perr > params.max_path_error_mm:", "mode, reason = STOPPING, tilt_text("),
                               ("if mode == STOPPING:", "qdot = _limit_rates_l(_ZERO5, prev, L)"),
                               ("if mode == STOPPING and not any(qdot):", "acc = np.zeros(5)")]}),),
        ("tests/motion/test_safety_nc.py", "tests/motion/test_nc.py", "tests/motion/test_ncore.py"),
        "not tick_for_tick and not same_pulses_with and not same_pulses_at_rest and not long_run "
        "and not bit_for_bit and not fk_equals_model_fk",
        "the NC's supervision: soft limits with the braking distance, following error, dead sensors, "
        "rate limits, the chain-offset slew; in nc_step the lines that apply them (halted/done, the "
        "faults, the path-error and tilt stops, braking to rest)"),
    "vf": Group((Target("src/pmctl/core/vf.py", ("x_vf_step", "x_vf_tick")),),
                ("tests/core/test_vf.py", "tests/motion/test_nc.py"), None,
                "the V-F converters (pulses, residue, saturation, the tie margin)"),
    "timescale": Group(
        (Target(TS, ("xǁTimeScalerǁstep", "xǁTimeScalerǁset_feed_override", "xǁTimeScalerǁset_rapid_override",
                     "xǁPathFollowerǁnext_target", "x_backward_pass", "x_sample_caps", "x_scaling_limits")),),
        ("tests/motion/test_safety_timescale.py", "tests/motion/test_follow.py",
         "tests/task/test_safety_hold.py", "tests/motion/test_timescale.py"),
        "not sigterm and not console and not memory",
        "sigma's rate and jerk limits, feed hold and overrides, caps, starvation, the backward pass"),
    "probe": Group(
        (Target(PROBE, ("xǁProbeMonitorǁtick", "xǁProbeMonitorǁ_contact", "xǁProbeMonitorǁ_arm",
                        "xǁProbeMonitorǁbound_mm", "xǁProbeMonitorǁ_effective_decel", "xǁProbeMonitorǁcancel",
                        "x_mark_probe_rows")),),
        ("tests/motion/test_safety_probe.py", "tests/motion/test_probe.py"), "not recorded_load and not serve_record and not pmctl_run",
        "stop on contact: tare, threshold and debounce, the stop's deceleration, the overtravel bound, "
        "the probing rows' feed cap"),
    "loop": Group(
        (Target(LOOP, ("x__was_stop", "x__executed"),
                {"xǁControlLoopǁrun": [("rest_rate = (", "rest_rate = ("),
                                       ("fb = be.read()", "stop_from_hold = True"),
                                       ("if positions:", "sent += pulses"),
                                       ("if self.quit:", "st = _stopping(st, why)"),
                                       ("if in_row >= cfg.max_overruns_in_row", "st = _stopping("),
                                       ("except Exception as e:", "st = _halt(st, reason)")],
                 "xǁControlLoopǁset_chain_offsets": [("for chain, mm in items:", "self.chain_offset = off")]},
                ("comp[w] = ",)),),
        ("tests/motion/test_safety_loop.py", "tests/motion/test_loop.py", "tests/hal/test_stall_hold.py", "tests/task/test_safety_hold.py"),
        "not bundled and not end_to_end and not k_theta and not tracks and not tracking and not restart_from "
        "and not survive_a_crash and not sigterm and not console",
        "the loop's stop rules: backend faults halt (counters follow the device), a stop request holds on "
        "the path then halts at rest, the job's end after settling, quit, stalls and missed deadlines stop, "
        "an unexpected error halts with the pending pulses uncounted; chain-offset inputs bounded"),
    "bridge": Group((Target("src/pmctl/hal/bridge_protocol.py", ("x_*", "xǁParserǁ*")),),
                    ("tests/hal/test_bridge_protocol.py", "tests/hal/test_safety_protocol.py", "tests/hal/test_safety_bridge.py"),
                    None, "framing, CRC, the parser, the codecs, the per-tick pulse limit"),
    "console": Group(
        (Target(GRBL, ("xǁGrblConsoleǁfeed", "xǁGrblConsoleǁ_override", "xǁGrblConsoleǁjog_cancel",
                       "xǁGrblConsoleǁstate"),
                {"xǁGrblConsoleǁsoft_reset": [("self._reset_gen += 1", "self.sup.spindle_override(1.0)")]}),),
        ("tests/interfaces/test_safety_console.py",), None,
        "the realtime bytes: status, hold (Run/Idle hold, Jog cancels), resume, soft reset (drops "
        "the lines and the queue, overrides back to 100 %), jog cancel, the overrides' steps and "
        "bounds, line assembly and the overlong line"),
    "planner": Group(
        (Target("src/pmctl/task/planner.py", ("x__violations", "x__check_samples", "x__check_reachable",
                                              "x__reach_problems")),),
        ("tests/task/test_safety_planner.py", "tests/task/test_safety_limits.py"), None,
        "the last check on the samples (joint and tip speed and acceleration), reachability of the "
        "programmed poses and of the path between them"),
    "swing": Group((Target("src/pmctl/core/kinematics.py", ("x_limit_violations",)),),
                   ("tests/core/test_safety_workspace.py", "tests/task/test_safety_limits.py", "tests/core/test_kinematics.py"), None,
                   "the workspace limits (tilt, chains, table, spherical-joint swing, platform above the base)"),
    "calibration": Group(
        (Target("src/pmctl/tools/calibrate/identify.py", ("x_analyse",),
                {"x_identify": [("n_ax = 0 if axis is None", "sigma = np.sqrt(np.maximum(np.diag(cov), 0.0))"),
                                ("var = np.einsum(", "res.predicted_axis_urad =")]}),),
        ("tests/tools/test_safety_calibration.py", "tests/tools/test_calibration.py"), None,
        "the identification's uncertainties: degrees of freedom, chi-square scaling, the identified "
        "directions (analyse), the predicted accuracy"),
    "twin": Group(
        (Target("src/pmctl/tools/twin/diagnose.py", ("x_accept", "x__passes", "x__share")),
         Target("src/pmctl/tools/twin/unexplained.py", (),
                {"x_unexplained": [("glob = excess >= EXCESS_MIN", "sig = _signatures(ctx, name, m, y, wins)"),
                                   ("if not glob or max(", "if not glob or max("),
                                   ("if max(v[0] for v in sw.values())", "if max(v[0] for v in sw.values())"),
                                   ("kind, frac, detail = \"broadband\", 0.0, None", "continue")]})),
        ("tests/tools/test_safety_twin.py", "tests/tools/test_twin_false_alarms.py"), "not clean_recording and not just_below",
        "the acceptance rule (accept: MIN_DSSE, REL_MIN, STRONG, the peak), the SHARE_MIN rule, and the "
        "unexplained block's no-structure rule (an excess without a structure is not reported)"),
}

# a revision without any of a group's test files (``--ref`` before they were written): the tests it had
FALLBACK = {
    "planner": (("tests/task/test_planner.py",), None),
    "twin": (("tests/tools/test_diagnose.py",), "clean_recording or concealed_effect"),
    "console": (("tests/interfaces/test_console.py",), None),
}

KILLED = {"killed", "timeout", "segfault", "caught by type check"}


def _module(path: str) -> str:
    return path[len("src/"):-len(".py")].replace("/", ".")


def _setup(work: Path, name: str, g: Group):
    """pyproject.toml of the copy: no xdist, the group's modules and tests."""
    pp = work / "pyproject.toml"
    text = pp.read_text()
    text = re.sub(r'^addopts = .*$', 'addopts = "-p no:cacheprovider"', text, flags=re.M)
    tests, kexpr = g.tests, g.kexpr
    sel = [t for t in tests if (work / t).exists()]
    if not sel and name in FALLBACK:             # a revision without the group's own test files
        tests, kexpr = FALLBACK[name]
        sel = [t for t in tests if (work / t).exists()]
    if not sel:
        raise RuntimeError(f"group {name}: none of its test files {list(tests)} is in the copy")
    if kexpr:
        sel += ["-k", kexpr]
    with (work / "tests" / "conftest.py").open("a") as f:
        f.write(ORDER_HOOK)
    text += ("\n[tool.mutmut]\n"
             'source_paths = ["src"]\n'
             f"only_mutate = {json.dumps(sorted({t.module for t in g.targets}))}\n"
             f"pytest_add_cli_args_test_selection = {json.dumps(sel)}\n"
             'also_copy = ["config", "examples", "firmware_bridge", "setup.py", "src/pmctl/config"]\n')
    pp.write_text(text)
    return sel


# added to the copy's tests/conftest.py: under mutmut (which runs each mutant's tests with -x), the
# quickest tests first, by the durations of its traced run, so that a mutant dies at its cheapest test
ORDER_HOOK = """

def pytest_collection_modifyitems(session, config, items):      # tools/mutation/run_mutmut.py
    import json as _json
    import os as _os
    if not _os.environ.get("MUTANT_UNDER_TEST"):
        return
    try:
        with open("mutmut-stats.json") as _f:
            _d = _json.load(_f)["duration_by_test"]
    except (OSError, ValueError, KeyError):
        return
    items.sort(key=lambda it: _d.get(it.nodeid, _d.get("mutants/" + it.nodeid, 1e9)))
"""


# ---------------------------------------------------------------- the group's scope (run inside the copy)

def _function_lines(source: str, key: str) -> tuple[int, int]:
    """(def line, last line) of mutmut's function key (x_f or xǁCǁm) in a module's source."""
    if "ǁ" in key:
        _, cls, fn = key.split("ǁ")
    else:
        cls, fn = None, key[2:]
    tree = ast.parse(source)
    body = tree.body
    if cls:
        body = next((n.body for n in body if isinstance(n, ast.ClassDef) and n.name == cls), [])
    for n in body:
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and n.name == fn:
            return n.lineno, n.end_lineno
    raise RuntimeError(f"{key}: no such function")


def _span_lines(source: str, key: str, spans, skip=()) -> set[int]:
    """File lines (1-based) inside the spans of a function: each from the one line of the function
    holding its first anchor to the next line holding its last; lines holding a ``skip`` text left out."""
    lo, hi = _function_lines(source, key)
    lines = source.splitlines()
    out = set()
    for a, b in spans:
        first = [i for i in range(lo, hi + 1) if a in lines[i - 1]]
        if len(first) != 1:
            raise RuntimeError(f"{key}: the span anchor {a!r} occurs {len(first)} times in the function "
                               f"(the source changed: update GROUPS)")
        last = [i for i in range(first[0], hi + 1) if b in lines[i - 1]]
        if not last:
            raise RuntimeError(f"{key}: the span's end {b!r} is not after {a!r}")
        out.update(i for i in range(first[0], last[0] + 1) if not any(t in lines[i - 1] for t in skip))
    return out


def _select_in_copy(spec: dict) -> dict:
    """In the copy (cwd): generate the mutants as ``mutmut run`` does, and pick the group's."""
    import libcst as cst
    import mutmut.__main__ as mm
    from mutmut.mutation.data import SourceFileMutationData
    from mutmut.mutation.diff_apply import read_functions_from_index
    os.makedirs("mutants", exist_ok=True)
    mm.copy_src_dir()
    mm.copy_also_copy_files()
    mm.setup_source_paths()
    mm.create_mutants(1)
    chosen, out_of_scope, per_fn = [], 0, {}
    for t in spec["targets"]:
        path = Path(t["module"])
        source = path.read_text()
        d = SourceFileMutationData(path=path)
        d.load()
        span_sets = {k: _span_lines(source, k, v, t["skip"]) for k, v in t["spans"].items()}
        for key in d.exit_code_by_key:
            fn = key.partition("__mutmut_")[0].rpartition(".")[2]
            whole = any(fnmatch.fnmatchcase(fn, g) for g in t["funcs"])
            if not whole and fn not in span_sets:
                continue
            if not whole:
                pair = read_functions_from_index(key, path)
                a, b = (cst.Module([f]).code.splitlines() for f in pair)
                def_i = next(i for i, ln in enumerate(a) if re.match(r"\s*(async\s+)?def\s", ln))
                def_line = _function_lines(source, fn)[0]
                changed = set()
                for tag, i1, i2, _, _ in difflib.SequenceMatcher(None, a, b, autojunk=False).get_opcodes():
                    if tag != "equal":
                        changed.update(range(i1, max(i2, i1 + 1)))
                lines = {def_line + i - def_i for i in changed}
                if not lines or not lines <= span_sets[fn]:
                    out_of_scope += 1
                    continue
            chosen.append(key)
            per_fn[fn] = per_fn.get(fn, 0) + 1
    return {"chosen": chosen, "out_of_scope": out_of_scope, "per_function": per_fn}


def _select(work: Path, g: Group) -> dict:
    spec = {"targets": [{"module": t.module, "funcs": list(t.funcs), "skip": list(t.skip),
                         "spans": {k: [list(s) for s in v] for k, v in t.spans.items()}} for t in g.targets]}
    out = work / "scope.json"
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)
    r = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--_select", json.dumps(spec), str(out)],
                       cwd=work, capture_output=True, text=True, env=env)
    if r.returncode:
        raise RuntimeError(f"choosing the mutants failed:\n{r.stdout[-3000:]}{r.stderr[-3000:]}")
    return json.loads(out.read_text())


# ---------------------------------------------------------------- running

def _results(work: Path) -> dict[str, str]:
    r = subprocess.run([sys.executable, "-m", "mutmut", "results", "--all", "true"], cwd=work,
                       capture_output=True, text=True)
    out = {}
    for ln in r.stdout.splitlines():
        if ":" in ln:
            name, status = ln.strip().rsplit(":", 1)
            out[name.strip()] = status.strip()
    return out


def _base(work_root: Path, ref: str | None) -> Path:
    """The copy (of the working tree or ``ref``) with its C extensions built, once per run; each group
    starts from a copy of it."""
    base = work_root / "_base"
    mark = _fingerprint(ref)
    if not (base / ".built").exists() or (base / ".built").read_text() != mark:   # (a --work folder reused)
        if base.exists():
            shutil.rmtree(base)
        base.mkdir(parents=True)
        _copy_tree(ROOT, base, ref)
        r = subprocess.run([sys.executable, "setup.py", "-q", "build_ext", "--inplace"], cwd=base,
                           capture_output=True, text=True)
        if r.returncode:
            raise RuntimeError(r.stderr[-2000:])
        shutil.rmtree(base / "build", ignore_errors=True)
        (base / ".built").write_text(mark)
    return base


def _fingerprint(ref: str | None) -> str:
    """What the copy is of: the revision ``ref``, or HEAD with a hash of the working tree's changes and
    untracked files (a reused scratch folder is copied again when the tests or the code changed)."""
    def git(*a):
        return subprocess.run(["git", "-C", str(ROOT), *a], check=True, capture_output=True).stdout
    if ref:
        return "ref " + git("rev-parse", ref).decode().strip()
    import hashlib
    h = hashlib.sha256(git("diff", "HEAD", "--binary"))
    for f in sorted(git("ls-files", "-z", "--others", "--exclude-standard").split(b"\0")):
        if f and (ROOT / f.decode()).is_file():
            h.update(f + b"\0" + (ROOT / f.decode()).read_bytes())
    return f"working tree {git('rev-parse', 'HEAD').decode().strip()} {h.hexdigest()}"


def run_group(name: str, ref: str | None, work_root: Path, max_children: int, survivors: bool,
              resume: bool = False, dry: bool = False, only=None) -> dict:
    """One group: its mutants in scope (or those ``only(name)`` takes), run; the counts and the survivors."""
    g = GROUPS[name]
    work = work_root / name
    t0 = time.monotonic()
    fresh = not (resume and (work / "scope.json").exists())
    if fresh:
        if work.exists():
            shutil.rmtree(work)
        shutil.copytree(_base(work_root, ref), work, symlinks=True)
        _setup(work, name, g)
        scope = _select(work, g)
        (work / "scope.json").write_text(json.dumps(scope))
    else:
        scope = json.loads((work / "scope.json").read_text())
    sel = json.loads(re.search(r"^pytest_add_cli_args_test_selection = (.*)$", (work / "pyproject.toml").read_text(),
                               re.M).group(1))
    chosen = scope["chosen"] if only is None else [m for m in scope["chosen"] if only(m)]
    todo = [] if dry else chosen
    if not fresh:
        done = _results(work)
        todo = [m for m in chosen if done.get(m, "not checked") == "not checked"]
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)
    with (work_root / f"{name}.log").open("a") as log:
        # in batches: a command line of a few hundred names stays short, and a stop loses little
        for i in range(0, len(todo), 200):
            subprocess.run([sys.executable, "-m", "mutmut", "run", "--max-children", str(max_children),
                            *todo[i:i + 200]], cwd=work, stdout=log, stderr=subprocess.STDOUT, env=env)
    secs = time.monotonic() - t0
    allres = _results(work)
    res = {k: allres.get(k, "not checked") for k in chosen}
    counts = {}
    for st in res.values():
        counts[st] = counts.get(st, 0) + 1
    killed = sum(v for k, v in counts.items() if k in KILLED)
    judged = sum(v for k, v in counts.items() if k not in ("not checked", "skipped"))
    out = {"group": name, "modules": [t.module for t in g.targets], "tests": sel, "mutants": len(res),
           "out_of_scope": scope["out_of_scope"], "per_function": scope["per_function"], "counts": counts,
           "killed": killed, "judged": judged, "rate": killed / judged if judged else None,
           "seconds": round(secs), "survived": sorted(k for k, v in res.items() if v not in KILLED),
           "statuses": res, "in_scope": scope["chosen"]}
    if survivors:
        diffs = {}
        for m in out["survived"]:
            d = subprocess.run([sys.executable, "-m", "mutmut", "show", m], cwd=work, capture_output=True, text=True)
            diffs[m] = d.stdout
        out["diffs"] = diffs
    return out


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--_select"]:          # internal: run inside a copy by _select
        Path(argv[2]).write_text(json.dumps(_select_in_copy(json.loads(argv[1]))))
        return 0
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--group", default="", help=f"comma-separated groups (default all: {', '.join(GROUPS)})")
    ap.add_argument("--ref", default=None, help="a git revision to copy instead of the working tree (e.g. main)")
    ap.add_argument("--work", default=None, help="scratch folder (kept; default: a temporary one, removed)")
    ap.add_argument("--resume", action="store_true",
                    help="with --work: go on with the mutants a stopped run of the same folder left unjudged")
    ap.add_argument("--max-children", type=int, default=2)
    ap.add_argument("--json", default=None, help="write the results here")
    ap.add_argument("--survivors", action="store_true", help="print each survivor's diff")
    ap.add_argument("--list", action="store_true", help="print each group's scope and tests and exit")
    ap.add_argument("--rerun", default=None, metavar="JSON",
                    help="run only the survivors of an earlier run's --json file (tests added since); the "
                         "table counts its killed ones as killed")
    ap.add_argument("--dry-run", action="store_true", help="make the mutants and count those in scope; run nothing")
    a = ap.parse_args(argv)
    names = [g for g in (a.group.split(",") if a.group else GROUPS)]
    for g in names:
        if g not in GROUPS:
            ap.error(f"unknown group {g!r}; groups: {', '.join(GROUPS)}")
    if a.resume and not a.work:
        ap.error("--resume needs --work (the folder of the stopped run)")
    if a.list:
        for n in names:
            g = GROUPS[n]
            print(f"{n}: {g.what}")
            for t in g.targets:
                print(f"  {t.module}: " + ", ".join(list(t.funcs) + [f"{k} (lines {', '.join(a for a, _ in v)} ...)"
                                                                     for k, v in t.spans.items()]))
            print("  tests: " + " ".join(g.tests) + (f" -k '{g.kexpr}'" if g.kexpr else ""))
        return 0
    root = Path(a.work) if a.work else Path(tempfile.mkdtemp(prefix="pmctl-mutmut-"))
    root.mkdir(parents=True, exist_ok=True)
    results = []
    before = {r["group"]: r for r in json.loads(Path(a.rerun).read_text())} if a.rerun else {}
    try:
        for g in names:
            only = None
            if a.rerun:
                if g not in before:
                    ap.error(f"{a.rerun} has no group {g}")
                surv, known = set(before[g]["survived"]), set(before[g]["statuses"])
                only = lambda m, surv=surv, known=known: m in surv or m not in known      # noqa: E731
            r = run_group(g, a.ref, root, a.max_children, a.survivors, a.resume, a.dry_run, only)
            if a.rerun:            # the earlier run's kills stand (tests were only added)
                p = before[g]
                r["statuses"] = {m: r["statuses"].get(m, p["statuses"].get(m, "not checked")) for m in r["in_scope"]}
                r["counts"] = {}
                for st in r["statuses"].values():
                    r["counts"][st] = r["counts"].get(st, 0) + 1
                r["killed"] = sum(v for k, v in r["counts"].items() if k in KILLED)
                r["judged"] = sum(v for k, v in r["counts"].items() if k not in ("not checked", "skipped"))
                r["rate"] = r["killed"] / r["judged"] if r["judged"] else None
                r["survived"] = sorted(k for k, v in r["statuses"].items() if v not in KILLED)
                r["mutants"], r["rerun_of"] = len(r["in_scope"]), a.rerun
                r["seconds_total"] = p.get("seconds_total", p["seconds"]) + r["seconds"]
            results.append(r)
            rate = "-" if r["rate"] is None else f"{100 * r['rate']:.0f} %"
            print(f"{g:12s} {r['killed']:4d}/{r['judged']:<4d} {rate:>6s}  {r['seconds']:5d} s  {r['counts']}"
                  f"  ({r['out_of_scope']} out of scope)", flush=True)
            if a.dry_run:
                print("  in scope: " + ", ".join(f"{k} {v}" for k, v in r["per_function"].items()))
            if a.survivors:
                for m in r["survived"]:
                    print(r["diffs"].get(m, m))
            if a.json:
                Path(a.json).write_text(json.dumps(results, indent=1))
    finally:
        if not a.work:
            shutil.rmtree(root, ignore_errors=True)
    k = sum(r["killed"] for r in results)
    n = sum(r["judged"] for r in results)
    print(f"{'all':12s} {k:4d}/{n:<4d} {100 * k / n if n else 0:5.0f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
