"""Recordings in the ``pmctl-recording/1`` format (docs/recording.md): strict reader, writer.

A recording is a folder holding ``recording.json`` (metadata) and ``data.csv`` (one header row of
channel names, one row per sample, plain decimal numbers; an empty cell or ``nan`` means "not
sampled at this instant").

Reading
-------
``read_recording(folder) -> Recording``. Everything is validated before anything is returned;
bad input raises :class:`pmctl.core.errors.InputError` naming the file, the line (1-based, the header
is line 1) and, for data.csv, the column (1-based, ``e.column``; the channel name is in the
message). Checked: recording.json is a JSON object (``//`` and ``/* */`` comments tolerated),
``format`` is exactly ``"pmctl-recording/1"``, ``machine`` names a config in ``config/`` or a
file relative to the folder, ``sample_rate_hz`` > 0, ``description`` a string, ``channels`` an
object; data.csv has the required channels (``t``, ``cmd_L1`` ``cmd_L2`` ``cmd_L3`` ``cmd_X``
``cmd_Y``), unique non-empty names, every row as long as the header, every cell a finite decimal
number or empty/``nan`` with |value| <= ``MAX_ABS_VALUE`` (1e9), and ``t`` present on every row and
strictly increasing. Blank lines are skipped. Unknown columns are carried along and listed in ``Recording.unknown_columns``.

Large files: data.csv may be up to ``MAX_DATA_BYTES`` (512 MiB); the text is parsed in one C pass (``numpy.loadtxt`` after empty cells are filled);
only when that fails does a per-cell Python scan run, to find and report the first bad cell.
10^6 rows x 20 channels read in a few seconds (``benchmarks/bench_recording.py``).

``Recording`` fields: ``path`` (Path of the folder), ``meta`` (the whole recording.json dict),
``columns`` (dict name -> float64 array of length ``n``, header order, NaN = not sampled),
``unknown_columns`` (list of names), ``machine_ref`` (the string in recording.json),
``machine_path`` (resolved config file), ``machine`` (the loaded :class:`pmctl.core.config.Machine`).
Helpers: ``rec.n``, ``rec.t``, ``rec["tip_x"]``, ``"tip_x" in rec``, ``rec.get(name)``,
``rec.sample_rate_hz``, ``rec.description``, ``rec.channel_notes``, ``rec.has_any(names)``.

Writing
-------
``write_recording(folder, columns, *, machine="prototype", sample_rate_hz, description="",
channel_notes=None, digits=10, exact=False, extra_meta=None) -> Path`` writes a whole recording;
``RecordingWriter`` (context manager, ``append(chunk)``, ``finish(complete=...)``) streams one in
chunks for long runs. Both refuse an existing recording unless ``overwrite=True``
(:func:`check_target` says so up front).
Column order: ``t``, the ``cmd_*`` channels, then the others in the order given. ``t`` is written
exact (shortest round-trip repr), other channels with ``digits`` significant digits (``exact=True``:
all exact); NaN is written as an empty cell. Everything is written into the sibling folder
``<folder>.partial`` (recording.json first, with ``"complete": false``) and renamed to ``folder``
when complete, so ``folder`` is never half a recording; a killed writer leaves the sibling, readable
and marked incomplete. A finished recording says ``"complete": true``; a recording without the key
(other loggers) counts as complete. Invalid data (missing required
channel, ragged lengths, non-increasing ``t``, infinities, bad names) raises InputError before
anything is written.

Channel names (docs/recording.md): ``KNOWN_FIXED`` plus ``temp_<name>``; :func:`channel_kind` classifies.
"""

from __future__ import annotations

import io
import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pmctl.core.config import CONFIG_DIR, Machine, load_machine
from pmctl.core.errors import InputError

FORMAT = "pmctl-recording/1"
MAX_META_BYTES = 16 * 2**20
MAX_DATA_BYTES = 512 * 2**20    # data.csv read at most this large (the whole table is held in memory)
META_FILE = "recording.json"
DATA_FILE = "data.csv"

AXES = ("L1", "L2", "L3", "X", "Y")
CMD = tuple(f"cmd_{a}" for a in AXES)
ENC = tuple(f"enc_{a}" for a in AXES)
TIP = ("tip_x", "tip_y", "tip_z")
TOOL = ("tool_i", "tool_j", "tool_k")
STRAIN = ("strain_1", "strain_2", "strain_3")
LOAD = ("load_fx", "load_fy", "load_fz")
REQUIRED = ("t",) + CMD
KNOWN_FIXED = REQUIRED + ENC + TIP + TOOL + STRAIN + LOAD

