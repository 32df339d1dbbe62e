"""The console's line interpreter: pmctl's RS-274 interpreter (pmctl.task.rs274) run one line at a time,
with the modal state, the work offsets and the tool offset kept from line to line, and grbl's error
codes for the sender.

It is the same interpreter as a job file's (the same words, meanings and refusals: docs/gcode.md),
with these differences of the console:

- the modal state starts (and a soft reset or M2/M30 returns to) grbl's: G0 G54 G17 G21 G90 G94 M5
  M9, no feed, no tool length offset (``reset_modal``);
- the coordinate systems, G92 and the G28/G30 positions persist in the journal (``offsets()``, the
  format of ``{"wcs": {"G54": [x, y, z, a, b], ...}, "g92": [...], "active": "G54", "g28": ...,
  "g30": ...}``; older journals with only ``wcs``/``g92``/``active`` load as they are);
- a line without motion still gives its events as an ``EVENT`` move (M3/M4/M5/S, M7/M8/M9, M6,
  M62-M68, G43/G43.1/G49, messages, pauses), so the console queues them in program order;
- O-word control flow spans lines and runs in job files only; a single-line ``o<name> call`` of a
  subroutine file on the subroutine path runs here too. Cutter compensation (its corners need the
  next move) runs in job files only.

A line with a problem changes nothing (its modal changes included) and raises :class:`LineError`
with grbl's error code; the probe flag ``st.probe_ok = False`` refuses G38 (a reader with no stop on
contact).
"""

from __future__ import annotations

import re

import numpy as np

from pmctl.core.errors import InputError
from pmctl.task.job import DWELL, EVENT, Job
from pmctl.task.rs274 import make_config, start_position
from pmctl.task.rs274.flow import Source
from pmctl.task.rs274.program import Interpreter
from pmctl.task.rs274.words import LexError

AXES = "XYZAB"
WCS_NAMES = ("G54", "G55", "G56", "G57", "G58", "G59")     # grbl's ($# lists these)
_ALL_WCS = ("G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3")


class LineError(Exception):
    def __init__(self, code: int, msg: str):
        super().__init__(msg)
        self.code = code


_CODES = [   # (pattern in the message, grbl 1.1 error code); first match wins
    (r"expected a word letter|'\)' without|comment|never closed|nested", 1),
    (r"missing value|missing parameter|bad value|is not an integer", 2),
    (r"line number", 27),
    (r"two G-codes of the same modal group|two M-codes of the same modal group", 21),
    (r"both use the axis words", 24),
    (r"appears twice", 25),
    (r"with no F|F0: the feed|feed rate must be > 0", 22),
    (r"needs axis words", 26),
    (r"with no motion mode|G80 \(which cancels", 31),
    (r"G53 needs G0 or G1", 30),
    (r"needs P|needs L|needs Q|needs D|needs H|needs E|needs R|needs its centre|needs an axis word", 28),
    (r"radius|too small to reach|R arc", 33),
    (r"has nothing to use it", 36),
    (r"out of range|must be", 4),
]


def error_code(msg: str, kind: str = "syntax") -> int:
    """grbl 1.1 error code of an interpreter problem (20: an unsupported command, and what this machine
    lacks; a syntax problem by its message)."""
    if kind in ("unsupported", "machine"):
        return 20
    for pat, code in _CODES:
        if re.search(pat, msg):
            return code
    return 20


class _Snapshot:
    """The console interpreter's whole state (``interp.st``): restorable (``interp.st = saved``), with
    the modes a jog needs (``units``: mm per program unit, ``absolute``) and the probe switch."""

    def __init__(self, owner, state=None):
        it = owner.it
        self._owner = owner
        self.state = state if state is not None else (it.ex.st.copy(), list(it.params.numbered),
                                                      dict(it.params.globals), it.cfg.tools)

    def __deepcopy__(self, memo):
        st, num, glob, tools = self.state
        return _Snapshot(self._owner, (st.copy(), list(num), dict(glob), tools))

    @property
    def units(self):
        return self.state[0].units

    @property
    def absolute(self):
        return self.state[0].absolute

    @property
    def probe_ok(self):
        return self._owner.it.cfg.probe_ok

    @probe_ok.setter
    def probe_ok(self, v):
        self._owner.it.cfg.probe_ok = bool(v)


