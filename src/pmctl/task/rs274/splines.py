"""G5 cubic and G5.1 quadratic splines in the XY plane, as LinuxCNC defines them, made into straight feed
moves along the curve.

``G5 X Y I J P Q``: a cubic Bezier curve from the current point to (X, Y); the first control point is the
start plus (I, J), the second the end plus (P, Q). In a series of G5 blocks, I and J may be left out:
the first control point is then the previous second control point reflected about the previous end
(the curve goes on smoothly). ``G5.1 X Y I J``: a quadratic Bezier curve whose control point is the
start plus (I, J). Both in G17 only, at the feed in force; Z, A and B stay.

The curve is flattened into lines whose chords stay within ``CHORD_TOL_MM`` of it (adaptive
subdivision, at most ``MAX_PIECES`` lines a block); LinuxCNC hands the curve to its motion planner as
NURBS, this machine's planner takes lines.
"""

from __future__ import annotations

import math

CHORD_TOL_MM = 0.001
MAX_PIECES = 4096


def _point(ctrl, t):
    n = len(ctrl) - 1
    if n == 2:
        (x0, y0), (x1, y1), (x2, y2) = ctrl
        a, b, c = (1 - t) ** 2, 2 * (1 - t) * t, t * t
        return a * x0 + b * x1 + c * x2, a * y0 + b * y1 + c * y2
    (x0, y0), (x1, y1), (x2, y2), (x3, y3) = ctrl
    a, b, c, d = (1 - t) ** 3, 3 * (1 - t) ** 2 * t, 3 * (1 - t) * t * t, t ** 3
    return a * x0 + b * x1 + c * x2 + d * x3, a * y0 + b * y1 + c * y2 + d * y3


def flatten(ctrl, tol=CHORD_TOL_MM):
    """Points (excluding the start) of a polyline within ``tol`` of the Bezier curve ``ctrl``."""
    out = []

    def split(t0, p0, t1, p1, depth):
        tm = 0.5 * (t0 + t1)
        pm = _point(ctrl, tm)
        # deviation of the curve from the chord at the middle and at the quarters
        dev = 0.0
        dx, dy = p1[0] - p0[0], p1[1] - p0[1]
        ln = math.hypot(dx, dy)
        for t in (tm, 0.5 * (t0 + tm), 0.5 * (tm + t1)):
            q = _point(ctrl, t)
            if ln > 0:
                dev = max(dev, abs((q[0] - p0[0]) * dy - (q[1] - p0[1]) * dx) / ln)
            else:
                dev = max(dev, math.hypot(q[0] - p0[0], q[1] - p0[1]))
        if depth >= 2 and (dev <= tol or depth >= 12 or len(out) >= MAX_PIECES):
            out.append(p1)
            return
        split(t0, p0, tm, pm, depth + 1)
        split(tm, pm, t1, p1, depth + 1)

    split(0.0, ctrl[0], 1.0, ctrl[-1], 0)
    return out
