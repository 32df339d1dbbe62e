"""Benchmark of the control loop (issue 3): per-tick compute time, lateness at 1 kHz, highest rate.

    .venv/bin/python benchmarks/bench_loop.py [--duration 60] [--rates 250,500,750,1000,1500,2000,3000]
                                              [--rate-seconds 5] [--no-flex]

1. NC step alone (pmctl.motion.nc.nc_step, tight loop): median / p99 per call.
2. Whole tick (read sim -> NC -> write sim -> record), ticks back to back (realtime=False).
3. Real-time run at 1 kHz for --duration seconds (SCHED_FIFO + mlockall when permitted): compute
   median/p99/max, lateness median/p99/max, overruns.
4. Each rate of --rates for --rate-seconds in real time: the highest one held with p99 compute
   (whole tick, sim plant included) <= 25 % of the period; overruns are printed beside it.
Trajectory: a tilted circle (radius 20 mm, 10 mm/s, tool axis precessing by 8 deg) on the loopback
sim (flexible mode on unless --no-flex). Prints the figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from pmctl import hal
from pmctl.core.config import load_machine
from pmctl.hal.base import Feedback
from pmctl.motion.loop import ControlLoop, prepare, tracking_stats
from pmctl.motion.service_config import LoopConfig, load_service_config
from pmctl.motion.nc import ModelFK, NCParams, counts_of, initial_state, nc_step
from pmctl.task.trajectory import Trajectory


def circle(dt, seconds, radius=20.0, feed=10.0, tilt_deg=8.0, z=10.0, ramp=2.0):
    """Circle of the tip at ``feed`` with the tool axis tilted by ``tilt_deg`` toward the centre's
    outside and precessing with it; speed and tilt ramp in smoothly over ``ramp`` seconds."""
    n = int(seconds / dt) + 1
    t = np.arange(n) * dt
    w = feed / radius
    # angular speed w * (1 - cos(pi t / ramp)) / 2 during the ramp: smooth start, no jerk step
    ph = np.where(t < ramp, w * (t / 2 - ramp / (2 * np.pi) * np.sin(np.pi * np.minimum(t, ramp) / ramp)),
                  w * (t - ramp / 2))
    tip = np.stack([radius * np.cos(ph) - radius, radius * np.sin(ph), np.full(n, z)], -1)
    a = np.radians(tilt_deg) * 0.5 * (1 - np.cos(np.pi * np.minimum(t, ramp) / ramp))
    axis = np.stack([np.sin(a) * np.cos(ph), np.sin(a) * np.sin(ph), np.cos(a)], -1)
    zz = np.zeros_like(tip)
    return Trajectory(dt, tip, axis, zz, zz.copy(), np.ones(n, int), np.zeros(n))


def pct(x, q):
    return float(np.percentile(x, q))


def bench_nc(m, n=20000):
    dt = 1e-3
    params = NCParams.from_machine(m, dt, kv=400.0)
    tr = circle(dt, n * dt + 1)
    tg = prepare(m, params, tr, dt)
    c0 = counts_of(tg.q[0], params)
    st = initial_state(m, c0)
    model = ModelFK(m)
    fb = Feedback()
    times = np.zeros(n, np.int64)
    mono = time.perf_counter_ns
    import gc
    gc.disable()
    c0 = time.thread_time_ns()
    for k in range(n):
        fb.enc[:] = st.counts / params.pulses_per_mm
        t0 = mono()
        _, st = nc_step(st, tg.rows[k], fb, params, model)
        times[k] = mono() - t0
    cpu = (time.thread_time_ns() - c0) / n / 1e3
    gc.enable()
    assert st.mode == 0, st.reason
    return times / 1e3, cpu


SPIN_US = 0.0


def run_loop(m, rate, seconds, realtime, flex=True):
    """The service config's NC gains (kv capped at 0.4/dt for high rates) on the sim plant."""
    dt = 1.0 / rate
    nc = load_service_config().nc
    nc.kv_per_s = min(nc.kv_per_s, 0.4 / dt)
    params = nc.params(m, dt)
    tr = circle(dt, seconds)
    tg = prepare(m, params, tr, dt)
    c0 = counts_of(tg.q[0], params)
    be = hal.create("sim", m, dt, {"flex": flex})
    be.open(c0)
    cfg = LoopConfig(rate_hz=rate, realtime=realtime, max_overruns_in_row=10 ** 9, stall_timeout_s=1.0,
                     settle_s=0.0, spin_us=SPIN_US)
    msgs = []
    lp = ControlLoop(m, be, params, tg, cfg, initial_state(m, c0), log=msgs.append)
    res = lp.run()
    return res, msgs


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=60.0, help="real-time run at 1 kHz, seconds (default 60)")
    ap.add_argument("--rates", default="250,500,750,1000,1500,2000,3000")
    ap.add_argument("--rate-seconds", type=float, default=5.0)
    ap.add_argument("--no-flex", action="store_true")
    ap.add_argument("--spin-us", type=float, default=0.0,
                    help="busy-wait this long before each deadline (loop.spin_us; keeps a VM's vCPU awake)")
    a = ap.parse_args(argv)
    global SPIN_US
    SPIN_US = a.spin_us
    m = load_machine()
    print(f"host: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}, python {sys.version.split()[0]}")

    c, cpu = bench_nc(m)
    print(f"1. nc_step alone: median {np.median(c):.1f} us, p99 {pct(c, 99):.1f} us, max {c.max():.1f} us "
          f"({len(c)} calls; mean CPU time {cpu:.1f} us per call)")

    res, _ = run_loop(m, 1000.0, 20.0, realtime=False, flex=not a.no_flex)
    s = res.timing.summary()
    print(f"2. whole tick, back to back ({s['ticks']} ticks): compute median {s['compute_median_us']:.1f} us, "
          f"p99 {s['compute_p99_us']:.1f} us, max {s['compute_max_us']:.1f} us; "
          f"tracking max {tracking_stats(res, m)['tip_max_um']:.3f} um")

    res, msgs = run_loop(m, 1000.0, a.duration, realtime=True, flex=not a.no_flex)
    s = res.timing.summary()
    for msg in msgs:
        print(f"   [{msg}]")
    print(f"3. real time at 1 kHz for {res.ticks / 1000:.1f} s: {res.status} {res.reason}")
    print(f"   tick compute median {s['compute_median_us']:.1f} us, p99 {s['compute_p99_us']:.1f} us, "
          f"max {s['compute_max_us']:.1f} us ({100 * s['compute_p99_us'] / 1000:.1f} % of the period at p99); "
          f"NC step alone median {s['nc_median_us']:.1f} us, p99 {s['nc_p99_us']:.1f} us")
    print(f"   lateness median {s['late_median_us']:.1f} us, p99 {s['late_p99_us']:.1f} us, "
          f"max {s['late_max_us']:.1f} us; overruns {s['overruns']} (max {s['max_overruns_in_row']} in a row)")

    best = None
    for r in (float(x) for x in a.rates.split(",")):
        res, _ = run_loop(m, r, a.rate_seconds, realtime=True, flex=not a.no_flex)
        s = res.timing.summary()
        period = 1e6 / r
        held = s["compute_p99_us"] <= 0.25 * period and res.status == "done"
        print(f"4. {r:6.0f} Hz: tick compute p99 {s['compute_p99_us']:6.1f} us = "
              f"{100 * s['compute_p99_us'] / period:5.1f} % of {period:.0f} us (NC alone p99 {s['nc_p99_us']:.1f} us); "
              f"lateness p99 {s['late_p99_us']:6.1f} us; overruns {s['overruns']}; {'held' if held else 'NOT held'}")
        if held:
            best = r
    print(f"highest rate held (p99 whole-tick compute <= 25 % of the period): "
          f"{'none of those tried' if best is None else f'{best:g} Hz'}")


if __name__ == "__main__":
    main()