class LineInterpreter:
    def __init__(self, machine, tip, axis, offsets=None, *, config=None):
        self.machine = machine
        from pmctl.task.job import home_pose
        cfg = make_config(config, home=home_pose(machine), ahead=False)
        self.it = Interpreter(cfg, start_position(tip, axis), offsets or None)
        self.line_no = 0
        self.changed = False           # offsets changed (persist them)
        self._reset_state()

    # ---- state
    @property
    def st(self):
        return _Snapshot(self)

    @st.setter
    def st(self, snap):
        st, num, glob, tools = snap.state
        it = self.it
        it.ex.st = st.copy()
        it.params.numbered[:] = num
        it.params.globals.clear()
        it.params.globals.update(glob)
        it.cfg.tools = tools

    def offsets(self) -> dict:
        return self.it.offsets()

    @property
    def wcs(self) -> dict:
        return self.it.offsets()["wcs"]

    @property
    def g92(self) -> list:
        return list(self.it.ex.st.g92)

    @property
    def active(self) -> str:
        return _ALL_WCS[self.it.ex.st.cs - 1]

    def wco(self) -> list[float]:
        st = self.it.ex.st
        return [st.g5x[i] + st.g92[i] for i in range(5)]

    def tlo(self) -> float:
        """The tool length offset in force (mm; G43/G43.1, 0 after G49)."""
        return self.it.ex.st.tlo

    def position_w(self) -> list[float]:
        """The interpreter's current position: tip in W (mm) and A, B (deg)."""
        return [float(x) for x in self.it.ex.st.pos]

    def sync(self, tip, axis):
        """Set the interpreter's position to where the machine is (after a reset, a jog, a hold)."""
        self.it.ex.st.pos = start_position(tip, axis)

    def _reset_state(self):
        st = self.it.ex.st
        st.units, st.absolute, st.ijk_absolute, st.plane = 1.0, True, False, 170
        st.motion, st.feed_mode, st.feed, st.speed, st.spindle = 0, 940, 0.0, 0.0, 0
        st.mist = st.flood = False
        st.comp, st.comp_first, st.cq, st.cq_end = 0, True, (), None
        st.cycle = st.cycle_il = None
        st.path, st.tolerance, st.naive_tolerance = 640, 0.0, 0.0
        st.tlo, st.tlo_code = 0.0, 490
        st.ended = False

    def reset_modal(self):
        """Soft reset: G0 G54 G17 G21 G90 G94 M5 M9 G49, no feed (offsets are kept)."""
        self._reset_state()
        if self.it.ex.st.cs != 1:
            self.it.ex.select_cs(self.it.ex.st, 1)
            self.changed = True           # journalled (the console persists after the reset)

    def parser_state(self) -> str:
        st = self.it.ex.st
        motion = {0: "G0", 10: "G1", 20: "G2", 30: "G3", 382: "G38.2", 383: "G38.3", 800: "G80"}.get(
            st.motion, f"G{st.motion // 10}" + (f".{st.motion % 10}" if st.motion % 10 else ""))
        wcs = _ALL_WCS[st.cs - 1]
        plane = {170: "G17", 180: "G18", 190: "G19"}[st.plane]
        coolant = " ".join(x for x, on in (("M7", st.mist), ("M8", st.flood)) if on) or "M9"
        spindle = {1: "M3", -1: "M4", 0: "M5"}[st.spindle]
        feed = (st.feed or 0.0) / st.units
        fm = {930: "G93", 940: "G94", 950: "G95"}[st.feed_mode]
        return (f"{motion} {wcs} {plane} {'G20' if st.units != 1.0 else 'G21'} {'G90' if st.absolute else 'G91'} "
                f"{fm} {spindle} {coolant} T{st.tool} F{feed:g} S{st.speed:g}")

    # ---- a line
    def _offset_key(self):
        num = self.it.params.numbered
        return (tuple(num[5161:5391]), self.it.ex.st.cs)

    def execute(self, text: str, seq: int):
        """Execute one line. Returns (moves, n_word, flags) where flags has 'end' (M2/M30) and
        'sync' (an offset changed). Raises LineError; on an error nothing changes."""
        saved = _Snapshot(self)
        try:
            return self._execute(text, seq)
        except LineError:
            self.st = saved
            raise

    def _execute(self, text, seq):
        it = self.it
        try:
            src = Source(text, "console")
            ln = src.lex(0) if src.lines else None
        except LexError as e:
            raise LineError(error_code(e.message), e.message) from None
        if ln is not None and ln.oword is not None and ln.oword.keyword != "call":
            raise LineError(20, "O-word control flow runs in job files; at the console only a single-line "
                                "o<name> call of a subroutine file")
        if ln is not None and ln.grbl is not None:
            raise LineError(3, "not a G-code line")
        if src.problems:
            raise LineError(error_code(src.problems[0].message), src.problems[0].message)
        if ln is None or ln.percent or (ln.blank and not ln.comments):
            return [], 0, {}
        n_word = 0
        for letter, v, _ in ln.words:
            if letter == "n" and v.__class__ is float:
                if v != int(v) or not 0 <= v <= 9_999_999:
                    raise LineError(27, f"line number N{v:g} out of range")
                n_word = int(v)
        for letter, v, _ in ln.words:
            if letter == "g" and v.__class__ is float and round(v * 10) in (410, 420, 411, 421):
                raise LineError(20, "cutter compensation (G41/G42) runs in job files only: its corners need "
                                    "the next move")
        before = self._offset_key()
        mark, pmark = len(it.moves), len(it.problems)
        it.ex.st.ended = False
        if ln.oword is not None:
            it.run_program(src)
            result = "end" if it.ex.st.ended else None
        else:
            result = it.block(src, 0, ln, lineno=seq)
            it.ex.flush_events(it.ex.st)
        moves = it.moves[mark:]
        del it.moves[mark:]
        del it.messages[:]
        if len(it.problems) > pmark:
            p = it.problems[pmark]
            del it.problems[pmark:]
            raise LineError(error_code(p.message, p.kind), p.message)
        del it.problems[:]
        flags = {}
        if result == "end":
            flags["end"] = True
            self.reset_modal()
        if self._offset_key() != before:
            self.changed = True
        if self.changed:
            flags["sync"] = True
        ends = [m for m in moves if m.kind != DWELL and m.kind != EVENT]
        if ends:
            from pmctl.task.gcode import check_job_reach
            try:
                check_job_reach(moves_job(moves), self.machine, "console")
            except InputError as e:
                raise LineError(33, f"target unreachable: {str(e).split(': ', 2)[-1]}") from None
        return moves, n_word, flags


def moves_job(moves, name="console") -> Job:
    ends = [m for m in moves if m.kind != DWELL and m.kind != EVENT]
    pts = np.array([m.tip for m in ends], float).reshape(-1, 3)
    return Job(tuple(moves), name, pts, np.array([m.line for m in ends], int))

