"""Write a G-code program of micro-segments, as V-carving CAM posts it: deterministic (a seed), of a
chosen size.

    .venv/bin/python benchmarks/make_microsegments.py OUT.ngc [--size-mb 1.2] [--seed 1]
                                                      [--units inch|mm] [--step MIN,MAX]

The program carves ``glyphs``: closed smooth curves (roses and epicycloids of 3-8 mm) traced by G1
moves of ``--step`` length each (default: 1-25 micro-inch in inch units, the steps of the V-carve
program that faulted the old planner; 0.2-1 um in mm units), with the depth going up and down
along the curve (a V bit's depth follows the width of the letter), and the coordinates printed
with 6 decimals (1 micro-inch; mm: 0.1 um with 4 decimals), so the quantised steps change direction
at random, as such programs do. Between glyphs: a retract, a rapid to the next one, a plunge. One
run of micro-segments in ten is followed by a few long flat strokes. It starts with ``%`` and a
comment header, G20/G21 G90 G64 and a spindle start, and ends with M5 M30 ``%``.

The whole program is inside the prototype's workspace (XY within 25 mm of the centre, Z 55-65 mm).
Prints the file's size, lines, moves and the micro-segments' length range.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

MM_PER_INCH = 25.4


def glyph(rng):
    """A closed smooth curve (x(t), y(t)) in mm around the origin, and its depth profile in [0, 1]."""
    kind = rng.integers(0, 2)
    size = rng.uniform(3.0, 8.0)
    k = int(rng.integers(2, 6))
    ph = rng.uniform(0, 2 * math.pi)

    def xy(t):
        if kind == 0:                                   # a rose r = cos(k t) + offset
            r = size * (0.6 + 0.4 * np.cos(k * t + ph))
            return r * np.cos(t), r * np.sin(t)
        R, r = size, size / (k + 1)                    # an epicycloid
        return ((R + r) * np.cos(t) - r * np.cos((R + r) / r * t + ph),
                (R + r) * np.sin(t) - r * np.sin((R + r) / r * t + ph))

    def depth(t):
        return 0.5 + 0.5 * np.sin(3 * t + ph)
    return xy, depth


def trace(xy, depth, steps_mm, t_span, z_top, z_amp):
    """Points (x, y, z) along the curve, z = z_top - z_amp * depth, with the given 3-D step lengths
    (walked on a fine table of t)."""
    t = np.linspace(0.0, t_span, 200_001)
    x, y = xy(t)
    z = z_top - z_amp * depth(t)
    d = np.concatenate([[0.0], np.cumsum(np.sqrt(np.diff(x) ** 2 + np.diff(y) ** 2 + np.diff(z) ** 2))])
    s = np.concatenate([[0.0], np.cumsum(steps_mm)])
    s = s[s <= d[-1]]
    tt = np.interp(s, d, t)
    px, py = xy(tt)
    return px, py, z_top - z_amp * depth(tt)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out")
    ap.add_argument("--size-mb", type=float, default=1.2, help="size of the program (default 1.2 MB)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--units", choices=("inch", "mm"), default="inch")
    ap.add_argument("--step", default=None, metavar="MIN,MAX",
                    help="step length range in program units (default: 1e-6,25e-6 inch or 0.0002,0.001 mm)")
    ap.add_argument("--feed", type=float, default=None, help="cutting feed, program units/min (default 60 ipm, 1500 mm/min)")
    ap.add_argument("--decimals", type=int, default=None, help="decimals of the coordinates (default 6 inch, 4 mm)")
    args = ap.parse_args()
    inch = args.units == "inch"
    unit = MM_PER_INCH if inch else 1.0
    lo, hi = (float(v) for v in args.step.split(",")) if args.step else ((1e-6, 25e-6) if inch else (2e-4, 1e-3))
    feed = args.feed or (60.0 if inch else 1500.0)
    nd = args.decimals or (6 if inch else 4)
    fmt = f"{{:.{nd}f}}".format
    rng = np.random.default_rng(args.seed)
    target = int(args.size_mb * 1e6)
    z_top, z_safe = 62.0, 65.0                                 # mm in W
    out = ["%", f"(V-carve micro-segment test program, seed {args.seed}, {args.units})",
           f"(steps {lo:g} to {hi:g} {args.units}; written by benchmarks/make_microsegments.py)",
           f"{'G20' if inch else 'G21'} G90 G64", "S18000 M3", f"G0 Z{fmt(z_safe / unit)}"]
    size = sum(len(s) + 1 for s in out)
    moves = 0
    micro = []
    g = 0
    while size < target:
        cx, cy = rng.uniform(-14.0, 14.0, 2)
        xy, depth = glyph(rng)
        steps = rng.uniform(lo, hi, int(rng.integers(2000, 8000))) * unit       # mm
        px, py, pz = trace(xy, depth, steps, 2 * math.pi, z_top - rng.uniform(0, 2.0), rng.uniform(0.1, 1.0))
        px, py = px + cx, py + cy
        lines = [f"G0 X{fmt(px[0] / unit)} Y{fmt(py[0] / unit)}", f"G1 Z{fmt(pz[0] / unit)} F{feed / 4:g}",
                 f"F{feed:g}"]
        prev = None
        for x, y, z in zip(px[1:] / unit, py[1:] / unit, pz[1:] / unit):
            w = f"X{fmt(x)}Y{fmt(y)}Z{fmt(z)}"
            if w == prev:
                continue
            lines.append("G1" + w if len(lines) == 3 else w)
            prev = w
        q = np.array([px, py, pz]).T
        step = np.linalg.norm(np.diff(np.round(q / unit, nd) * unit, axis=0), axis=1)
        micro.append(step[step > 0])
        if g % 10 == 9:                                           # a few long flat strokes
            x0, y0 = px[-1], py[-1]
            for k in range(4):
                x0 = min(24.0, max(-24.0, x0 + rng.uniform(-6, 6)))
                y0 = min(24.0, max(-24.0, y0 + rng.uniform(-6, 6)))
                lines.append(f"X{fmt(x0 / unit)}Y{fmt(y0 / unit)}")
        lines.append(f"G0 Z{fmt(z_safe / unit)}")
        out += lines
        size += sum(len(s) + 1 for s in lines)
        moves += len(lines) - 1
        g += 1
    out += ["M5", "M30", "%"]
    Path(args.out).write_text("\n".join(out) + "\n")
    st = np.concatenate(micro) / unit
    print(f"{args.out}: {Path(args.out).stat().st_size / 1e6:.3f} MB, {len(out)} lines, {g} glyphs, about {moves} "
          f"moves; micro-segments {st.min():.3g} to {st.max():.3g} {args.units} (median {np.median(st):.3g})")


if __name__ == "__main__":
    main()
