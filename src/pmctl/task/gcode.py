"""RS-274 (G-code) subset reader -> a job (pmctl.task.job) for the planner.

Supported (LinuxCNC semantics unless noted):

- motion: ``G0`` rapid, ``G1`` feed line, ``G2``/``G3`` clockwise/counter-clockwise arc or helix in the
  XY plane (``G17``, the only plane) with centre offsets ``I``/``J`` (always relative to the start) or
  radius ``R`` (R < 0: the arc longer than a half turn), optional ``P`` full turns; ``G4 P<seconds>`` dwell;
- modes: ``G17``, ``G20`` inch / ``G21`` mm, ``G90`` absolute / ``G91`` incremental (also for A, B),
  ``G94`` units per minute (the only feed mode), ``G97`` spindle in rpm (the only spindle mode);
- accepted because they hold anyway: ``G40`` (no cutter compensation), ``G49`` (no tool length
  offset: the tool length is in the machine config), ``G54`` (the program's frame is W, the only
  one), ``G61`` exact path and ``G64`` (with an optional ``P``/``Q`` tolerance): the planner always
  follows the programmed path exactly, which meets any blending tolerance; ``G80`` (no canned cycle
  active), ``M9`` (no coolant);
- words: ``X Y Z`` tool tip in W, ``A B`` tool tilt as roll / pitch in degrees (docs/machine.md §3: axis =
  Rx(A) Ry(B) z), ``F`` feed (mm/min or in/min), ``S`` spindle rpm, ``N`` line number;
- probing: ``G38.2`` probe toward the target, an error if the move ends without contact, ``G38.3`` the
  same without the error (grbl semantics); it needs an axis word and a feed (``F`` on the line or
  before; the inverse of ``G0``), is a straight feed line otherwise (modal like G1), and makes a
  ``LINE`` move with ``probe`` = 2 / 3: the control loop stops it on contact (pmctl.motion.probe). Its
  A/B must not change (the tool axis stays put while probing). ``G38.4``/``G38.5`` (probe away) are
  refused; a reader whose state says ``probe_ok = False`` (no stop on contact there) refuses G38 too;
- ``M3`` spindle on clockwise, ``M4`` counter-clockwise (the moves' spindle_rpm is negative), at S: an
  ``M3``/``M4`` while S is 0, or ``S0`` while the spindle turns, is refused (the spindle never runs at
  0 rpm in silence); ``M5`` off, ``M2``/``M30`` end of program (later lines are
  ignored);
- comments ``( ... )`` and ``;`` to the end of the line; spaces anywhere. ``(MSG, text)`` comments are
  operator messages: kept in ``Job.messages`` as (line, text) and shown by ``pmctl run``;
- ``%``: a program whose first line is ``%`` ends at the next ``%`` line (later lines are ignored), and
  must have one unless it ends with M2/M30 first; a ``%`` line elsewhere is refused.

Numbers: every word value goes through one parser (``_number``): plain decimals (no exponent, ASCII
digits only), finite, within ``WORD_LIMITS`` for its letter; a dwell is at most ``MAX_DWELL_S`` and
an arc at most ``MAX_ARC_TURNS`` turns. Beyond that: InputError with file, line, column and reason.

Not supported, and refused by name: expressions ``[...]``, parameters ``#...``, O-word subroutines
and control flow, canned cycles (G73, G76, G81-G89), cutter compensation, tool length offsets and
tool changes, other planes, coordinate-system offsets, inverse-time feed, threading, probing,
probing away from the workpiece (G38.4/G38.5), splines, pauses (M0/M1), coolant on, user M-codes...

Execution order inside a line is RS-274's: F, S, M3/M4/M5, G4, G17/G20/G21/G90/G91/G94, motion, M2/M30.
The whole program is parsed and checked before a job exists: an unknown or unsupported word, a missing
or repeated value, two motion codes on a line, axis words without a motion mode, a feed move before any
F, an arc whose end radius differs from its start radius by more than ``ARC_RADIUS_TOL_MM``, an R arc
that cannot reach its end, an unclosed comment... raise ``InputError`` with file, line, column and
reason; with a machine, every programmed end pose is also checked with ``kinematics.ik_batch``.

Public API: ``parse_gcode(text, path, start_tip, start_axis)`` -> ``Job`` (pure),
``read_gcode(path, machine, start=None)`` -> ``Job`` (reads, parses, checks reachability).
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from pmctl.core import kinematics as K
from pmctl.core.errors import InputError
from pmctl.task.job import ARC, DWELL, LINE, RAPID, Job, Move, check_reach, home_pose, read_job_text

MM_PER_INCH = 25.4
ARC_RADIUS_TOL_MM = 0.005         # |r_end - r_start| allowed for I/J arcs (becomes a tiny spiral)
MAX_DWELL_S = 3600.0              # one G4 at most an hour
MAX_ARC_TURNS = 1000              # G2/G3 P at most this many turns
LETTERS = set("ABFGIJMNPQRSXYZ")
# Largest |value| per word letter (program units: mm or inch, degrees, per minute, rpm, seconds).
WORD_LIMITS = {"N": 99_999_999, "G": 999, "M": 999, "F": 1e6, "S": 1e6, "P": 1e12, "Q": 1e12,
               **{k: 1e5 for k in "XYZIJR"}, "A": 1e4, "B": 1e4}
G_MOTION = {0, 10, 20, 30, 382, 383}   # G-codes times 10 (382/383: G38.2/G38.3 probing)
G_PROBE = {382: 2, 383: 3}
G_NOOP = {400, 490, 540, 610, 640, 800, 970}   # G40 G49 G54 G61 G64 G80 G97: hold anyway (see above)
G_OTHER = {40, 170, 200, 210, 900, 910, 940} | G_NOOP
M_CODES = {2, 3, 4, 5, 9, 30}
_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)")

_G_UNSUPPORTED = [          # (codes x 10, reason); first match wins
    ({50, 51, 52, 53}, "splines (G5) are not supported"),
    ({70, 80}, "lathe diameter/radius modes (G7/G8) are not supported"),
    ({100}, "G10 (setting offsets and tool data) is not supported"),
    ({171, 180, 181, 190, 191}, "only the XY plane (G17) is supported"),
    ({280, 281, 300, 301}, "G28/G30 (go to a stored position) are not supported"),
    ({330, 331, 760}, "threading (G33/G76) is not supported"),
    ({384, 385}, "probing away from the workpiece (G38.4/G38.5) is not supported"),
    ({410, 411, 420, 421}, "cutter radius compensation (G41/G42) is not supported"),
    ({430, 431, 432}, "tool length offsets (G43) are not supported: the tool length is in the machine config"),
    ({520, 920, 921, 922, 923}, "coordinate system offsets (G52/G92) are not supported"),
    ({530}, "machine coordinates (G53) are not supported"),
    ({550, 560, 570, 580, 590, 591, 592, 593}, "work coordinate systems other than G54 are not supported"),
    ({611}, "exact stop mode (G61.1) is not supported"),
    ({730, 740, 810, 820, 830, 840, 850, 860, 870, 880, 890, 980, 990},
     "canned cycles are not supported"),
    ({930, 950}, "only units-per-minute feed (G94) is supported"),
    ({960}, "constant surface speed (G96) is not supported"),
]
_M_UNSUPPORTED = [
    ({0, 1, 60}, "program pauses (M0/M1/M60) are not supported"),
    ({6, 61}, "tool changes are not supported"),
    ({7, 8}, "coolant is not supported"),
    ({19}, "spindle orientation (M19) is not supported"),
    (set(range(48, 54)), "override controls (M48-M53) are not supported"),
    (set(range(62, 71)), "digital/analog I/O (M62-M70) is not supported"),
    (set(range(100, 200)), "user M-codes (M100-M199) are not supported"),
]
_LETTER_UNSUPPORTED = {
    "O": "O-word subroutines and control flow are not supported",
    "T": "tool selection (T) is not supported",
    "H": "tool offsets (H) are not supported",
    "D": "cutter compensation (D) is not supported",
    "C": "axis C is not on this machine (axes X Y Z A B)",
    "U": "axis U is not on this machine (axes X Y Z A B)",
    "V": "axis V is not on this machine (axes X Y Z A B)",
    "W": "axis W is not on this machine (axes X Y Z A B)",
    "K": "K (arcs outside the XY plane, canned cycles) is not supported",
    "L": "L (canned-cycle repeats, G10) is not supported",
    "E": "E is not a word here (numbers have no exponent in G-code)",
}


def _unsupported_reason(table, code):
    for codes, why in table:
        if code in codes:
            return why
    return None


def _number(letter, text, path, lineno, col):
    """The one parser of word values: a plain decimal, finite, within WORD_LIMITS[letter]."""
    v = float(text)                       # the regex admits only [+-]digits[.digits]: never raises
    lim = WORD_LIMITS[letter]
    if not math.isfinite(v) or abs(v) > lim:
        show = text if len(text) <= 24 else text[:20] + "..."
        raise InputError(path, lineno, f"{letter}{show} is out of range (|{letter}| <= {lim:g})", column=col)
    return v


def _strip_comments(raw, path, lineno, messages=None):
    """Return [(column, char)] of the line without comments and blanks (columns 1-based); the text of
    ``(MSG, ...)`` comments is appended to ``messages`` as (line, text)."""
    out = []
    i = 0
    n = len(raw)
    while i < n:
        ch = raw[i]
        if ch == ";":
            break
        if ch == "(":
            j = raw.find(")", i + 1)
            if j < 0:
                raise InputError(path, lineno, "comment '(' is never closed", column=i + 1)
            if "(" in raw[i + 1:j]:
                raise InputError(path, lineno, "nested '(' inside a comment", column=raw.index("(", i + 1) + 1)
            body = raw[i + 1:j].lstrip()
            if messages is not None and body[:4].upper() == "MSG,":
                messages.append((lineno, body[4:].strip()))
            i = j + 1
            continue
        if ch == ")":
            raise InputError(path, lineno, "')' without '('", column=i + 1)
        if not ch.isspace():
            out.append((i + 1, ch))
        i += 1
    return out


def _words(chars, path, lineno):
    """[(letter, value, column)] of a comment-free line."""
    text = "".join(c for _, c in chars)
    cols = [c for c, _ in chars]
    words = []
    i = 0
    while i < len(text):
        ch = text[i]
        letter = ch.upper() if ch.isascii() else ch
        col = cols[i]
        if ch == "[":
            raise InputError(path, lineno, "expressions [...] are not supported", column=col)
        if ch == "#":
            raise InputError(path, lineno, "parameters (#...) are not supported", column=col)
        if ch == "<":
            raise InputError(path, lineno, "named parameters and O-word names <...> are not supported", column=col)
        if not (ch.isascii() and ch.isalpha()):
            raise InputError(path, lineno, f"expected a word letter, got {ch!r}", column=col)
        m = _NUMBER.match(text, i + 1)
        if letter not in LETTERS:
            word = letter + (m.group(0) if m else "")
            why = _LETTER_UNSUPPORTED.get(letter)
            raise InputError(path, lineno, f"unknown word {word!r}" + (f": {why}" if why else ""), column=col)
        if not m:
            nxt = text[i + 1:i + 2]
            if nxt == "[":
                raise InputError(path, lineno, f"expressions [...] are not supported (after '{letter}')",
                                 column=cols[i + 1])
            if nxt == "#":
                raise InputError(path, lineno, f"parameters (#...) are not supported (after '{letter}')",
                                 column=cols[i + 1])
            raise InputError(path, lineno, f"missing value after '{letter}'", column=col)
        words.append((letter, _number(letter, m.group(0), path, lineno, col), col))
        i = m.end()
    return words


class _State:
    def __init__(self, tip, axis):
        self.pos = np.array(tip, float)
        a, b = K.roll_pitch_from_axis(np.asarray(axis, float))
        self.a, self.b = math.degrees(float(a)), math.degrees(float(b))
        self.units = 1.0            # mm per program unit
        self.absolute = True
        self.motion = None          # 0, 10, 20, 30
        self.feed = None            # mm/s
        self.s = 0.0                # rpm
        self.spindle_on = False
        self.probe_ok = True        # G38.2/G38.3 accepted (a reader without stop-on-contact says False)


def parse_gcode(text: str, path="<string>", start_tip=(0.0, 0.0, 0.0), start_axis=(0.0, 0.0, 1.0)) -> Job:
    """Parse a program (pure). ``start_*``: where the tool is when the program starts (G91 and arcs
    are relative to it; the initial A/B are its roll/pitch)."""
    st = _State(start_tip, start_axis)
    moves, points, point_lines, messages = [], [], [], []
    percent_line = None           # line of the opening '%', while the program is inside one
    seen = False                  # any content line yet
    ended = False
    for lineno, raw in enumerate(text.split("\n"), 1):
        line_msgs = []
        chars = _strip_comments(raw, path, lineno, line_msgs)
        messages.extend(line_msgs)
        if not chars:
            continue
        if len(chars) == 1 and chars[0][1] == "%":
            if percent_line is not None:
                ended = True
                break                 # the closing '%': the program ends here
            if seen:
                raise InputError(path, lineno, "'%' inside a program that did not start with '%'",
                                 column=chars[0][0])
            percent_line = lineno
            seen = True
            continue
        seen = True
        words = _words(chars, path, lineno)
        if _execute_line(words, st, path, lineno, moves, points, point_lines):
            ended = True
            break
    if percent_line is not None and not ended:
        raise InputError(path, percent_line, "the program starts with '%' but has no closing '%' (nor M2/M30)")
    pts = np.array(points, float).reshape(-1, 3)
    return Job(tuple(moves), str(path), pts, np.array(point_lines, int), tuple(messages))


def _execute_line(words, st: _State, path, lineno, moves, points, point_lines):
    err = lambda msg, col=None: InputError(path, lineno, msg, column=col)  # noqa: E731
    vals = {}
    gs, ms = [], []
    for letter, v, col in words:
        if letter == "G":
            code = round(v * 10)
            if code in G_PROBE and abs(v * 10 - code) <= 1e-9 and not st.probe_ok:
                raise err(f"unsupported G-code G{v:g}: probing is not available here (it runs in "
                          f"'pmctl run', which stops on contact)", col)
            if abs(v * 10 - code) > 1e-9 or code not in G_MOTION | G_OTHER:
                why = _unsupported_reason(_G_UNSUPPORTED, code) if abs(v * 10 - code) <= 1e-9 else None
                raise err(f"unsupported G-code G{v:g}" + (f": {why}" if why else ""), col)
            if code in [g for g, _ in gs]:
                raise err(f"G{v:g} repeated", col)
            gs.append((code, col))
        elif letter == "M":
            if v != int(v) or int(v) not in M_CODES:
                why = _unsupported_reason(_M_UNSUPPORTED, int(v)) if v == int(v) else None
                raise err(f"unsupported M-code M{v:g}" + (f": {why}" if why else ""), col)
            if int(v) in [c for c, _ in ms]:
                raise err(f"M{int(v)} repeated", col)
            ms.append((int(v), col))
        else:
            if letter in vals:
                raise err(f"word '{letter}' repeated", col)
            vals[letter] = (v, col)
    codes = [g for g, _ in gs]
    mcodes = [c for c, _ in ms]
    motion = [g for g in codes if g in G_MOTION]
    if len(motion) > 1:
        raise err("two motion codes (G0/G1/G2/G3/G38) on one line", gs[codes.index(motion[1])][1])
    if (200 in codes and 210 in codes) or (900 in codes and 910 in codes) or (len({3, 4, 5} & set(mcodes)) > 1) \
            or (2 in mcodes and 30 in mcodes):
        raise err("conflicting modal codes on one line")
    if "N" in vals:
        n, col = vals.pop("N")
        if n != int(n) or n < 0:
            raise err(f"line number N{n:g} must be a non-negative integer", col)
    # G20/G21 first so that F and coordinates on this line use the new unit.
    if 200 in codes:
        st.units = MM_PER_INCH
    if 210 in codes:
        st.units = 1.0
    if "F" in vals:
        f, col = vals.pop("F")
        if not f > 0:
            raise err(f"feed F{f:g} must be > 0", col)
        st.feed = f * st.units / 60.0
    if "S" in vals:
        s, col = vals.pop("S")
        if s < 0:
            raise err(f"spindle speed S{s:g} must be >= 0", col)
        if s == 0 and st.spindle_on and 5 not in mcodes:
            raise err("S0 while the spindle turns (M3): stop it with M5", col)
        st.s = s
    if 3 in mcodes or 4 in mcodes:
        m = 3 if 3 in mcodes else 4
        if not st.s > 0:
            raise err(f"M{m} with no spindle speed: program S<rpm> (> 0) on this line or before",
                      ms[mcodes.index(m)][1])
        st.spindle_on = 1 if m == 3 else -1
    if 5 in mcodes:
        st.spindle_on = False
    rpm = st.s * st.spindle_on if st.spindle_on else 0.0
    if 40 in codes:
        if motion or any(k in vals for k in "XYZABIJR"):
            raise err("G4 cannot share a line with motion or axis words")
        if "P" not in vals:
            raise err("G4 dwell needs P<seconds>")
        p, col = vals.pop("P")
        if not 0 <= p <= MAX_DWELL_S:
            raise err(f"dwell P{p:g} must be within 0 .. {MAX_DWELL_S:g} s", col)
        moves.append(Move(DWELL, st.pos.copy(), _axis(st), line=lineno, dwell=p, spindle_rpm=rpm))
    if 640 in codes:
        for k in "PQ":
            if k in vals:
                t, col = vals.pop(k)
                if t < 0:
                    raise err(f"G64 tolerance {k}{t:g} must be >= 0", col)
    if 900 in codes:
        st.absolute = True
    if 910 in codes:
        st.absolute = False
    if motion:
        st.motion = motion[0]
    axis_words = [k for k in "XYZAB" if k in vals]
    if motion and motion[0] in G_PROBE and not axis_words:
        raise err(f"G38.{motion[0] - 380} needs an axis word (the probe target)", gs[codes.index(motion[0])][1])
    arc_words = [k for k in "IJR" if k in vals]
    if axis_words:
        if st.motion is None:
            raise err("axis words with no motion mode (G0/G1/G2/G3/G38) active", vals[axis_words[0]][1])
        _move(st, vals, rpm, err, lineno, moves, points, point_lines)
    elif arc_words:
        raise err(f"'{arc_words[0]}' without an arc end point (X/Y)", vals[arc_words[0]][1])
    if "P" in vals:
        raise err("'P' only goes with G4, G64 or an arc", vals["P"][1])
    if "Q" in vals:
        raise err("'Q' only goes with G64", vals["Q"][1])
    return 2 in mcodes or 30 in mcodes


def _axis(st):
    return K.axis_from_roll_pitch(math.radians(st.a), math.radians(st.b))


def _axis_of(ab):
    return K.axis_from_roll_pitch(math.radians(ab[0]), math.radians(ab[1]))


def _move(st: _State, vals, rpm, err, lineno, moves, points, point_lines):
    start = st.pos.copy()
    start_ab = (st.a, st.b)
    target = start.copy()
    for i, k in enumerate("XYZ"):
        if k in vals:
            v = vals.pop(k)[0] * st.units
            target[i] = v if st.absolute else start[i] + v
    for k in "AB":
        if k in vals:
            v = vals.pop(k)[0]
            setattr(st, k.lower(), v if st.absolute else getattr(st, k.lower()) + v)
    axis = _axis(st)
    if st.motion == 0:
        if any(k in vals for k in "IJR"):
            raise err("I/J/R words need G2/G3")
        moves.append(Move(RAPID, target, axis, line=lineno, spindle_rpm=rpm))
    else:
        if st.feed is None:
            raise err("feed move with no F (set a feed rate first)")
        if st.motion in G_PROBE:
            if any(k in vals for k in "IJR"):
                raise err("I/J/R words need G2/G3")
            if np.linalg.norm(axis - _axis_of(start_ab)) > 1e-12:
                raise err(f"G38.{st.motion - 380} with A/B changing: the tool axis must stay put while probing")
            if np.linalg.norm(target - start) < 1e-9:
                raise err(f"G38.{st.motion - 380} target is the current position (no probing direction)")
            moves.append(Move(LINE, target, axis, line=lineno, feed=st.feed, spindle_rpm=rpm,
                              probe=G_PROBE[st.motion]))
        elif st.motion == 10:
            if any(k in vals for k in "IJR"):
                raise err("I/J/R words need G2/G3")
            moves.append(Move(LINE, target, axis, line=lineno, feed=st.feed, spindle_rpm=rpm))
        else:
            center, sweep = _arc(st, start, target, vals, err)
            moves.append(Move(ARC, target, axis, line=lineno, feed=st.feed, spindle_rpm=rpm,
                              center=center, sweep=sweep))
    st.pos = target
    points.append(target.copy())
    point_lines.append(lineno)


def _arc(st: _State, start, end, vals, err):
    ccw = st.motion == 30
    turns = 1
    if "P" in vals:
        p, col = vals.pop("P")
        if p != int(p) or not 1 <= p <= MAX_ARC_TURNS:
            raise err(f"arc turns P{p:g} must be an integer within 1 .. {MAX_ARC_TURNS}", col)
        turns = int(p)
    has_ij = "I" in vals or "J" in vals
    if has_ij and "R" in vals:
        raise err("arc with both R and I/J", vals["R"][1])
    d_xy = end[:2] - start[:2]
    chord = float(np.hypot(*d_xy))
    if has_ij:
        i = vals.pop("I")[0] * st.units if "I" in vals else 0.0
        j = vals.pop("J")[0] * st.units if "J" in vals else 0.0
        center = start[:2] + np.array([i, j])
        r0 = float(np.hypot(*(start[:2] - center)))
        r1 = float(np.hypot(*(end[:2] - center)))
        if r0 < 1e-9:
            raise err("arc radius is zero (I = J = 0)")
        if abs(r1 - r0) > ARC_RADIUS_TOL_MM:
            raise err(f"arc end radius {r1:.4f} mm differs from start radius {r0:.4f} mm "
                      f"(tolerance {ARC_RADIUS_TOL_MM} mm)")
    elif "R" in vals:
        r, col = vals.pop("R")
        r *= st.units
        if chord < 1e-9:
            raise err("an R arc cannot be a full circle (use I/J)", col)
        if abs(r) < 0.5 * chord - ARC_RADIUS_TOL_MM:
            raise err(f"arc radius |R| = {abs(r):.4f} mm too small for a chord of {chord:.4f} mm", col)
        h = math.sqrt(max(r * r - 0.25 * chord * chord, 0.0))
        e = d_xy / chord
        left = np.array([-e[1], e[0]])
        side = (1.0 if ccw else -1.0) * (1.0 if r > 0 else -1.0)
        center = 0.5 * (start[:2] + end[:2]) + side * h * left
        if abs(r) < 0.5 * chord:
            center = 0.5 * (start[:2] + end[:2])
    else:
        raise err("arc needs I/J or R")
    th0 = math.atan2(start[1] - center[1], start[0] - center[0])
    th1 = math.atan2(end[1] - center[1], end[0] - center[0])
    if chord < 1e-9:
        sweep = 2 * math.pi if ccw else -2 * math.pi          # full circle
    elif ccw:
        sweep = (th1 - th0) % (2 * math.pi)
    else:
        sweep = -((th0 - th1) % (2 * math.pi))
    sweep += math.copysign(2 * math.pi * (turns - 1), sweep)
    return center, sweep


def read_gcode(path, machine, *, start=None) -> Job:
    """Read, parse and check a G-code file; every programmed end pose must be reachable."""
    path = Path(path)
    text = read_job_text(path)
    tip, axis = home_pose(machine) if start is None else start
    job = parse_gcode(text, path, tip, axis)
    ends = [m for m in job.moves if m.kind != DWELL]
    if ends:
        tips = np.array([m.tip for m in ends])
        axes = np.array([m.axis for m in ends])
        lines = np.array([m.line for m in ends])
        check_reach(tips, axes, lines, machine, path)
    return job