GENERIC = "axes"         # "machine" of a recording of independent axes (pmctl.core.recording_axes)
MAX_ABS_VALUE = 1e9      # largest |value| of any cell (mm, s, microstrain, N...): beyond it, not a measurement
_KIND = {"t": "time", **{c: "cmd" for c in CMD}, **{c: "enc" for c in ENC}, **{c: "tip" for c in TIP},
         **{c: "tool" for c in TOOL}, **{c: "strain" for c in STRAIN}, **{c: "load" for c in LOAD}}
_TEMP_RE = re.compile(r"^temp_[A-Za-z0-9_.\-]+$")
_NUM_RE = re.compile(r"^[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?$")
_NAN_RE = re.compile(r"^[+-]?nan$", re.IGNORECASE)
_BAD_NAME_CHARS = re.compile(r"[\s,\"']")


def channel_kind(name: str, generic: bool = False) -> str | None:
    """'time', 'cmd', 'enc', 'tip', 'tool', 'strain', 'load', 'temp' or None (unknown channel).
    ``generic``: the channels of a recording of independent axes ('time', 'cmd', 'enc', 'load',
    'effort', 'acc', 'temp'; pmctl.core.recording_axes)."""
    if generic:
        from pmctl.core.recording_axes import channel_kind as generic_kind
        return generic_kind(name)
    k = _KIND.get(name)
    if k is None and _TEMP_RE.match(name):
        return "temp"
    return k


def axis_of(name: str) -> str | None:
    """'L1'..'Y' for cmd_*/enc_* channels, else None."""
    if name.startswith(("cmd_", "enc_")) and name[4:] in AXES:
        return name[4:]
    return None


@dataclass
class Recording:
    path: Path
    meta: dict
    columns: dict[str, np.ndarray]
    unknown_columns: list[str]
    machine_ref: str
    machine_path: Path
    machine: Machine
    data_lines: np.ndarray | None = field(default=None, repr=False)   # file line of each row (if not row+2)

    @property
    def n(self) -> int:
        return len(self.columns["t"])

    @property
    def t(self) -> np.ndarray:
        return self.columns["t"]

    @property
    def sample_rate_hz(self) -> float | None:
        return self.meta.get("sample_rate_hz")

    @property
    def description(self) -> str:
        return self.meta.get("description", "")

    @property
    def channel_notes(self) -> dict:
        return self.meta.get("channels", {})

    @property
    def name(self) -> str:
        return self.path.name

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    def __contains__(self, name: str) -> bool:
        return name in self.columns

    def get(self, name: str, default=None):
        return self.columns.get(name, default)

    def has_any(self, names) -> bool:
        return any(n in self.columns for n in names)

    def line_of_row(self, row: int) -> int:
        """File line number (1-based) of data row ``row`` (0-based)."""
        if self.data_lines is None:
            return row + 2
        return int(self.data_lines[row])


# ---------------------------------------------------------------- recording.json

def _strip_json_comments(text: str) -> str:
    """Remove // and /* */ comments outside strings, keeping line structure (for error lines)."""
    out, i, n, in_str = [], 0, len(text), False
    while i < n:
        c = text[i]
        if in_str:
            out.append(c)
            if c == "\\" and i + 1 < n:
                out.append(text[i + 1])
                i += 2
                continue
            if c == '"':
                in_str = False
            i += 1
        elif c == '"':
            in_str = True
            out.append(c)
            i += 1
        elif text.startswith("//", i):
            j = text.find("\n", i)
            i = n if j < 0 else j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
            out.append("\n" * text.count("\n", i, j))
            i = j
        else:
            out.append(c)
            i += 1
    return "".join(out)


def _key_line(text: str, key: str) -> int | None:
    m = re.search(r'"%s"\s*:' % re.escape(key), text)
    return text.count("\n", 0, m.start()) + 1 if m else None


def _json_object(text: str, mp: Path) -> dict:
    """Parse recording.json (comments tolerated); InputError for anything that is not a JSON object,
    including nesting too deep for the parser and numbers too long to convert."""
    def parse(t):
        return json.loads(t, parse_constant=_no_constant)
    try:
        try:
            meta = parse(text)
        except json.JSONDecodeError as e:
            try:
                meta = parse(_strip_json_comments(text))
            except json.JSONDecodeError:
                raise InputError(mp, e.lineno, f"not valid JSON: {e.msg}", column=e.colno) from None
    except RecursionError:
        raise InputError(mp, None, "not valid JSON: arrays or objects nested too deeply") from None
    except ValueError as e:            # NaN/Infinity, or an integer of more than 4300 digits
        raise InputError(mp, None, f"not valid JSON: {e}") from None
    if not isinstance(meta, dict):
        raise InputError(mp, 1, "must be a JSON object")
    return meta


