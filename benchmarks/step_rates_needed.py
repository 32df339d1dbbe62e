"""The step rates a job asks of a step/dir bridge, from a recording of it (docs/stepdir.md).

    .venv/bin/pmctl run --backend sim --no-realtime --job examples/jobs/hemisphere.cl --record DIR --state ''
    .venv/bin/python benchmarks/step_rates_needed.py DIR [DIR ...]

For each recording: the most pulses in one tick per axis (from the commanded counters, cmd_* x the
machine's pulses per mm), the most in one tick in total, its 99th percentile, and how many axes were
above 150 pulses in the same tick. At 1 kHz, pulses per tick are kstep/s.
"""

from __future__ import annotations

import argparse

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default)
import numpy as np

from pmctl.core.config import load_machine
from pmctl.core.recording import read_recording
from pmctl.hal import bridge_protocol as bp


def needs(path: str, config: str | None = None) -> dict:
    r = read_recording(path)
    ppm = load_machine(config).resolution.pulses_per_mm
    cmd = np.stack([np.asarray(r.columns[f"cmd_{a}"]) for a in bp.AXES], -1)
    p = np.abs(np.diff(np.rint(cmd * ppm).astype(np.int64), axis=0))
    tot = p.sum(1)
    return {"ticks": len(p), "rate_hz": r.meta.get("sample_rate_hz"), "max_per_axis": p.max(0).tolist(),
            "max_total": int(tot.max()), "p99_total": float(np.percentile(tot, 99)),
            "axes_above_150_at_once": int((p > 150).sum(1).max())}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("recordings", nargs="+", help="recording folders (pmctl run --record)")
    ap.add_argument("--config", default=None, help="machine config the jobs ran with (default: the shipped one)")
    a = ap.parse_args()
    for d in a.recordings:
        n = needs(d, a.config)
        print(f"{d}: {n['ticks']} ticks at {n['rate_hz']} Hz; most pulses in a tick, {' / '.join(bp.AXES)}: "
              f"{' / '.join(map(str, n['max_per_axis']))}; in total {n['max_total']} (p99 {n['p99_total']:.0f}); "
              f"axes above 150 in the same tick: {n['axes_above_150_at_once']}")


if __name__ == "__main__":
    main()
