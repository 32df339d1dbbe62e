"""Benchmark of the control loop: the NC step (compiled vs Python), the whole tick, real-time rates.

    .venv/bin/python benchmarks/bench_loop.py [--duration 60] [--rates 1000,2000,3000,4000,5000]
                                              [--rt-rate 2000] [--no-flex] [--spin-us 0]
                                              [--sections 1,1b,2,3,4]

Everything runs with the service config's NC (config/service.toml: gains, K_theta, pulse mode,
gravity-strain compensation) on the loopback sim with the service's [hal.sim] options (flexible
mode on unless --no-flex); kv is capped at 0.4/dt for high rates.

1. NC step alone, both implementations in this run on the same inputs (each on its own closed
   loop with an ideal plant, same targets, pulses compared tick for tick): median / p99 per call, CPU
   time per call (the loop's timer around the call included), and the Python/compiled ratio.
1b. The path follower alone (pmctl.motion.timescale), both implementations in this run on the same
   sample stream (the circle's rows through a ring fed as the rt process feeds it, a feed hold and
   its resume, feed overrides 50 % and 150 %): median / p99 per next_target call, CPU per call,
   the ratio, and in how many ticks the targets were identical.
2. Whole tick (read sim -> NC -> write sim -> record), ticks back to back (realtime=False), for
   each implementation; 2b: the same with the sim's effect catalogue on (backlash, pitch error,
   thermal growth, friction on every axis: the effects' per-tick Python between the C step and
   sample).
3. Real time at --rt-rate Hz for --duration seconds (SCHED_FIFO + mlockall when permitted).
4. Each rate of --rates for --duration seconds in real time. A rate is held when the run finishes
   (the service's max_overruns_in_row stop did not trigger), the whole-tick compute p99 is
   <= 25 % of the period, and overruns are <= 1 per 10 000 ticks. The line says which criterion
   failed: compute (the tick's work) or lateness (the scheduler woke the loop too late).
Every figure comes with the load average (this machine may be shared) and the CPU time used.
Trajectory: a tilted circle (radius 20 mm, 10 mm/s, tool axis precessing by 8 deg). Prints the
figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import gc
import os
import sys
import time

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default, pmctl/__init__.py)
import numpy as np

from pmctl import hal
from pmctl.core.config import load_machine
from pmctl.hal.base import Feedback
from pmctl.motion.loop import ControlLoop, prepare, tracking_stats
from pmctl.motion.nc import counts_of, initial_state
from pmctl.motion.ncore import make_nc
from pmctl.motion.service_config import load_service_config
from pmctl.motion.trajectory import Trajectory


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


def load():
    return "load average %.2f %.2f %.2f" % os.getloadavg()


def service(m, rate, impl=None):
    svc = load_service_config()
    svc.nc.kv_per_s = min(svc.nc.kv_per_s, 0.4 * rate)
    if impl:
        svc.nc.implementation = impl
    return svc, svc.nc.params(m, 1.0 / rate)


def bench_nc(m, rate, n):
    """Each NC on its own closed loop with an ideal plant (encoders = counters, a constant strain
    reading), the same targets: the pulses are compared tick for tick afterwards, so both saw
    the same inputs. Timed one after the other (no cache interference between them)."""
    svc, params = service(m, rate)
    dt = params.dt
    tg = prepare(m, params, circle(dt, n * dt + 1), dt)
    c0 = counts_of(tg.q[0], params)
    out = {}
    mono, cpu = time.perf_counter_ns, time.thread_time_ns
    for impl in ("compiled", "python"):
        nc = make_nc(m, params, impl)
        st = nc.load(initial_state(m, c0))
        fb = Feedback()
        fb.strain[:] = 0.3
        t = np.zeros(n, np.int64)
        pulses = np.zeros((n, 5), np.int64)
        gc.disable()
        try:
            c1 = cpu()
            for k in range(n):
                fb.enc[:] = st.counts / params.pulses_per_mm
                t0 = mono()
                p, st = nc.step(st, tg.rows[k], fb)
                t[k] = mono() - t0
                pulses[k] = p
            c2 = cpu()
        finally:
            gc.enable()
        out[impl] = (t / 1e3, (c2 - c1) / n / 1e3, pulses, st.mode)
    same = int(np.sum(np.all(out["compiled"][2] == out["python"][2], axis=1)))
    return out["compiled"][0], out["python"][0], out["compiled"][1], out["python"][1], same, params


def bench_follower(m, rate, n):
    """Each follower on its own ring with the same rows pushed at the same ticks and the same
    operator requests; targets compared tick for tick afterwards. One after the other."""
    from pmctl.motion.loop import target_samples
    from pmctl.motion.ring import Ring
    from pmctl.motion.timescale import WIDTH, make_follower
    svc, params = service(m, rate)
    dt = params.dt
    rows = target_samples(prepare(m, params, circle(dt, n * dt * 1.2 + 2), dt), dt, params)
    events = {n // 5: ("hold", True), n // 5 + 600: ("hold", False), n // 2: ("feed", 1.5), 3 * n // 4: ("feed", 0.5)}
    mono, cpu = time.perf_counter_ns, time.thread_time_ns
    out = {}
    for impl in ("compiled", "python"):
        ring = Ring(4096, WIDTH)
        fol = make_follower(ring, params, dt, implementation=impl)
        fed = ring.push(rows[:3000])
        t = np.zeros(n, np.int64)
        tg = np.zeros((n, 12))
        busy = 0
        gc.disable()
        try:
            for k in range(n):
                if k % 10 == 0 and fed < len(rows):
                    fed += ring.push(rows[fed:fed + 12])
                ev = events.get(k)
                if ev is not None:
                    if ev[0] == "hold":
                        fol.scaler.hold = ev[1]
                    else:
                        fol.scaler.set_feed_override(ev[1])
                c1 = cpu()
                t0 = mono()
                x = fol.next_target()
                t[k] = mono() - t0
                busy += cpu() - c1
                tg[k] = x
        finally:
            gc.enable()
        out[impl] = (t / 1e3, busy / n / 1e3, tg, fol.s_total)
    same = int(np.sum(np.all(out["compiled"][2] == out["python"][2], axis=1)))
    return out["compiled"], out["python"], same


# [hal.sim] effects for the 2b line: every catalogue effect of the sim on every axis
SIM_EFFECTS = {"backlash_mm": 0.01, "pitch_error_amp_mm": 0.003, "thermal_delta_K": 2.0,
               "friction_coulomb_mm": 0.004, "friction_stribeck_mm": 0.002}


def run_loop(m, rate, seconds, realtime, flex=True, impl=None, spin_us=0.0, effects=None):
    """The service config's NC and loop policy (max_overruns_in_row, stall limit) on the sim plant
    (``effects``: more [hal.sim] options)."""
    svc, params = service(m, rate, impl)
    dt = 1.0 / rate
    tr = circle(dt, seconds)
    tg = prepare(m, params, tr, dt)
    c0 = counts_of(tg.q[0], params)
    opts = dict(svc.backend_options)
    opts["flex"] = flex
    opts.update(effects or {})
    be = hal.create("sim", m, dt, opts)
    be.open(c0)
    cfg = svc.loop
    cfg.rate_hz, cfg.realtime, cfg.settle_s, cfg.spin_us, cfg.state_file = rate, realtime, 0.0, spin_us, ""
    msgs = []
    lp = ControlLoop(m, be, params, tg, cfg, initial_state(m, c0), log=msgs.append)
    la0 = os.getloadavg()[0]
    c0_cpu, w0 = time.process_time(), time.monotonic()
    res = lp.run()
    cpu_frac = (time.process_time() - c0_cpu) / max(time.monotonic() - w0, 1e-9)
    la1 = os.getloadavg()[0]
    return res, msgs, cpu_frac, (la0, la1)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=60.0,
                    help="seconds of each real-time run (§3 and every rate of §4; default 60)")
    ap.add_argument("--rates", default="1000,2000,3000,4000,5000")
    ap.add_argument("--rt-rate", type=float, default=2000.0, help="rate of the §3 run (default 2000 Hz)")
    ap.add_argument("--nc-ticks", type=int, default=20000, help="ticks of §1 (default 20000)")
    ap.add_argument("--follower-ticks", type=int, default=20000, help="ticks of §1b (default 20000)")
    ap.add_argument("--no-flex", action="store_true")
    ap.add_argument("--sections", default="1,1b,2,3,4", help="which sections to run (default all: 1,1b,2,3,4)")
    ap.add_argument("--spin-us", type=float, default=0.0,
                    help="busy-wait this long before each deadline (loop.spin_us; keeps a VM's vCPU awake)")
    a = ap.parse_args(argv)
    m = load_machine()
    flex = not a.no_flex
    print(f"host: {os.cpu_count()} CPUs, {load()}, python {sys.version.split()[0]}, uid {os.getuid()}")

    rate = a.rt_rate
    sections = {x.strip() for x in a.sections.split(",")}
    if "1" in sections:
        bench_nc_section(m, rate, a.nc_ticks)
    if "1b" in sections:
        (tc, cc, _, sc), (tp, cp, _, sp), same = bench_follower(m, rate, a.follower_ticks)
        print(f"1b. path follower alone at {rate:g} Hz ({len(tc)} ticks with a hold, its resume and feed overrides; "
              f"same targets in {same} of {len(tc)}, path {sc:.1f} / {sp:.1f} samples; {load()}):")
        print(f"   compiled: median {np.median(tc):6.2f} us, p99 {pct(tc, 99):6.2f} us, CPU {cc:6.2f} us per tick")
        print(f"   python:   median {np.median(tp):6.2f} us, p99 {pct(tp, 99):6.2f} us, CPU {cp:6.2f} us per tick")
        print(f"   ratio python/compiled: median {np.median(tp) / np.median(tc):.0f}x, p99 {pct(tp, 99) / pct(tc, 99):.0f}x, "
              f"CPU per tick {cp / cc:.0f}x")
    if "2" in sections:
        whole_tick_section(m, rate, flex)
    if "3" in sections:
        realtime_section(m, rate, flex, a)
    if "4" in sections:
        rates_section(m, flex, a)


def bench_nc_section(m, rate, n):
    tc, tp, cc, cp, same, params = bench_nc(m, rate, n)
    print(f"1. NC step alone at {rate:g} Hz, K_theta {params.k_theta[0]:g}/s, {'multi' if params.max_pulses_per_tick > 1 else 'single'}"
          f"-pulse ({len(tc)} ticks, same pulses in {same} of {len(tc)}; {load()}):")
    print(f"   compiled: median {np.median(tc):6.2f} us, p99 {pct(tc, 99):6.2f} us, CPU {cc:6.2f} us per tick")
    print(f"   python:   median {np.median(tp):6.1f} us, p99 {pct(tp, 99):6.1f} us, CPU {cp:6.1f} us per tick")
    print(f"   ratio python/compiled: median {np.median(tp) / np.median(tc):.0f}x, p99 {pct(tp, 99) / pct(tc, 99):.0f}x, "
          f"CPU per tick {cp / cc:.0f}x (CPU per tick includes the harness: encoder copy, timer)")


def whole_tick_section(m, rate, flex):
    for impl in ("compiled", "python"):
        res, _, cpu_frac, la = run_loop(m, rate, 10.0, realtime=False, flex=flex, impl=impl)
        s = res.timing.summary()
        print(f"2. whole tick, back to back, {impl:8s} ({s['ticks']} ticks at {rate:g} Hz): compute median "
              f"{s['compute_median_us']:6.1f} us, p99 {s['compute_p99_us']:6.1f} us, max {s['compute_max_us']:7.1f} us "
              f"(NC median {s['nc_median_us']:.1f} us); tracking max {tracking_stats(res, m)['tip_max_um']:.3f} um; "
              f"load average {la[0]:.2f} -> {la[1]:.2f}")
    res, _, cpu_frac, la = run_loop(m, rate, 10.0, realtime=False, flex=flex, effects=SIM_EFFECTS)
    s = res.timing.summary()
    print(f"2b. whole tick, back to back, compiled, sim with the effect catalogue on every axis ({s['ticks']} ticks): "
          f"compute median {s['compute_median_us']:6.1f} us, p99 {s['compute_p99_us']:6.1f} us; "
          f"load average {la[0]:.2f} -> {la[1]:.2f}")


def realtime_section(m, rate, flex, a):
    res, msgs, cpu_frac, la = run_loop(m, rate, a.duration, realtime=True, flex=flex, spin_us=a.spin_us)
    s = res.timing.summary()
    for msg in msgs:
        print(f"   [{msg}]")
    period = 1e6 / rate
    print(f"3. real time at {rate:g} Hz for {res.ticks / rate:.1f} s: {res.status} {res.reason}; "
          f"load average {la[0]:.2f} -> {la[1]:.2f}; CPU {100 * cpu_frac:.0f} % of one core")
    print(f"   tick compute median {s['compute_median_us']:.1f} us, p99 {s['compute_p99_us']:.1f} us, "
          f"max {s['compute_max_us']:.1f} us ({100 * s['compute_p99_us'] / period:.1f} % of the period at p99); "
          f"NC step median {s['nc_median_us']:.1f} us, p99 {s['nc_p99_us']:.1f} us")
    print(f"   lateness median {s['late_median_us']:.1f} us, p99 {s['late_p99_us']:.1f} us, "
          f"max {s['late_max_us']:.1f} us; overruns {s['overruns']} (max {s['max_overruns_in_row']} in a row)")


def rates_section(m, flex, a):
    best = None
    for r in (float(x) for x in a.rates.split(",")):
        res, _, cpu_frac, la = run_loop(m, r, a.duration, realtime=True, flex=flex, spin_us=a.spin_us)
        s = res.timing.summary()
        period = 1e6 / r
        why = []
        if res.status != "done":
            why.append(f"stopped: {res.reason}")
        if s["compute_p99_us"] > 0.25 * period:
            why.append("compute p99 over 25 %")
        if s["overruns"] * 10000 > max(res.ticks, 1):
            why.append("overruns over 1 per 10 000 ticks (" +
                       ("lateness" if s["late_p99_us"] + s["compute_p99_us"] > 0.5 * period or
                        s["compute_p99_us"] <= 0.25 * period else "compute") + ")")
        held = not why
        print(f"4. {r:6.0f} Hz, {res.ticks / r:5.1f} s: compute p99 {s['compute_p99_us']:6.1f} us = "
              f"{100 * s['compute_p99_us'] / period:5.1f} % of {period:.0f} us (median {s['compute_median_us']:.1f}, "
              f"NC p99 {s['nc_p99_us']:.1f} us); lateness p99 {s['late_p99_us']:6.1f} us, max {s['late_max_us']:.0f} us; "
              f"overruns {s['overruns']} in {res.ticks}; CPU {100 * cpu_frac:.0f} %; load {la[0]:.2f} -> {la[1]:.2f}; "
              f"{'held' if held else 'NOT held: ' + '; '.join(why)}")
        if held:
            best = r if best is None else max(best, r)
    print(f"highest rate held (run finished, whole-tick compute p99 <= 25 % of the period, <= 1 overrun per "
          f"10 000 ticks, {a.duration:g} s each): {'none of those tried' if best is None else f'{best:g} Hz'}; {load()}")


if __name__ == "__main__":
    main()
