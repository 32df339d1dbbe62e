"""The state journal: what the controller must remember across a restart besides the pulse
counters (which the rt process keeps in its own counter file, pmctl.motion.state_store).

``<state file>.journal`` holds, as one JSON object written atomically (temp file, fsync, rename,
fsync of the folder): the work offsets (G54-G59.3 with their XY rotations, G92, the active system,
the G28/G30 positions: pmctl.task.rs274's ``offsets()``; older journals without the new keys load), the console settings
($10), whether the machine is homed, the job in progress (its file, or "console"), its line and
the pose it was planned from (for a resume), and when it was written. A
damaged journal is an error naming the file: the daemon does not guess offsets.
"""

from __future__ import annotations

import json
import math
import threading
import time
from pathlib import Path

from pmctl.core.errors import InputError
from pmctl.motion.state_store import atomic_write      # shared with the pulse counters
from pmctl.task.rs274.modal import WCS_NAMES           # G54-G59.3

FORMAT = "pmctl-journal/1"


def _numbers(v, n) -> bool:
    """``v`` is a list of ``n`` finite numbers (no booleans)."""
    return isinstance(v, list) and len(v) == n and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)


def journal_path(state_file) -> Path:
    return Path(str(state_file) + ".journal")

class Journal:
    """In-memory journal with ``save()``; ``path`` None keeps it in memory only."""

    def __init__(self, path, machine: str):
        self.path = Path(path) if path else None
        self.machine = machine
        self.data = {"format": FORMAT, "machine": machine, "offsets": {}, "settings": {"10": 1},
                     "homed": False, "job": None, "line": 0, "running": False, "wall_time": 0.0}
        self.loaded = False
        self._save_lock = threading.Lock()

    def load(self):
        if self.path is None:
            return self
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return self
        except OSError as e:
            raise InputError(self.path, None, f"cannot read the journal: {e.strerror or e}") from None
        try:
            d = json.loads(text)
        except json.JSONDecodeError as e:
            raise InputError(self.path, e.lineno, f"journal is not valid JSON: {e.msg}", column=e.colno) from None
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise InputError(self.path, 1, f"format: expected {FORMAT!r}")
        if d.get("machine") != self.machine:
            raise InputError(self.path, 1, f"machine: journal is for {d.get('machine')!r}, not {self.machine!r}")
        off = d.get("offsets", {})
        if not isinstance(off, dict):
            raise InputError(self.path, 1, "offsets: expected an object")
        wcs = off.get("wcs", {})
        if not isinstance(wcs, dict):
            raise InputError(self.path, 1, "offsets.wcs: expected an object")
        for k, v in wcs.items():
            if k not in WCS_NAMES:
                raise InputError(self.path, 1, f"offsets.wcs.{k}: not a work coordinate system (G54-G59.3)")
            if not _numbers(v, 5):
                raise InputError(self.path, 1, f"offsets.wcs.{k}: expected 5 numbers")
        for k in ("g92", "g28", "g30"):
            if not _numbers(off.get(k, [0.0] * 5), 5):
                raise InputError(self.path, 1, f"offsets.{k}: expected 5 numbers")
        rot = off.get("rotation", {})
        if not isinstance(rot, dict) or any(k not in WCS_NAMES or not _numbers([v], 1) for k, v in rot.items()):
            raise InputError(self.path, 1, "offsets.rotation: expected work coordinate system -> degrees")
        if off.get("active", "G54") not in WCS_NAMES:
            raise InputError(self.path, 1, f"offsets.active: expected one of G54-G59.3, got {off.get('active')!r}")
        settings = d.get("settings", {})
        s10 = settings.get("10", 1) if isinstance(settings, dict) else None
        if isinstance(s10, bool) or not isinstance(s10, int) or not 0 <= s10 <= 255:
            raise InputError(self.path, 1, "settings.10: expected the $10 mask, an integer 0..255")
        job = d.get("job")
        if job is not None and not isinstance(job, str):
            raise InputError(self.path, 1, "job: expected a file name or null")
        line = d.get("line", 0)
        if not (isinstance(line, int) and not isinstance(line, bool) and line >= 0):
            raise InputError(self.path, 1, "line: expected a line number >= 0")
        start = d.get("job_start")
        if start is not None and not (isinstance(start, list) and len(start) == 6
                                      and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in start)):
            raise InputError(self.path, 1, "job_start: expected 6 numbers (tool tip and axis) or null")
        if not isinstance(d.get("homed", False), bool):
            raise InputError(self.path, 1, "homed: expected true or false")
        self.data.update(d)
        self.loaded = True
        return self

    def save(self, **changes):
        """Update and write the whole journal. One writer at a time: the console (offsets) and the
        daemon's job tracking (line, homed) save from their own threads, and a write that took its
        copy of the data before another's update must not land after it."""
        with self._save_lock:
            self.data.update(changes)
            self.data["wall_time"] = time.time()
            if self.path is not None:
                atomic_write(self.path, json.dumps(self.data) + "\n")
