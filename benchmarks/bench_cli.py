"""Command-line start-up: wall time of `pmctl --help` and `pmctl <command> --help` (median, p99,
max over repeated runs, with the load average), and what building the parsers imports.

    .venv/bin/python benchmarks/bench_cli.py [--repeat 20]

Not a test: nothing here asserts a time. The goal is `pmctl --help` well under 1 s; the test suite
checks the cause instead (tests/interfaces/test_cli_help.py: building the parsers imports no numpy).
"""

import argparse
import os
import shutil
import subprocess
import sys
import time

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default, pmctl/__init__.py)
import numpy as np


def wall(cmd, n):
    ts = []
    for _ in range(n):
        t0 = time.perf_counter()
        subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
        ts.append(time.perf_counter() - t0)
    ts = np.array(ts) * 1e3
    return np.median(ts), np.percentile(ts, 99), ts.max()


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=20)
    args = ap.parse_args()
    exe = shutil.which("pmctl", path=os.path.dirname(sys.executable)) or "pmctl"
    print(f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}, "
          f"{args.repeat} runs each, wall clock ms")
    base = wall([sys.executable, "-c", "pass"], args.repeat)
    print(f"  {'python -c pass':34s} median {base[0]:7.1f}  p99 {base[1]:7.1f}  max {base[2]:7.1f}")
    for argv in (["--help"], ["run", "--help"], ["twin", "synth", "--help"], ["analyze", "vf", "--help"]):
        m, p99, mx = wall([exe, *argv], args.repeat)
        print(f"  {'pmctl ' + ' '.join(argv):34s} median {m:7.1f}  p99 {p99:7.1f}  max {mx:7.1f}  "
              f"(x{m / base[0]:.1f} of a bare interpreter)")
    code = ("import sys; from pmctl.interfaces.cli import build_parser; build_parser(); "
            "print(len(sys.modules), [m for m in ('numpy', 'scipy', 'matplotlib') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True).stdout.strip()
    print(f"  modules after building every parser: {out}")


if __name__ == "__main__":
    main()
