"""Write a V-carve-like G-code program of micro-segments for the planner: at least 1 MB of steps of
1 um and smaller, deterministic from a seed.

    .venv/bin/python benchmarks/make_microsegments.py OUT.ngc [--seed 1] [--bytes 1100000] [--check]

Like the output of V-carving CAM on a real job (tests/corpus/vcarve/vcarve.ngc: half its steps are under
51 micro-inch), the program is a series of strokes, each a long run of tiny G1 steps whose direction
turns slowly (collinear and near-collinear neighbours) while Z follows the carving depth of a V bit.
Step lengths are drawn per run from 1 um down to 1 micro-inch (0.0254 um), written with 6 decimals; each
stroke has its own feed between F100 and F3000 mm/min and is written either with G1 on every line or
modal (coordinates only), as CAM posts do. Between strokes the tool retracts with G0.

All of it lies inside this machine's workspace (docs/machine.md; examples/jobs/README.md): 3-axis, tool
vertical (A0 B0), the tip within +-25 mm of the table centre in X and Y, carving 0-1.2 mm deep into
the workpiece face at z = 60 mm, retracting to z = 62. ``--check`` reads the file back with today's job
reader (``pmctl.task.job.load_job``, which checks every pose against the machine) and prints its moves.
Prints the number of steps, their lengths (min, median, max), the feeds and the extents.
"""

from __future__ import annotations

import argparse
import math
import random
import statistics
from pathlib import Path

FACE_Z = 60.0          # workpiece face (z in the workpiece frame W, mm)
SAFE_Z = 62.0
MAX_DEPTH = 1.2
HALF = 25.0            # |x|, |y| of the carving area (mm)
INCH_UM = 25.4e-3      # one micro-inch in um


def strokes(rng: random.Random):
    """Endless strokes: (feed, modal, [(x, y, z), ...]) with every step of at most 1 um."""
    while True:
        x, y = rng.uniform(-HALF * 0.8, HALF * 0.8), rng.uniform(-HALF * 0.8, HALF * 0.8)
        heading = rng.uniform(0.0, 2.0 * math.pi)
        turn = rng.uniform(-0.02, 0.02)                     # rad per mm: slow curvature
        feed = rng.choice([100, 200, 300, 500, 800, 1000, 1500, 2000, 2500, 3000])
        modal = rng.random() < 0.5
        length_mm = rng.uniform(0.3, 2.0)                   # one stroke: 0.3-2 mm of carving
        phase, wave = rng.uniform(0, 2 * math.pi), rng.uniform(0.5, 3.0)
        pts, s = [], 0.0
        while s < length_mm:
            # a run of equal steps: 1 um, or smaller down to 1 micro-inch
            step_um = 1.0 if rng.random() < 0.45 else math.exp(rng.uniform(math.log(INCH_UM), 0.0))
            jitter = rng.choice([0.0, 0.0, 1e-4, 1e-3])     # collinear, or near-collinear neighbours
            for _ in range(rng.randint(50, 400)):
                step = step_um * 1e-3                            # the 3-D length of this step (mm)
                heading += turn * step + rng.gauss(0.0, jitter)
                slope = MAX_DEPTH * 0.45 * wave * math.cos(phase + wave * s)  # d depth / d s
                h = step / math.hypot(1.0, slope)                # its XY part
                x += h * math.cos(heading)
                y += h * math.sin(heading)
                s += h
                depth = MAX_DEPTH * (0.5 + 0.45 * math.sin(phase + wave * s))   # V-bit depth follows the width
                if abs(x) > HALF or abs(y) > HALF:
                    break
                pts.append((x, y, FACE_Z - depth))
            if abs(x) > HALF or abs(y) > HALF:
                break
        if len(pts) > 1:
            yield feed, modal, pts


def program(seed: int, nbytes: int) -> tuple[str, dict]:
    rng = random.Random(seed)
    lines = [f"(pmctl micro-segment V-carve test program, benchmarks/make_microsegments.py --seed {seed})",
             "G21 G90 G17 G94", "G0 Z%.3f A0 B0" % SAFE_Z, "S12000 M3"]
    size = sum(len(s) + 1 for s in lines)
    steps, feeds = [], set()
    lo, hi = [math.inf] * 3, [-math.inf] * 3
    for feed, modal, pts in strokes(rng):
        x0, y0, z0 = pts[0]
        block = [f"G0 X{x0:.6f} Y{y0:.6f}", f"G1 Z{z0:.6f} F100"]
        prev = pts[0]
        for k, (x, y, z) in enumerate(pts[1:]):
            xyz = f"X{x:.6f} Y{y:.6f} Z{z:.6f}"
            block.append(f"G1 {xyz} F{feed}" if k == 0 else (xyz if modal else "G1 " + xyz))
            steps.append(math.dist(prev, (round(x, 6), round(y, 6), round(z, 6))))
            prev = (round(x, 6), round(y, 6), round(z, 6))
        block.append(f"G0 Z{SAFE_Z:.3f}")
        feeds.add(feed)
        for x, y, z in pts:
            for i, v in enumerate((x, y, z)):
                lo[i], hi[i] = min(lo[i], v), max(hi[i], v)
        lines += block
        size += sum(len(s) + 1 for s in block)
        if size >= nbytes:
            break
    lines += ["M5", "M30"]
    text = "\n".join(lines) + "\n"
    stats = {"bytes": len(text.encode()), "steps": len(steps), "step_um": [1e3 * min(steps), 1e3 * statistics.median(steps),
             1e3 * max(steps)], "feeds": sorted(feeds), "lo": lo, "hi": hi}
    return text, stats


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--bytes", type=int, default=1_100_000, help="stop after this many bytes (default 1100000)")
    ap.add_argument("--check", action="store_true", help="read it back with today's job reader")
    a = ap.parse_args(argv)
    text, st = program(a.seed, a.bytes)
    a.out.write_text(text)
    print(f"wrote {a.out}: {st['bytes']} bytes, {st['steps']} steps of {st['step_um'][0]:.4f} / "
          f"{st['step_um'][1]:.4f} / {st['step_um'][2]:.4f} um (min / median / max), feeds {st['feeds']}")
    print("extents x %.3f..%.3f  y %.3f..%.3f  z %.4f..%.4f mm" % (st["lo"][0], st["hi"][0], st["lo"][1],
                                                                   st["hi"][1], st["lo"][2], st["hi"][2]))
    if a.check:
        from pmctl.core.config import load_machine
        from pmctl.task.job import load_job
        job = load_job(a.out, load_machine())
        print(f"today's job reader: {len(job)} moves, every pose reachable")


if __name__ == "__main__":
    main()
