"""Bounded-memory reading of ``pmctl-recording/1`` folders: data.csv in chunks of rows.

:func:`pmctl.core.recording.read_recording` reads data.csv whole (the file's bytes, a filled copy
and the parsed table at once: about 900 MB for 10^6 rows). This module reads the same file block
by block (``block_bytes`` of text at a time, cut at a line end) and parses every block with the
reader's own parse functions (``_fast_parse``, falling back to ``_slow_parse`` which names the
first bad cell), so the rules and the error messages are the reader's: the header, row lengths,
numbers, ``t`` on every row and strictly increasing (checked across block boundaries too).

- :func:`iter_chunks(folder)` yields ``(names, first_row, block)`` with ``block`` an (m, ncol)
  float64 array; memory is one block.
- :func:`read_columns(folder, channels=None, measured_dtype=np.float32, progress=None)` returns
  ``(meta, machine, columns)`` holding only the channels asked for (default: every known one),
  ``t`` and the ``cmd_*`` in float64 and the measured channels in ``measured_dtype`` (float32
  keeps 7 significant digits: 30 nm on a 500 mm axis, far below the 0.5 µm encoder pulse).
  Memory: the kept columns plus one block. ``progress(done_bytes, total_bytes)`` is called per
  block. ``rows=[(start, stop), ...]`` (sorted, disjoint row ranges) keeps only those rows: every
  row is still read and checked, but memory is the kept rows plus one block, whatever the file's
  length. ``info`` (a dict), when given, receives ``rows_total`` (rows in the file) and, with
  ``rows``, ``cmd_direction_before``: per range, {cmd_*: the direction of that command's last
  motion before the range's first row (+1/-1; 0: it had not moved)}, read from the skipped rows: a
  play's side or a friction's sign at the start of a range depends on it.
- :func:`count_rows(folder)`: an upper bound of the data rows (the file's line count minus the
  header; exact without blank lines), from one pass over the bytes without parsing.
- :func:`plan_segments(n, max_rows, n_segments)`: the row ranges a bounded reader keeps of an
  n-row file: all of it when n <= max_rows, else ``n_segments`` contiguous runs of
  ``max_rows // n_segments`` rows spread evenly from the first row to the last.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from pmctl.core.config import load_machine
from pmctl.core.errors import InputError
from pmctl.core.plant_effects import direction
from pmctl.core.recording import (CMD, DATA_FILE, META_FILE, REQUIRED, _fast_parse, _header, _slow_parse,
                                  channel_kind, is_generic, read_meta, torn_tail)

BLOCK_BYTES = 16 << 20


def _folder(folder) -> Path:
    folder = Path(folder)
    if folder.name in (META_FILE, DATA_FILE) and folder.is_file():
        folder = folder.parent
    return folder


def iter_chunks(folder, *, block_bytes=BLOCK_BYTES, progress=None, drop_torn_tail=False, generic=False):
    """Yield (names, first_row, block) over data.csv (see the module docstring); ``drop_torn_tail``:
    a last line without its newline is left out (pmctl.core.recording.torn_tail); ``generic``: a
    recording of independent axes (its header needs t and one cmd_<A>)."""
    path = _folder(folder) / DATA_FILE
    try:
        fh = open(path, "rb")
    except OSError as e:
        raise InputError(path, None, f"cannot read: {e.strerror or e}") from None
    total = os.fstat(fh.fileno()).st_size
    with fh:
        head = fh.readline()
        if head.startswith(b"\xef\xbb\xbf"):
            head = head[3:]
        names, _ = _header(head, path, generic)
        ncol = len(names)
        jt = names.index("t")
        line = 2                   # file line of the next block's first line
        row = 0
        last_t = -np.inf
        done = len(head)
        carry = b""
        while True:
            buf = fh.read(block_bytes)
            eof = not buf
            data = carry + buf
            if not eof:
                cut = data.rfind(b"\n")
                if cut < 0:
                    carry = data
                    continue
                body, carry = data[:cut + 1], data[cut + 1:]
            else:
                body, carry = data, b""
                if drop_torn_tail and body and not body.endswith(b"\n"):
                    body = body[:body.rfind(b"\n") + 1]
            if body:
                nlines = body.count(b"\n") + (0 if body.endswith(b"\n") else 1)
                b = body.replace(b"\r\n", b"\n") if b"\r" in body else body
                arr = _fast_parse(b, ncol)
                lines = None
                if arr is None:
                    arr, lines = _slow_parse(b, names, path, line)
                elif arr.shape[0] != nlines:        # blank lines: find each row's line for errors
                    lines = np.array([line + k for k, ln in enumerate(b.split(b"\n")) if ln.strip()])
                t = arr[:, jt]

                def line_of(r):
                    return int(lines[r]) if lines is not None else line + r

                bad = np.flatnonzero(np.isnan(t))
                if bad.size:
                    raise InputError(path, line_of(bad[0]), "channel 't' is empty: every row needs a time",
                                     column=jt + 1)
                d = np.diff(np.concatenate([[last_t], t]))
                dec = np.flatnonzero(d <= 0)
                if dec.size:
                    r = dec[0]
                    prev = last_t if r == 0 else t[r - 1]
                    raise InputError(path, line_of(r), f"channel 't' is not strictly increasing "
                                                       f"({prev!r} then {t[r]!r})", column=jt + 1)
                if len(t):
                    last_t = float(t[-1])
                    yield names, row, arr
                    row += len(t)
                line += nlines
                done += len(body)
                if progress:
                    progress(done, total)
            if eof:
                break
    if row == 0:
        raise InputError(path, 2, "no samples after the header")


def count_rows(folder, *, block_bytes=BLOCK_BYTES) -> int:
    """Lines of data.csv after the header (an upper bound of its rows; exact without blank lines)."""
    path = _folder(folder) / DATA_FILE
    try:
        fh = open(path, "rb")
    except OSError as e:
        raise InputError(path, None, f"cannot read: {e.strerror or e}") from None
    lines, last = 0, b"\n"
    with fh:
        while buf := fh.read(block_bytes):
            lines += buf.count(b"\n")
            last = buf[-1:]
    return max(lines + (last != b"\n") - 1, 0)


def plan_segments(n: int, max_rows: int, n_segments: int) -> list[tuple[int, int]]:
    """Row ranges [(start, stop), ...] to keep of n rows: [(0, n)] when n <= max_rows, else
    n_segments runs of max_rows // n_segments rows, the first at row 0, the last ending at row n."""
    if n <= max_rows:
        return [(0, n)]
    k = max(1, min(n_segments, max_rows))
    length = max_rows // k
    starts = np.linspace(0, n - length, k).round().astype(int) if k > 1 else np.array([0])
    return [(int(s), int(s) + length) for s in starts]


