"""Benchmark of homing's re-reference on the step/dir bridge: how long ``StepDirBackend.rereference``
blocks the loop tick it runs in (END, the bridge runs out its queue, RESET, a status of the new
counters), against the loop's stall limit.

    .venv/bin/python benchmarks/bench_homing.py [--repeats 50] [--rt-priority 0]

The backend drives the host build of the bridge on a pty at 1 kHz with idle ticks (the machine at
rest, as homing re-references), then re-references; repeated. Prints the median, p99 and maximum
and the load average; asserts nothing.
"""

from __future__ import annotations

import argparse
import os
import time

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default, pmctl/__init__.py)
import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=50)
    ap.add_argument("--rt-priority", type=int, default=0, help="SCHED_FIFO of the bridge process (0 = normal)")
    a = ap.parse_args(argv)
    from pmctl.core.config import load_machine
    from pmctl.hal.stepdir import StepDirBackend
    m = load_machine()
    be = StepDirBackend(m, 1e-3, {"bridge_rt_priority": a.rt_priority, "read_timeout_ms": 200.0,
                                  "link_timeout_ms": 500.0, "watchdog_ms": 1000.0})
    counts = np.full(5, 1000, np.int64)
    be.open(counts)
    dts = []
    try:
        for _ in range(a.repeats):
            for _ in range(20):                       # idle ticks: the queue full, as at rest in the loop
                be.read()
                be.write_pulses(np.zeros(5, np.int64))
            counts = counts + 1
            t0 = time.perf_counter()
            be.rereference(counts)
            dts.append(time.perf_counter() - t0)
    finally:
        be.close()
    d = np.array(dts) * 1e3
    print(f"stepdir rereference over {len(d)}: median {np.median(d):.2f} ms, p99 {np.percentile(d, 99):.2f} ms, "
          f"max {d.max():.2f} ms (loop stall limit 50 ms); bridge priority {a.rt_priority}; "
          f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
