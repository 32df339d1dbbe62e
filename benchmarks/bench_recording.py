"""Read (and write) time of pmctl-recording/1 folders against length: 10^4, 10^5, 10^6 rows.

A 1 kHz log with 23 channels: t, cmd_*, enc_*, strain_*, temp_screw1, and a 100 Hz laser tracker
(tip_*, tool_*; 9 of 10 cells empty). Prints median read time, rows/s and the scaling exponent.

    .venv/bin/python benchmarks/bench_recording.py [--max-rows 1000000] [--repeat 3] [--twin]
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default, pmctl/__init__.py)
import numpy as np

from pmctl.core.recording import CMD, ENC, STRAIN, TIP, TOOL, read_recording, write_recording


def make_columns(n, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 1000.0
    cols = {"t": t}
    for i, c in enumerate(CMD):
        cols[c] = 300 + 50 * np.sin(0.3 * t + i)
    for c, k in zip(ENC, CMD):
        cols[c] = cols[k] + rng.normal(0, 5e-4, n)
    tracker = (np.arange(n) % 10) == 0
    for c in TIP + TOOL:
        cols[c] = np.where(tracker, rng.normal(0, 10, n), np.nan)
    for c in STRAIN:
        cols[c] = -40 + rng.normal(0, 0.5, n)
    cols["temp_screw1"] = 20 + t / 600
    return cols


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--max-rows", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--twin", action="store_true", help="also time the nominal-twin replay (predict)")
    args = ap.parse_args()
    sizes = [n for n in (10_000, 100_000, 1_000_000) if n <= args.max_rows]
    tmp = Path(tempfile.mkdtemp(prefix="bench-rec-"))
    rows = []
    try:
        for n in sizes:
            cols = make_columns(n)
            t0 = time.perf_counter()
            write_recording(tmp / f"r{n}", cols, sample_rate_hz=1000)
            tw = time.perf_counter() - t0
            size_mb = (tmp / f"r{n}" / "data.csv").stat().st_size / 1e6
            times = []
            for _ in range(args.repeat if n < 1_000_000 else max(1, args.repeat - 1)):
                t0 = time.perf_counter()
                rec = read_recording(tmp / f"r{n}")
                times.append(time.perf_counter() - t0)
                assert rec.n == n
            med = statistics.median(times)
            rows.append((n, size_mb, tw, med, max(times)))
            print(f"rows {n:>9,d}  {size_mb:7.1f} MB  write {tw:7.2f} s  read median {med:7.3f} s "
                  f"(max {max(times):.3f} s)  {n / med / 1e6:5.2f} Mrow/s", flush=True)
            if args.twin:
                from pmctl.tools.twin.nominal import predict
                t0 = time.perf_counter()
                pred = predict(rec)
                tp = time.perf_counter() - t0
                print(f"    nominal twin predict ({len(pred)} channels): {tp:.2f} s, {n / tp / 1e6:.2f} Msample/s",
                      flush=True)
            shutil.rmtree(tmp / f"r{n}")
        if len(rows) >= 2:
            n = np.log([r[0] for r in rows])
            tr = np.log([r[3] for r in rows])
            print(f"read time ~ rows^{np.polyfit(n, tr, 1)[0]:.2f} over {sizes[0]:,}..{sizes[-1]:,} rows")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