def _no_constant(name):
    raise ValueError(f"{name} is not a JSON number")


def _finite_real(v) -> bool:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    if isinstance(v, int):
        return abs(v) <= 2**53
    return math.isfinite(v)


def resolve_machine(ref: str, folder: Path) -> Path | None:
    """A config file for a recording's ``machine``: a path relative to the folder, else config/NAME.toml."""
    if not isinstance(ref, str) or not ref or "\0" in ref:
        return None
    p = Path(ref)
    cand = p if p.is_absolute() else folder / p
    try:
        if cand.is_file():
            return cand
    except (OSError, ValueError):       # a name too long for the file system
        return None
    if ref and re.fullmatch(r"[A-Za-z0-9_.\-]+", ref):
        c = CONFIG_DIR / (ref if ref.endswith(".toml") else f"{ref}.toml")
        if c.is_file():
            return c
    return None


def read_meta(folder: str | Path) -> tuple[dict, Path | None, Path]:
    """Validate recording.json; returns (meta, machine_path, meta_path). ``machine_path`` is None
    for a recording of independent axes (``"machine": "axes"``, pmctl.core.recording_axes)."""
    folder = Path(folder)
    mp = folder / META_FILE
    if not folder.is_dir():
        raise InputError(folder, None, "not a recording folder (no such directory)")
    try:
        with open(mp, "rb") as f:
            raw = f.read(MAX_META_BYTES + 1)
    except OSError as e:
        raise InputError(mp, None, f"cannot read: {e.strerror or e}") from None
    if len(raw) > MAX_META_BYTES:
        raise InputError(mp, None, f"larger than {MAX_META_BYTES // 2**20} MiB: not a recording's metadata")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = raw.count(b"\n", 0, e.start) + 1
        col = e.start - (raw.rfind(b"\n", 0, e.start) + 1) + 1
        raise InputError(mp, line, f"byte 0x{raw[e.start]:02x} is not UTF-8 text", column=col) from None
    meta = _json_object(text, mp)

    def bad(key, reason):
        return InputError(mp, _key_line(text, key), f"{key}: {reason}")

    fmt = meta.get("format")
    if fmt is None:
        raise InputError(mp, 1, f'format: missing (expected "{FORMAT}")')
    if fmt != FORMAT:
        raise bad("format", f'{fmt!r} is not "{FORMAT}"')
    ref = meta.get("machine", "prototype")
    if not isinstance(ref, str) or not ref.strip() or "\0" in ref or len(ref) > 1024:
        raise bad("machine", "must be a config name or a path relative to the recording folder")
    machine_path = None if ref == GENERIC else resolve_machine(ref, folder)
    if machine_path is None and ref != GENERIC:
        raise bad("machine", f"unknown machine {ref!r}: neither config/{ref}.toml nor a file "
                             f"relative to {folder}")
    sr = meta.get("sample_rate_hz")
    if sr is not None and not (_finite_real(sr) and 0 < sr <= 1e9):
        show = repr(sr) if len(repr(sr)) <= 40 else repr(sr)[:37] + "..."
        raise bad("sample_rate_hz", f"must be a positive number up to 1e9, got {show}")
    if "description" in meta and not isinstance(meta["description"], str):
        raise bad("description", "must be a string")
    ch = meta.get("channels", {})
    if not isinstance(ch, dict) or any(not isinstance(v, dict) for v in ch.values()):
        raise bad("channels", "must be an object of {channel: {note: value}}")
    return meta, machine_path, mp


# ---------------------------------------------------------------- data.csv

def _header(raw: bytes, path: Path, generic: bool = False) -> tuple[list[str], int]:
    """Channel names and the byte offset where the data starts. ``generic``: a recording of
    independent axes (``t`` and at least one ``cmd_<A>`` required, pmctl.core.recording_axes)."""
    nl = raw.find(b"\n")
    head = raw if nl < 0 else raw[:nl]
    try:
        text = head.decode("utf-8").rstrip("\r")
    except UnicodeDecodeError:
        raise InputError(path, 1, "header is not UTF-8 text") from None
    if not text.strip():
        raise InputError(path, 1, "empty header: expected a row of channel names")
    names = [c.strip().strip('"').strip() for c in text.split(",")]
    seen: dict[str, int] = {}
    for j, nm in enumerate(names, 1):
        if not nm:
            raise InputError(path, 1, "empty channel name", column=j)
        if nm in seen:
            raise InputError(path, 1, f"channel {nm!r} appears twice (columns {seen[nm]} and {j})", column=j)
        seen[nm] = j
    if generic:
        from pmctl.core.recording_axes import check_required
        check_required(names, path)
        return names, (len(raw) if nl < 0 else nl + 1)
    for req in REQUIRED:
        if req not in seen:
            raise InputError(path, 1, f"missing required channel {req!r} "
                                      f"(required: {', '.join(REQUIRED)})")
    return names, (len(raw) if nl < 0 else nl + 1)


