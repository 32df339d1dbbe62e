"""CL data (seed 000 §7.5, Fig. 7.10): the CAM main processor's output, and its post-processing.

Format: one cutter location per line, ``Px,Py,Pz,Vx,Vy,Vz,flag`` (commas and/or blanks between
fields), P the tool tip in the workpiece frame W (mm), V the unit tool axis (tip -> spindle, so V_z > 0
on this machine), flag one of

- ``s`` start point: the tool approaches it along its axis, cutting begins there;
- ``w`` work point: cutting continues through it;
- ``e`` end point: cutting ends there and the tool retracts along its axis.

An optional header line (first content line, starting with ``Px``), blank lines and comment lines
(``#`` or ``;``) are allowed. The seed's Fig. 7.10 lists the surface normal into the material
(V_z < 0); by default V is the tool axis as in APT ``GOTO/x,y,z,i,j,k``, so a downward vector is an
error rather than silently flipped. Seed-style files are read with ``vector="normal"`` (axis = -V).

Numbers are plain ASCII decimals (an exponent allowed), |P| <= ``MAX_COORD_MM`` and |V| components
<= 2. Every line is parsed and checked before anything is returned: malformed lines, non-unit vectors
(|V| off by more than ``AXIS_TOL``; within it V is normalised), tool axes pointing down or tilted
beyond the config's theta2 limit, pass structure (``w``/``e`` outside a pass, ``s`` inside one, a
pass never ended) and unreachable poses (``kinematics.ik_batch``) raise ``InputError`` naming the
file and line. Nothing is produced from a bad file.

Public API: ``parse_cl(text, path)`` -> ``CLData`` (syntax and vectors only), ``read_cl(path, machine)``
(parse + workspace check), ``cl_actuators(cl, machine)`` -> q (N, 5) (the post-processor),
``cl_job(cl, ...)`` / ``read_cl_job(path, machine, ...)`` -> ``job.Job`` for the planner.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pmctl.core.errors import InputError
from pmctl.core.tolerances import AXIS_TOL    # allowed | |V| - 1 |, the same as for pmctl kin --axis
from pmctl.task.job import LINE, RAPID, Job, Move, check_reach, read_job_text

DEFAULT_FEED_MM_MIN = 600.0     # 10 mm/s
DEFAULT_CLEARANCE_MM = 5.0      # approach/retract distance along the tool axis
FLAGS = ("s", "w", "e")
_SPLIT = re.compile(r"[,\s]+")
_DECIMAL = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]{1,3})?")
MAX_COORD_MM = 1e5              # |Px|, |Py|, |Pz| at most (|V| components are at most 2)


@dataclass(frozen=True)
class CLData:
    tip: np.ndarray      # (N, 3) mm, tool tip in W
    axis: np.ndarray     # (N, 3) unit tool axis
    flag: np.ndarray     # (N,) 's' | 'w' | 'e'
    line: np.ndarray     # (N,) 1-based source line
    source: str = ""

    def __len__(self):
        return len(self.tip)


def _float(text, limit):
    """A plain ASCII decimal (optional exponent) with |v| <= limit, else None."""
    if len(text) > 64 or not _DECIMAL.fullmatch(text):
        return None
    v = float(text)
    return v if math.isfinite(v) and abs(v) <= limit else None


def parse_cl(text: str, path="<string>", *, vector="axis") -> CLData:
    """Parse CL text; checks syntax, vectors (unit, pointing up) and pass structure. No machine needed.

    ``vector="axis"``: V is the tool axis (tip -> spindle); ``"normal"``: V is the seed's surface normal
    into the material (spindle -> tip, as printed in Fig. 7.10), and the tool axis is -V."""
    if vector not in ("axis", "normal"):
        raise InputError(path, None, f"vector convention must be 'axis' or 'normal', got {vector!r}")
    sign = 1.0 if vector == "axis" else -1.0
    tips, axes, flags, lines = [], [], [], []
    seen_content = False
    open_pass = None       # line of the 's' of the pass in progress
    n_pass = 0
    for lineno, raw in enumerate(text.split("\n"), 1):
        s = raw.strip()
        if not s or s.startswith("#") or s.startswith(";"):
            continue
        fields = [f for f in _SPLIT.split(s) if f]
        if not seen_content and fields and fields[0].lower() == "px":
            seen_content = True
            continue                           # header line
        seen_content = True
        if len(fields) != 7:
            raise InputError(path, lineno, f"expected 7 fields Px,Py,Pz,Vx,Vy,Vz,flag, got {len(fields)}")
        vals = []
        for k, (name, f) in enumerate(zip(("Px", "Py", "Pz", "Vx", "Vy", "Vz"), fields[:6])):
            lim = MAX_COORD_MM if k < 3 else 2.0
            v = _float(f, lim)
            if v is None:
                show = f if len(f) <= 40 else f[:37] + "..."
                raise InputError(path, lineno, f"field {k + 1} ({name}): {show!r} is not a decimal number "
                                               f"within +-{lim:g}")
            vals.append(v)
        flag = fields[6].lower()
        if flag not in FLAGS:
            raise InputError(path, lineno, f"field 7 (flag): {fields[6]!r} is not one of s, w, e")
        v = np.array(vals[3:])
        n = float(np.linalg.norm(v))
        if abs(n - 1.0) > AXIS_TOL:
            raise InputError(path, lineno, f"tool vector ({vals[3]:g}, {vals[4]:g}, {vals[5]:g}) is not a unit "
                                           f"vector: |V| = {n:.6g} (tolerance {AXIS_TOL:g})")
        v = sign * v / n
        if v[2] <= 0.0:
            raise InputError(path, lineno, f"tool vector ({vals[3]:g}, {vals[4]:g}, {vals[5]:g}) points "
                                           + ("downward; V is the tool axis from the tip to the spindle (V_z > 0)"
                                              if vector == "axis" else
                                              "upward; a 'normal' V points from the spindle into the material (V_z < 0)"))
        if flag == "s":
            if open_pass is not None:
                raise InputError(path, lineno, f"'s' inside the pass started on line {open_pass} (end it with 'e')")
            open_pass = lineno
        elif open_pass is None:
            raise InputError(path, lineno, f"'{flag}' outside a pass (a pass starts with 's')")
        elif flag == "e":
            open_pass = None
        n_pass += flag == "s"
        tips.append(vals[:3])
        axes.append(v)
        flags.append(flag)
        lines.append(lineno)
    if open_pass is not None:
        raise InputError(path, open_pass, "pass started here is never ended with 'e'")
    if not tips:
        raise InputError(path, None, "no CL points")
    return CLData(np.array(tips, float), np.array(axes, float), np.array(flags), np.array(lines, int), str(path))


def read_cl(path, machine, *, vector="axis") -> CLData:
    """Read and fully check a CL file (syntax, vectors, pass structure, reachability)."""
    path = Path(path)
    text = read_job_text(path)
    cl = parse_cl(text, path, vector=vector)
    check_reach(cl.tip, cl.axis, cl.line, machine, path)
    return cl


def cl_actuators(cl: CLData, machine) -> np.ndarray:
    """Post-processor: actuator targets q = (L1, L2, L3, X, Y) per CL point, (N, 5) mm (vectorised IK)."""
    return check_reach(cl.tip, cl.axis, cl.line, machine, cl.source).q


def cl_job(cl: CLData, machine=None, *, feed_mm_min=DEFAULT_FEED_MM_MIN, clearance_mm=DEFAULT_CLEARANCE_MM,
           spindle_rpm=10000.0) -> Job:
    """CL points -> moves. Each pass: rapid to ``clearance_mm`` above its 's' point along the tool axis,
    feed down to it, feed through its points, feed back up ``clearance_mm`` along the axis after 'e'.
    With a machine, the added approach/retract poses are checked for reachability too."""
    if not feed_mm_min > 0 or not math.isfinite(feed_mm_min):
        raise InputError(cl.source, None, f"feed must be a positive number of mm/min, got {feed_mm_min!r}")
    if not clearance_mm >= 0 or not math.isfinite(clearance_mm):
        raise InputError(cl.source, None, f"clearance must be >= 0 mm, got {clearance_mm!r}")
    feed = feed_mm_min / 60.0
    moves = []
    for p, v, f, ln in zip(cl.tip, cl.axis, cl.flag, cl.line):
        ln = int(ln)
        if f == "s":
            if clearance_mm > 0:
                moves.append(Move(RAPID, p + clearance_mm * v, v, line=ln, spindle_rpm=spindle_rpm))
            moves.append(Move(LINE, p.copy(), v.copy(), line=ln, feed=feed, spindle_rpm=spindle_rpm))
        else:
            moves.append(Move(LINE, p.copy(), v.copy(), line=ln, feed=feed, spindle_rpm=spindle_rpm))
            if f == "e" and clearance_mm > 0:
                moves.append(Move(LINE, p + clearance_mm * v, v.copy(), line=ln, feed=feed, spindle_rpm=spindle_rpm))
    if machine is not None and clearance_mm > 0:
        check_reach(np.array([m.tip for m in moves]), np.array([m.axis for m in moves]),
                    np.array([m.line for m in moves]), machine, cl.source)
    return Job(tuple(moves), cl.source, cl.tip.copy(), cl.line.copy())


def read_cl_job(path, machine, *, vector="axis", feed_mm_min=DEFAULT_FEED_MM_MIN, clearance_mm=DEFAULT_CLEARANCE_MM,
                spindle_rpm=10000.0) -> Job:
    """Read, check and convert a CL file into a job (see :func:`cl_job`)."""
    cl = read_cl(path, machine, vector=vector)
    return cl_job(cl, machine, feed_mm_min=feed_mm_min, clearance_mm=clearance_mm, spindle_rpm=spindle_rpm)
