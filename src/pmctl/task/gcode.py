"""RS-274 (G-code) subset reader -> a job (pmctl.task.job) for the planner.

Supported (LinuxCNC semantics unless noted):

- motion: ``G0`` rapid, ``G1`` feed line, ``G2``/``G3`` clockwise/counter-clockwise arc or helix in the
  XY plane (``G17``, the only plane) with centre offsets ``I``/``J`` (always relative to the start) or
  radius ``R`` (R < 0: the arc longer than a half turn), optional ``P`` full turns; ``G4 P<seconds>`` dwell;
- modes: ``G17``, ``G20`` inch / ``G21`` mm, ``G90`` absolute / ``G91`` incremental (also for A, B),
  ``G94`` units per minute (the only feed mode);
- words: ``X Y Z`` tool tip in W, ``A B`` tool tilt as roll / pitch in degrees (MACHINE.md §3: axis =
  Rx(A) Ry(B) z), ``F`` feed (mm/min or in/min), ``S`` spindle rpm, ``N`` line number;
- ``M3`` spindle on clockwise (at S), ``M4`` counter-clockwise (the moves' spindle_rpm is negative), ``M5``
  off, ``M2``/``M30`` end of program (later lines are ignored);
- comments ``( ... )`` and ``;`` to the end of the line; spaces anywhere; a line holding only ``%``.

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
from pmctl.task.job import ARC, DWELL, LINE, RAPID, Job, Move, check_reach, home_pose

MM_PER_INCH = 25.4
ARC_RADIUS_TOL_MM = 0.005         # |r_end - r_start| allowed for I/J arcs (becomes a tiny spiral)
LETTERS = set("ABFGIJMNPRSXYZ")
G_MOTION = {0, 10, 20, 30}        # G-codes times 10
G_OTHER = {40, 170, 200, 210, 900, 910, 940}
M_CODES = {2, 3, 4, 5, 30}
_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)")


def _strip_comments(raw, path, lineno):
    """Return [(column, char)] of the line without comments and blanks (columns 1-based)."""
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
        letter = text[i].upper()
        col = cols[i]
        if not letter.isalpha():
            raise InputError(path, lineno, f"expected a word letter, got {text[i]!r}", column=col)
        if letter not in LETTERS:
            m = _NUMBER.match(text, i + 1)
            word = letter + (m.group(0) if m else "")
            raise InputError(path, lineno, f"unknown word {word!r}", column=col)
        m = _NUMBER.match(text, i + 1)
        if not m:
            raise InputError(path, lineno, f"missing value after '{letter}'", column=col)
        words.append((letter, float(m.group(0)), col))
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


def parse_gcode(text: str, path="<string>", start_tip=(0.0, 0.0, 0.0), start_axis=(0.0, 0.0, 1.0)) -> Job:
    """Parse a program (pure). ``start_*``: where the tool is when the program starts (G91 and arcs
    are relative to it; the initial A/B are its roll/pitch)."""
    st = _State(start_tip, start_axis)
    moves, points, point_lines = [], [], []
    for lineno, raw in enumerate(text.split("\n"), 1):
        chars = _strip_comments(raw, path, lineno)
        if not chars:
            continue
        if len(chars) == 1 and chars[0][1] == "%":
            continue
        words = _words(chars, path, lineno)
        end = _execute_line(words, st, path, lineno, moves, points, point_lines)
        if end:
            break
    pts = np.array(points, float).reshape(-1, 3)
    return Job(tuple(moves), str(path), pts, np.array(point_lines, int))


def _execute_line(words, st: _State, path, lineno, moves, points, point_lines):
    err = lambda msg, col=None: InputError(path, lineno, msg, column=col)  # noqa: E731
    vals = {}
    gs, ms = [], []
    for letter, v, col in words:
        if letter == "G":
            code = round(v * 10)
            if abs(v * 10 - code) > 1e-9 or code not in G_MOTION | G_OTHER:
                raise err(f"unsupported G-code G{v:g}", col)
            if code in [g for g, _ in gs]:
                raise err(f"G{v:g} repeated", col)
            gs.append((code, col))
        elif letter == "M":
            if v != int(v) or int(v) not in M_CODES:
                raise err(f"unsupported M-code M{v:g}", col)
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
        raise err("two motion codes (G0/G1/G2/G3) on one line", gs[codes.index(motion[1])][1])
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
        st.s = s
    if 3 in mcodes or 4 in mcodes:
        st.spindle_on = 1 if 3 in mcodes else -1
    if 5 in mcodes:
        st.spindle_on = False
    rpm = st.s * st.spindle_on if st.spindle_on else 0.0
    if 40 in codes:
        if motion or any(k in vals for k in "XYZABIJR"):
            raise err("G4 cannot share a line with motion or axis words")
        if "P" not in vals:
            raise err("G4 dwell needs P<seconds>")
        p, col = vals.pop("P")
        if p < 0:
            raise err(f"dwell P{p:g} must be >= 0 s", col)
        moves.append(Move(DWELL, st.pos.copy(), _axis(st), line=lineno, dwell=p, spindle_rpm=rpm))
    if 900 in codes:
        st.absolute = True
    if 910 in codes:
        st.absolute = False
    if motion:
        st.motion = motion[0]
    axis_words = [k for k in "XYZAB" if k in vals]
    arc_words = [k for k in "IJR" if k in vals]
    if axis_words:
        if st.motion is None:
            raise err("axis words with no motion mode (G0/G1/G2/G3) active", vals[axis_words[0]][1])
        _move(st, vals, rpm, err, lineno, moves, points, point_lines)
    elif arc_words:
        raise err(f"'{arc_words[0]}' without an arc end point (X/Y)", vals[arc_words[0]][1])
    if "P" in vals:
        raise err("'P' only goes with G4 or an arc", vals["P"][1])
    return 2 in mcodes or 30 in mcodes


def _axis(st):
    return K.axis_from_roll_pitch(math.radians(st.a), math.radians(st.b))


def _move(st: _State, vals, rpm, err, lineno, moves, points, point_lines):
    start = st.pos.copy()
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
        if st.motion == 10:
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
        if p != int(p) or p < 1:
            raise err(f"arc turns P{p:g} must be a positive integer", col)
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
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(path, None, f"cannot read: {e}") from None
    tip, axis = home_pose(machine) if start is None else start
    job = parse_gcode(text, path, tip, axis)
    ends = [m for m in job.moves if m.kind != DWELL]
    if ends:
        tips = np.array([m.tip for m in ends])
        axes = np.array([m.axis for m in ends])
        lines = np.array([m.line for m in ends])
        check_reach(tips, axes, lines, machine, path)
    return job
