"""Benchmark of the step/dir bridge's RP2040 image on the emulated chip, in simulated time (issue 30).

    .venv/bin/python benchmarks/bench_rp2040.py [--ticks 60] [--rates 1000,2000] [--stalls] [--quick]

Runs build/rp2040/bridge.elf in rp2040js (pmctl.hal.rp2040_emu) and drives it through the stepdir
backend, which waits for the chip (its timeouts run on the chip's clock), and the chip's clock waits
for the host (host-paced, 2 ms): the figures are the chip's, not this computer's load. Every figure is in the
chip's simulated time at 125 MHz, from the pins the harness records and the CPU cycles the emulator
executed (WFI sleep not counted):

- step rate: the most pulses per tick, on one axis and on all five at once (1 kHz, step width
  2.5 us, the shipped config), that the chip emits without stopping (it stops with 'late' when an
  edge is due more than 200 us ago) and on pace (the k-th tick starts within 200 us of k periods
  after the first), every pulse on the pins; with the worst lateness of a rising edge behind its
  ideal even place; the steps per second that makes, against Klipper's RP2040 figures (about 4 M steps/s with
  one stepper and 2.6 M with three, at 200 MHz: Klipper docs/Benchmarks.md), and our rate scaled to
  200 MHz for the comparison;
- CPU per tick at each rate: emulated cycles the CPU executed per tick (mean, p99; awake, i.e.
  not in WFI), and of those the work: less the cycles the firmware counted spinning on an edge's
  time or a pulse width (g_spin_cycles); with no pulses, and with 100 kstep/s in total (20 pulses
  per 1 ms tick, 10 per 0.5 ms tick, on each axis), as a share of the tick;
- with --stalls: how long a host stall the link rides out: the host stops sending for S ms of the
  chip's time after a steady stream, then resumes; the outcome (the chip ran its queue and kept
  stepping / paused at an empty queue and resumed / latched its watchdog) and what it executed.

The emulator runs slower than real time; the whole run takes a few minutes. Asserts nothing. The
emulator times instructions by the rp2040js cycle model (single-cycle SRAM, I/O 1-4 cycles, no
bus contention), so its cycle counts approximate, not measure, a real RP2040's.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default)
import numpy as np

from pmctl.core.config import load_machine
from pmctl.hal import bridge_protocol as bp
from pmctl.hal.rp2040_emu import Emulator, read_cpu_log
from pmctl.hal.stepdir import BridgeFault, StepDirBackend

CLK_HZ = 125e6
KLIPPER = {"one stepper": 4.0e6, "three steppers (total)": 2.6e6}   # steps/s at 200 MHz
PACE_NS = 200_000          # the k-th tick starts within 200 us of k periods after the first: the pace is kept


def drive(tmp: Path, ticks: np.ndarray, rate: float, **opts) -> dict:
    """Runs the ticks through the emulated chip; returns the edge log, the CPU log and figures
    ("stopped": the reason when the chip stopped, e.g. late)."""
    edge_log, cpu_log = tmp / "edges.bin", tmp / "cpu.bin"
    emu = Emulator(edge_log=edge_log, cpu_log=cpu_log, host_paced_ms=2.0)    # a late host is not the chip's limit
    stopped = ""
    try:
        be = StepDirBackend(load_machine(), 1.0 / rate, {"port": emu.port, **opts}, clock=emu.sim_time)
        be.open(np.zeros(5, int))
        try:
            for p in ticks:
                be.read()
                be.write_pulses(p)
        except BridgeFault as e:
            stopped = str(e)
        be.close()
    finally:
        fig = emu.stop()
    log = bp.read_edge_log(edge_log)
    cpu = read_cpu_log(cpu_log)
    return {"log": log, "cpu": cpu, "fig": fig, "stats": dict(be.stats), "stopped": stopped}


def timing(log, period_ns: int, n_ticks: int) -> dict:
    """Tick-start regularity (the k-th tick starting k periods after the first, within 200 us: the
    chip keeps the pace, no tick stretched) and edge lateness against t0 + (2i+1) T / 2n (t0: the
    TICK strobe)."""
    starts = log[log["kind"] == bp.EDGE_TICK]
    t0 = {int(r["tick"]): int(r["t"]) for r in starts}
    ks = sorted(k for k in t0 if k < n_ticks)
    gaps = np.diff([t0[k] for k in ks])
    drift = max((t0[k] - t0[ks[0]] - (k - ks[0]) * period_ns for k in ks), default=0)
    late = 0
    hi = lo = np.inf
    for a in range(5):
        ax = log[log["axis"] == a]
        r_all = ax[ax["kind"] == bp.EDGE_HIGH]
        f_all = ax[ax["kind"] == bp.EDGE_LOW]
        if len(r_all) and len(f_all):
            n = min(len(r_all), len(f_all))
            rt, ft = r_all["t"][:n].astype(np.int64), f_all["t"][:n].astype(np.int64)
            hi = min(hi, float((ft - rt).min()))
            if n > 1:
                lo = min(lo, float((rt[1:] - ft[:-1]).min()))
        for k in ks:
            r = r_all[r_all["tick"] == k]["t"].astype(np.int64)
            if len(r):
                ideal = t0[k] + (2 * np.arange(len(r)) + 1) * period_ns // (2 * len(r))
                late = max(late, int((r - ideal).max()))
    return {"gap_max": int(gaps.max()) if len(gaps) else 0, "late_max": late, "high_min": hi, "low_min": lo,
            "drift": int(drift), "paced": bool(len(ks) == n_ticks and drift <= PACE_NS)}


def step_rate(tmp: Path, n_ticks: int, axes: int, quick: bool) -> list:
    """The pulses per tick on `axes` axes, from 10 up to the 200 a 1 ms tick holds at 2.5 us, each
    with whether the chip held it."""
    rows = []
    levels = [20, 50, 100, 150, 200] if quick else [10, 20, 30, 40, 50, 60, 80, 100, 120, 150, 200]
    for p in levels:
        ticks = np.zeros((n_ticks + 5, 5), np.int64)
        ticks[:n_ticks, :axes] = p
        r = drive(tmp, ticks, 1000.0)
        t = timing(r["log"], 1_000_000, n_ticks)
        executed = bp.executed_steps(r["log"])
        held = not r["stopped"] and t["paced"] and np.array_equal(executed, ticks.sum(0))
        rows.append({"pulses": p, "steps_per_s": p * axes * 1000, **t, "held": held})
        why = r["stopped"][:90] or f"drift {t['drift'] / 1e3:.0f} us"
        print(f"  {axes} ax{'es' if axes > 1 else 'is'} x {p:3d} pulses/tick = {p * axes * 1000 / 1e3:6.0f} kstep/s: "
              + (f"held: every tick on pace (drift {t['drift'] / 1e3:.1f} us), pins = pulses sent; "
                 if held else f"NOT held ({why}); ")
              + f"worst edge {t['late_max'] / 1e3:.1f} us late, largest tick-start gap {t['gap_max'] / 1e3:.1f} us, "
              f"shortest high {t['high_min']:.0f} ns, low {t['low_min']:.0f} ns", flush=True)
    return rows


def cpu_per_tick(tmp: Path, rate: float, n_ticks: int, pulses: int) -> dict:
    ticks = np.zeros((n_ticks + 5, 5), np.int64)
    ticks[:n_ticks] = pulses
    r = drive(tmp, ticks, rate)
    if r["stopped"]:
        return {"stopped": r["stopped"]}
    cpu = r["cpu"]
    cyc = np.diff(cpu["cycles"].astype(np.int64))[2:n_ticks - 2]      # steady state, between tick starts
    work = cyc - np.diff(cpu["spin"].astype(np.int64))[2:n_ticks - 2]
    period = CLK_HZ / rate
    # the mean: a tick's frames are handled in whichever tick they arrive, so single ticks vary
    return {"mean": float(np.mean(cyc)), "p99": float(np.percentile(cyc, 99)), "share_mean": float(np.mean(cyc) / period),
            "share_p99": float(np.percentile(cyc, 99) / period), "work_mean": float(np.mean(work)),
            "work_p99": float(np.percentile(work, 99))}


def stalls(tmp: Path, durations_ms) -> list:
    """A steady stream, a host stall of S ms (chip time), then the stream again."""
    rows = []
    for s_ms in durations_ms:
        edge_log = tmp / "edges.bin"
        emu = Emulator(edge_log=edge_log)
        out = "rode it out"
        try:
            be = StepDirBackend(load_machine(), 1e-3, {"port": emu.port}, clock=emu.sim_time)   # shipped timeouts
            be.open(np.zeros(5, int))
            p = np.array([20, -20, 10, 5, 0])
            for _ in range(50):
                be.read()
                be.write_pulses(p)
            u0 = be.status_last.underruns
            t = emu.sim_time()
            while emu.sim_time() < t + s_ms / 1e3:      # the host stalls; the chip's time goes on
                time.sleep(0.002)
            try:
                for _ in range(50):
                    be.read()
                    be.write_pulses(p)
                be.close()
                s = be.status_last
                if s.underruns > u0:
                    out = f"paused at an empty queue ({s.underruns - u0} underrun) and resumed"
            except BridgeFault as e:
                out = f"stopped: {str(e)[:160]}"
                be.close()
        finally:
            emu.stop()
        executed = bp.executed_steps(bp.read_edge_log(edge_log))
        rows.append((s_ms, out, executed))
        print(f"  stall {s_ms:6.1f} ms: {out}; pins: {executed.tolist()}", flush=True)
    return rows


def print_rate(best):
    print("\nhighest step rate held (simulated time, 125 MHz) vs Klipper's RP2040 (200 MHz):")
    print(f"  one axis:  {best[1] / 1e3:7.0f} kstep/s  ({best[1] * 200 / 125 / 1e3:.0f} k at 200 MHz; "
          f"Klipper {KLIPPER['one stepper'] / 1e6:.1f} M with one stepper)")
    print(f"  five axes: {best[5] / 1e3:7.0f} kstep/s in total ({best[5] * 200 / 125 / 1e3:.0f} k at 200 MHz; "
          f"Klipper {KLIPPER['three steppers (total)'] / 1e6:.1f} M with three)")
    print("  (the protocol caps an axis at 200 pulses per 1 ms tick at 2.5 us: 200 kstep/s, 1 Mstep/s for five)")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ticks", type=int, default=60, help="ticks per step-rate level (default 60)")
    ap.add_argument("--rates", default="1000,2000", help="tick rates for the CPU figures, Hz")
    ap.add_argument("--stalls", action="store_true", help="also measure the host-stall tolerance")
    ap.add_argument("--quick", action="store_true", help="fewer step-rate levels")
    ap.add_argument("--parts", default="rate,cpu", help="what to measure: rate, cpu (default both; --stalls adds stalls)")
    a = ap.parse_args()
    la = os.getloadavg()
    print(f"load average before: {la[0]:.2f} {la[1]:.2f} {la[2]:.2f} ({os.cpu_count()} CPUs); "
          f"figures in the emulated chip's time (125 MHz)")
    t_wall = time.monotonic()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        parts = set(a.parts.split(","))
        best = {}
        for axes in (1, 5) if "rate" in parts else ():
            print(f"\nstep rate, {axes} ax{'es' if axes > 1 else 'is'} stepping, 1 kHz ticks, 2.5 us step width:")
            rows = step_rate(tmp, a.ticks, axes, a.quick)
            held = [r for r in rows if r["held"]]
            best[axes] = held[-1]["steps_per_s"] if held else 0
        if "rate" in parts:
            print_rate(best)
        for rate in (float(x) for x in a.rates.split(",")) if "cpu" in parts else ():
            for pulses in (0, int(round(20 * 1000 / rate))):        # none, and 100 kstep/s in total
                c = cpu_per_tick(tmp, rate, max(a.ticks, 40), pulses)
                period = CLK_HZ / rate
                if "stopped" in c:
                    print(f"\nCPU per tick at {rate:g} Hz, {pulses} pulses/tick on each axis: the chip stopped: "
                          f"{c['stopped'][:120]}", flush=True)
                    continue
                print(f"\nCPU per tick at {rate:g} Hz, {pulses} pulses/tick on each axis: awake mean {c['mean']:.0f} "
                      f"cycles ({100 * c['share_mean']:.1f} % of the tick), p99 {c['p99']:.0f} ({100 * c['share_p99']:.1f} %); "
                      f"of which work (not spinning on a time) mean {c['work_mean']:.0f} ({100 * c['work_mean'] / period:.1f} %), "
                      f"p99 {c['work_p99']:.0f} ({100 * c['work_p99'] / period:.1f} %)", flush=True)
        if a.stalls:
            print("\nhost stalls (1 kHz, queue 4, prime 2, watchdog 100 ms: the shipped config):")
            stalls(tmp, [2.0, 3.0, 10.0, 50.0, 95.0, 105.0, 200.0])
    la = os.getloadavg()
    print(f"\nload average after: {la[0]:.2f} {la[1]:.2f} {la[2]:.2f}; wall time {time.monotonic() - t_wall:.0f} s")


if __name__ == "__main__":
    main()
