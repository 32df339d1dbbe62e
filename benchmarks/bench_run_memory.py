"""Peak memory of `pmctl run` on a long job: the client (supervisor side: planner, recording sink,
tracking figures) and the rt motion process, each by its VmHWM (peak resident set), sampled once a
second while the run goes on.

    .venv/bin/python benchmarks/bench_run_memory.py [--minutes 21] [--realtime] [-- extra pmctl run args]

The job: back-and-forth X moves of 10 mm at 1 mm/s (10 s each) for --minutes of machine time (the
default, 21 min, is longer than the batch planner's MAX_SAMPLES of 20 min at 1 kHz, which bounded
`pmctl run` before it streamed). Without --realtime the run is an offline simulation (ticks back to
back). Prints the run's report, the peaks, the wall time and the load average; asserts nothing.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _hwm_kb(pid: int):
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmHWM"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def run_watched(args, period_s=1.0):
    """Run ``args`` (a pmctl run command line) and sample the VmHWM of the client and of the rt motion
    process (its pid read from the client's log) every ``period_s``: (Popen, stdout, peak kB by name)."""
    p = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    rt = []

    def read_err():
        for line in p.stderr:
            m = re.search(r"rt motion process \(pid (\d+)\)", line)
            if m:
                rt.append(int(m.group(1)))
    threading.Thread(target=read_err, daemon=True).start()
    peak = {"client": 0, "rt": 0}
    while p.poll() is None:
        for name, pid in (("client", p.pid), ("rt", rt[0] if rt else None)):
            v = _hwm_kb(pid) if pid else None
            if v:
                peak[name] = max(peak[name], v)
        time.sleep(period_s)
    return p, p.stdout.read(), peak


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=21.0)
    ap.add_argument("--realtime", action="store_true")
    ap.add_argument("extra", nargs="*")
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="pmctl-bench-mem-"))
    job = tmp / "long.ngc"
    lines = ["(back and forth)", "G17 G21 G90 G94", "G0 X5 Y0 Z65 A-4.5088 B8.9351", "G0 Z60", "F60"]
    lines += ["G1 X-5" if i % 2 == 0 else "G1 X5" for i in range(int(round(a.minutes * 6)))]
    job.write_text("\n".join(lines) + "\n")
    args = [sys.executable, "-m", "pmctl.interfaces.cli", "run", "--job", str(job), "--state", "", "--quiet",
            "--backend", "sim", *([] if a.realtime else ["--no-realtime"]), *a.extra]
    t0 = time.monotonic()
    p, out, peak = run_watched(args)
    print(out, end="")
    print(f"job: {a.minutes:g} min of machine time, {'real time' if a.realtime else 'offline (--no-realtime)'}")
    print(f"peak RSS (VmHWM): client {peak['client'] / 1024:.1f} MB, rt process {peak['rt'] / 1024:.1f} MB")
    print(f"wall {time.monotonic() - t0:.1f} s; load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
