"""``pmctl twin import SRC OUT_DIR``: what users have, as a recording of independent axes
(``"machine": "axes"``, docs/recording.md "Generic axes").

Sources (``--format``, else told by the file):

- ``csv``: a table with a header row; comma, tab, semicolon or blanks between cells; ``#`` lines
  are comments. Columns are named by ``--map`` (``cmd_X=pos_ref,enc_X=pos_act``; a 1-based column
  number works too);
- ``halsampler``: LinuxCNC's ``halsampler`` output, one line of blank-separated numbers per sample
  in the order of the sampler's pins (``--map cmd_X=1,enc_X=2``), with the sample number first when
  it was run with ``-t`` (found by itself: a first column counting 0, 1, 2, ...). The sample
  period is the thread's: ``--rate HZ``;
- ``halscope``: halscope's saved log (``Sampling period is N ns``, then per sample ``LABEL value``
  pairs); ``--map`` names the labels or their 1-based order;
- ``mat``: a MATLAB .mat file (up to v7.2; scipy.io): ``--map`` names variables, each a vector
  of the same length;
- ``klipper``: Klipper's raw accelerometer CSV (``#time,accel_x,accel_y,accel_z``, mm/s²): becomes
  ``acc_X``, ``acc_Y``, ``acc_Z`` with the command of each axis held at 0 (Klipper does not log
  it). A resonance PSD (``freq,psd_x,...``) is a spectrum, not a time series: ``pmctl analyze
  resonance FILE`` reads it.

A map entry may scale its source: ``effort_X=vir*gtau`` (a number, or in a .mat file a scalar
variable: the EMPS bench's drive gain), ``cmd_X=pos/1000``. Units go in ``--unit CH=UNIT`` (or
``--unit CH=UNIT,CH=UNIT``) and are written into the notes, converted when the recording is read.
Time: ``--time COLUMN`` (with ``--time-unit``), else ``--rate HZ``. Everything is checked before
anything is written; an error names the source file, its line or the option.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from pmctl.core.errors import InputError, PmctlError
from pmctl.core.recording import write_recording
from pmctl.core.recording_axes import axes_machine, axis_of, channel_kind

FORMATS = ("csv", "halsampler", "halscope", "mat", "klipper")
_EXPR = re.compile(r"^\s*([^*/]+?)\s*(?:([*/])\s*([^*/]+?)\s*)?$")


def parse_pairs(items, what) -> dict:
    """``["a=b,c=d", "e=f"]`` -> {"a": "b", "c": "d", "e": "f"}; PmctlError naming the option."""
    out = {}
    for item in items or []:
        for part in str(item).split(","):
            if not part.strip():
                continue
            if "=" not in part:
                raise PmctlError(f"{what} {part!r}: expected CHANNEL=VALUE")
            k, v = (x.strip() for x in part.split("=", 1))
            if not k or not v:
                raise PmctlError(f"{what} {part!r}: expected CHANNEL=VALUE")
            if k in out:
                raise PmctlError(f"{what}: {k} given twice")
            out[k] = v
    return out


def detect_format(src: Path) -> str:
    if src.suffix.lower() == ".mat":
        return "mat"
    try:
        with open(src, "rb") as fh:
            head = fh.read(4096).decode("utf-8", errors="replace")
    except OSError as e:
        raise InputError(src, None, f"cannot read: {e.strerror or e}") from None
    first = next((ln for ln in head.splitlines() if ln.strip()), "")
    if first.lstrip("#").strip().startswith(("time,accel_x", "freq,psd_x")):
        return "klipper"
    if first.startswith("Sampling period is"):
        return "halscope"
    cells = first.replace(",", " ").replace(";", " ").replace("\t", " ").split()
    if cells and all(_num(c) for c in cells) and not first.startswith("#"):
        return "halsampler"
    return "csv"


def _num(s) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


# ---------------------------------------------------------------- readers: (columns by source name, row line numbers)

def read_table(src: Path):
    """A CSV/TSV with a header row -> ({column: values}, [names], first data line)."""
    text = _text(src)
    lines = text.splitlines()
    hi = next((i for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")), None)
    if hi is None:
        raise InputError(src, 1, "no header row")
    head = lines[hi]
    delim = next((d for d in ("\t", ";", ",") if d in head), None)

    def split(ln):
        return [c.strip().strip('"') for c in (ln.split(delim) if delim else ln.split())]
    names = split(head)
    if all(_num(c) for c in names):
        raise InputError(src, hi + 1, "the first row is numbers: a CSV needs a header row naming its columns "
                                      "(for a headerless log use --format halsampler and column numbers)")
    rows = []
    for k, ln in enumerate(lines[hi + 1:], hi + 2):
        if not ln.strip() or ln.lstrip().startswith("#"):
            continue
        cells = split(ln)
        if len(cells) != len(names):
            raise InputError(src, k, f"row has {len(cells)} cells, the header has {len(names)}")
        rows.append((k, cells))
    return _columns(src, names, rows), names


def _columns(src, names, rows):
    data = {n: np.empty(len(rows)) for n in names}
    for r, (k, cells) in enumerate(rows):
        for n, c in zip(names, cells):
            if c == "" or c.lower() == "nan":
                data[n][r] = math.nan
                continue
            try:
                data[n][r] = float(c)
            except ValueError:
                raise InputError(src, k, f"column {n!r}: {c!r} is not a number") from None
    return data


def _text(src):
    try:
        return Path(src).read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(src, None, f"cannot read: {getattr(e, 'strerror', None) or e}") from None


def read_halsampler(src: Path):
    """halsampler's lines -> ({"1": ..., "2": ...}, names); the -t sample number, when there, as
    "sample" (not counted among the numbered columns)."""
    rows = []
    for k, ln in enumerate(_text(src).splitlines(), 1):
        if not ln.strip() or ln.lstrip().startswith("#"):
            continue
        rows.append((k, ln.split()))
    if not rows:
        raise InputError(src, 1, "no samples")
    n = len(rows[0][1])
    for k, cells in rows:
        if len(cells) != n:
            raise InputError(src, k, f"line has {len(cells)} values, the first has {n}")
    names = [str(j) for j in range(1, n + 1)]
    cols = _columns(src, names, rows)
    first = cols["1"]
    if n > 1 and len(first) > 2 and np.all(np.diff(first) == 1) and float(first[0]).is_integer():
        cols = {"sample": first, **{str(j - 1): cols[str(j)] for j in range(2, n + 1)}}
        names = ["sample"] + [str(j) for j in range(1, n)]
    return cols, names


def read_halscope(src: Path):
    """halscope's log -> ({label: values, "1": ...}, names, sample period in s)."""
    lines = _text(src).splitlines()
    m = re.match(r"\s*Sampling period is\s+([0-9.eE+-]+)\s*ns", lines[0] if lines else "")
    if not m:
        raise InputError(src, 1, "not a halscope log: expected 'Sampling period is N ns' on its first line")
    period = float(m.group(1)) * 1e-9
    labels, rows = None, []
    for k, ln in enumerate(lines[1:], 2):
        tok = ln.split()
        if not tok:
            continue
        if len(tok) % 2:
            raise InputError(src, k, "expected LABEL value pairs")
        lab, vals = tok[0::2], tok[1::2]
        if labels is None:
            labels = lab
        elif lab != labels:
            raise InputError(src, k, f"labels {lab} differ from the first sample's {labels}")
        rows.append((k, vals))
    if not rows:
        raise InputError(src, 2, "no samples")
    cols = _columns(src, labels, rows)
    for j, lab in enumerate(labels, 1):
        cols[str(j)] = cols[lab]
    return cols, labels, period


