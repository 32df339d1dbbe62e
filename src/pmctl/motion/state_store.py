"""Pulse counters that survive a crash or restart.

The counters are written atomically (temp file in the same folder + fsync + rename + fsync of the
folder), so the file on disk is always either the previous or the new complete state, never a
torn one. The loop hands counters to a small writer thread every N ticks (no I/O on the hot path)
and writes synchronously at a stop. ``clean`` tells a restart whether the last write was a
controlled stop (counters exact) or a periodic snapshot (a crash may have lost the pulses of up
to one persist interval: re-home, or trust the drives' absolute encoders).

The file also says what the counts are in: ``pulses_per_mm``, the resolution of each counter (L1 L2
L3 X Y: the machine config's chain and table pulses per mm) when they were written. Counts saved at
another resolution than the machine config's are refused on load (:class:`ResolutionMismatch`,
naming the file and both resolutions): a count is a position only at the resolution it was counted
in, and whether the old pulses are worth old or new millimetres (a drive's electronic gear was
changed, or the config was wrong) only the integrator knows. A file without the field (written
before it existed) is loaded as counts at the current resolution, and ``SavedCounters.note`` says so.
"""

from __future__ import annotations

import json
import math
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pmctl.core.errors import InputError, PmctlError

FORMAT = "pmctl-counters/1"


class ResolutionMismatch(InputError):
    """The counter file's counts were saved at another resolution than the machine config's."""


class StateLock:
    """One controller per machine: an exclusive, non-blocking lock on ``<state file>.lock``, held
    for the life of the run (the kernel drops it if the process dies). A second ``pmctl run`` on
    the same state file is refused before anything moves."""

    def __init__(self, state_path):
        import fcntl
        self._fd = None
        self.path = Path(str(state_path) + ".lock")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                raise PmctlError(f"{state_path}: another pmctl run holds {self.path} "
                                 f"(one controller per machine)") from None
            try:                         # the holder before may have removed the file it locked
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        self._fd = fd
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())

    def release(self, remove: bool = False):
        """Drop the lock; ``remove`` (a clean exit): the lock file goes too, removed while held."""
        if self._fd is not None:
            if remove:
                try:
                    os.unlink(self.path)
                except OSError:
                    pass
            os.close(self._fd)
            self._fd = None

    def __del__(self):                   # the run or the service ended: nothing is left behind
        self.release(remove=True)


@dataclass
class SavedCounters:
    counts: np.ndarray
    clean: bool
    tick: int
    machine: str
    wall_time: float
    offsets: np.ndarray | None = None     # a backend's reference offsets (homing on drives that keep their positions)
    pulses_per_mm: np.ndarray | None = None   # the resolution the counts were saved at (None: an older file)
    note: str = ""                        # what a reader should tell the operator (an older file: no resolution)


def _fmt_ppm(ppm) -> str:
    """Per-axis pulses per mm as the machine config gives them: chain (L1 L2 L3) and table (X Y)."""
    v = [float(x) for x in ppm]

    def one(xs):             # 12 digits: two resolutions told apart never print the same
        return f"{xs[0]:.12g}" if len(set(xs)) == 1 else "/".join(f"{x:.12g}" for x in xs)
    if len(v) == 5:
        return f"chain {one(v[:3])}, table {one(v[3:])} pulses/mm"
    return one(v) + " pulses/mm"


def _same_resolution(a, b) -> bool:
    return len(a) == len(b) and all(math.isclose(float(x), float(y), rel_tol=1e-12, abs_tol=0.0)
                                    for x, y in zip(a, b))


def save_counters(path, counts, *, machine: str, clean: bool, tick: int = 0, offsets=None,
                  pulses_per_mm=None) -> None:
    """Atomic write of the counters (temp + fsync + rename + fsync dir). ``offsets``: the backend's
    reference offsets (pmctl.hal.base.Backend.reference_offset), written with the counters they belong
    to; None keeps the ones already in the file (a writer that does not know them does not drop them).
    ``pulses_per_mm``: the resolution of each counter (``Machine.resolution.pulses_per_mm``), written
    with them so that a reader with another resolution does not take them for a position; None writes
    no resolution (the file then reads as one written before the field existed)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = {"format": FORMAT, "machine": machine, "counts": [int(c) for c in counts],
            "clean": bool(clean), "tick": int(tick), "wall_time": time.time()}
    if pulses_per_mm is not None:
        ppm = [float(x) for x in pulses_per_mm]
        if len(ppm) != len(data["counts"]) or not all(math.isfinite(x) and x > 0 for x in ppm):
            raise ValueError(f"pulses_per_mm: expected {len(data['counts'])} positive numbers, got {ppm!r}")
        data["pulses_per_mm"] = ppm
    if offsets is None:
        try:
            offsets = json.loads(path.read_text(encoding="utf-8")).get("device_offsets")
        except (OSError, ValueError, AttributeError):
            offsets = None
    if offsets is not None:
        data["device_offsets"] = [int(c) for c in offsets]
    atomic_write(path, json.dumps(data) + "\n")


def atomic_write(path, text) -> None:
    """Write ``text`` to ``path`` so that a crash or power cut leaves the old file or the new one,
    never a mix: a temporary sibling (named per process and thread, so two writers never share
    one), fsync, rename, fsync of the folder. ``text``: a str, or an iterable of str chunks written
    as they come (a large file is never whole in memory); an error while writing leaves the old file
    and no temporary."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            for chunk in ([text] if isinstance(text, str) else text):
                f.write(chunk)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    try:
        dfd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
    except OSError:
        pass


