"""Executing one block (a line's words) in LinuxCNC's order of execution, producing moves.

The order within a block (LinuxCNC's "G-code order of execution"): comments and messages; feed mode
(G93 G94 G95); F; S; T; outputs (M62-M68); tool change (M6, M61); spindle (M3 M4 M5); coolant (M7 M8
M9); user M-codes (M100-M199); dwell (G4); plane (G17 G18 G19); units (G20 G21); cutter compensation
(G40 G41 G42); tool length (G43 G43.1 G49); coordinate system (G54 .. G59.3); path control (G61 G61.1
G64); distance mode (G90 G91, G90.1 G91.1); retract mode (G98 G99); G10 G28 G30 G52 G92; motion (G0
G1 G2 G3 G38.2 G38.3 G73 G74 G81-G89, with G53); stops (M0 M1 M2 M30 M60).

What happens on the way is recorded as ``EVENT`` moves at the point the path reaches (spindle,
coolant, tool change, tool offset, outputs, messages, pauses, user M-codes), in program order:
the events of one block before its motion go in one EVENT move, a stop after it in another.

A problem raises :class:`Refusal` (kind syntax / unsupported / machine, the message, the column);
the caller (pmctl.task.rs274.program) then drops the whole block: the state the block started from
is kept (the executor works on a copy and commits it at the end).
"""

from __future__ import annotations

import math

import numpy as np

from pmctl.core import kinematics as K
from pmctl.task.job import ARC, DWELL, EVENT, LINE, RAPID, Move
from pmctl.task.rs274 import arcs as A
from pmctl.task.rs274 import parameters as P
from pmctl.task.rs274.expressions import EvalError
from pmctl.task.rs274.modal import (AXIS_USERS, CYCLES, G_GROUP, G_REFUSED, M_GROUP, M_REFUSED, M_USER,
                                    MM_PER_INCH, SAVED_MODES, WCS_CODES, WCS_NAMES)

MAX_DWELL_S = 3600.0
MAX_ARC_TURNS = 1000
# Largest |value| of a word (program units, degrees, per minute, rpm, seconds): beyond, a typo.
WORD_LIMITS = {"n": 99_999_999, "g": 999, "m": 999, "f": 1e8, "@": 1e5, "^": 1e6, "s": 1e6, "p": 1e12, "q": 1e12, "l": 1e6,
               "t": 99_999, "h": 99_999, "d": 99_999, "e": 1e6, **{k: 1e5 for k in "xyzijkr"},
               "a": 1e4, "b": 1e4, "c": 1e5, "u": 1e5, "v": 1e5, "w": 1e5}
WORD_MEANING = {"i": "an arc centre (G2/G3) or G87", "j": "an arc centre (G2/G3) or G87",
                "k": "an arc centre (G2/G3) or G87", "r": "an arc radius (G2/G3), a canned cycle's R plane or G10",
                "p": "G4, G10, G64, an arc's turns, a canned cycle's dwell, M62-M68 or a user M-code",
                "q": "G64, a peck cycle (G73 G83), M66-M68 or a user M-code",
                "l": "G10 or a canned cycle's repeats", "d": "cutter compensation (G41 G42)",
                "h": "G43", "e": "M66-M68"}
AXIS_INDEX = {"x": 0, "y": 1, "z": 2, "a": 3, "b": 4}
_FAST_LETTERS = frozenset("xyzabfn")
MODE_SWITCHES = (434, 435, 531, 682)   # another machine's TCP / tilted-plane modes: noted, the line goes on


class Refusal(Exception):
    """A problem with a block: ``kind`` (syntax / unsupported / machine), message, column."""

    def __init__(self, kind, message, column=None):
        super().__init__(message)
        self.kind, self.message, self.column = kind, message, column


def gname(code: int) -> str:
    """G-code text of a code x 10: 382 -> 'G38.2'."""
    return f"G{code // 10}" + (f".{code % 10}" if code % 10 else "")


def fmt(v: float) -> str:
    return f"{v:.6f}".rstrip("0").rstrip(".") if math.isfinite(v) else str(v)


def whole(value, word, column, what):
    """A word that must be a non-negative integer (a tool number, a line number): its int, or a Refusal
    saying what the word is."""
    if value != int(value) or value < 0:
        raise Refusal("syntax", f"{word}{fmt(value)}: {what} (a non-negative integer)", column)
    return int(value)


class Block:
    """The evaluated words of a line: ``v`` letter -> value (program units), ``col`` letter ->
    column, ``g``/``m``: [(code, column)], ``comments``: [(text, column)]."""

    __slots__ = ("v", "col", "g", "m", "groups", "mgroups")

    def __init__(self):
        self.v, self.col, self.g, self.m = {}, {}, [], []
        self.groups, self.mgroups = {}, {}


class Config:
    """What the interpreter needs from the service config ([interpreter]) and the machine."""

    def __init__(self, tools, *, user_m_codes=(), optional_stop=True, block_delete=False, digital_outputs=4,
                 analog_outputs=4, subroutine_path=(), home=(0.0, 0.0, 0.0, 0.0, 0.0), probe_ok=True,
                 ahead=True):
        self.tools = tools
        self.user_m_codes = frozenset(user_m_codes)
        self.optional_stop = optional_stop
        self.block_delete = block_delete
        self.digital_outputs = digital_outputs
        self.analog_outputs = analog_outputs
        self.subroutine_path = tuple(subroutine_path)
        self.home = tuple(home)          # machine position of the home pose (G28/G30 default), X Y Z A B
        self.probe_ok = probe_ok
        self.ahead = ahead               # the program is interpreted before it runs (a job file)