def read_mat(src: Path):
    """A .mat file's vectors (and scalars, for scale factors) -> ({name: array}, names)."""
    from scipy import io as sio
    try:
        d = sio.loadmat(str(src), squeeze_me=True)
    except NotImplementedError:
        raise InputError(src, None, "a MATLAB v7.3 file (HDF5) is not supported: save it with -v7 in MATLAB") from None
    except (OSError, ValueError, TypeError) as e:
        raise InputError(src, None, f"not a readable .mat file: {e}") from None
    out = {}
    for k, v in d.items():
        if k.startswith("__"):
            continue
        a = np.asarray(v)
        if a.dtype.kind in "fiub" and a.ndim <= 1:
            out[k] = a.astype(float)
    return out, list(out)


# ---------------------------------------------------------------- the import

def _resolve(expr, cols, src, channel):
    m = _EXPR.match(expr)
    if not m:
        raise PmctlError(f"--map {channel}={expr}: expected SOURCE, SOURCE*FACTOR or SOURCE/FACTOR")
    name, op, fac = m.group(1), m.group(2), m.group(3)
    if name not in cols:
        shown = ", ".join(list(cols)[:12]) + (" ..." if len(cols) > 12 else "")
        raise InputError(src, None, f"--map {channel}={expr}: no column or variable {name!r} (there are: {shown})")
    x = np.asarray(cols[name], float)
    if x.ndim != 1 or x.size < 2:
        raise InputError(src, None, f"--map {channel}={expr}: {name!r} is not a series of samples")
    if op:
        if _num(fac):
            k = float(fac)
        elif fac in cols and np.asarray(cols[fac]).size == 1:
            k = float(np.asarray(cols[fac]).reshape(-1)[0])
        else:
            raise InputError(src, None, f"--map {channel}={expr}: {fac!r} is neither a number nor a scalar of the file")
        if op == "/" and k == 0:
            raise PmctlError(f"--map {channel}={expr}: division by zero")
        x = x * k if op == "*" else x / k
    return x


