"""Line-by-line G-code interpreter for streamed lines (the operator console): modal state kept from
line to line, work offsets, and the same reader and reachability check as a job file.

Each line is tokenised and executed by pmctl.task.gcode (the job reader's own line executor), after
the codes a job file does not use are taken out here:
- work coordinate systems ``G54``-``G59``, ``G10 L2 Pn`` (set offset) and ``G10 L20 Pn`` (set so
  that the current position reads the given value), ``G92`` / ``G92.1``, ``G53`` (machine
  coordinates for this line);
- ``M7 M8 M9`` (coolant) and ``T`` (tool number) are accepted and ignored (no such hardware).
Coordinates of X Y Z A B in absolute mode are program (work) coordinates: W = program + WCO, with
WCO = the active G5x offset + the G92 offset. A line with an error changes nothing (its modal
changes included): the state is restored. Errors raise :class:`LineError` with grbl's error code.
"""

from __future__ import annotations

import copy
import math

import numpy as np

from pmctl.core.errors import InputError
from pmctl.task import gcode as G
from pmctl.task.job import DWELL, Job, check_reach

AXES = "XYZAB"
WCS_NAMES = ("G54", "G55", "G56", "G57", "G58", "G59")


class LineError(Exception):
    def __init__(self, code: int, msg: str):
        super().__init__(msg)
        self.code = code


def error_code(msg: str) -> int:
    """grbl 1.1 error code of a reader message."""
    m = msg
    if "expected a word letter" in m:
        return 1
    if "missing value" in m or "bad number" in m:
        return 2
    if "unknown word" in m or "unsupported G-code" in m or "unsupported M-code" in m:
        return 20
    if "two motion codes" in m or "conflicting modal" in m:
        return 21
    if "no F" in m:
        return 22
    if "repeated" in m:
        return 25
    if "line number" in m:
        return 27
    if "G4 dwell needs P" in m:
        return 28
    if "arc" in m and ("radius" in m or "R " in m or "|R|" in m):
        return 33
    if "I/J/R words need" in m or "without an arc end" in m:
        return 36
    if "axis words with no motion mode" in m:
        return 31
    if "only goes with G4" in m:
        return 36
    if "comment" in m:
        return 1
    if "must be" in m:
        return 4
    return 20