def _fill_empty(body: bytes) -> bytes:
    """Empty cells -> 'nan' so one C pass can parse the table (passes that find nothing are skipped)."""
    body = b"\n" + body
    if not body.endswith(b"\n"):
        body += b"\n"
    if b",," in body:
        body = body.replace(b",,", b",nan,").replace(b",,", b",nan,")
    if b"\n," in body:
        body = body.replace(b"\n,", b"\nnan,")
    if b",\n" in body:
        body = body.replace(b",\n", b",nan\n")
    return body


# Bytes the fast path may see: ASCII digits, signs, point, exponent, "nan" in any case, comma, space,
# tab and newline. Anything else (a stray non-ASCII byte, a fullwidth digit, "inf", "_", a quote...)
# goes to the strict scan, so that both paths always read a file the same way.
_FAST_BYTES = b"0123456789+-.eEnNaA, \t\n"


def _fast_parse(body: bytes, ncol: int) -> np.ndarray | None:
    """One C pass; None when anything is unusual (the slow scan then decides)."""
    if body.translate(None, _FAST_BYTES):
        return None
    if not body.strip():
        return np.zeros((0, ncol))
    try:
        arr = np.loadtxt(io.BytesIO(_fill_empty(body)), delimiter=",", comments=None, ndmin=2,
                         dtype=np.float64, encoding=None)
    except (ValueError, UnicodeDecodeError):
        return None
    if arr.shape[0] == 0:
        return np.zeros((0, ncol))
    if arr.shape[1] != ncol or np.isinf(arr).any():
        return None
    return arr


_BLANK = " \t"           # the only blanks around a cell (no Unicode spaces, no control characters)


def _slow_parse(body: bytes, names: list[str], path: Path, first_line: int) -> tuple[np.ndarray, np.ndarray]:
    """Exact per-cell scan; returns (data, file line of each row) or raises at the first bad cell."""
    ncol = len(names)
    rows, lines = [], []
    for k, rawline in enumerate(body.split(b"\n")):
        lineno = first_line + k
        line = rawline.decode("utf-8", errors="replace").rstrip("\r")
        if not line.strip(_BLANK):
            continue
        cells = line.split(",")
        if len(cells) != ncol:
            # column: the first missing cell, or the first cell past the header
            raise InputError(path, lineno, f"row has {len(cells)} cells, the header has {ncol}",
                             column=min(len(cells), ncol) + 1)
        vals = []
        for j, cell in enumerate(cells):
            s = cell.strip(_BLANK)
            if not s or _NAN_RE.match(s):
                vals.append(math.nan)
            elif _NUM_RE.match(s):
                v = float(s)
                if not math.isfinite(v):
                    raise InputError(path, lineno, f"channel {names[j]!r}: {s!r} is out of range",
                                     column=j + 1)
                vals.append(v)
            else:
                show = s if len(s) <= 40 else s[:37] + "..."
                raise InputError(path, lineno, f"channel {names[j]!r}: {show!r} is not a number",
                                 column=j + 1)
        rows.append(vals)
        lines.append(lineno)
    data = np.array(rows, dtype=np.float64).reshape(len(rows), ncol)
    return data, np.array(lines, dtype=np.int64)


def _row_lines(body: bytes, first_line: int) -> np.ndarray | None:
    """File line of each data row when blank lines break 'row + 2' (None otherwise)."""
    core = b"\n" + body.rstrip()
    if b"\n\n" not in core and b"\n " not in core and b"\n\t" not in core and b"\n\r" not in core:
        return None
    if not re.search(rb"\n[ \t\r]*\n", core):
        return None
    return np.array([first_line + k for k, ln in enumerate(body.split(b"\n")) if ln.strip()], dtype=np.int64)


def torn_tail(meta: dict) -> bool:
    """Whether a cut last line of data.csv is dropped rather than refused: in a recording marked
    incomplete (``"complete": false``), whose writer may have been killed in the middle of a row."""
    return meta.get("complete", True) is False


