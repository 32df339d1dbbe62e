"""Benchmark of the mechanism analysis (prints medians/p99 and throughputs; not a test).

    .venv/bin/python benchmarks/bench_mechanism.py
"""

import time

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default, pmctl/__init__.py)
import numpy as np

from pmctl.core import kinematics as K
from pmctl.tools.analysis import mechanism as M
from pmctl.core.config import load_machine

D = M.DEG


def _rate(fn, n):
    t = time.perf_counter()
    fn()
    return n / (time.perf_counter() - t)


def main():
    m = load_machine()
    g = m.geometry
    rng = np.random.default_rng(0)
    n = 100_000
    Z = rng.uniform(293, 458, n)
    t1 = rng.uniform(0, np.pi, n)
    t2 = rng.uniform(-20 * D, 20 * D, n)
    print(f"io_ratio:                 {_rate(lambda: M.io_ratio(Z, t1, t2, g), n):12,.0f} poses/s")
    print(f"drive_characteristics_at: {_rate(lambda: M.drive_characteristics_at(Z, t1, t2, g), n):12,.0f} poses/s")
    print(f"compliance_errors:        {_rate(lambda: M.compliance_errors(Z, t1, t2, m), n):12,.0f} poses/s")

    for label, tip in (("P", np.zeros(3)), ("tool tip", g.tool_tip_p)):
        times, counts = [], []
        for _ in range(200):
            a = np.array([rng.uniform(293, 458), rng.uniform(0, 180) * D, rng.uniform(-20, 20) * D])
            b = np.array([rng.uniform(293, 458), rng.uniform(0, 180) * D, rng.uniform(-20, 20) * D])
            seg = M.ZttSegment(a, b, g, tip)
            t = time.perf_counter()
            r = M.adaptive_control_parameters(seg, 1e-3)
            times.append(time.perf_counter() - t)
            counts.append(len(r.s) - 1)
        times = np.array(times) * 1e3
        print(f"adaptive spacing, random (Z, th1, th2) segment, 1 um, error of {label:8s}: "
              f"median {np.median(times):.2f} ms, p99 {np.percentile(times, 99):.2f} ms, "
              f"intervals median {np.median(counts):.0f} max {max(counts)}")
    times, counts = [], []
    for _ in range(100):
        ax0 = K.tilt_to_axis(rng.uniform(0, 180) * D, rng.uniform(-20, 20) * D)
        ax1 = K.tilt_to_axis(rng.uniform(0, 180) * D, rng.uniform(-20, 20) * D)
        p0 = rng.uniform([-50, -50, 60], [50, 50, 200])
        p1 = rng.uniform([-50, -50, 60], [50, 50, 200])
        t = time.perf_counter()
        s = M.control_points_tool(p0, ax0, p1, ax1, m, 1e-3)
        times.append(time.perf_counter() - t)
        counts.append(len(s) - 1)
    times = np.array(times) * 1e3
    print(f"adaptive spacing, random tool-pose segment, 1 um tip error: median {np.median(times):.2f} ms, "
          f"p99 {np.percentile(times, 99):.2f} ms, intervals median {np.median(counts):.0f} max {max(counts)}")


if __name__ == "__main__":
    main()
