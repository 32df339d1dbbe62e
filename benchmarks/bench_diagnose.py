"""Diagnosis time against recording length (10^4, 10^5, 10^6 samples) and its scaling.

    .venv/bin/python benchmarks/bench_diagnose.py [--sizes 1e4,1e5,1e6] [--repeat 3]

Each size is a synth calibration run at 1 kHz with one hidden backlash (so the selection runs two
rounds), diagnosed with the default settings (at most DEFAULT_CAP analysis samples per channel;
the nominal twin replays only the analysis rows). Prints the median and max wall time per size and
the log-log slope between sizes (1 = linear in the recording length).
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np

from pmctl.core.config import load_machine
from pmctl.tools.twin import synth
from pmctl.tools.twin.diagnose import diagnose


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="1e4,1e5,1e6")
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    m = load_machine()
    sizes = [int(float(s)) for s in a.sizes.split(",")]
    med = {}
    print(f"{'samples':>9s} {'median s':>9s} {'max s':>7s} {'runs':>4s}  findings")
    for n in sizes:
        rng = np.random.default_rng(5)
        case = synth.synth_case(rng, [synth.Effect("backlash", {"axis": "X"}, {"width_mm": 0.02})],
                                run="calibration", duration_s=n / 1000.0, rate_hz=1000.0, machine=m, seed=5)
        reps = a.repeat if n <= 100_000 else 1
        ts = []
        for _ in range(reps):
            t0 = time.perf_counter()
            rep, _ = diagnose(case.columns, m)
            ts.append(time.perf_counter() - t0)
        med[n] = statistics.median(ts)
        print(f"{n:9d} {med[n]:9.2f} {max(ts):7.2f} {reps:4d}  "
              f"{[(f['effect'], f.get('axis'), f['parameters']) for f in rep['findings']]}", flush=True)
    ns = sorted(med)
    for n1, n2 in zip(ns, ns[1:]):
        print(f"scaling {n1:.0e} -> {n2:.0e}: time x{med[n2] / med[n1]:.2f} for samples x{n2 / n1:.0f}, "
              f"slope {math.log(med[n2] / med[n1]) / math.log(n2 / n1):.2f}")


if __name__ == "__main__":
    main()