def read_data(path: str | Path, drop_torn_tail: bool = False,
              generic: bool = False) -> tuple[list[str], np.ndarray, np.ndarray | None]:
    """Parse and validate data.csv -> (names, data (n, ncol) float64, row lines or None).
    ``drop_torn_tail``: a last line without its newline is left out (see :func:`torn_tail`);
    ``generic``: the header of a recording of independent axes (see :func:`_header`)."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_DATA_BYTES + 1)
    except OSError as e:
        raise InputError(path, None, f"cannot read: {e.strerror or e}") from None
    if len(raw) > MAX_DATA_BYTES:
        raise InputError(path, None, f"larger than {MAX_DATA_BYTES // 2**20} MiB (about 2.5 million rows of 20 "
                                     "channels): split the recording")
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]
    names, start = _header(raw, path, generic)
    body = raw[start:]
    if drop_torn_tail and body and not body.endswith(b"\n"):
        body = body[:body.rfind(b"\n") + 1]
    if b"\r" in body:
        body = body.replace(b"\r\n", b"\n")
    ncol = len(names)
    data = _fast_parse(body, ncol)
    lines = None
    if data is None:
        data, lines = _slow_parse(body, names, path, 2)
        if np.array_equal(lines, np.arange(2, 2 + len(lines))):
            lines = None
    else:
        lines = _row_lines(body, 2)

    def line_of(r):
        return int(lines[r]) if lines is not None else r + 2

    if data.shape[0] == 0:
        raise InputError(path, 2, "no samples after the header")
    with np.errstate(invalid="ignore"):
        over = np.abs(data) > MAX_ABS_VALUE
    if over.any():
        r, j = (int(x) for x in np.argwhere(over)[0])
        raise InputError(path, line_of(r), f"channel {names[j]!r}: {float(data[r, j])!r} is out of range "
                                           f"(|value| <= {MAX_ABS_VALUE:g})", column=j + 1)
    jt = names.index("t")
    t = data[:, jt]
    nan_t = np.flatnonzero(np.isnan(t))
    if nan_t.size:
        raise InputError(path, line_of(nan_t[0]), "channel 't' is empty: every row needs a time",
                         column=jt + 1)
    dec = np.flatnonzero(np.diff(t) <= 0)
    if dec.size:
        r = dec[0] + 1
        raise InputError(path, line_of(r), f"channel 't' is not strictly increasing "
                                           f"({t[r - 1]!r} then {t[r]!r})", column=jt + 1)
    return names, data, lines


def read_recording(folder: str | Path) -> Recording:
    """Read and validate a ``pmctl-recording/1`` folder (see the module docstring). A path to the
    folder's recording.json or data.csv is accepted too."""
    folder = Path(folder)
    if folder.name in (META_FILE, DATA_FILE) and folder.is_file():
        folder = folder.parent
    meta, machine_path, mp = read_meta(folder)
    generic = is_generic(meta)
    names, data, lines = read_data(folder / DATA_FILE, drop_torn_tail=torn_tail(meta), generic=generic)
    columns = {nm: np.ascontiguousarray(data[:, j]) for j, nm in enumerate(names)}
    if generic:
        from pmctl.core.recording_axes import axes_machine, convert
        machine, conv = axes_machine(names, meta, mp, mp.read_text(encoding="utf-8-sig", errors="replace"))
        convert(columns, conv)
    else:
        machine = load_machine(machine_path)
    unknown = [nm for nm in names if channel_kind(nm, generic) is None]
    return Recording(folder, meta, columns, unknown, meta.get("machine", "prototype"), machine_path,
                     machine, lines)


def is_generic(meta: dict) -> bool:
    """Whether recording.json describes a machine of independent axes (``"machine": "axes"``)."""
    return meta.get("machine") == GENERIC


# ---------------------------------------------------------------- writing

def _check_name(name, folder):
    if not isinstance(name, str) or not name or _BAD_NAME_CHARS.search(name):
        raise InputError(folder, None, f"bad channel name {name!r}: non-empty, no spaces, commas or quotes")


def _order(names, generic=False):
    if generic:          # t, the commands in their order, then the rest
        first = ["t"] + [n for n in names if n.startswith("cmd_")]
    else:
        first = list(REQUIRED)
    return first + [n for n in names if n not in first]


def _missing(names, generic=False) -> list[str]:
    """The required channels a writer was not given (a generic recording: t and one cmd_<A>)."""
    if generic:
        from pmctl.core.recording_axes import axes_of
        return [r for r in ("t",) if r not in names] + ([] if axes_of(names) else ["cmd_<A>"])
    return [r for r in REQUIRED if r not in names]