class Executor:
    """Runs blocks against a state; appends Moves to ``moves``. ``file``: the Move.file of the
    lines being run ("" for the job's own file)."""

    def __init__(self, cfg: Config, params: P.Parameters, state, moves: list, messages: list):
        self.cfg = cfg
        self.params = params
        self.st = state
        self.moves = moves
        self.messages = messages
        self.file = ""
        self.line = 0
        self.events = []
        self._axes = {}
        self.probed = False           # a G38 ran: the probe result parameters are unknown ahead of the run
        self.comp = None              # cutter compensation engine (pmctl.task.rs274.cutter_comp), set by the caller
        self.notes = []               # problems of the block that do not stop it: (kind, message, column)
        self.saved = {}               # call level -> (modes saved by M70/M73, restore on return)
        self._install_dynamic()
        self.select_cs(self.st, self.st.cs)

    # ------------------------------------------------------------------ helpers
    def axis(self, a, b):
        key = (a, b)
        v = self._axes.get(key)
        if v is None:
            v = np.asarray(K.axis_from_roll_pitch(math.radians(a), math.radians(b)), float)
            v.setflags(write=False)
            if len(self._axes) > 4096:
                self._axes.clear()
            self._axes[key] = v
        return v

    def to_w(self, st, p):
        """Program coordinates (mm, deg; 5 values) -> W."""
        if st.rotation == 0.0:
            o = st.wco
            return [p[0] + o[0], p[1] + o[1], p[2] + o[2], p[3] + o[3], p[4] + o[4]]
        g, r = st.g92, math.radians(st.rotation)
        x, y = p[0] + g[0], p[1] + g[1]
        c, s = math.cos(r), math.sin(r)
        o = st.g5x
        return [c * x - s * y + o[0], s * x + c * y + o[1], p[2] + g[2] + o[2], p[3] + g[3] + o[3],
                p[4] + g[4] + o[4]]

    def to_prog(self, st, w):
        if st.rotation == 0.0:
            o = st.wco
            return [w[0] - o[0], w[1] - o[1], w[2] - o[2], w[3] - o[3], w[4] - o[4]]
        o, g, r = st.g5x, st.g92, math.radians(st.rotation)
        x, y = w[0] - o[0], w[1] - o[1]
        c, s = math.cos(r), math.sin(r)
        return [c * x + s * y - g[0], -s * x + c * y - g[1], w[2] - o[2] - g[2], w[3] - o[3] - g[3],
                w[4] - o[4] - g[4]]

    def rotate_vec(self, st, v):
        """A direction in program coordinates -> W (the XY rotation only)."""
        if st.rotation == 0.0:
            return v
        r = math.radians(st.rotation)
        c, s = math.cos(r), math.sin(r)
        return (c * v[0] - s * v[1], s * v[0] + c * v[1], v[2])

    def machine_of(self, st, w):
        """W tip -> machine coordinates of the reference point (the tip of the reference tool):
        tip + tool offset along the tool axis (G53, G28, G30)."""
        if st.tlo == 0.0:
            return list(w)
        ax = self.axis(w[3], w[4])
        return [w[0] + st.tlo * ax[0], w[1] + st.tlo * ax[1], w[2] + st.tlo * ax[2], w[3], w[4]]

    def from_machine(self, st, m):
        if st.tlo == 0.0:
            return list(m)
        ax = self.axis(m[3], m[4])
        return [m[0] - st.tlo * ax[0], m[1] - st.tlo * ax[1], m[2] - st.tlo * ax[2], m[3], m[4]]

    # ------------------------------------------------------------------ coordinate systems
    def select_cs(self, st, n):
        base = P.coordinate_base(n)
        num = self.params.numbered
        st.cs = n
        st.g5x = [num[base + i] for i in range(5)]
        st.rotation = num[base + 9]
        self._wco(st)

    def _wco(self, st):
        st.wco = [st.g5x[i] + st.g92[i] for i in range(5)]

    def note(self, kind, message, column=None):
        """A problem that leaves the block's meaning clear (what this machine lacks): recorded, and the
        block goes on as written, so the lines after it are read as the program means them."""
        self.notes.append((kind, message, column))

    # ------------------------------------------------------------------ output
    def event(self, name, value):
        if name == "spindle" and self.events and self.events[-1][0] == "spindle":
            self.events[-1] = (name, value)         # S then M4 on one line: one change, to the end state
        else:
            self.events.append((name, value))

    def spindle_now(self, st, rpm):
        """A spindle change where the path is now (canned cycles): its own EVENT move."""
        self.event("spindle", rpm)
        self.flush_events(st)

    def flush_events(self, st):
        if self.events:
            ev = tuple(self.events)
            self.events = []
            self.emit(st, Move(EVENT, np.array(st.pos[:3]), self.axis(st.pos[3], st.pos[4]), line=self.line,
                               spindle_rpm=self.rpm(st), tool_offset=st.tlo, events=ev, file=self.file))

    def emit(self, st, move):
        if self.comp is not None and self.comp.pending(st):
            self.comp.queue_other(st, move)
        else:
            self.moves.append(move)

    def rpm(self, st):
        return st.speed * st.spindle if st.spindle else 0.0

    def tolerance(self, st):
        return st.tolerance if st.path == 640 else 0.0

    def move(self, st, kind, end_w, *, feed=0.0, center=None, sweep=0.0, normal=None, duration=0.0, probe=0,
             record=True):
        """Append a move to W position ``end_w`` (5 values) and make it the current position."""
        self.flush_events(st)
        m = Move(kind, np.array(end_w[:3]), self.axis(end_w[3], end_w[4]), line=self.line, feed=feed,
                 spindle_rpm=self.rpm(st), center=center, sweep=sweep, probe=probe, normal=normal,
                 tool_offset=st.tlo, duration=duration, tolerance=self.tolerance(st), file=self.file)
        self.moves.append(m)
        st.pos = list(end_w)
        return m

    # ------------------------------------------------------------------ reading
    def read(self, line, lineno) -> Block:
        blk = Block()
        v, col = blk.v, blk.col
        params = self.params
        for letter, val, c in line.words:
            if val.__class__ is not float:
                params.column = c
                val = val.ev(params)
            lim = WORD_LIMITS.get(letter)
            if lim is not None and not -lim <= val <= lim:
                raise Refusal("syntax", f"{letter.upper()}{fmt(val)} is out of range (|{letter.upper()}| <= {lim:g})", c)
            if letter == "g":
                code = round(val * 10)
                if abs(val * 10 - code) > 1e-3:
                    raise Refusal("unsupported", f"G{fmt(val)} is not a G-code pmctl knows", c)
                blk.g.append((code, c))
            elif letter == "m":
                code = round(val)
                if abs(val - code) > 1e-4:
                    raise Refusal("unsupported", f"M{fmt(val)} is not an M-code pmctl knows", c)
                blk.m.append((code, c))
            else:
                if letter in v:
                    raise Refusal("syntax", f"word {letter.upper()} appears twice on the line "
                                            f"({letter.upper()}{fmt(v[letter])} and {letter.upper()}{fmt(val)})", c)
                v[letter] = val
                col[letter] = c
        return blk

    def keep_modes(self, blk):
        """After a refused block: the plain modal settings it made (units, distance modes, plane, feed mode
        and F, S, retract and path modes, motion mode) still hold for the lines after it, so that one bad
        word does not make every later line look wrong. Nothing moves, nothing switches on."""
        st, v, groups = self.st, blk.v, blk.groups
        for grp, attr, conv in ((6, "units", lambda c: MM_PER_INCH if c == 200 else 1.0),
                                (3, "absolute", lambda c: c == 900), (4, "ijk_absolute", lambda c: c == 901),
                                (2, "plane", lambda c: c), (10, "retract", lambda c: c), (13, "path", lambda c: c)):
            if grp in groups and not (grp == 2 and st.comp):
                setattr(st, attr, conv(groups[grp][0]))
        if 5 in groups:
            st.feed_mode = groups[5][0]
            st.feed = 0.0
        f = v.get("f")
        if f is not None and f.__class__ is float and f > 0 and st.feed_mode != 930:
            st.feed = f * st.units
        s = v.get("s")
        if s is not None and s.__class__ is float and s >= 0 and not st.spindle:
            st.speed = s
        if 1 in groups and groups[1][0] != 800:
            st.motion = groups[1][0]

    # ------------------------------------------------------------------ the common case, fast
    def fast_line(self, ln) -> bool:
        """A G0/G1 line of axis words, F and N only (most of what CAM writes), in G94 with no cutter
        compensation and no XY rotation: executed here without the general machinery. False: the
        caller runs the general path (which also reports any problem)."""
        st = self.st
        if st.comp or st.feed_mode != 940 or st.rotation != 0.0 or st.comp_base is not None or ln.comments \
                or ln.assigns:
            return False
        motion = st.motion
        vals = {}
        for letter, v, _ in ln.words:
            if letter in vals or v.__class__ is not float:
                return False
            if letter == "g":
                if v == 0.0:
                    motion = 0
                elif v == 1.0:
                    motion = 10
                else:
                    return False
            elif letter not in _FAST_LETTERS:
                return False
            lim = WORD_LIMITS[letter]
            if not -lim <= v <= lim:
                return False
            vals[letter] = v
        if motion not in (0, 10):
            return False
        feed = st.feed
        if "f" in vals:
            if vals["f"] < 0:
                return False
            feed = vals["f"] * st.units
        n = vals.get("n")
        if n is not None and (n != int(n) or n < 0):
            return False
        has_axes = "x" in vals or "y" in vals or "z" in vals or "a" in vals or "b" in vals
        if motion == 10 and not feed > 0 and (has_axes or "g" in vals):
            return False
        if not has_axes and "g" not in vals:
            st.feed = feed
            return True
        o, u, pos = st.wco, st.units, st.pos
        if st.absolute:
            end = [vals["x"] * u + o[0] if "x" in vals else pos[0], vals["y"] * u + o[1] if "y" in vals else pos[1],
                   vals["z"] * u + o[2] if "z" in vals else pos[2], vals["a"] + o[3] if "a" in vals else pos[3],
                   vals["b"] + o[4] if "b" in vals else pos[4]]
        else:
            end = [pos[0] + vals.get("x", 0.0) * u, pos[1] + vals.get("y", 0.0) * u, pos[2] + vals.get("z", 0.0) * u,
                   pos[3] + vals.get("a", 0.0), pos[4] + vals.get("b", 0.0)]
        st.motion, st.feed, st.arc_not_allowed, st.cycle_il = motion, feed, False, None
        if not has_axes:
            return True
        axis = self.axis(end[3], end[4])
        self.moves.append(Move(RAPID if motion == 0 else LINE, np.array(end[:3]), axis, line=self.line,
                               feed=0.0 if motion == 0 else feed / 60.0,
                               spindle_rpm=st.speed * st.spindle if st.spindle else 0.0, tool_offset=st.tlo,
                               tolerance=st.tolerance if st.path == 640 else 0.0, file=self.file))
        st.pos = end
        return True

    # ------------------------------------------------------------------ checks
    def check_codes(self, st, blk):
        groups = blk.groups
        for code, c in blk.g:
            if code == 51 and "q" in blk.v and not any(k in blk.v for k in "xyzijpr"):
                groups[16] = (code, c)             # Fanuc's G5.1 Q (AI contour control), not a spline: no effect
                continue
            ref = G_REFUSED.get(code)
            if ref is not None:
                if ref[0] == "machine" and code in MODE_SWITCHES:
                    self.note("machine", f"{gname(code)}: {ref[1]}", c)   # noted; the rest of the line runs
                    continue
                raise Refusal(ref[0], f"{gname(code)}: {ref[1]}", c)
            grp = G_GROUP.get(code)
            if grp is None:
                raise Refusal("unsupported", f"{gname(code)} is not a G-code pmctl knows (docs/gcode.md lists "
                                             "the ones it runs)", c)
            if grp == 1 and (code == 800 or groups.get(1, (None,))[0] == 800):
                if code == 800 and grp in groups:
                    continue                       # LinuxCNC: G80 beside another motion code is ignored
            elif grp in groups and not (grp == 17):
                raise Refusal("syntax", f"two G-codes of the same modal group on one line ({gname(groups[grp][0])} "
                                        f"and {gname(code)}): keep one", c)
            if code in (382, 383) and not self.cfg.probe_ok:
                raise Refusal("unsupported", f"{gname(code)}: probing is not available here (it runs in 'pmctl run' "
                                             "and at the console, which stop on contact)", c)
            groups[grp] = (code, c)
        mg = blk.mgroups
        for code, c in blk.m:
            ref = M_REFUSED.get(code)
            if ref is not None:
                if ref[0] == "machine":
                    self.note("machine", f"M{code}: {ref[1]}", c)          # noted; the rest of the line runs
                    continue
                raise Refusal(ref[0], f"M{code}: {ref[1]}", c)
            if code in M_USER:
                if code not in self.cfg.user_m_codes:
                    raise Refusal("unsupported", f"M{code}: user M-codes (M100-M199) run only when configured: "
                                                 "list it in [interpreter] user_m_codes of the service config", c)
                grp = 10
            else:
                grp = M_GROUP.get(code)
                if grp is None:
                    raise Refusal("unsupported", f"M{code} is not an M-code pmctl knows (docs/gcode.md lists the "
                                                 "ones it runs)", c)
            if grp in mg and not (grp == 8 and {mg[grp][0], code} == {7, 8}):
                raise Refusal("syntax", f"two M-codes of the same modal group on one line (M{mg[grp][0]} and "
                                        f"M{code}): keep one", c)
            mg[grp if not (grp == 8 and grp in mg) else 80] = (code, c)

    # ------------------------------------------------------------------ execution
    def run(self, st, blk, line):
        """Execute a block on ``st`` (a copy). Returns None, "end" (M2/M30), or ("m98", P, L) / "m99"."""
        v, col, groups, mg = blk.v, blk.col, blk.groups, blk.mgroups
        self.prev_motion = st.motion
        self.check_codes(st, blk)
        for letter in "cuvw":
            if letter in v:
                self.note("machine", f"{letter.upper()}{fmt(v[letter])}: axis {letter.upper()} is not on this "
                                     "machine (its axes are X Y Z and the tool tilts A B): the program was "
                                     "posted for another machine", col[letter])
                del v[letter]
        if "$" in v:                                          # pragma: no cover - the lexer has no '$'
            raise Refusal("unsupported", "spindle selection ($) is not supported", col["$"])
        if "n" in v:
            whole(v["n"], "N", col["n"], "the line number must be a whole number")
        g0 = groups.get(0, (None, None))[0]
        gm = groups.get(1, (None, None))[0]
        axis_words = [k for k in "xyzab@^" if k in v]
        tlo_axes = groups.get(8, (None,))[0] == 431
        motion = gm if gm is not None else st.motion
        if axis_words and not tlo_axes:
            if g0 in AXIS_USERS:
                if gm is not None and gm != 800 and not (g0 in (280, 300) and gm == 0):
                    raise Refusal("syntax", f"{gname(g0)} and {gname(gm)} both use the axis words: put them on "
                                            "separate lines", groups[1][1])
            elif gm == 800:
                raise Refusal("syntax", "axis words with G80 (which cancels the motion mode): put them on another "
                                        "line with G0/G1", col[axis_words[0]])
            elif motion == 800:
                raise Refusal("syntax", f"axis words with no motion mode (G0/G1/G2/G3/G38) active: "
                                        f"{axis_words[0].upper()}{fmt(v[axis_words[0]])} needs a motion code",
                              col[axis_words[0]])
        self.check_words(st, blk, g0, motion, axis_words)
        mcode = lambda grp: mg.get(grp, (None,))[0]  # noqa: E731

        # 1. comments are handled by the caller (messages), in order, before this
        # 2. feed mode
        fm = groups.get(5, (None,))[0]
        if fm is not None:
            st.feed_mode = fm
            if fm != 930:
                st.feed = 0.0                     # LinuxCNC: G94 and G95 clear the feed (F must follow)
        # 3. F
        if "f" in v:
            f = v["f"]
            if f < 0:
                raise Refusal("syntax", f"feed F{fmt(f)} must be > 0", col["f"])
            if st.feed_mode != 930:
                st.feed = f * st.units
        # 4. S
        if "s" in v:
            s = v["s"]
            if s < 0:
                raise Refusal("syntax", f"spindle speed S{fmt(s)} must be >= 0", col["s"])
            if s != st.speed:
                st.speed = s
                if st.spindle:
                    self.event("spindle", self.rpm(st))
        # 5. T
        if "t" in v:
            st.selected = whole(v["t"], "T", col["t"], "T is a tool number")
        # 6. outputs M62-M68
        io = mcode(5)
        if io is not None:
            self.outputs(st, blk, io)
        # 7. M6 / M61
        tc = mcode(6)
        if tc == 6:
            tool = st.selected if st.selected is not None else st.tool
            if st.comp:
                raise Refusal("syntax", "M6 with cutter compensation on: turn it off (G40) before a tool change",
                              mg[6][1])
            if st.spindle:
                st.spindle = 0
                self.event("spindle", 0.0)
            self.event("tool_change", tool)
            st.tool = tool
        elif tc == 61:
            if "q" not in v:
                raise Refusal("syntax", "M61 needs Q<tool number> (the tool now in the spindle)", mg[6][1])
            st.tool = whole(v["q"], "M61 Q", col["q"], "Q is the tool number")
        # 8. spindle
        sp = mcode(7)
        if sp is not None:
            d = {3: 1, 4: -1, 5: 0}[sp]
            if d != st.spindle:
                st.spindle = d
                self.event("spindle", self.rpm(st))
        # 9. coolant
        for grp in (8, 80):
            cc = mcode(grp)
            if cc == 7 and not st.mist:
                st.mist = True
                self.event("coolant", "mist")
            elif cc == 8 and not st.flood:
                st.flood = True
                self.event("coolant", "flood")
            elif cc == 9 and (st.mist or st.flood):
                st.mist = st.flood = False
                self.event("coolant", "off")
        # 9b. modal state: M70 save, M71 forget, M72 restore, M73 save and restore on return
        ms = mcode(12)
        if ms is not None:
            self.modal_state(st, ms, mg[12][1])
        # 10. user M-codes
        um = mcode(10)
        if um is not None:
            self.event("user_m", (um, float(v.get("p", 0.0)), float(v.get("q", 0.0))))
        # 11. dwell
        if g0 == 40:
            if "p" not in v:
                raise Refusal("syntax", "G4 dwell needs P<seconds>", groups[0][1])
            p = v["p"]
            if p < 0:
                raise Refusal("syntax", f"dwell P{fmt(p)} must be within 0 .. {MAX_DWELL_S:g} s", col["p"])
            if p > MAX_DWELL_S:
                self.note("machine", f"dwell P{fmt(p)} must be within 0 .. {MAX_DWELL_S:g} s: P is seconds here (as in "
                                     "LinuxCNC and grbl; some controllers read milliseconds)", col["p"])
            else:
                self.flush_events(st)
                self.dwell(st, p)
        # 12. plane
        pl = groups.get(2)
        if pl is not None:
            if st.comp and pl[0] != st.plane:
                raise Refusal("syntax", f"{gname(pl[0])} with cutter compensation on: turn it off (G40) first", pl[1])
            st.plane = pl[0]
        # 13. units
        un = groups.get(6)
        if un is not None:
            st.units = MM_PER_INCH if un[0] == 200 else 1.0
        # 14. cutter compensation
        cr = groups.get(7)
        if cr is not None:
            self.cutter_comp(st, blk, cr)
        # 15. tool length
        tl = groups.get(8)
        if tl is not None:
            self.tool_length(st, blk, tl)
        # 16. coordinate system
        cs = groups.get(12)
        if cs is not None:
            n = WCS_CODES.index(cs[0]) + 1
            if st.comp:
                raise Refusal("syntax", f"{WCS_NAMES[n - 1]} with cutter compensation on: turn it off (G40) first",
                              cs[1])
            self.select_cs(st, n)
        # 17. path control
        pc = groups.get(13)
        if pc is not None:
            st.path = pc[0]
            if pc[0] == 640:
                st.tolerance = v["p"] * st.units if "p" in v else 0.0
                st.naive_tolerance = v["q"] * st.units if "q" in v else st.tolerance
                if st.tolerance < 0 or st.naive_tolerance < 0:
                    raise Refusal("syntax", "G64 tolerances P and Q must be >= 0", col.get("p", col.get("q")))
        g187 = groups.get(16)
        if g187 is not None and g187[0] == 1870 and "e" in v:
            if v["e"] < 0:
                raise Refusal("syntax", "G187 E (the path tolerance) must be >= 0", col["e"])
            st.path, st.tolerance = 640, v["e"] * st.units
        # 18. distance modes
        dm = groups.get(3)
        if dm is not None:
            st.absolute = dm[0] == 900
        im = groups.get(4)
        if im is not None:
            st.ijk_absolute = im[0] == 901
        # 19. retract mode
        rm = groups.get(10)
        if rm is not None:
            st.retract = rm[0]
        # 20. G10 G28 G30 G52 G92 (G53 modifies the motion)
        g53 = g0 == 530
        if g0 is not None and g0 not in (40, 530):
            self.modal0(st, blk, g0, groups[0][1])
        if g53:
            if motion not in (0, 10) or (gm is None and not axis_words):
                raise Refusal("syntax", "G53 needs G0 or G1 (on the line or in force) and axis words", groups[0][1])
            if not st.absolute:
                raise Refusal("syntax", "G53 in incremental mode (G91): machine coordinates are absolute, use G90",
                              groups[0][1])
            if st.comp:
                raise Refusal("syntax", "G53 with cutter compensation on: turn it off (G40) first", groups[0][1])
        # 21. motion
        if gm is not None and gm != 800:
            st.motion = gm
        if gm == 800:
            st.motion = 800                       # the cycle words stay remembered (LinuxCNC's cycle_p ...)
            st.cycle_il = None
        do_motion = (gm is not None and gm != 800 and not (g0 in AXIS_USERS and axis_words)) or \
            (axis_words and g0 not in AXIS_USERS and not tlo_axes) or \
            (not axis_words and gm is None and motion in (20, 30) and any(k in v for k in "ijk"))
        if do_motion and motion in CYCLES and not axis_words:
            raise Refusal("syntax", f"{gname(motion)} needs axis words (the hole)", blk.groups.get(1, (0, None))[1])
        if do_motion:
            if motion not in CYCLES:
                st.cycle_il = None
            self.motion(st, blk, motion, g53, bool(gm is not None), axis_words)
            st.comp_base = None
        elif tc in (6, 61):
            st.comp_base = None   # LinuxCNC re-reads the position after a tool change: where the tool is after G40
        # 22. stops
        stop = mcode(4)
        flow = mcode(11)
        result = None
        if stop is not None:
            if stop == 0:
                self.event("pause", "M0")
            elif stop == 1:
                if self.cfg.optional_stop:
                    self.event("pause", "M1")
            elif stop == 60:
                self.event("pause", "M60")
            else:
                self.program_end(st)
                result = "end"
        if flow == 98:
            if "p" not in v:
                raise Refusal("syntax", "M98 needs P<program number> (the O-number of the subprogram)", mg[11][1])
            p = v["p"]
            n = int(v.get("l", 1))
            if p != int(p) or p < 0 or n < 0 or v.get("l", 1) != n:
                raise Refusal("syntax", "M98 P (the O-number) and L (repeats) must be non-negative integers",
                              mg[11][1])
            result = ("m98", int(p), n)
        elif flow == 99:
            result = "m99"
        self.flush_events(st)
        return result

    # ------------------------------------------------------------------ word permissions
    def check_words(self, st, blk, g0, motion, axis_words):
        v, col, groups, mg = blk.v, blk.col, blk.groups, blk.mgroups
        gm = groups.get(1, (None,))[0]
        arc = motion in (20, 30) and (gm is not None or axis_words or (gm is None and g0 not in AXIS_USERS))
        cycle = motion in CYCLES and (gm is not None or axis_words)
        users = {k: False for k in "ijkrpqlhde"}
        if arc:
            users.update(i=True, j=True, k=True, r=True, p=True)
        if cycle:
            users.update(r=True, l=True, p=motion in (820, 860, 880, 890, 740, 840), q=motion in (730, 830),
                         i=motion == 870, j=motion == 870, k=motion == 870)
        if g0 == 40:
            users["p"] = True
        if g0 == 100:
            users.update(l=True, p=True, r=True, i=True, j=True, q=True)
        if 13 in groups and groups[13][0] == 640:
            users.update(p=True, q=True)
        if 16 in groups:
            users.update(p=True, e=True, q=True)
        if motion in (50, 51) and (gm is not None or axis_words):
            users.update(i=True, j=True, p=motion == 50, q=motion == 50)
        if 7 in groups and groups[7][0] in (410, 420, 411, 421):
            users["d"] = True
        if 8 in groups and groups[8][0] == 430:
            users["h"] = True
        if 5 in mg:
            users.update(p=True, e=True, q=True, l=True)
        if 10 in mg:
            users.update(p=True, q=True)
        if 11 in mg:
            users.update(p=True, l=True)
        if 6 in mg and mg[6][0] == 61:
            users["q"] = True
        for k, used in users.items():
            if k in v and not used:
                if k in "ijk" and 1 not in groups and motion in (20, 30) and not axis_words:
                    pass
                raise Refusal("syntax", f"{k.upper()}{fmt(v[k])} has nothing to use it: {k.upper()} is "
                                        f"{WORD_MEANING[k]}", col[k])

    # ------------------------------------------------------------------ M62-M68
    def outputs(self, st, blk, code):
        v, col, c = blk.v, blk.col, blk.mgroups[5][1]
        if code == 66:
            self.note("machine", "M66 (wait for an input): this machine has no inputs a program can read", c)
            self.params.numbered[P.M66_RESULT] = -1.0
            return
        if code in (62, 63, 64, 65):
            if "p" not in v:
                raise Refusal("syntax", f"M{code} needs P<output number>", c)
            word, kind, count, value = "p", "digital", self.cfg.digital_outputs, 1.0 if code in (62, 64) else 0.0
        else:
            if "e" not in v or "q" not in v:
                raise Refusal("syntax", f"M{code} needs E<output number> and Q<value>", c)
            word, kind, count, value = "e", "analog", self.cfg.analog_outputs, float(v["q"])
        k = v[word]
        if k != int(k) or not 0 <= k < count:
            self.note("machine", f"M{code} {word.upper()}{fmt(k)}: this machine has {kind} outputs 0 .. {count - 1} "
                                 f"([interpreter] {kind}_outputs)", col[word])
            return
        self.event("output", (kind, int(k), value))

    # ------------------------------------------------------------------ M70-M73
    def modal_state(self, st, code, c):
        """LinuxCNC's M70/M71/M72/M73 at this call level: the units, distance modes, plane, feed mode,
        coordinate system, retract and path modes, F, S, spindle and coolant (SAVED_MODES; not the motion
        mode, the tool offset or cutter compensation)."""
        level = len(self.params.frames) - 1
        if code in (70, 73):
            self.saved[level] = ({k: getattr(st, k) for k in SAVED_MODES}, code == 73)
        elif code == 71:
            self.saved.pop(level, None)
        else:
            if level not in self.saved:
                raise Refusal("syntax", "M72 with no saved state here: save it first with M70", c)
            self.restore_modes(st, self.saved[level][0])

    def restore_modes(self, st, saved):
        rpm, mist, flood = self.rpm(st), st.mist, st.flood
        for k, v in saved.items():
            if k != "cs":
                setattr(st, k, v)
        if saved["cs"] != st.cs:
            self.select_cs(st, saved["cs"])
        if self.rpm(st) != rpm:
            self.event("spindle", self.rpm(st))
        if not st.mist and not st.flood and (mist or flood):
            self.event("coolant", "off")
        else:
            if st.mist and not mist:
                self.event("coolant", "mist")
            if st.flood and not flood:
                self.event("coolant", "flood")

    def leave_level(self, level):
        """Returning from the subroutine at ``level``: an M73 there restores the caller's modes."""
        saved = self.saved.pop(level, None)
        if saved is not None and saved[1]:
            self.restore_modes(self.st, saved[0])
            self.flush_events(self.st)

    # ------------------------------------------------------------------ G4
    def dwell(self, st, seconds):
        self.emit(st, Move(DWELL, np.array(st.pos[:3]), self.axis(st.pos[3], st.pos[4]), line=self.line,
                           dwell=float(seconds), spindle_rpm=self.rpm(st), tool_offset=st.tlo, file=self.file))

    # ------------------------------------------------------------------ G40 G41 G42
    def cutter_comp(self, st, blk, cr):
        code, c = cr
        v, col = blk.v, blk.col
        if code == 400:
            if st.comp and st.comp_radius > 0 and not st.comp_first:
                self.comp.off(st)
                st.arc_not_allowed = True
            st.comp = 0
            st.comp_first = True
            return
        if st.comp:
            raise Refusal("syntax", f"{gname(code)} while cutter compensation is on: turn it off (G40) first", c)
        if st.plane != 170:
            raise Refusal("unsupported", f"{gname(code)}: cutter compensation runs in the XY plane (G17) only", c)
        if code in (411, 421):
            if "d" not in v:
                raise Refusal("syntax", f"{gname(code)} needs D (the tool diameter)", c)
            radius, n = v["d"] * st.units / 2.0, None
        elif "d" in v:
            n = whole(v["d"], f"{gname(code)} D", col["d"], "D is a tool number")
        else:
            n = st.tool
        if n is not None:
            tool = self.table_tool(n, f"{gname(code)} D", col.get("d", c), "add it with its diameter")
            radius = tool.diameter / 2.0 if tool is not None else 0.0
        side = 1 if code in (410, 411) else 2
        if radius < 0:                       # a negative diameter switches the side (LinuxCNC)
            radius, side = -radius, 3 - side
        st.comp = side
        st.comp_radius = radius
        st.comp_first = True
        st.cq, st.cq_end = (), None

    def table_tool(self, n, word, column, advice):
        """Tool ``n`` of the tool table (None for tool 0, no tool); not in the table: a machine problem
        noted (the line goes on without its data)."""
        if n == 0:
            return None
        tool = self.cfg.tools.get(n)
        if tool is None:
            self.note("machine", f"{word}{n}: tool {n} is not in the tool table {self.cfg.tools.source}; {advice}",
                      column)
        return tool

    # ------------------------------------------------------------------ G43 G43.1 G49
    def tool_length(self, st, blk, tl):
        code, c = tl
        v, col = blk.v, blk.col
        if code == 490:
            new = 0.0
        elif code == 431:
            for k in "xyab":
                if k in v and v[k] != 0.0:
                    self.note("machine", f"G43.1 {k.upper()}{fmt(v[k])}: this machine's tool offset is a length "
                                         "along the tool axis: give it as Z", col[k])
            new = v.get("z", 0.0) * st.units
        else:
            if "h" in v:
                n = whole(v["h"], "G43 H", col["h"], "H is a tool number")
            else:
                n = st.tool
            tool = self.table_tool(n, "G43 H", col.get("h", c), "add it, or use G43.1")
            new = tool.length if tool is not None else 0.0
        st.tlo_code = code
        self.set_tlo(st, new)

    def set_tlo(self, st, new):
        if new == st.tlo:
            return
        # the platform stays put: the tip moves along the tool axis by the change of length
        ax = self.axis(st.pos[3], st.pos[4])
        d = new - st.tlo
        st.pos = [st.pos[0] - d * ax[0], st.pos[1] - d * ax[1], st.pos[2] - d * ax[2], st.pos[3], st.pos[4]]
        st.tlo = new
        self.event("tool_offset", new)

    # ------------------------------------------------------------------ G10 G28 G30 G52 G92
    def modal0(self, st, blk, g0, c):
        v, col = blk.v, blk.col
        if g0 == 100:
            return self.g10(st, blk, c)
        if g0 in (280, 300):
            return self.home(st, blk, g0, c)
        if g0 in (281, 301):
            base = P.G28_BASE if g0 == 281 else P.G30_BASE
            m = self.machine_of(st, st.pos)
            for i in range(5):
                self.params.numbered[base + i] = m[i]
            return None
        if st.comp:
            raise Refusal("syntax", f"{gname(g0)} with cutter compensation on: turn it off (G40) first", c)
        num = self.params.numbered
        if g0 in (920, 520):
            axes = [k for k in "xyzab" if k in v]
            if not axes:
                raise Refusal("syntax", f"{gname(g0)} needs axis words (the values the current position gets)", c)
            if g0 == 920:
                cur = self.to_prog(st, st.pos)
                g = list(st.g92)
                for k in axes:
                    i = AXIS_INDEX[k]
                    val = v[k] * (st.units if i < 3 else 1.0)
                    g[i] = cur[i] + st.g92[i] - val
            else:
                g = list(st.g92)
                for k in axes:
                    i = AXIS_INDEX[k]
                    g[i] = v[k] * (st.units if i < 3 else 1.0)
            st.g92 = g
            num[P.G92_FLAG] = 1.0
            for i in range(5):
                num[P.G92_BASE + i] = g[i]
        elif g0 in (921, 922):
            st.g92 = [0.0] * 5
            num[P.G92_FLAG] = 0.0
            if g0 == 921:
                for i in range(5):
                    num[P.G92_BASE + i] = 0.0
        elif g0 == 923:
            num[P.G92_FLAG] = 1.0
            st.g92 = [num[P.G92_BASE + i] for i in range(5)]
        self._wco(st)
        return None

    def g10(self, st, blk, c):
        v, col = blk.v, blk.col
        if "l" not in v:
            raise Refusal("syntax", "G10 needs L: L1/L10/L11 (tool table), L2/L20 (coordinate system)", c)
        L = v["l"]
        if L not in (1, 2, 10, 11, 20):
            raise Refusal("syntax", f"G10 L{fmt(L)}: use L1, L10 or L11 (tool table) or L2 or L20 (coordinate "
                                    "system)", col["l"])
        if "p" not in v:
            raise Refusal("syntax", f"G10 L{int(L)} needs P (the {'tool number' if L in (1, 10, 11) else 'coordinate system, 1-9 or 0 for the active one'})",
                          c)
        p = v["p"]
        num = self.params.numbered
        if L in (2, 20):
            if p != int(p) or not 0 <= p <= 9:
                raise Refusal("syntax", f"G10 L{int(L)} P{fmt(p)}: P is the coordinate system, 1-9 (G54-G59.3) or "
                                        "0 for the active one", col["p"])
            n = int(p) or st.cs
            if st.comp and n == st.cs:
                raise Refusal("syntax", "G10 on the active coordinate system with cutter compensation on: turn it off "
                                        "(G40) first", c)
            for k in "ijk":
                if k in v:
                    raise Refusal("syntax", f"G10 L{int(L)} takes no {k.upper()}", col[k])
            base = P.coordinate_base(n)
            if L == 20 and "r" in v:
                raise Refusal("syntax", "G10 L20 takes no R (set the rotation with G10 L2)", col["r"])
            r = v["r"] if "r" in v else num[base + 9]
            off = [num[base + i] for i in range(5)]
            if L == 2:
                for k in "xyzab":
                    if k in v:
                        i = AXIS_INDEX[k]
                        off[i] = v[k] * (st.units if i < 3 else 1.0)
            else:
                # the offset that makes the current position read the given values in system n
                g = [num[P.G92_BASE + i] for i in range(5)] if num[P.G92_FLAG] else [0.0] * 5
                cur = self._in_system(st, off, num[base + 9], g)
                want = list(cur)
                for k in "xyzab":
                    if k in v:
                        i = AXIS_INDEX[k]
                        want[i] = v[k] * (st.units if i < 3 else 1.0)
                rr = math.radians(r)
                cs_, sn = math.cos(rr), math.sin(rr)
                x, y = want[0] + g[0], want[1] + g[1]
                w = st.pos
                if "x" in v or "y" in v:
                    off[0] = w[0] - (cs_ * x - sn * y)
                    off[1] = w[1] - (sn * x + cs_ * y)
                for i in (2, 3, 4):
                    if "xyzab"[i] in v:
                        off[i] = w[i] - want[i] - g[i]
            for i in range(5):
                num[base + i] = off[i]
            num[base + 9] = r
            if n == st.cs:
                self.select_cs(st, n)
            return None
        # tool table
        p = whole(p, f"G10 L{int(L)} P", col["p"], "P is a tool number")
        from pmctl.task.rs274.tools import Tool
        tools = self.cfg.tools
        old = tools.get(int(p)) or Tool(int(p))
        for k in "xyab":
            if k in v and (L == 1 and v[k] != 0.0):
                self.note("machine", f"G10 L1 {k.upper()}{fmt(v[k])}: this machine's tool table holds a length "
                                     "(Z) and a diameter (R or D): set Z", col[k])
        for k in "ijq":
            if k in v and v[k] != 0.0:
                self.note("machine", f"G10 L{int(L)} {k.upper()}: lathe tool data have no meaning on this mill",
                          col[k])
        length, diameter = old.length, old.diameter
        if "r" in v:
            diameter = 2.0 * v["r"] * st.units
        if L == 1:
            if "z" in v:
                length = v["z"] * st.units
        else:
            if "x" in v or "y" in v or "a" in v or "b" in v:
                k = next(k for k in "xyab" if k in v)
                self.note("machine", f"G10 L{int(L)} {k.upper()}: this machine's tool offset is a length: touch "
                                     "off with Z", col[k])
            if "z" in v:
                # the length that makes the current tip read Z in the current (L10) or G59.3 (L11) system
                ref = self.machine_of(st, st.pos)
                ax = self.axis(st.pos[3], st.pos[4])
                if L == 10:
                    z0 = st.wco[2] if st.rotation == 0.0 else st.g5x[2] + st.g92[2]
                else:
                    z0 = num[P.coordinate_base(9) + 2]
                length = (ref[2] - z0 - v["z"] * st.units) / ax[2]
        self.cfg.tools = tools.with_tool(Tool(int(p), old.pocket, length, diameter, old.comment))
        return None

    def _in_system(self, st, off, rot, g92):
        """The current position in a coordinate system with origin ``off`` and rotation ``rot``."""
        w = st.pos
        x, y = w[0] - off[0], w[1] - off[1]
        r = math.radians(rot)
        c, s = math.cos(r), math.sin(r)
        return [c * x + s * y - g92[0], -s * x + c * y - g92[1], w[2] - off[2] - g92[2], w[3] - off[3] - g92[3],
                w[4] - off[4] - g92[4]]

    def home(self, st, blk, g0, c):
        v = blk.v
        if st.comp:
            raise Refusal("syntax", f"{gname(g0)} with cutter compensation on: turn it off (G40) first", c)
        base = P.G28_BASE if g0 == 280 else P.G30_BASE
        num = self.params.numbered
        stored = [num[base + i] for i in range(5)]
        # LinuxCNC: a rapid to the waypoint (the axis words; none: where it is), then the axes named (none:
        # all) go to the stored machine position, each replaced in the program coordinates of the waypoint
        mid = self.target(st, blk, False)
        self.move(st, RAPID, mid)
        home = self.to_prog(st, self.from_machine(st, stored))
        axes = [k for k in "xyzab" if k in v]
        p = self.to_prog(st, mid)
        for k in (axes or "xyzab"):
            i = AXIS_INDEX[k]
            p[i] = home[i]
        self.move(st, RAPID, self.to_w(st, p))
        return None

    # ------------------------------------------------------------------ targets
    def target(self, st, blk, g53):
        """The end point (W, 5 values) of a straight move from the block's axis words."""
        v = blk.v
        if g53:
            m = self.machine_of(st, st.pos)
            for k in "xyzab":
                if k in v:
                    i = AXIS_INDEX[k]
                    m[i] = v[k] * (st.units if i < 3 else 1.0)
            return self.from_machine(st, m)
        p = self.to_prog(st, st.pos)
        if st.comp and not st.comp_first and st.comp_prog is not None:
            p[0], p[1] = st.comp_prog[0], st.comp_prog[1]       # LinuxCNC: from the programmed point
        elif st.comp_base is not None:
            p[0], p[1] = st.comp_base[0], st.comp_base[1]       # the first move after G40
        u = st.units
        if st.absolute:
            if "x" in v:
                p[0] = v["x"] * u
            if "y" in v:
                p[1] = v["y"] * u
            if "z" in v:
                p[2] = v["z"] * u
            if "a" in v:
                p[3] = v["a"]
            if "b" in v:
                p[4] = v["b"]
        else:
            if "x" in v:
                p[0] += v["x"] * u
            if "y" in v:
                p[1] += v["y"] * u
            if "z" in v:
                p[2] += v["z"] * u
            if "a" in v:
                p[3] += v["a"]
            if "b" in v:
                p[4] += v["b"]
        if "@" in v or "^" in v:
            self.polar(st, blk, p)
        return self.to_w(st, p)

    def polar(self, st, blk, p):
        """X Y of ``p`` (program mm) from the polar words @ (radius) and ^ (angle, degrees about the
        program origin; G91: added to the current radius and angle), as LinuxCNC."""
        v, col = blk.v, blk.col
        c = col.get("@", col.get("^"))
        if "x" in v or "y" in v:
            raise Refusal("syntax", "X or Y with polar coordinates (@ ^): give one or the other", c)
        x, y = p[0], p[1]
        if st.absolute and "@" in v and "^" in v:
            r, th = v["@"] * st.units, math.radians(v["^"])
        else:
            if x == 0.0 and y == 0.0:
                raise Refusal("syntax", "polar coordinates from the origin: the angle (^) is undefined there: give "
                                        "both @ and ^ in G90", c)
            r, th = math.hypot(x, y), math.atan2(y, x)
            if "@" in v:
                r = v["@"] * st.units + (r if not st.absolute else 0.0)
            if "^" in v:
                th = math.radians(v["^"]) + (th if not st.absolute else 0.0)
        p[0], p[1] = r * math.cos(th), r * math.sin(th)

    # ------------------------------------------------------------------ motion
    def feed_for(self, st, blk, what):
        """(feed mm/s, duration s) of a feed move of length ``length`` (set later for G93)."""
        where = blk.groups.get(1, (None, None))[1] or next((blk.col[k] for k in "xyzab@^" if k in blk.col), None)
        if st.feed_mode == 930:
            if "f" not in blk.v:
                raise Refusal("syntax", f"{what} in inverse time (G93) needs F on the line (F = 1 / minutes for "
                                        "the move)", where)
            f = blk.v["f"]
            if not f > 0:
                raise Refusal("syntax", f"{what} in inverse time (G93): F{fmt(f)} must be > 0", blk.col["f"])
            return 0.0, 60.0 / f                  # the feed: the move's length over this duration
        if st.feed_mode == 950:
            if not st.feed > 0:
                raise Refusal("syntax", f"{what} with no F: set a feed per revolution (G95 F, > 0) on this line or "
                                        "before", blk.col.get("f", where))
            if not st.spindle or not st.speed > 0:
                raise Refusal("syntax", f"{what} in feed per revolution (G95) with the spindle stopped: start it "
                                        "(M3/M4 S) first", blk.col.get("f", where))
            return st.feed * st.speed / 60.0, 0.0
        if not st.feed > 0:
            if "f" in blk.v:
                raise Refusal("syntax", f"{what} with F0: the feed rate must be > 0", blk.col["f"])
            raise Refusal("syntax", f"{what} with no F: set a feed rate (F, > 0) on this line or before", where)
        return st.feed / 60.0, 0.0

    def motion(self, st, blk, motion, g53, explicit, axis_words):
        v, col = blk.v, blk.col
        mc = blk.groups.get(1, (None, None))[1]
        if motion in (0, 10):
            if st.arc_not_allowed:
                st.arc_not_allowed = False
            end = self.target(st, blk, g53)
            if g53 and "z" in v and self.machine_of(st, end)[2] <= 1e-9:
                self.note("machine", f"G53 Z{fmt(v['z'])}: machine Z {fmt(self.machine_of(st, end)[2])} "
                                     "mm is at or below the table top on this machine (machine coordinates are "
                                     "the workpiece frame W without work offsets, not the top of travel): "
                                     "retract with G28 (home height) or a work-coordinate Z instead",
                          col.get("z"))
            if motion == 10:
                feed, duration = self.feed_for(st, blk, "G1")
            if not axis_words:
                return
            if st.comp and self.comp is not None:
                return self.compensated(st, blk, motion, end, lambda: self.comp.straight(st, blk, motion, end))
            if motion == 0:
                self.move(st, RAPID, end)
            else:
                if duration:
                    feed = self._length(st.pos, end, None, 0.0) / duration
                self.move(st, LINE, end, feed=feed, duration=duration)
            return
        if motion in (20, 30):
            if st.arc_not_allowed:
                raise Refusal("syntax", "the move right after G40 must be a straight line (LinuxCNC's rule): add "
                                        "a G1 before the arc", mc)
            return self.arc(st, blk, motion, explicit, axis_words)
        if motion in (382, 383):
            if st.comp:
                raise Refusal("syntax", f"{gname(motion)} with cutter compensation on: turn it off (G40) first", mc)
            if not axis_words:
                raise Refusal("syntax", f"{gname(motion)} needs an axis word (the probe target)", mc)
            if st.feed_mode == 930:
                raise Refusal("syntax", f"{gname(motion)} in inverse time (G93): probe in G94", mc)
            feed, _ = self.feed_for(st, blk, gname(motion))
            end = self.target(st, blk, g53)
            if abs(end[3] - st.pos[3]) > 1e-12 or abs(end[4] - st.pos[4]) > 1e-12:
                raise Refusal("syntax", f"{gname(motion)} with A/B changing: the tool axis must stay put while "
                                        "probing", mc)
            if math.dist(end[:3], st.pos[:3]) < 1e-9:
                raise Refusal("syntax", f"{gname(motion)} target is the current position (no probing direction)", mc)
            self.move(st, LINE, end, feed=feed, probe=2 if motion == 382 else 3)
            self.probed = True
            return
        if motion in CYCLES:
            from pmctl.task.rs274.cycles import run_cycle
            return run_cycle(self, st, blk, motion, explicit, axis_words)
        if motion in (50, 51):
            return self.spline(st, blk, motion)
        raise Refusal("unsupported", f"{gname(motion)} is not supported", mc)   # pragma: no cover

    def compensated(self, st, blk, motion, end, run, c2=None, turn=0):
        """A move with cutter compensation; when the tool does not fit (CompFit), a machine problem is
        noted and the path carries on (pmctl.task.rs274.cutter_comp.CutterComp.carry_on)."""
        from pmctl.task.rs274.cutter_comp import CompFit
        saved = (st.cq, st.cq_start, st.cq_end, st.comp_prog, st.comp_cur, st.comp_first, list(st.pos),
                 len(self.moves))
        try:
            return run()
        except CompFit as e:
            st.cq, st.cq_start, st.cq_end, st.comp_prog, st.comp_cur, st.comp_first, st.pos, n = saved
            del self.moves[n:]
            self.note("machine", f"{e.message} (tool radius {st.comp_radius / st.units:.4f} from the tool table "
                                 f"{self.cfg.tools.source} or G41.1/G42.1)", e.column)
            self.comp.carry_on(st, blk, motion, end, c2, turn)

    def spline(self, st, blk, motion):
        """G5 / G5.1 (pmctl.task.rs274.splines): straight feeds along the curve."""
        from pmctl.task.rs274.splines import flatten
        v, col = blk.v, blk.col
        mc = blk.groups.get(1, (None, None))[1]
        name = gname(motion)
        if st.plane != 170:
            raise Refusal("syntax", f"{name} runs in the XY plane (G17) only", mc)
        if st.comp:
            raise Refusal("syntax", f"{name} with cutter compensation on: turn it off (G40) first", mc)
        for k in "zab@^":
            if k in v:
                raise Refusal("syntax", f"{name} takes X and Y only (the curve lies in the XY plane)", col[k])
        feed, duration = self.feed_for(st, blk, name)
        u = st.units
        p0 = self.to_prog(st, st.pos)
        end = self.to_prog(st, self.target(st, blk, False))
        start, fin = (p0[0], p0[1]), (end[0], end[1])
        if motion == 51:
            if "i" not in v or "j" not in v:
                raise Refusal("syntax", "G5.1 needs I and J (the control point, from the start)", mc)
            ctrl = [start, (start[0] + v["i"] * u, start[1] + v["j"] * u), fin]
            st.spline_prev = None
        else:
            if "p" not in v or "q" not in v:
                raise Refusal("syntax", "G5 needs P and Q (the second control point, from the end)", mc)
            if "i" in v or "j" in v:
                if not ("i" in v and "j" in v):
                    raise Refusal("syntax", "G5 needs both I and J (or neither, to go on from the G5 before)", mc)
                c1 = (start[0] + v["i"] * u, start[1] + v["j"] * u)
            elif self.prev_motion == 50 and st.spline_prev is not None:
                (ex, ey), (qx, qy) = st.spline_prev
                c1 = (2 * ex - qx, 2 * ey - qy)
            else:
                raise Refusal("syntax", "G5 needs I and J (the first control point) at the start of a series", mc)
            c2 = (fin[0] + v["p"] * u, fin[1] + v["q"] * u)
            ctrl = [start, c1, c2, fin]
            st.spline_prev = (fin, c2)
        pts = flatten(ctrl)
        if duration:
            length = sum(math.dist(a, b) for a, b in zip([start] + pts[:-1], pts))
            per = duration / max(len(pts), 1)
            feed = length / duration
        for x, y in pts:
            q = list(end)
            q[0], q[1] = x, y
            self.move(st, LINE, self.to_w(st, q), feed=feed, duration=per if duration else 0.0)

    def _length(self, p0, p1, center, sweep):
        return math.dist(p0[:3], p1[:3])

    def arc(self, st, blk, motion, explicit, axis_words):
        v, col = blk.v, blk.col
        plane = st.plane
        fi, si, ti = A.PLANE_AXES[plane]
        ow = A.OFFSET_WORDS[plane]
        mc = blk.groups.get(1, (None, None))[1]
        has_r = "r" in v
        ijk = [k for k in "ijk" if k in v]
        if not has_r and not ijk:
            raise Refusal("syntax", f"{gname(motion)} needs its centre: I J K (offsets) or R (radius)", mc)
        if has_r and ijk:
            raise Refusal("syntax", f"{gname(motion)} with both R and {ijk[0].upper()}: use the radius or the centre, "
                                    "not both", col["r"])
        feed, duration = self.feed_for(st, blk, gname(motion))
        turns = 1
        if "p" in v:
            p = v["p"]
            if p != int(p) or not 1 <= p <= MAX_ARC_TURNS:
                raise Refusal("syntax", f"arc turns P{fmt(p)} must be an integer within 1 .. {MAX_ARC_TURNS}", col["p"])
            turns = int(p)
        if has_r:
            inplane = [k for k in "xyz" if k in v and "xyz".index(k) in (fi, si)] + \
                ([k for k in "@^" if k in v] if plane == 170 else [])
            if not inplane:
                a, b = "XYZ"[fi], "XYZ"[si]
                raise Refusal("syntax", f"{gname(motion)} R needs an end point in the {A.PLANE_NAMES[plane]} plane "
                                        f"({a} and/or {b}): an R arc cannot be a full circle", col["r"])
        end = self.target(st, blk, False)
        # the arc in program coordinates (mm)
        ps = self.to_prog(st, st.pos)
        if st.comp and not st.comp_first and st.comp_prog is not None and st.comp_radius > 0:
            ps[0], ps[1] = st.comp_prog[0], st.comp_prog[1]     # LinuxCNC: the programmed start
        pe = self.to_prog(st, end)
        s2, e2 = (ps[fi], ps[si]), (pe[fi], pe[si])
        ccw = motion == 30
        try:
            if has_r:
                c2 = A.center_r(plane, s2, e2, v["r"] * st.units, st.units, ccw)
            else:
                off = [v.get(ow[0], 0.0) * st.units, v.get(ow[1], 0.0) * st.units]
                if st.ijk_absolute:
                    for k, w in zip(ow[:2], off):
                        if k not in v:
                            raise Refusal("syntax", f"{k.upper()} word missing in an absolute-centre arc (G90.1)", mc)
                c2 = A.center_ijk(plane, s2, e2, off, st.ijk_absolute, st.units, ccw)
        except A.ArcError as e:
            raise Refusal("syntax", e.message, col.get(e.word) if e.word else mc) from None
        if st.comp and self.comp is not None and plane == 170:
            t = turns if ccw else -turns
            return self.compensated(st, blk, motion, end,
                                    lambda: self.comp.arc(st, blk, motion, end, c2, t, feed, duration), c2, t)
        sw = A.sweep(s2, c2, e2, turns if ccw else -turns)
        self.emit_arc(st, ps, pe, c2, sw, end, feed, duration)

    def emit_arc(self, st, ps, pe, c2, sw, end, feed, duration):
        plane = st.plane
        fi, si, ti = A.PLANE_AXES[plane]
        cp = [0.0] * 5
        cp[fi], cp[si], cp[ti] = c2[0], c2[1], ps[ti]
        cp[3], cp[4] = ps[3], ps[4]
        cw = self.to_w(st, cp)
        r0 = math.hypot(ps[fi] - c2[0], ps[si] - c2[1])
        r1 = math.hypot(pe[fi] - c2[0], pe[si] - c2[1])
        if duration:
            feed = A.helix_length(r0, r1, sw, pe[ti] - ps[ti]) / duration
        if plane == 170:
            center, normal = np.array(cw[:2]), None
        else:
            n = [0.0, 0.0, 0.0]
            n[ti] = 1.0
            center = np.array(cw[:3])
            normal = np.array(self.rotate_vec(st, n), float)
        self.move(st, ARC, end, feed=feed, center=center, sweep=sw, normal=normal, duration=duration)

    # ------------------------------------------------------------------ M2 / M30
    def program_end(self, st):
        """LinuxCNC's M2/M30: G54, XY plane, G90, G94, cutter compensation off, spindle and coolant off,
        G1 motion mode (the work offsets and G92 stay)."""
        if st.comp and self.comp is not None:
            self.comp.off(st)
        st.comp = 0
        if st.spindle:
            st.spindle = 0
            self.event("spindle", 0.0)
        if st.mist or st.flood:
            st.mist = st.flood = False
            self.event("coolant", "off")
        self.select_cs(st, 1)
        st.plane, st.absolute, st.feed_mode, st.motion = 170, True, 940, 10
        st.cycle = st.cycle_il = None
        st.ended = True

    # ------------------------------------------------------------------ predefined parameters
    def _install_dynamic(self):
        d = self.params.dynamic
        ex = self

        def prog(i):
            def f():
                st = ex.st
                p = ex.to_prog(st, st.pos)
                return p[i] / (st.units if i < 3 else 1.0)
            return f
        for i, k in enumerate("xyzab"):
            d["_" + k] = prog(i)
            d[P.POS_BASE + i] = prog(i)
            d["_abs_" + k] = (lambda i=i: ex.st.pos[i] / (ex.st.units if i < 3 else 1.0))
        for i in range(5, 9):
            d[P.POS_BASE + i] = (lambda: 0.0)
        for k in "cuvw":
            d["_" + k] = (lambda: 0.0)
        s = lambda: ex.st  # noqa: E731
        d.update({
            "_metric": lambda: float(s().units == 1.0), "_imperial": lambda: float(s().units != 1.0),
            "_absolute": lambda: float(s().absolute), "_incremental": lambda: float(not s().absolute),
            "_inverse_time": lambda: float(s().feed_mode == 930),
            "_units_per_minute": lambda: float(s().feed_mode == 940),
            "_units_per_rev": lambda: float(s().feed_mode == 950),
            "_coord_system": lambda: float(WCS_CODES[s().cs - 1]),
            "_tool_offset": lambda: float(s().tlo_code != 490),
            "_plane": lambda: float(s().plane), "_motion_mode": lambda: float(s().motion),
            "_ccomp": lambda: float({0: 400, 1: 410, 2: 420}[s().comp]),
            "_retract_r_plane": lambda: float(s().retract == 990),
            "_retract_old_z": lambda: float(s().retract == 980),
            "_ijk_absolute_mode": lambda: float(s().ijk_absolute),
            "_spindle_rpm_mode": lambda: 1.0, "_spindle_css_mode": lambda: 0.0,
            "_lathe_diameter_mode": lambda: 0.0, "_lathe_radius_mode": lambda: 1.0,
            "_spindle_on": lambda: float(s().spindle != 0), "_spindle_cw": lambda: float(s().spindle >= 0),
            "_mist": lambda: float(s().mist), "_flood": lambda: float(s().flood),
            "_speed_override": lambda: 1.0, "_feed_override": lambda: 1.0, "_adaptive_feed": lambda: 0.0,
            "_feed_hold": lambda: 0.0,
            "_feed": lambda: s().feed / s().units, "_rpm": lambda: s().speed,
            "_current_tool": lambda: float(s().tool), "_current_pocket": lambda: float(s().tool),
            "_selected_tool": lambda: float(s().selected if s().selected is not None else -1),
            "_selected_pocket": lambda: float(s().selected if s().selected is not None else -1),
            "_line": lambda: float(ex.line), "_vmajor": lambda: 2.0, "_vminor": lambda: 9.0,
            "_task": lambda: 1.0, "_remap_level": lambda: 0.0,
            "_call_level": lambda: float(len(ex.params.frames) - 1),
        })
        d[5400] = lambda: float(ex.st.tool)
        for i in range(1, 10):
            d[5400 + i] = (lambda i=i: ex.st.tlo if i == 3 else 0.0)
        d[5410] = lambda: (ex.cfg.tools.get(ex.st.tool).diameter if ex.cfg.tools.get(ex.st.tool) else 0.0)
        for i in range(11, 14):
            d[5400 + i] = (lambda: 0.0)
        self.params.globals.setdefault("_value", 0.0)
        self.params.globals.setdefault("_value_returned", 0.0)
        probe_guard = self._probe_guard
        for i in range(P.PROBE_BASE, P.PROBE_OK + 1):
            d[i] = (lambda i=i: probe_guard(i))

    def _probe_guard(self, i):
        if self.probed and self.cfg.ahead:
            raise EvalError(f"#{i} is the probe result, which is known only when the probe has run: a job file is "
                            "interpreted before it runs, so it cannot use it (probe at the console)", self.params.column)
        return self.params.numbered[i]
