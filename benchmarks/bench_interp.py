"""RS-274 interpreter speed and memory: lines per second on programs of about 1 MB, and bytes per move.

    .venv/bin/python benchmarks/bench_interp.py [--mb 1.0] [--runs 5] [--file PROGRAM ...]

Three generated programs (deterministic, seed 0) of about --mb megabytes each, the kinds CAM writes:
``3d``    G1 X Y Z lines of a 3D raster (short segments, every line a move, G21);
``arcs``  G2/G3 with I J and F between G1 lines, comments every 20 lines (a 2D profile of a Fanuc-style post);
``macro`` a subroutine called in a while loop with parameters and expressions (few lines, many blocks).
``--file`` adds programs of your own (a corpus file, say). For each: the median and p99 of the wall time
of ``pmctl.task.rs274.interpret`` over --runs runs, lines (and executed blocks) per second at the median,
and the memory of the resulting job per move (tracemalloc, one extra run). The load average is printed
with the figures (the machine may be shared). Not a test: nothing here asserts a time.
"""

import argparse
import math
import os
import random
import statistics
import time
import tracemalloc

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default)

from pmctl.task.rs274 import interpret


def program_3d(mb, rng):
    out = ["(3d raster)", "G21 G90 G17 G94", "S12000 M3", "G0 X0 Y0 Z5", "F1500"]
    size, x, y = 0, 0.0, 0.0
    while size < mb * 1e6:
        x += rng.uniform(-0.4, 0.4)
        y += rng.uniform(-0.4, 0.4)
        line = f"G1 X{x:.4f} Y{y:.4f} Z{rng.uniform(-3, 0):.4f}"
        out.append(line)
        size += len(line) + 1
    return "\n".join(out + ["M30"]) + "\n"


def program_arcs(mb, rng):
    out = ["%", "O1001 (profile)", "G21 G90 G17 G94 G40 G49 G80", "T1 M6", "G43 H1", "S8000 M3 M8", "G0 X10 Y0 Z5",
           "G1 Z-1 F300"]
    size, k, x, y = 0, 0, 10.0, 0.0
    while size < mb * 1e6:
        k += 1
        if k % 3:                                  # an arc from where the tool is, its centre towards the origin
            r = rng.uniform(2, 20)
            t = math.atan2(-y, -x) + rng.uniform(-1, 1)
            cx, cy = x + r * math.cos(t), y + r * math.sin(t)
            a = math.atan2(y - cy, x - cx) + rng.uniform(0.2, 3.0) * (1 if k % 2 else -1)
            i, j = cx - x, cy - y
            x, y = round(cx + r * math.cos(a), 4), round(cy + r * math.sin(a), 4)
            line = f"G{3 if k % 2 else 2} X{x:.4f} Y{y:.4f} I{i:.4f} J{j:.4f} F{rng.choice([600, 800, 1000])}"
        else:
            x, y = round(rng.uniform(-20, 20), 4), round(rng.uniform(-20, 20), 4)
            line = f"G1 X{x:.4f} Y{y:.4f}"
        if k % 20 == 0:
            line += " (pass %d)" % k
        out.append(line)
        size += len(line) + 1
    return "\n".join(out + ["M9 M5", "G28 G91 Z0", "M30", "%"]) + "\n"


def program_macro(mb, rng):
    n = int(mb * 1e6 / 30)                         # about as many moves as a 30-byte-a-line program
    return (f"G21 G90 F800\n#<n> = {n // 4}\n#1 = 0\no<sq> sub\n  G1 X[#1] Y0\n  G1 X[#1] Y[#1]\n  G1 X0 Y[#1]\n"
            "  G1 X0 Y0\no<sq> endsub\no100 while [#1 LT #<n>]\n  o<sq> call [[#1 MOD 20] + 1]\n"
            "  #1 = [#1 + 1]\no100 endwhile\nM2\n")


def measure(name, text, runs):
    lines = text.count("\n")
    ts = []
    for _ in range(runs):
        t0 = time.perf_counter()
        job, problems = interpret(text, name)
        ts.append(time.perf_counter() - t0)
    tracemalloc.start()
    job, problems = interpret(text, name)
    size, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    med = statistics.median(ts)
    p99 = sorted(ts)[min(len(ts) - 1, int(0.99 * len(ts)))]
    moves = len(job.moves)
    print(f"{name:>10s} {len(text) / 1e6:6.2f} MB {lines:8d} lines {moves:8d} moves  median {med:6.3f} s  "
          f"p99 {p99:6.3f} s  {lines / med:9.0f} lines/s {moves / med:9.0f} moves/s  "
          f"{size / max(moves, 1):5.0f} B/move (peak {peak / 1e6:.0f} MB)  problems {len(problems)}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mb", type=float, default=1.0, help="size of the generated programs (MB)")
    ap.add_argument("--runs", type=int, default=5, help="timed runs per program")
    ap.add_argument("--file", nargs="*", default=[], help="programs of your own to time too")
    a = ap.parse_args()
    rng = random.Random(0)
    print("load average %.2f %.2f %.2f, %d CPUs" % (os.getloadavg() + (os.cpu_count(),)))
    for name, make in (("3d", program_3d), ("arcs", program_arcs), ("macro", program_macro)):
        measure(name, make(a.mb, rng), a.runs)
    for f in a.file:
        with open(f, errors="replace") as fh:
            measure(os.path.basename(f), fh.read(), a.runs)
    print("load average %.2f %.2f %.2f" % os.getloadavg())


if __name__ == "__main__":
    main()
