"""Arc geometry of G2/G3 in any plane, with LinuxCNC's rules and tolerances.

An arc is computed in its plane's coordinates (first, second) with the third axis along the plane's
normal: G17 (X, Y; normal +Z), G18 (Z, X; normal +Y), G19 (Y, Z; normal +X), as LinuxCNC's canon.
Centre format: ``I J K`` offsets from the start (G91.1, the default) or absolute (G90.1); radius
format: ``R`` (R < 0: the arc longer than a half turn). ``P`` full turns. The sweep is the turn from
the start radius to the end radius, counter-clockwise about the normal for G3, clockwise for G2;
end = start is a full circle (and P-1 more turns), as LinuxCNC's ``find_turn``.

Tolerances (LinuxCNC's defaults, in the program's units): a centre-format arc whose end radius
differs from its start radius by more than 100 x 0.0283 mm (0.00283 in), or by more than 0.0283 mm
(0.00283 in) and 0.1 % of the radius, is refused; a smaller difference becomes a spiral. An R arc may
fall short of half the chord by 0.00127 mm (0.00005 in) before it is refused.
"""

from __future__ import annotations

import math

# (first, second, third) axis indices of X Y Z for each plane (G17 G18 G19 x 10)
PLANE_AXES = {170: (0, 1, 2), 180: (2, 0, 1), 190: (1, 2, 0)}
PLANE_NAMES = {170: "XY (G17)", 180: "XZ (G18)", 190: "YZ (G19)"}
OFFSET_WORDS = {170: ("i", "j", "k"), 180: ("k", "i", "j"), 190: ("j", "k", "i")}
SPIRAL_MM = 2 * 0.01 * math.sqrt(2)          # CENTER_ARC_RADIUS_TOLERANCE_MM
SPIRAL_IN = 2 * 0.001 * math.sqrt(2)         # ..._INCH
SPIRAL_REL = 0.001
RADIUS_IN = 0.00005
RADIUS_MM = RADIUS_IN * 25.4


class ArcError(Exception):
    def __init__(self, message, word=None):
        super().__init__(message)
        self.message, self.word = message, word


def _fmt(v, units):
    return f"{v / units:.4f}"


def center_ijk(plane, start, end, off, absolute, units, ccw):
    """Centre (first, second) of an I J K arc. ``start``/``end``: (first, second) in mm; ``off``:
    the two in-plane centre words in mm (absolute centre coordinates with G90.1). ArcError if the
    end radius does not match the start radius within LinuxCNC's tolerance."""
    c = (off[0], off[1]) if absolute else (start[0] + off[0], start[1] + off[1])
    r1 = math.hypot(start[0] - c[0], start[1] - c[1])
    r2 = math.hypot(end[0] - c[0], end[1] - c[1])
    inch = units != 1.0
    tol_r = RADIUS_IN if inch else RADIUS_MM
    spiral = (SPIRAL_IN if inch else SPIRAL_MM) * units     # in mm
    a, b = (_axis_letters(plane))
    if r1 < tol_r * units or r2 < tol_r * units:
        raise ArcError(f"zero-radius arc: the centre ({a}{_fmt(c[0], units)} {b}{_fmt(c[1], units)}) is on the "
                       "start or end point; check the centre words")
    err = abs(r1 - r2)
    if err > 100.0 * spiral or (err / max(r1, r2) > SPIRAL_REL and err > spiral):
        hint = ""
        if not absolute:
            q1 = math.hypot(start[0] - off[0], start[1] - off[1])
            q2 = math.hypot(end[0] - off[0], end[1] - off[1])
            if q1 > 0 and abs(q1 - q2) <= spiral:
                hint = ("; the centre words fit as absolute coordinates: if the program was written for a "
                        "controller whose arc centres are absolute (Mach3's default), put G90.1 at its start")
        msg = (f"the radius to the end of the arc ({_fmt(r2, units)}) differs from the radius to its start "
               f"({_fmt(r1, units)}) by {_fmt(err, units)}; tolerance {_fmt(spiral, units)} and 0.1 %")
        if hint:
            raise ArcError(msg + hint)
        raise ArcError(msg + f": check the end point and the centre words (start {a}{_fmt(start[0], units)} "
                             f"{b}{_fmt(start[1], units)}, centre {a}{_fmt(c[0], units)} {b}{_fmt(c[1], units)}, "
                             f"end {a}{_fmt(end[0], units)} {b}{_fmt(end[1], units)})")
    return c


def center_r(plane, start, end, radius, units, ccw):
    """Centre of an R arc (radius in mm; < 0: the long way round)."""
    if end[0] == start[0] and end[1] == start[1]:
        raise ArcError("an R arc cannot end where it starts (a full circle needs I J K centre words)", "r")
    inch = units != 1.0
    tol = (RADIUS_IN if inch else RADIUS_MM) * units
    ar = abs(radius)
    mx, my = (end[0] + start[0]) / 2.0, (end[1] + start[1]) / 2.0
    half = math.hypot(mx - end[0], my - end[1])
    if half - ar > tol:
        raise ArcError(f"arc radius R{radius / units:g} is too small to reach the end point (half the chord is "
                       f"{_fmt(half, units)})", "r")
    if ar == 0.0:
        raise ArcError("arc radius R0", "r")
    if half / ar > 1.0 - 1e-12:
        half = ar
    d = math.atan2(end[1] - start[1], end[0] - start[0])
    theta = d - math.pi / 2 if ((not ccw and radius > 0) or (ccw and radius < 0)) else d + math.pi / 2
    offset = ar * math.cos(math.asin(half / ar))
    return (mx + offset * math.cos(theta), my + offset * math.sin(theta))


def sweep(start, center, end, turns):
    """LinuxCNC's find_turn: the signed angle from start to end about center, ``turns`` full or
    partial circles (> 0 counter-clockwise)."""
    if turns == 0:
        return 0.0
    alpha = math.atan2(start[1] - center[1], start[0] - center[0])
    beta = math.atan2(end[1] - center[1], end[0] - center[0])
    if turns > 0:
        if beta <= alpha:
            beta += 2 * math.pi
        return (beta - alpha) + (turns - 1) * 2 * math.pi
    if alpha <= beta:
        alpha += 2 * math.pi
    return (beta - alpha) + (turns + 1) * 2 * math.pi


def _axis_letters(plane):
    f, s, _ = PLANE_AXES[plane]
    return "XYZ"[f], "XYZ"[s]


def helix_length(r0, r1, sweep_rad, dz):
    """Length of the (spiral) helix: mean radius times the sweep, with the rise."""
    return math.hypot(0.5 * (r0 + r1) * sweep_rad, dz)
