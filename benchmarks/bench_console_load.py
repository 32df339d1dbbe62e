"""The console and the rt side under load: `pmctl serve` in real time on the sim while CPU hogs run
beside it (default 2, on this 2-core machine: load average about 4), streaming a job of about five
minutes by character counting with `?` at 5 Hz. Reports: alarms and errors on the console, stalls
the rt side rode out (a feed hold on the path, resumed) or stopped on, the job's wall time against
its nominal time, status latency median/p99/max, overruns, and the load average.

    .venv/bin/python benchmarks/bench_console_load.py [--hogs 2] [--minutes 5]
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from grbl_sender import Sender, start_serve, stop_serve  # noqa: E402


def job_lines(minutes: float, feed=600.0):
    """Passes back and forth in X with arcs between them, about ``minutes`` at ``feed`` mm/min."""
    out = ["G21 G90 G94", f"F{feed:g}", "G0 X-15 Y-15 Z60"]
    length, y, sign = 0.0, -15.0, 1
    while length < minutes * 60 * feed / 60:
        out.append(f"G1 X{15 * sign:g}")
        length += 30
        out.append(f"G{2 if sign > 0 else 3} X{15 * sign:g} Y{y + 2:g} R1")
        length += math.pi
        y += 2
        if y > 13:
            out.append("G1 Y-15")
            length += 28
            y = -15
        sign = -sign
    out.append("M30")
    return out, length / (feed / 60)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--hogs", type=int, default=2)
    ap.add_argument("--minutes", type=float, default=5.0)
    a = ap.parse_args()
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(a.hogs)]
    tmp = Path(tempfile.mkdtemp(prefix="pmctl-load-"))
    p, link = start_serve(tmp, realtime=True)
    s = Sender(link)
    loads, lat = [], []
    try:
        lines, nominal = job_lines(a.minutes)
        t0 = time.monotonic()
        last_q = 0.0
        n0 = len(s.answers)

        def poll():
            nonlocal last_q
            now = time.monotonic()
            if now - last_q >= 0.2:
                last_q = now
                k = len(s.reports)
                s.realtime(b"?")
                s.wait_for(lambda: len(s.reports) > k, 10)
                lat.append(time.monotonic() - now)
                loads.append(os.getloadavg()[0])
        for line in lines:
            s.send(line, wait=False, timeout=600)
            poll()
        while len(s.answers) - n0 < len(lines) or not any("Pgm End" in x for x in s.pushed):
            poll()
            if time.monotonic() - t0 > 4 * nominal + 600:
                break
        wall = time.monotonic() - t0
        st = s.status()
    finally:
        s.close()
        stop_serve(p)
        for h in hogs:
            h.kill()
    err = (tmp / "serve.err").read_text()
    answers = s.answers[n0:]
    alarms = [x for x in s.pushed if x.startswith("ALARM:")]
    lat_ms = sorted(x * 1e3 for x in lat)
    q = lambda f: lat_ms[min(len(lat_ms) - 1, int(f * len(lat_ms)))]  # noqa: E731
    print(f"hogs {a.hogs}, load average median {sorted(loads)[len(loads) // 2]:.2f} (max {max(loads):.2f}), "
          f"{len(lines)} lines, nominal {nominal:.0f} s, wall {wall:.0f} s; final state {st and st['state']}")
    print(f"answers: {answers.count('ok')} ok, {len([x for x in answers if x.startswith('error')])} errors; "
          f"alarms: {alarms or 'none'}")
    print(f"rt side: {err.count('loop stalled')} stalls, {err.count('resumed after the stall')} resumed after a "
          f"feed hold, {err.count('controlled stop')} controlled stops; overrun warnings {err.count('overran its deadline')}")
    print(f"status latency ({len(lat_ms)} requests): median {q(0.5):.1f} ms, p99 {q(0.99):.1f} ms, max {lat_ms[-1]:.1f} ms")
    return 0 if not alarms and answers.count("ok") == len(lines) else 1


if __name__ == "__main__":
    sys.exit(main())