def _check_rows(arr, channels, last_t, row0, folder):
    """t finite and strictly increasing (also across chunks), no infinities."""
    t = arr[:, 0]
    if not np.all(np.isfinite(t)):
        raise InputError(folder, None, f"t must be finite on every row (row {row0 + int(np.argmin(np.isfinite(t)))})")
    d = np.diff(np.concatenate([[last_t], t]))
    if np.any(d <= 0):
        raise InputError(folder, None, f"t is not strictly increasing at row {row0 + int(np.argmax(d <= 0))}")
    if np.isinf(arr).any():
        r, c = np.argwhere(np.isinf(arr))[0]
        raise InputError(folder, None, f"channel {channels[c]!r} row {row0 + r}: infinite value")
    with np.errstate(invalid="ignore"):
        over = np.abs(arr) > MAX_ABS_VALUE
    if over.any():            # the reader refuses these: never write what cannot be read back
        r, c = np.argwhere(over)[0]
        raise InputError(folder, None, f"channel {channels[c]!r} row {row0 + r}: {arr[r, c]!r} is out of range "
                                       f"(|value| <= {MAX_ABS_VALUE:g})")


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"{type(o).__name__} is not JSON serialisable")


class RecordingWriter:
    """Streams a recording to ``folder`` in chunks. Use as a context manager::

        with RecordingWriter(folder, ["t", "cmd_L1", ...], sample_rate_hz=1000) as w:
            w.append({"t": t_chunk, "cmd_L1": ..., ...})     # or an (n, nchannels) array

    Safe writes (docs/recording.md, "Writing a recording safely"):

    - ``folder`` must not exist yet (an empty directory is accepted); an existing recording is
      refused with InputError unless ``overwrite=True``, and even then only a folder that holds a
      recording (recording.json / data.csv) or nothing is replaced, never any other folder.
    - Everything is written into the sibling ``<folder>.partial/``: recording.json first, marked
      ``"complete": false``, then data.csv, flushed chunk by chunk. A process killed mid-way
      leaves that sibling, readable as a recording that says it is incomplete.
    - On a clean exit recording.json is rewritten with ``"complete": true`` and the sibling is
      renamed to ``folder`` in one step, so ``folder`` either does not exist or is whole.
    - On an exception inside the ``with`` block, or when the writer refuses a chunk, the sibling is
      removed; nothing appears under ``folder``'s name.
    - ``finish(complete=False, reason=...)`` instead of a clean exit renames what was written into
      place marked incomplete (a session that ended early but whose samples are worth keeping).
    """

    def __init__(self, folder, channels, *, machine="prototype", sample_rate_hz, description="",
                 channel_notes=None, digits=10, exact=False, extra_meta=None, overwrite=False,
                 force_flag="--force"):
        self.folder = Path(folder)
        for nm in channels:
            _check_name(nm, self.folder)
        if len(set(channels)) != len(channels):
            raise InputError(self.folder, None, "a channel name appears twice")
        generic = machine == GENERIC
        missing = _missing(list(channels), generic)
        if missing:
            raise InputError(self.folder, None, f"missing required channel(s) {', '.join(missing)}")
        if isinstance(sample_rate_hz, bool) or not isinstance(sample_rate_hz, (int, float)) \
                or not math.isfinite(sample_rate_hz) or sample_rate_hz <= 0:
            raise InputError(self.folder, None, f"sample_rate_hz must be a positive number, got {sample_rate_hz!r}")
        if not isinstance(machine, str) or (
                not generic and resolve_machine(machine, self.folder) is None
                and not Path(os.path.normpath(self.folder / machine)).is_file()):
            # (a path relative to a folder that does not exist yet is resolved lexically)
            raise InputError(self.folder, None, f"unknown machine {machine!r}")
        self.overwrite = bool(overwrite)
        check_target(self.folder, overwrite=self.overwrite, force_flag=force_flag)
        self.channels = _order(list(channels), generic)
        self._perm = [list(channels).index(c) for c in self.channels]
        self.meta = {"format": FORMAT, "machine": machine, "sample_rate_hz": sample_rate_hz,
                     "description": description}
        if channel_notes:
            self.meta["channels"] = {k: dict(v) for k, v in channel_notes.items()}
        if extra_meta:
            for k, v in extra_meta.items():
                self.meta.setdefault(k, v)
        self.meta["complete"] = False
        tail = "%r" if exact else f"%.{int(digits)}g"
        self._fmt = "%r" + ("," + tail) * (len(self.channels) - 1)
        self._last_t = -math.inf
        self._rows = 0
        self._fh = None
        self.partial = partial_path(self.folder)
        self._done = False

    @property
    def rows(self) -> int:
        """Samples written so far."""
        return self._rows

    def __enter__(self):
        part = self.partial
        if part.exists():
            if not self.overwrite:
                raise InputError(self.folder, None,
                                 f"{part} exists: another writer is using it, or a killed run left it "
                                 f"(it is readable as an incomplete recording); move it away or remove it")
            _remove_recording_dir(part)
        part.mkdir(parents=True)
        try:
            self._write_meta()
            self._fh = open(part / DATA_FILE, "w", encoding="utf-8", newline="\n")
            self._fh.write(",".join(self.channels) + "\n")
            self._fh.flush()
        except BaseException:
            self._discard()
            raise
        return self

    def _write_meta(self):
        tmp = self.partial / (META_FILE + ".tmp")
        tmp.write_text(json.dumps(self.meta, indent=2, default=_json_default) + "\n", encoding="utf-8")
        os.replace(tmp, self.partial / META_FILE)

    def append(self, chunk):
        """Append rows: a dict {channel: array} (all channels) or an (n, nchannels) array in the
        order the channels were given to the constructor. Each chunk is flushed to the file."""
        if self._fh is None:
            raise InputError(self.folder, None, "append() outside the writer's with-block")
        try:
            if isinstance(chunk, dict):
                if set(chunk) != set(self.channels):
                    extra = set(chunk) ^ set(self.channels)
                    raise InputError(self.folder, None, f"chunk channels differ from the header: {sorted(extra)}")
                cols = [np.asarray(chunk[c], dtype=np.float64).reshape(-1) for c in self.channels]
                lens = {len(c) for c in cols}
                if len(lens) > 1:
                    raise InputError(self.folder, None, f"channels have different lengths {sorted(lens)}")
                arr = np.stack(cols, 1) if cols else np.zeros((0, 0))
            else:
                arr = np.asarray(chunk, dtype=np.float64)
                if arr.ndim != 2 or arr.shape[1] != len(self.channels):
                    raise InputError(self.folder, None, f"chunk must be (n, {len(self.channels)}), got {arr.shape}")
                arr = arr[:, self._perm]
            if arr.shape[0] == 0:
                return
            _check_rows(arr, self.channels, self._last_t, self._rows, self.folder)
        except InputError:
            # a refused chunk ends the recording: nothing half-valid is kept under any name
            self._discard()
            raise
        fmt = self._fmt
        text = "\n".join([fmt % row for row in map(tuple, arr.tolist())])
        text = text.replace(",nan", ",")
        self._fh.write(text + "\n")
        self._fh.flush()
        self._last_t = float(arr[-1, 0])
        self._rows += arr.shape[0]

    def _discard(self):
        if self._fh is not None:
            self._fh.close()
            self._fh = None
        self._done = True
        _remove_recording_dir(self.partial, missing_ok=True)

    def finish(self, *, complete=True, reason="", extra_meta=None):
        """Close the recording and rename it into place. ``complete=False`` keeps what was
        written, marked ``"complete": false`` (with ``incomplete_reason``). ``extra_meta``: keys
        of recording.json to set or replace now (what is known only at the end, e.g. a run's
        status and figures; not the format keys). Returns the folder."""
        if self._done:
            return self.folder
        self._fh.close()
        self._fh = None
        self._done = True
        if self._rows == 0:
            _remove_recording_dir(self.partial, missing_ok=True)
            raise InputError(self.folder, None, "no samples to write")
        for k, v in (extra_meta or {}).items():
            if k not in ("format", "machine", "sample_rate_hz", "complete", "incomplete_reason"):
                self.meta[k] = v
        self.meta["complete"] = bool(complete)
        if not complete and reason:
            self.meta["incomplete_reason"] = str(reason)
        self._write_meta()
        _rename_into_place(self.partial, self.folder, overwrite=self.overwrite)
        return self.folder

    def __exit__(self, exc_type, exc, tb):
        if self._done:
            return False
        if exc_type is not None:
            self._discard()
            return False
        self.finish()
        return False


