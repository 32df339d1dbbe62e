"""Benchmark of the step/dir link (issue 10): round trip per tick, host CPU cost of the `stepdir`
backend at 1 and 2 kHz, and the step rate the bridge's host build holds.

    .venv/bin/python benchmarks/bench_stepdir.py [--seconds 5] [--rates 1000,2000]

For each rate, the backend drives the host build of the bridge (started on a pty, as the shipped
service config does) on absolute deadlines (clock_nanosleep; SCHED_FIFO 50 for this process and 51
for the bridge when permitted, as `pmctl run` does, unless --no-realtime) with the most pulses
a tick holds on all five axes (1 ms: 200 per axis = 200 kpulse/s per axis, 1 Mpulse/s in total):
- round trip: TICK frame written -> its ACK parsed by the host, in a separate run that waits for
  each ACK right after the write (up to half a period; how many arrived in time is printed);
- host cost: wall time of read() + write_pulses() per tick, and the host process's CPU time per
  tick (user + system) over the run, as a share of one core;
- bridge: its CPU time over the run (it computes every step edge and writes the edge log);
- spacing: from the edge log, how far rising edges sit from their ideal even spacing, and the
  shortest high and low times;
- rate held: from the edge log, the steps per second over the run and whether every tick started
  exactly one period after the previous one (no underrun: the host kept the queue fed).
Prints medians, p99s and the load average; asserts nothing. On the host build the step edges are
computed timestamps: the rate figures prove the generator's arithmetic keeps up on this CPU, not
electrical timing (that needs a board and a logic analyser).
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default, pmctl/__init__.py)
import numpy as np

from pmctl.core.config import load_machine
from pmctl.hal import bridge_protocol as bp
from pmctl.hal.stepdir import StepDirBackend
from pmctl.motion.loop import AbsoluteSleeper, setup_realtime, undo_realtime


def run(rate: float, seconds: float, tmp: str, bridge_prio: int, measure_rtt: bool) -> dict:
    dt = 1.0 / rate
    machine = load_machine()
    log_path = os.path.join(tmp, f"edges-{int(rate)}.bin")
    be = StepDirBackend(machine, dt, {"edge_log": log_path, "link_timeout_ms": 200.0, "read_timeout_ms": 50.0,
                                      "watchdog_ms": 200.0, "bridge_rt_priority": bridge_prio})
    be.open(np.zeros(5, int))
    n = int(seconds * rate)
    p = np.full(5, be.max_step, np.int64)
    call = np.zeros(n)
    rtt = np.full(n, np.nan)
    sleeper = AbsoluteSleeper()
    period = int(round(1e9 / rate))
    ru0 = resource.getrusage(resource.RUSAGE_SELF)
    rc0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    deadline = time.monotonic_ns() + period
    late = np.zeros(n)
    for k in range(n):
        sleeper.until(deadline)
        late[k] = time.monotonic_ns() - deadline
        t0 = time.perf_counter_ns()
        be.read()
        be.write_pulses(p if k < n - 10 else np.zeros(5, np.int64))
        t1 = time.perf_counter_ns()
        call[k] = t1 - t0
        # round trip: wait for this tick's ACK now (the loop itself would see it at its next read)
        while measure_rtt and be.unacked and time.perf_counter_ns() - t1 < period // 2:
            be._pump(0.0002)
        if measure_rtt and not be.unacked:
            rtt[k] = time.perf_counter_ns() - t1
        deadline += period
        now = time.monotonic_ns()
        if now > deadline:                      # overran: skip the missed deadlines, as the loop does
            deadline += ((now - deadline) // period + 1) * period
    ru1 = resource.getrusage(resource.RUSAGE_SELF)
    st = be.status_last
    underruns = st.underruns if st else -1
    be.close()
    ruc = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    log = bp.read_edge_log(log_path)
    rises = log[log["kind"] == bp.EDGE_HIGH]
    starts = np.sort(log[log["kind"] == bp.EDGE_TICK]["t"].astype(np.int64))
    gaps = np.diff(starts)
    full = n - 10
    t_full = starts[full] - starts[0] if len(starts) > full else float("nan")
    steps_full = int(np.sum(log[(log["kind"] == bp.EDGE_HIGH)]["tick"] < full))
    per_axis = np.array([np.sum((rises["axis"] == a) & (rises["tick"] < full)) for a in range(5)])
    rtt = rtt[np.isfinite(rtt)] / 1e3
    spacing = edge_figures(log, be.tick_ns, min(full, 300))
    os.unlink(log_path)
    return {"rate": rate, "ticks": n, "pulses_per_tick": int(be.max_step),
            "rtt_med": np.median(rtt) if len(rtt) else np.nan,
            "rtt_p99": np.percentile(rtt, 99) if len(rtt) else np.nan, "rtt_n": len(rtt),
            "call_med": np.median(call) / 1e3, "call_p99": np.percentile(call, 99) / 1e3,
            "cpu_us_per_tick": cpu / n * 1e6, "cpu_share": cpu / (n * dt),
            "late_med": np.median(late) / 1e3, "late_p99": np.percentile(late, 99) / 1e3,
            "bridge_cpu_s": (ruc.ru_utime + ruc.ru_stime) - (rc0.ru_utime + rc0.ru_stime), "underruns": underruns,
            "steps_per_s": steps_full / (t_full / 1e9), "axis_min_per_s": per_axis.min() / (t_full / 1e9),
            "gap_max_us": gaps[:full].max() / 1e3 if len(gaps) else float("nan"),
            "gaps_exact": bool(np.all(gaps[:full - 1] == period)), "retransmits": be.stats["retransmits"],
            **spacing}


def edge_figures(log, tick_ns: int, n_ticks: int) -> dict:
    """From the edge log, over the first n_ticks: the largest deviation of a rising edge from its
    ideal place t0 + (2i+1) T / 2n (no direction changes in this run), and the shortest high and
    low times."""
    t0 = {int(r["tick"]): int(r["t"]) for r in log[log["kind"] == bp.EDGE_TICK]}
    dev, hi, lo = 0.0, np.inf, np.inf
    for a in range(5):
        ax = log[(log["axis"] == a) & (log["tick"] < n_ticks)]
        for k in range(n_ticks):
            ev = ax[ax["tick"] == k]
            r = ev[ev["kind"] == bp.EDGE_HIGH]["t"].astype(np.int64)
            f = ev[ev["kind"] == bp.EDGE_LOW]["t"].astype(np.int64)
            n = len(r)
            if n == 0 or k not in t0:
                continue
            ideal = t0[k] + (2 * np.arange(n) + 1) * tick_ns / (2 * n)
            dev = max(dev, float(np.abs(r - ideal).max()))
            hi = min(hi, float((f - r).min()))
            if n > 1:
                lo = min(lo, float((r[1:] - f[:-1]).min()))
    return {"edge_dev_ns": dev, "high_min_ns": hi, "low_min_ns": lo, "edge_ticks": n_ticks}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--rates", default="1000,2000")
    ap.add_argument("--no-realtime", action="store_true", help="do not ask for SCHED_FIFO (host and bridge)")
    a = ap.parse_args()
    ap_rt = not a.no_realtime
    if ap_rt:
        for m in setup_realtime(50, lock_memory=True):
            print(m)
    la = os.getloadavg()
    print(f"load average before: {la[0]:.2f} {la[1]:.2f} {la[2]:.2f} ({os.cpu_count()} CPUs)")
    with tempfile.TemporaryDirectory() as tmp:
        for r in (float(x) for x in a.rates.split(",")):
            prio = 0 if a.no_realtime else 51
            o = run(r, a.seconds, tmp, prio, False)
            o.update({k: v for k, v in run(r, min(a.seconds, 2.0), tmp, prio, True).items() if k.startswith("rtt")})
            print(f"\n{o['rate']:g} Hz, {o['ticks']} ticks, {o['pulses_per_tick']} pulses/tick on each of 5 axes")
            print(f"  round trip TICK -> ACK: median {o['rtt_med']:.0f} us, p99 {o['rtt_p99']:.0f} us "
                  f"({o['rtt_n']} of {int(min(a.seconds, 2.0) * r)} ticks of a separate {min(a.seconds, 2.0):g} s run "
                  f"within half a period); retransmits {o['retransmits']}")
            print(f"  host read()+write_pulses() per tick: median {o['call_med']:.0f} us, p99 {o['call_p99']:.0f} us")
            print(f"  host CPU per tick: {o['cpu_us_per_tick']:.0f} us = {100 * o['cpu_share']:.1f} % of one core "
                  f"(wake-up lateness median {o['late_med']:.0f} us, p99 {o['late_p99']:.0f} us)")
            print(f"  bridge CPU: {o['bridge_cpu_s']:.2f} s over the {a.seconds:g} s run "
                  f"({100 * o['bridge_cpu_s'] / a.seconds:.1f} % of one core, edge log included)")
            print(f"  edge log, first {o['edge_ticks']} ticks: rising edges within {o['edge_dev_ns']:.1f} ns of their "
                  f"ideal even spacing; shortest high {o['high_min_ns']:.0f} ns, shortest low {o['low_min_ns']:.0f} ns")
            print(f"  steps held: {o['steps_per_s'] / 1e6:.3f} Mstep/s total, slowest axis "
                  f"{o['axis_min_per_s'] / 1e3:.1f} kstep/s; underruns {o['underruns']}; tick starts all exactly "
                  f"one period apart: {'yes' if o['gaps_exact'] else 'no'} (largest gap {o['gap_max_us']:.0f} us)")
    if ap_rt:
        undo_realtime(True)
    la = os.getloadavg()
    print(f"\nload average after: {la[0]:.2f} {la[1]:.2f} {la[2]:.2f}")


if __name__ == "__main__":
    main()
