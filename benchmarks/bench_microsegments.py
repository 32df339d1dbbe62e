"""CAM micro-segments: planning time and peak memory of a >= 1 MB V-carve program of micro-inch steps,
and the program machined to done with ``pmctl run --backend sim --no-realtime``.

    .venv/bin/python benchmarks/bench_microsegments.py [--bytes 1100000] [--seed 1] [--repeat 3] [--no-run]

The program is written by benchmarks/make_microsegments.py (V-carve strokes of steps of 1 um down to 1
micro-inch, 6 decimals: the kind of program that faulted "could not meet the joint/feed limits after 10
re-planning iterations" after 151.8 s of machining). Then, each in a fresh process:

1. planning, ``--repeat`` times: the job read, checked and planned whole as ``pmctl check`` and ``pmctl
   run`` do (``validate(full=True)``: streamed, no samples kept), then streamed as the supervisor streams
   it (``plan_stream`` of the checked path); the child prints its CPU times and its peak RSS (VmHWM of
   /proc/self/status at its end). Medians and the largest peak are reported;
2. ``pmctl check FILE --json``: wall time, its verdict and summary;
3. ``pmctl run --backend sim --no-realtime``: wall time, the run's report, and the peak RSS (VmHWM,
   sampled every 0.2 s) of the client and of the rt motion process.

Prints the load average with the figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import sys, time, json
import pmctl  # noqa: F401  (before numpy)
from pmctl.core.config import load_machine
from pmctl.task.job import home_pose, parse_job
from pmctl.task.planner import plan_stream, validate
m = load_machine()
t0 = time.process_time()
job, problems = parse_job(sys.argv[1], m, start=home_pose(m))
assert not problems, problems
t1 = time.process_time()
path = validate(job, m, 1e-3, full=True)
t2 = time.process_time()
n = 0
biggest = 0
for piece in plan_stream(job, m, 1e-3, path=path):
    n += len(piece)
    biggest = max(biggest, len(piece))
t3 = time.process_time()
hwm = [int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmHWM")][0]
print(json.dumps({"moves": len(job.moves), "segments": int(path.n), "samples": n, "biggest_piece": biggest,
                  "read_s": t1 - t0, "check_s": t2 - t1, "stream_s": t3 - t2, "hwm_kb": hwm,
                  "fallbacks": int(getattr(path, "fallbacks", 0))}))
"""


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bytes", type=int, default=1_100_000, help="size of the program (default 1100000)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-run", action="store_true", help="skip the pmctl run part")
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="pmctl-bench-micro-"))
    job = tmp / "vcarve.ngc"
    gen = [sys.executable, str(ROOT / "benchmarks" / "make_microsegments.py"), str(job), "--bytes", str(a.bytes),
           "--seed", str(a.seed)]
    print(subprocess.run(gen, check=True, capture_output=True, text=True).stdout.strip())
    runs = []
    for _ in range(a.repeat):
        r = subprocess.run([sys.executable, "-c", CHILD, str(job)], capture_output=True, text=True, cwd=ROOT)
        if r.returncode:
            print(r.stderr)
            raise SystemExit(1)
        runs.append(json.loads(r.stdout))
    med = {k: statistics.median(x[k] for x in runs) for k in ("read_s", "check_s", "stream_s")}
    r0 = runs[0]
    print(f"planning ({a.repeat} runs, CPU s, median): read+parse {med['read_s']:.2f}, check (validate full: "
          f"planned whole, no samples kept) {med['check_s']:.2f}, stream {med['stream_s']:.2f}; "
          f"{r0['moves']} moves -> {r0['segments']} segments, {r0['samples']} samples "
          f"({r0['samples'] / 1000:.1f} s at 1 kHz), largest piece {r0['biggest_piece']}, fallbacks {r0['fallbacks']}")
    print(f"planning peak RSS (VmHWM of the child): {max(x['hwm_kb'] for x in runs) / 1024:.1f} MB "
          f"(min {min(x['hwm_kb'] for x in runs) / 1024:.1f} MB)")
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", "check", str(job), "--json", "--state", ""],
                       capture_output=True, text=True, cwd=ROOT)
    rep = json.loads(r.stdout)
    print(f"pmctl check --json: exit {r.returncode}, ok {rep['ok']}, {len(rep['problems'])} problems, "
          f"{time.monotonic() - t0:.2f} s wall; summary {json.dumps(rep['summary'])}")
    if not a.no_run:
        args = [sys.executable, "-m", "pmctl.interfaces.cli", "run", "--job", str(job), "--state", "", "--quiet",
                "--backend", "sim", "--no-realtime"]
        sys.path.insert(0, str(ROOT / "benchmarks"))
        from bench_run_memory import run_watched
        t0 = time.monotonic()
        p, out, peak = run_watched(args, period_s=0.2)
        print(out, end="")
        print(f"pmctl run --no-realtime: exit {p.returncode}, {time.monotonic() - t0:.1f} s wall; peak RSS (VmHWM) "
              f"client {peak['client'] / 1024:.1f} MB, rt process {peak['rt'] / 1024:.1f} MB")
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