def partial_path(folder) -> Path:
    """Where a recording of ``folder`` is written until it is complete: the sibling ``<name>.partial``."""
    folder = Path(folder)
    return folder.with_name(folder.name + ".partial")


def _is_recording_dir(p: Path) -> bool:
    """A folder holding a recording (recording.json or data.csv, plus files only: plots, notes),
    or nothing: what ``overwrite`` may replace. A folder with sub-folders is never replaced."""
    entries = list(p.iterdir())
    if not entries:
        return True
    return all(q.is_file() and not q.is_symlink() for q in entries) and \
        any(q.name in (META_FILE, DATA_FILE) for q in entries)


def check_target(folder, *, overwrite=False, force_flag="--force") -> None:
    """Refuse a recording target that exists (an empty directory is fine) unless ``overwrite``;
    never replace something that is not a recording, and refuse its ``<folder>.partial`` sibling (a
    killed writer's rows) unless ``overwrite``. Raises InputError naming the folder (and
    ``force_flag``, the caller's way to replace a recording; None: it has none)."""
    folder = Path(folder)
    part = partial_path(folder)
    if not overwrite and (part.exists() or part.is_symlink()):
        raise InputError(folder, None, f"{part} exists (a killed run or session left it; it reads as an incomplete "
                                       "recording); move it away"
                         + (f", or {force_flag} to replace it" if force_flag else ", or choose another name"))
    if not folder.exists() and not folder.is_symlink():
        parent = folder.parent if str(folder.parent) else Path(".")
        anc = parent
        while not anc.exists():
            anc = anc.parent
        if not anc.is_dir() or not os.access(anc, os.W_OK | os.X_OK):
            raise InputError(folder, None, f"cannot create it: {anc} is not a writable folder")
        return
    if not folder.is_dir() or folder.is_symlink():
        raise InputError(folder, None, "exists and is not a folder; choose another name")
    if not any(folder.iterdir()):
        if not os.access(folder.parent if str(folder.parent) else Path("."), os.W_OK):
            raise InputError(folder, None, "its parent folder is not writable")
        return
    if not _is_recording_dir(folder):
        raise InputError(folder, None, "exists and holds files that are not a recording; choose another name"
                         + (f" (not even {force_flag} replaces it)" if force_flag else ""))
    if not overwrite:
        raise InputError(folder, None, "a recording is already there; choose another name"
                         + (f", or {force_flag} to replace it" if force_flag else ""))


