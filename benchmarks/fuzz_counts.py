"""Fuzzing with large budgets: the strategies and targets of tests/test_fuzz_*.py (tests/fuzz_common.py),
run N inputs per reader; prints inputs tried, clean refusals (the project's own error), valid results
(finite, in range), and crashes (anything else), with the first crash's input when there is one.

    python benchmarks/fuzz_counts.py [--n 2000] [--only gcode,cli] [--seed 0]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import traceback
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from hypothesis import HealthCheck, given, seed, settings  # noqa: E402

import fuzz_common  # noqa: E402


def run(name, strategy, target, n, rng_seed):
    counts = Counter()
    first = []

    @seed(rng_seed)
    @settings(max_examples=n, deadline=None, database=None, derandomize=False,
              suppress_health_check=list(HealthCheck), phases=["generate"])
    @given(strategy)
    def probe(x):
        counts["tried"] += 1
        try:
            counts[target(x)] += 1
        except Exception as e:         # noqa: BLE001 -- a crash: count it, keep the first
            counts["crash"] += 1
            if not first:
                first.append((x, "".join(traceback.format_exception_only(type(e), e)).strip()))

    t0 = time.perf_counter()
    probe()
    return counts, time.perf_counter() - t0, first


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=2000, help="inputs per reader")
    ap.add_argument("--only", default="", help="comma-separated reader names")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    names = [x for x in a.only.split(",") if x] or list(fuzz_common.TARGETS)
    print(f"# fuzz_counts: {a.n} inputs per reader, seed {a.seed}, load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"{'reader':<16}{'tried':>8}{'refused':>9}{'valid':>8}{'crashes':>9}{'seconds':>9}")
    total = Counter()
    for name in names:
        strategy, target = fuzz_common.TARGETS[name]
        c, secs, first = run(name, strategy, target, a.n, a.seed)
        total.update(c)
        print(f"{name:<16}{c['tried']:>8}{c['refused']:>9}{c['valid']:>8}{c['crash']:>9}{secs:>9.1f}")
        if first:
            x, err = first[0]
            print(f"    first crash: {err}\n    input: {x!r:.300}")
    print(f"{'total':<16}{total['tried']:>8}{total['refused']:>9}{total['valid']:>8}{total['crash']:>9}")
    return 1 if total["crash"] else 0


if __name__ == "__main__":
    sys.exit(main())