def load_counters(path, *, machine: str, axes: int = 5, pulses_per_mm=None) -> SavedCounters | None:
    """The saved counters, None if there is no file. A damaged file or one for another machine is an
    InputError naming the file and the field: the loop must not guess a position.

    ``pulses_per_mm`` (the machine config's resolution per axis): counts saved at another resolution
    are refused (:class:`ResolutionMismatch`, naming the file and both resolutions); a file that
    carries no resolution is taken at this one and ``note`` says so. None: no check."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return None
    except OSError as e:
        raise InputError(path, None, f"cannot read the counter state: {e.strerror or e}") from None
    try:
        d = json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(path, e.lineno, f"counter state is not valid JSON: {e.msg}", column=e.colno) from None
    if not isinstance(d, dict) or d.get("format") != FORMAT:
        raise InputError(path, 1, f"format: expected {FORMAT!r}")
    if d.get("machine") != machine:
        raise InputError(path, 1, f"machine: state is for {d.get('machine')!r}, not {machine!r}")
    c = d.get("counts")
    if (not isinstance(c, list) or len(c) != axes
            or any(isinstance(x, bool) or not isinstance(x, int) for x in c)):
        raise InputError(path, 1, f"counts: expected a list of {axes} integers, got {c!r}")
    if any(abs(x) >= 2**63 for x in c):
        raise InputError(path, 1, f"counts: out of the int64 range: {c!r}")
    clean, tick, wall = d.get("clean", False), d.get("tick", 0), d.get("wall_time", 0.0)
    if not isinstance(clean, bool):
        raise InputError(path, 1, f"clean: expected true or false, got {clean!r}")
    if isinstance(tick, bool) or not isinstance(tick, int) or tick < 0:
        raise InputError(path, 1, f"tick: expected a non-negative integer, got {tick!r}")
    if isinstance(wall, bool) or not isinstance(wall, (int, float)):
        raise InputError(path, 1, f"wall_time: expected a number, got {wall!r}")
    off = d.get("device_offsets")
    if off is not None and (not isinstance(off, list) or len(off) != axes or any(
            isinstance(x, bool) or not isinstance(x, int) or abs(x) >= 2**63 for x in off)):
        raise InputError(path, 1, f"device_offsets: expected a list of {axes} integers, got {off!r}")
    ppm = d.get("pulses_per_mm")
    if ppm is not None and (not isinstance(ppm, list) or len(ppm) != axes or any(
            isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) or x <= 0 for x in ppm)):
        raise InputError(path, 1, f"pulses_per_mm: expected a list of {axes} positive numbers, got {ppm!r}")
    note = ""
    if pulses_per_mm is not None:
        want = [float(x) for x in pulses_per_mm]
        if ppm is None:
            note = (f"{path} carries no resolution (written before the counter file had one): its counts are "
                    f"taken as pulses at the machine config's {_fmt_ppm(want)}")
        elif not _same_resolution(ppm, want):
            raise ResolutionMismatch(
                path, 1, f"pulses_per_mm: the counts were saved at {_fmt_ppm(ppm)} but the machine config "
                         f"says {_fmt_ppm(want)}; they are not used as a position. Put the old resolution "
                         f"back, or move the file away (its counts are then lost) and home the machine")
    return SavedCounters(np.array(c, dtype=np.int64), clean, tick, machine, float(wall),
                         None if off is None else np.array(off, dtype=np.int64),
                         None if ppm is None else np.array(ppm, dtype=float), note)


class CounterWriter:
    """Background writer: ``offer`` (hot path) copies the counters into a preallocated slot and
    wakes the thread; the thread does the file I/O. ``stop`` writes the final state synchronously."""

    def __init__(self, path, *, machine: str, axes: int = 5, pulses_per_mm=None):
        self.path, self.machine = Path(path), machine
        self.pulses_per_mm = None if pulses_per_mm is None else [float(x) for x in pulses_per_mm]
        self._slot = np.zeros(axes, np.int64)
        self._offsets = None
        self._tick = 0
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._quit = False
        self.error: str = ""
        self.writes = 0
        self._thread = threading.Thread(target=self._run, name="pmctl-counter-writer", daemon=True)
        self._thread.start()

    def offer(self, counts, tick: int, offsets=None) -> None:
        """``offsets`` (a re-reference changed them): from now on written with these counters."""
        with self._lock:
            self._slot[:] = counts
            self._tick = tick
            if offsets is not None:
                self._offsets = np.array(offsets, np.int64)
        self._wake.set()

    def _run(self):
        while True:
            self._wake.wait()
            self._wake.clear()
            if self._quit:
                return
            with self._lock:
                c = self._slot.copy()
                tick = self._tick
                off = self._offsets
            try:
                save_counters(self.path, c, machine=self.machine, clean=False, tick=tick, offsets=off,
                              pulses_per_mm=self.pulses_per_mm)
                self.writes += 1
            except OSError as e:
                self.error = f"cannot write {self.path}: {e.strerror or e}"

    def stop(self, counts=None, tick: int = 0, clean: bool = True) -> None:
        """End the thread; with ``counts``, write them synchronously (``clean`` = controlled stop)."""
        self._quit = True
        self._wake.set()
        self._thread.join(timeout=5.0)
        if counts is not None:
            save_counters(self.path, counts, machine=self.machine, clean=clean, tick=tick,
                          pulses_per_mm=self.pulses_per_mm)
            self.writes += 1
