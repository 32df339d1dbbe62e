"""Planner throughput: plan the bundled jobs and a long (~10 min at 10 mm/s) 5-axis CL job at 1 kHz;
and the streaming planner's memory on a generated multi-hour G-code job.

    .venv/bin/python benchmarks/bench_planner.py [--repeat 3] [--minutes 10]
    .venv/bin/python benchmarks/bench_planner.py --stream-hours 3 [--rows]

Prints, per job: moves, trajectory duration, samples, planning time (median of the repeats) and the
ratio of machining time to planning time. With ``--stream-hours H``: a 5-axis G-code job of about H
hours (``long_gcode_text``) is written to a temporary file, read, validated and planned by
``plan_stream`` (with ``--rows`` also turned into the rt side's sample rows, as the daemon does), in
a fresh process; it prints the samples, the largest piece, the CPU time of each step, the peak RSS
(ru_maxrss) after reading the job and at the end, and the load average.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from pathlib import Path

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default, pmctl/__init__.py)
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


def long_gcode_text(hours, feed_mm_min=600.0, step_mm=2.2):
    """A 5-axis G-code finishing job of about ``hours`` of cutting at ``feed_mm_min``: zig-zag rows
    along X (60 mm, moves of ``step_mm``) over a wavy surface, the tool tilted (A/B) to its normal,
    with a G4 and a rapid lift every 100 rows."""
    per_row = int(round(60.0 / step_mm))
    rows = max(1, int(hours * 3600.0 * feed_mm_min / 60.0 / (per_row * step_mm)))
    lines = ["(bench: long 5-axis finishing job)", "G17 G21 G90 G94", "G0 X-30 Y-25 Z70", "S6000 M3",
             f"F{feed_mm_min:g}"]
    for i in range(rows):
        y = -25.0 + 50.0 * i / rows
        xs = np.linspace(-30.0, 30.0, per_row + 1)
        for x in (xs if i % 2 == 0 else xs[::-1]):
            z = 60.0 + 3.0 * math.sin(x / 15.0) * math.cos(y / 20.0)
            dzdx = 0.2 * math.cos(x / 15.0) * math.cos(y / 20.0)
            dzdy = -0.15 * math.sin(x / 15.0) * math.sin(y / 20.0)
            lines.append(f"G1 X{x:.4f} Y{y:.4f} Z{z:.4f} A{math.degrees(math.atan(dzdy)):.4f} "
                         f"B{math.degrees(-math.atan(dzdx)):.4f}")
        if i % 100 == 99:
            lines += ["G4 P0.5", f"G0 Z{z + 5:.4f}", f"G1 Z{z:.4f}"]
    lines.append("M30")
    return "\n".join(lines) + "\n"


def stream_bench(hours, dt, rows):
    """Runs in a fresh process (so that ru_maxrss is this job's): see the module docstring."""
    import os
    import resource
    import tempfile
    from pmctl.task.planner import plan_stream, validate
    peak = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024     # noqa: E731  (MiB)
    machine = load_machine()
    with tempfile.TemporaryDirectory() as d:
        f = Path(d) / "long.ngc"
        f.write_text(long_gcode_text(hours))
        size = f.stat().st_size
        c0 = time.process_time()
        job = load_job(f, machine)
    c1 = time.process_time()
    rss_job = peak()
    path = validate(job, machine, dt)
    c2 = time.process_time()
    pieces = plan_stream(job, machine, dt, path=path)
    n = biggest = 0
    if rows:
        from pmctl.motion.service_config import load_service_config
        from pmctl.motion.timescale import iter_stream_rows
        from pmctl.core.job import RAPID
        params = load_service_config(None).nc.params(machine, dt)

        def counted():
            nonlocal n, biggest
            for p in pieces:
                n += len(p)
                biggest = max(biggest, len(p))
                yield p
        nrows = 0
        for r in iter_stream_rows(counted(), machine, params, rapid_lines={m.line for m in job.moves if m.kind == RAPID}):
            nrows += len(r)
        assert nrows == n
    else:
        for p in pieces:
            n += len(p)
            biggest = max(biggest, len(p))
    c3 = time.process_time()
    print(f"stream {hours:g} h job: {size / 2**20:.1f} MiB of G-code, {len(job.moves)} moves, {n} samples "
          f"({n * dt / 3600:.2f} h at {1 / dt:g} Hz), largest piece {biggest} samples{' (+ sample rows)' if rows else ''}")
    print(f"  CPU: read {c1 - c0:.1f} s, validate {c2 - c1:.1f} s, plan{' + rows' if rows else ''} {c3 - c2:.1f} s "
          f"(machining/planning {n * dt / (c3 - c2):.0f}x)")
    print(f"  peak RSS: {rss_job:.0f} MiB after reading the job, {peak():.0f} MiB at the end; "
          f"load average {os.getloadavg()[0]:.2f}")


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
    ap.add_argument("--stream-hours", type=float, default=None,
                    help="only the streaming planner's memory/CPU on a generated job of that many hours")
    ap.add_argument("--rows", action="store_true", help="with --stream-hours: also make the sample rows")
    a = ap.parse_args()
    if a.stream_hours is not None:
        stream_bench(a.stream_hours, a.dt, a.rows)
        return
    machine = load_machine()
    for f in sorted(JOBS.glob("*")):
        if f.suffix in (".cl", ".ngc"):
            bench(f.name, load_job(f, machine), machine, a.dt, a.repeat)
    cl = parse_cl(long_cl_text(a.minutes), "long.cl")
    bench(f"long {a.minutes:g} min", cl_job(cl, machine), machine, a.dt, a.repeat)


if __name__ == "__main__":
    main()
