"""Planner throughput: plan the bundled jobs and a long (~10 min at 10 mm/s) 5-axis CL job at 1 kHz.

    .venv/bin/python benchmarks/bench_planner.py [--repeat 3] [--minutes 10]

Prints, per job: moves, trajectory duration, samples, planning time (median of the repeats) and the
ratio of machining time to planning time.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from pathlib import Path

import numpy as np

from pmctl.task.cldata import cl_job, parse_cl
from pmctl.core.config import load_machine
from pmctl.task.planner import load_job, plan

JOBS = Path(__file__).resolve().parents[1] / "examples" / "jobs"


def long_cl_text(minutes, feed_mm_s=10.0, step_deg=1.0):
    """A spherical spiral in a bowl (R 30 mm), the tool tilted up to 15 deg toward the normal, long
    enough for ``minutes`` of cutting at ``feed_mm_s``."""
    length = minutes * 60.0 * feed_mm_s
    R, c = 30.0, np.array([0.0, 0.0, 60.0])
    rows = []
    s = 0.0
    psi = 0.0
    prev = None
    while s < length:
        phi = math.radians(25.0 + 30.0 * (0.5 - 0.5 * math.cos(psi / 40.0)))   # wanders between 25 and 55 deg
        p = c + R * np.array([math.sin(phi) * math.cos(psi), math.sin(phi) * math.sin(psi), -math.cos(phi)])
        n = c - p
        h = math.hypot(n[0], n[1])
        tilt = math.radians(15.0)
        v = np.array([n[0] / h * math.sin(tilt), n[1] / h * math.sin(tilt), math.cos(tilt)])
        if prev is not None:
            s += float(np.linalg.norm(p - prev))
        rows.append((p, v))
        prev = p
        psi += math.radians(step_deg)
    lines = []
    for k, (p, v) in enumerate(rows):
        flag = "s" if k == 0 else ("e" if k == len(rows) - 1 else "w")
        lines.append(",".join(f"{x:.6f}" for x in (*p, *v)) + "," + flag)
    return "\n".join(lines) + "\n"


def bench(name, job, machine, dt, repeat):
    times = []
    traj = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        traj = plan(job, machine, dt)
        times.append(time.perf_counter() - t0)
    med = statistics.median(times)
    print(f"{name:>16}: {len(job.moves):6d} moves  {traj.duration:8.2f} s  {len(traj):8d} samples  "
          f"plan {med:7.3f} s (median of {repeat}, min {min(times):.3f})  ratio {traj.duration / med:7.1f}x")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--dt", type=float, default=1e-3)
    a = ap.parse_args()
    machine = load_machine()
    for f in sorted(JOBS.glob("*")):
        if f.suffix in (".cl", ".ngc"):
            bench(f.name, load_job(f, machine), machine, a.dt, a.repeat)
    cl = parse_cl(long_cl_text(a.minutes), "long.cl")
    bench(f"long {a.minutes:g} min", cl_job(cl, machine), machine, a.dt, a.repeat)


if __name__ == "__main__":
    main()
