"""The control loop of this tree against the one of a git revision, on the same jobs in one run.

    .venv/bin/python benchmarks/bench_loop_ab.py [--base main] [--reps 7] [--seconds 10] [--rate 2000]

For a change to pmctl.motion.loop that must keep the ticks as they were and not slow them:
1. Same ticks: both loops run the bench's tilted circle (benchmarks/bench_loop.py) offline on the
   sim with the service config, with the compiled and the Python NC, with the sim's effect catalogue,
   and with a stop request at tick 3000; the per-tick records (counters, encoders, strain, load
   side, targets, sigma, path clock, line), the pulses sent, the end status, reason and tick count
   are compared exactly.
2. Whole-tick compute (the loop's own timer, compiled NC, ticks back to back), the two loops
   interleaved --reps times (the order alternating): each run's median and p99, their medians, and
   the ratio this tree / base; with the load average before and after.
The base revision's loop.py is loaded from ``git show BASE:src/pmctl/motion/loop.py`` beside this
tree's modules (everything else is this tree's). Prints the figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default)
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_loop as B  # noqa: E402

from pmctl import hal  # noqa: E402
from pmctl.core.config import load_machine  # noqa: E402
from pmctl.motion import loop as NEW  # noqa: E402
from pmctl.motion.nc import counts_of, initial_state  # noqa: E402

RECORDS = ("counts", "enc", "strain", "truth", "target", "pulses_sent", "sigma", "path_s", "line")


def base_loop(rev: str):
    root = Path(__file__).resolve().parents[1]
    src = subprocess.run(["git", "show", f"{rev}:src/pmctl/motion/loop.py"], cwd=root, check=True,
                         capture_output=True, text=True).stdout
    f = Path(tempfile.mkdtemp()) / "loop_base.py"
    f.write_text(src)
    spec = importlib.util.spec_from_file_location("pmctl.motion._loop_base", f)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def run(mod, m, rate, seconds, impl, effects=None, stop_at=None):
    svc, params = B.service(m, rate, impl)
    dt = 1.0 / rate
    tg = mod.prepare(m, params, B.circle(dt, seconds), dt)
    c0 = counts_of(tg.q[0], params)
    opts = dict(svc.backend_options)
    opts.update(effects or {})
    be = hal.create("sim", m, dt, opts)
    be.open(c0)
    cfg = svc.loop
    cfg.rate_hz, cfg.realtime, cfg.settle_s, cfg.state_file = rate, False, 0.05, ""

    def hook(lp, k, st):
        if stop_at is not None and k == stop_at:
            lp.stop_request = "bench stop"
        return st
    return mod.ControlLoop(m, be, params, tg, cfg, initial_state(m, c0), log=lambda s: None, hook=hook).run()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", default="main", help="git revision of the loop to compare with (default main)")
    ap.add_argument("--reps", type=int, default=7, help="interleaved timing runs of each loop (default 7)")
    ap.add_argument("--seconds", type=float, default=10.0, help="seconds of circle per timing run (default 10)")
    ap.add_argument("--rate", type=float, default=2000.0)
    a = ap.parse_args(argv)
    m = load_machine()
    old = base_loop(a.base)
    print(f"host: {os.cpu_count()} CPUs, {B.load()}; base {a.base}")
    for impl, eff, stop in (("compiled", None, None), ("python", None, None), ("compiled", B.SIM_EFFECTS, None),
                            ("compiled", None, 3000)):
        x = run(old, m, a.rate, 4.0, impl, eff, stop)
        y = run(NEW, m, a.rate, 4.0, impl, eff, stop)
        same = (x.status, x.reason, x.ticks) == (y.status, y.reason, y.ticks)
        for f in RECORDS:
            u, v = getattr(x, f), getattr(y, f)
            same = same and u.shape == v.shape and np.array_equal(u, v, equal_nan=True)
        print(f"1. {impl:8s} NC, effects {'on ' if eff else 'off'}, stop at tick {stop}: {x.status}/{y.status}, "
              f"{x.ticks}/{y.ticks} ticks; records identical: {same}")
    med = {"base": [], "this": []}
    p99 = {"base": [], "this": []}
    la0 = B.load()
    for rep in range(a.reps):
        pair = (("base", old), ("this", NEW))
        for name, mod in (pair if rep % 2 == 0 else pair[::-1]):
            s = run(mod, m, a.rate, a.seconds, "compiled").timing.summary()
            med[name].append(s["compute_median_us"])
            p99[name].append(s["compute_p99_us"])
    print(f"2. whole tick, compiled, back to back at {a.rate:g} Hz, {a.reps} interleaved runs of {a.seconds:g} s each; "
          f"{la0} before, {B.load()} after:")
    for name in ("base", "this"):
        print(f"   {name}: run medians {[round(x, 2) for x in med[name]]} -> {np.median(med[name]):.2f} us; "
              f"run p99s {[round(x, 1) for x in p99[name]]} -> {np.median(p99[name]):.1f} us")
    print(f"   ratio this/base: median {np.median(med['this']) / np.median(med['base']):.3f}, "
          f"p99 {np.median(p99['this']) / np.median(p99['base']):.3f}")


if __name__ == "__main__":
    main()