def import_source(src, out, *, fmt=None, mapping=None, units=None, time=None, time_unit=None, rate=None,
                  overwrite=False) -> tuple[Path, dict]:
    """Convert ``src`` into the recording folder ``out``. Returns (folder, summary)."""
    src = Path(src)
    if not src.is_file():
        raise InputError(src, None, "no such file")
    fmt = fmt or detect_format(src)
    if fmt not in FORMATS:
        raise PmctlError(f"--format {fmt}: one of {', '.join(FORMATS)}")
    mapping = dict(mapping or {})
    units = dict(units or {})
    period = None
    if fmt == "klipper":
        from pmctl.tools.analysis.resonance import read_accel_csv
        kind, d = read_accel_csv(src)
        if kind != "raw":
            raise InputError(src, 1, "a Klipper resonance PSD is a spectrum, not a time series: "
                                     "read it with  pmctl analyze resonance " + str(src))
        cols = {"time": d["t"] - d["t"][0], "accel_x": d["x"], "accel_y": d["y"], "accel_z": d["z"]}
        mapping = mapping or {"acc_X": "accel_x", "acc_Y": "accel_y", "acc_Z": "accel_z"}
        time = time or "time"
        for ch in mapping:
            units.setdefault(ch, "mm/s^2")
    elif fmt == "csv":
        cols, names = read_table(src)
        for j, n in enumerate(names, 1):
            cols.setdefault(str(j), cols[n])
    elif fmt == "halsampler":
        cols, _ = read_halsampler(src)
    elif fmt == "halscope":
        cols, _, period = read_halscope(src)
    else:
        cols, _ = read_mat(src)
    if not mapping:
        raise PmctlError("--map: name at least the commanded position, e.g. --map cmd_X=COLUMN,enc_X=COLUMN")
    for ch in mapping:
        if channel_kind(ch) in (None, "time"):
            raise PmctlError(f"--map {ch}=...: not a channel of a recording of independent axes "
                             "(cmd_<A>, enc_<A>, load_<A>, effort_<A>, acc_<A>, temp_<name>)")
    data = {ch: _resolve(expr, cols, src, ch) for ch, expr in mapping.items()}
    n = {len(v) for v in data.values()}
    if len(n) != 1:
        raise InputError(src, None, "--map: the mapped series differ in length "
                                    + ", ".join(f"{k} {len(v)}" for k, v in data.items()))
    n = n.pop()
    axes = sorted({axis_of(ch) for ch in data if axis_of(ch)})
    for a in axes:                    # an accelerometer log has no command: held at 0, and said so
        if f"cmd_{a}" not in data:
            if fmt != "klipper":
                raise PmctlError(f"--map: axis {a} needs its commanded position cmd_{a}")
            data[f"cmd_{a}"] = np.zeros(n)
    notes = {ch: {"source": f"{src.name}: {mapping[ch]}" if ch in mapping else
                  "not logged (Klipper's accelerometer log has no commanded position): held at 0"}
             for ch in data}
    for ch, u in units.items():
        if ch not in data and ch != "t":
            raise PmctlError(f"--unit {ch}={u}: {ch} is not mapped")
        notes.setdefault(ch, {})["unit"] = u
    if time is not None:
        t = _resolve(time, cols, src, "t")
        if len(t) != n:
            raise InputError(src, None, f"--time {time}: {len(t)} samples, the mapped series have {n}")
        if time_unit:
            notes.setdefault("t", {})["unit"] = time_unit
    else:
        if rate is None and period is None and "sample" not in cols:
            raise PmctlError("no time: give --time COLUMN, or --rate HZ (the log's sample rate)")
        dt = 1.0 / rate if rate else period
        if dt is None:
            raise PmctlError("--rate HZ: the thread's rate, to turn halsampler's sample numbers into time")
        idx = cols["sample"] - cols["sample"][0] if "sample" in cols and fmt == "halsampler" else np.arange(n)
        t = idx * dt
    good = np.isfinite(t)
    if not good.all():
        raise InputError(src, None, f"the time has {int((~good).sum())} empty cells")
    d = np.diff(t)
    if np.any(d <= 0):
        raise InputError(src, None, f"the time is not strictly increasing (sample {int(np.argmax(d <= 0)) + 2})")
    # the units, checked before anything is written (the reader converts them)
    axes_machine(["t"] + list(data), {"channels": notes})
    cols_out = {"t": t, **data}
    sr = float(1.0 / np.median(d)) if len(d) else 1.0
    if "t" in notes and "unit" in notes["t"]:
        from pmctl.core.recording_axes import TIME, _norm
        sr = sr / TIME.get(_norm(notes["t"]["unit"]), 1.0)
    folder = write_recording(out, cols_out, machine="axes", sample_rate_hz=sr,
                             description=f"imported from {src.name} ({fmt}) by pmctl twin import",
                             channel_notes=notes, exact=True, overwrite=overwrite)
    return Path(folder), {"format": fmt, "rows": n, "channels": list(cols_out), "axes": axes}


def _cmd(args) -> int:
    try:
        folder, s = import_source(args.src, args.out_dir, fmt=args.format, mapping=parse_pairs(args.map, "--map"),
                                  units=parse_pairs(args.unit, "--unit"), time=args.time,
                                  time_unit=args.time_unit, rate=args.rate, overwrite=args.force)
    except PmctlError:
        raise
    print(f"wrote {folder}: {s['rows']} samples of axes {', '.join(s['axes'])} from {Path(args.src).name} "
          f"({s['format']}); channels {', '.join(s['channels'])}")
    print(f"next:  pmctl twin diagnose {folder}")
    return 0