def _motion_before(names, row0, arr, rows, motion, before):
    """For every row range starting in this block: the direction (+1/-1, 0: none yet) of each
    command's last motion before its first row, carried over blocks in ``motion`` (its last finite
    value and direction). An empty cell is no motion: the command holds its last value through it."""
    starts = [(k, a) for k, (a, _) in enumerate(rows) if row0 < a <= row0 + len(arr)]
    for n, (last, d) in list(motion.items()):
        x = arr[:, names.index(n)]
        ok = np.isfinite(x)
        if not ok.all():                     # hold the last finite value through empty cells
            at = np.where(ok, np.arange(len(x)), -1)
            np.maximum.accumulate(at, out=at)
            x = np.where(at >= 0, x[np.maximum(at, 0)], np.nan if last is None else last)
        # the direction held through stops, from the previous block's last value on; before the
        # command's first move in this block, the direction carried in
        held = direction(np.concatenate([[x[0] if last is None else last], x]))[1:]
        held[held == 0] = d
        for k, a in starts:
            before[k][n] = float(held[a - 1 - row0])
        motion[n] = (x[-1] if np.isfinite(x[-1]) else last, float(held[-1]))


def read_columns(folder, channels=None, *, measured_dtype=np.float32, block_bytes=BLOCK_BYTES,
                 progress=None, rows=None, info=None):
    """(meta, machine, columns) with only ``channels`` kept (default: all known channels) and, with
    ``rows`` (sorted disjoint (start, stop) ranges), only those rows."""
    folder = _folder(folder)
    meta, machine_path, mp = read_meta(folder)
    generic = is_generic(meta)
    machine = None if generic else load_machine(machine_path)
    conv = {}
    parts: dict[str, list] = {}
    keep = None
    total = 0
    motion = None           # per command: (its last value, direction of its last motion) so far
    before = [{} for _ in rows] if rows is not None else None
    for names, row0, arr in iter_chunks(folder, block_bytes=block_bytes, progress=progress,
                                        drop_torn_tail=torn_tail(meta), generic=generic):
        total = row0 + len(arr)
        if keep is None:
            cmds = [n for n in names if channel_kind(n, generic) == "cmd"]
            req = ["t"] + cmds if generic else list(REQUIRED)
            want = [n for n in names if channel_kind(n, generic) is not None] if channels is None else \
                [n for n in names if n in set(channels) | set(req)]
            keep = [(n, names.index(n), np.float64 if n in req or n in cmds else measured_dtype) for n in want]
            parts = {n: [] for n, _, _ in keep}
            motion = {n: (None, 0.0) for n in names if n in cmds}
            if generic:
                from pmctl.core.recording_axes import axes_machine
                machine, conv = axes_machine(names, meta, mp, mp.read_text(encoding="utf-8-sig", errors="replace"))
        if rows is not None:
            _motion_before(names, row0, arr, rows, motion, before)
            sel = [np.arange(max(a, row0), min(b, total)) - row0 for a, b in rows if a < total and b > row0]
            if not sel:
                continue
            arr = arr[np.concatenate(sel)]
        for n, j, dt in keep:
            parts[n].append(arr[:, j].astype(dt))
    if info is not None:
        info["rows_total"] = total
        if before is not None:
            info["cmd_direction_before"] = before
    columns = {}
    for n, _, dt in keep:
        p = parts.pop(n)
        columns[n] = np.concatenate(p) if p else np.zeros(0, dt)
    if generic:
        from pmctl.core.recording_axes import convert
        convert(columns, conv)
    return meta, machine, columns
