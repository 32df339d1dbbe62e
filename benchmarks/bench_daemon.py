"""The rt tick with the daemon attached vs alone, at 1 kHz, and console latency under load.

1. alone: the control loop in one process (as `pmctl run`), real-time pacing, a planned job;
2. attached: `pmctl serve`'s two processes (rt process + supervisor with the grbl console on a pty)
   while a sender streams the same job by character counting and asks `?` at 10 Hz;
   per-tick compute time and wake-up lateness come from the rt side's records;
3. console latency: time from writing `?` to reading the status report, under that streaming load.
Prints medians, p99 and max, the ratio attached/alone, and the load average (this is a shared
machine: compare ratios, not absolute numbers).

    .venv/bin/python benchmarks/bench_daemon.py [--seconds 10]
"""

from __future__ import annotations

import argparse
import os
import select
import sys
import tempfile
import time
import tty
from pathlib import Path

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default, pmctl/__init__.py)
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from pmctl import hal  # noqa: E402
from pmctl.core import kinematics as K  # noqa: E402
from pmctl.core.config import load_machine  # noqa: E402
from pmctl.motion.loop import ControlLoop, prepare  # noqa: E402
from pmctl.motion.nc import counts_of, initial_state  # noqa: E402
from pmctl.motion.recorder import R_LATE_NS, R_PREV_COMPUTE_NS  # noqa: E402
from pmctl.motion.service_config import load_service_config  # noqa: E402
from pmctl.task.gcode import parse_gcode  # noqa: E402
from pmctl.core.job import home_pose  # noqa: E402
from pmctl.task.planner import plan  # noqa: E402


def program(seconds):
    n = max(2, int(seconds * 10 / 8))
    lines = ["G21 G90 G1 F600"]
    for i in range(n):
        lines.append(f"X{8 * ((i + 1) % 2)} Y{2 * (i % 3)}")
    return lines


def stats(a_ns):
    a = np.asarray(a_ns, float) / 1e3
    return f"median {np.median(a):7.1f} us  p99 {np.percentile(a, 99):7.1f} us  max {a.max():8.1f} us  (n={len(a)})"


def alone(seconds):
    m = load_machine()
    svc = load_service_config(None)
    cfg = svc.loop
    cfg.realtime, cfg.lock_memory, cfg.max_overruns_in_row = True, False, 1 << 30
    dt = cfg.dt
    params = svc.nc.params(m, dt)
    tip, ax = home_pose(m)
    job = parse_gcode("\n".join(program(seconds)).replace("G1 F600", f"G1 F600 Z{tip[2] - 5}"), "b", tip, ax)
    tr = plan(job, m, dt, start=(tip, ax))
    tg = prepare(m, params, tr, dt)
    c0 = counts_of(tg.q[0], params)
    be = hal.create("sim", m, dt, svc.backend_options)
    be.open(c0)
    lp = ControlLoop(m, be, params, tg, cfg, initial_state(m, c0), log=lambda s: None)
    res = lp.run()
    return res.timing.compute_ns, res.timing.late_ns


def attached(seconds):
    from pmctl.interfaces.console.grbl import GrblConsole
    from pmctl.interfaces.console.port import ConsolePort
    from pmctl.task.jog import make_jogger
    from pmctl.task.journal import Journal
    from pmctl.task.supervisor import Supervisor
    sup = Supervisor("prototype", realtime=True)
    rows = []
    sup.record_sink = rows.append
    tip, ax = home_pose(sup.machine)
    sup.start(counts_of(K.ik(tip, ax, sup.machine).q, sup.params))
    tmp = tempfile.mkdtemp()
    port = ConsolePort(f"pty:{tmp}/tty")
    con = GrblConsole(sup, port.fd, Journal(None, sup.machine.name), jogger=make_jogger(sup))
    con.start()
    fd = os.open(f"{tmp}/tty", os.O_RDWR | os.O_NOCTTY)
    tty.setraw(fd)
    buf = b""
    lat = []
    reports = 0
    oks = 0

    def pump(t=0.0):
        """Read what the console sent; count `ok`s and status reports line by line (an `ok` that
        arrives before a report is an `ok`, not part of it)."""
        nonlocal buf, reports, oks
        r, _, _ = select.select([fd], [], [], t)
        if r:
            buf += os.read(fd, 65536)
        while b"\n" in buf:
            line, buf = buf.split(b"\n", 1)
            line = line.strip()
            if line == b"ok":
                oks += 1
                if pending:
                    pending.pop(0)
            elif line.startswith(b"error"):
                raise SystemExit(f"the console answered {line!r}")
            elif line.startswith(b"<"):
                reports += 1
                last_report[0] = line

    lines = program(seconds)
    lines[0] = lines[0] + f" Z{tip[2] - 5}"
    pending, sent = [], 0
    last_report = [b""]
    t_end = time.monotonic() + seconds + 30
    last_q = 0.0
    while time.monotonic() < t_end:
        while sent < len(lines) and sum(pending) + len(lines[sent]) + 1 <= 128:
            d = (lines[sent] + "\n").encode()
            os.write(fd, d)
            pending.append(len(d))
            sent += 1
        now = time.monotonic()
        if now - last_q > 0.1:
            last_q = now
            n0 = reports
            t0 = time.perf_counter()
            os.write(fd, b"?")
            while reports == n0 and time.perf_counter() - t0 < 5:
                pump(0.5)
            lat.append(time.perf_counter() - t0)
            if last_report[0].startswith(b"<Idle") and sent == len(lines) and oks >= len(lines):
                break
        pump(0.01)
    else:
        print(f"warning: the job did not end within {seconds + 30:.0f} s ({oks}/{len(lines)} lines answered)")
    con.stop()
    sup.shutdown()
    port.close()
    os.close(fd)
    a = np.concatenate(rows) if rows else np.zeros((0, 32))
    return a[1:, R_PREV_COMPUTE_NS], a[:, R_LATE_NS], np.array(lat) * 1e9


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=10.0)
    a = ap.parse_args()
    print(f"load average before: {os.getloadavg()}")
    c1, l1 = alone(a.seconds)
    print("alone    tick compute:", stats(c1))
    print("alone    lateness:    ", stats(l1))
    c2, l2, lat = attached(a.seconds)
    print("attached tick compute:", stats(c2))
    print("attached lateness:    ", stats(l2))
    print(f"ratio attached/alone: compute p99 {np.percentile(c2, 99) / np.percentile(c1, 99):.2f}, "
          f"lateness p99 {np.percentile(l2, 99) / max(np.percentile(l1, 99), 1):.2f}")
    print("console '?' -> report latency under streaming:", stats(lat))
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