def _remove_recording_dir(p: Path, missing_ok=False):
    import shutil
    if not p.exists():
        if missing_ok:
            return
        raise FileNotFoundError(p)
    shutil.rmtree(p)


def _rename_into_place(part: Path, folder: Path, *, overwrite: bool):
    """``part`` -> ``folder`` in one rename; an existing ``folder`` (already checked) is moved
    aside first and removed after, so a reader sees the old or the new recording, never a mix."""
    old = None
    if folder.exists() and any(folder.iterdir()):
        if not overwrite or not _is_recording_dir(folder):
            raise InputError(folder, None, f"appeared while writing; the new recording is complete "
                                           f"in {part}")
        old = folder.with_name(f"{folder.name}.old-{os.getpid()}")
        os.replace(folder, old)
    elif folder.is_dir():
        folder.rmdir()          # empty: nothing to keep
    try:
        os.replace(part, folder)
    except OSError as e:
        if old is not None:
            os.replace(old, folder)
        raise InputError(folder, None, f"cannot rename {part} into place: {e.strerror or e}; "
                                       f"the recording is in {part}") from None
    if old is not None:
        _remove_recording_dir(old, missing_ok=True)


def write_recording(folder, columns, *, machine="prototype", sample_rate_hz, description="",
                    channel_notes=None, digits=10, exact=False, extra_meta=None, overwrite=False,
                    complete=True, incomplete_reason="") -> Path:
    """Write a whole recording: ``columns`` is a dict {channel: 1-D array}; returns the folder.
    Written into ``<folder>.partial`` and renamed into place (see :class:`RecordingWriter`); an
    existing recording is refused unless ``overwrite``. ``complete=False`` marks a recording of a
    run that ended early."""
    folder = Path(folder)
    cols = {k: np.asarray(v, dtype=np.float64) for k, v in columns.items()}
    for k, v in cols.items():
        if v.ndim != 1:
            raise InputError(folder, None, f"channel {k!r} must be 1-D, got shape {v.shape}")
    n = {len(v) for v in cols.values()}
    if len(n) > 1:
        raise InputError(folder, None, f"channels have different lengths {sorted(n)}")
    total = n.pop() if n else 0
    names = _order(list(cols), machine == GENERIC)
    missing = _missing(list(cols), machine == GENERIC)
    if missing:
        raise InputError(folder, None, f"missing required channel(s) {', '.join(missing)}")
    if total:
        _check_rows(np.stack([cols[c] for c in names], 1), names, -math.inf, 0, folder)
    with RecordingWriter(folder, list(cols), machine=machine, sample_rate_hz=sample_rate_hz,
                         description=description, channel_notes=channel_notes, digits=digits,
                         exact=exact, extra_meta=extra_meta, overwrite=overwrite) as w:
        step = 200_000
        for s in range(0, total, step):
            w.append({k: v[s:s + step] for k, v in cols.items()})
        w.finish(complete=complete, reason=incomplete_reason)
    return folder