class LineInterpreter:
    def __init__(self, machine, tip, axis, offsets=None):
        self.machine = machine
        self.st = G._State(tip, axis)
        o = offsets or {}
        self.wcs = {n: list(map(float, o.get("wcs", {}).get(n, [0.0] * 5))) for n in WCS_NAMES}
        self.g92 = list(map(float, o.get("g92", [0.0] * 5)))
        self.active = o.get("active", "G54") if o.get("active", "G54") in WCS_NAMES else "G54"
        self.line_no = 0
        self.changed = False           # offsets changed (persist them)

    # ---- state
    def offsets(self) -> dict:
        return {"wcs": {k: list(v) for k, v in self.wcs.items()}, "g92": list(self.g92), "active": self.active}

    def wco(self) -> list[float]:
        w = self.wcs[self.active]
        return [w[i] + self.g92[i] for i in range(5)]

    def position_w(self) -> list[float]:
        """The interpreter's current position: tip in W (mm) and A, B (deg)."""
        return [*map(float, self.st.pos), self.st.a, self.st.b]

    def sync(self, tip, axis):
        """Set the interpreter's position to where the machine is (after a reset, a jog, a hold)."""
        from pmctl.core import kinematics as K
        self.st.pos = np.array(tip, float)
        a, b = K.roll_pitch_from_axis(np.asarray(axis, float))
        self.st.a, self.st.b = math.degrees(float(a)), math.degrees(float(b))

    def reset_modal(self):
        """Soft reset: G0 G54 G17 G21 G90 G94 M5, no feed (offsets are kept)."""
        st = self.st
        st.units, st.absolute, st.motion, st.feed, st.s, st.spindle_on = 1.0, True, None, None, 0.0, False
        if self.active != "G54":
            self.active = "G54"
            self.changed = True           # journalled (the console persists after the reset)

    def parser_state(self) -> str:
        st = self.st
        motion = {None: "G0", 0: "G0", 10: "G1", 20: "G2", 30: "G3"}[st.motion]
        feed = (st.feed or 0.0) * 60.0 / st.units
        return (f"{motion} {self.active} G17 {'G20' if st.units != 1.0 else 'G21'} {'G90' if st.absolute else 'G91'} "
                f"G94 {'M3' if st.spindle_on else 'M5'} M9 T0 F{feed:g} S{st.s:g}")

    # ---- a line
    def execute(self, text: str, seq: int):
        """Execute one line. Returns (moves, n_word, flags) where flags has 'end' (M2/M30) and
        'sync' (an offset changed). Raises LineError; on an error nothing changes."""
        saved = (copy.deepcopy(self.st), copy.deepcopy(self.wcs), list(self.g92), self.active)
        try:
            return self._execute(text, seq)
        except LineError:
            self.st, self.wcs, self.g92, self.active = saved
            raise
        except InputError as e:
            self.st, self.wcs, self.g92, self.active = saved
            raise LineError(error_code(str(e)), str(e).split(": ", 1)[-1]) from None

    def _execute(self, text, seq):
        path = "console"
        chars = G._strip_comments(text, path, seq)
        if not chars or (len(chars) == 1 and chars[0][1] == "%"):
            return [], 0, {}
        # pull out what the job reader does not know, as raw (letter, value) words
        words = _tokens(chars, path, seq)
        gcodes = [round(v * 10) for k, v, _ in words if k == "G"]
        n_word = 0
        flags = {}
        keep = []
        g10 = g92 = g53 = False
        for k, v, col in words:
            if k == "G":
                c = round(v * 10)
                if c in (540, 550, 560, 570, 580, 590):
                    name = WCS_NAMES[(c - 540) // 10]
                    if name != self.active:       # the active system is journalled with the offsets
                        self.active = name
                        self.changed = True
                        flags["sync"] = True
                    continue
                if c in (591, 592, 593):
                    raise LineError(29, "G59.1-G59.3 are not supported")
                if c == 100:
                    g10 = True
                    continue
                if c == 920:
                    g92 = True
                    continue
                if c == 921:
                    self.g92 = [0.0] * 5
                    self.changed = True
                    flags["sync"] = True
                    continue
                if c == 530:
                    g53 = True
                    continue
                if c in (800, 940, 490, 400, 610):
                    continue              # cancel modes that are already in force
            if k == "M" and v in (7, 8, 9):
                continue
            if k == "T":
                continue
            if k == "N":
                if v != int(v) or not 0 <= v <= 9_999_999:
                    raise LineError(27, f"line number N{v:g} out of range")
                n_word = int(v)
            keep.append((k, v, col))
        if not g10 and any(k == "L" for k, _, _ in keep):
            raise LineError(20, "'L' only goes with G10")
        if g10 or g92:
            self._offset_command(keep, g10, g92, gcodes)
            flags["sync"] = True
            return [], n_word, flags
        # program -> W coordinates: absolute axis words get the work offset (G53: none)
        st = self.st
        absolute = st.absolute
        for k, v, _ in keep:
            if k == "G" and round(v * 10) in (900, 910):
                absolute = round(v * 10) == 900
            if k == "G" and round(v * 10) in (200, 210):
                pass
        wco = [0.0] * 5 if g53 else self.wco()
        units = st.units
        for k, v, _ in keep:
            if k == "G" and round(v * 10) == 200:
                units = G.MM_PER_INCH
            if k == "G" and round(v * 10) == 210:
                units = 1.0
        out = []
        for k, v, col in keep:
            if absolute and k in AXES:
                i = AXES.index(k)
                off = wco[i] / (units if i < 3 else 1.0)
                v = v + off
            out.append((k, v, col))
        moves, points, plines = [], [], []
        end = G._execute_line(out, st, path, seq, moves, points, plines)
        if end:
            flags["end"] = True
            self.reset_modal()
            if self.changed:
                flags["sync"] = True      # M2/M30 went back to G54: journalled
        ends = [m for m in moves if m.kind != DWELL]
        if ends:
            tips = np.array([m.tip for m in ends])
            axes = np.array([m.axis for m in ends])
            try:
                check_reach(tips, axes, np.full(len(ends), seq), self.machine, path)
            except InputError as e:
                raise LineError(33, f"target unreachable: {str(e).split(': ', 2)[-1]}") from None
        return moves, n_word, flags

    def _offset_command(self, words, g10, g92, gcodes):
        vals = {k: v for k, v, _ in words if k in AXES or k in "LP"}
        other = [k for k, _, _ in words if k not in AXES and k not in "LPN"]
        if other:
            raise LineError(24 if "G" in other else 36, "offset commands take only axis words (and L, P)")
        st = self.st
        cur = self.position_w()
        u = st.units
        if g92:
            if not any(k in vals for k in AXES):
                raise LineError(26, "G92 needs axis words")
            w = self.wcs[self.active]
            for i, k in enumerate(AXES):
                if k in vals:
                    p = vals[k] * (u if i < 3 else 1.0)
                    self.g92[i] = cur[i] - w[i] - p
        else:
            L = vals.get("L")
            P = vals.get("P", 0)
            if L not in (2, 20):
                raise LineError(28, "G10 needs L2 or L20")
            if P != int(P) or not 0 <= P <= 6:
                raise LineError(29, "G10 P must be 0 (active) or 1-6 (G54-G59)")
            name = self.active if int(P) == 0 else WCS_NAMES[int(P) - 1]
            w = self.wcs[name]
            for i, k in enumerate(AXES):
                if k in vals:
                    p = vals[k] * (u if i < 3 else 1.0)
                    w[i] = p if L == 2 else cur[i] - self.g92[i] - p
        self.changed = True


def _tokens(chars, path, lineno):
    """(letter, value, column) words of a comment-free line; letters outside the job reader's set
    that the console knows (T) are accepted here."""
    text = "".join(c for _, c in chars)
    cols = [c for c, _ in chars]
    words = []
    i = 0
    while i < len(text):
        letter = text[i].upper()
        col = cols[i]
        if not letter.isalpha():
            raise LineError(1, f"expected a word letter, got {text[i]!r}")
        m = G._NUMBER.match(text, i + 1)
        if not m:
            raise LineError(2, f"missing value after '{letter}'")
        if letter not in G.LETTERS and letter not in "LT":
            raise LineError(20, f"unknown word {letter}{m.group(0)}")
        words.append((letter, float(m.group(0)), col))
        i = m.end()
    return words


def moves_job(moves, name="console") -> Job:
    pts = np.array([m.tip for m in moves if m.kind != DWELL], float).reshape(-1, 3)
    return Job(tuple(moves), name, pts, np.array([m.line for m in moves if m.kind != DWELL], int))
