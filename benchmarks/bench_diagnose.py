"""Diagnosis cost against recording length: CPU time and peak memory (10^4, 10^5, 10^6 samples).

    .venv/bin/python benchmarks/bench_diagnose.py [--sizes 1e4,1e5,1e6] [--keep DIR]

Each size is a synth calibration run at 1 kHz with one hidden backlash (width 0.02 mm on X),
written as a pmctl-recording/1 folder. A fresh child process then reads it with the bounded-
memory reader (pmctl.core.recording_chunks.read_columns: data.csv in 16 MB blocks, measured
channels in float32) and diagnoses it with the default settings (at most DEFAULT_CAP analysis
samples per channel). The child reports its CPU time (read and diagnose apart) and its peak
resident memory (ru_maxrss), so sizes do not share an allocator. Also printed: the machine's
load average, since the CPU time of a loaded 2-core machine is less stable than its memory.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHILD = r"""
import json, resource, sys, time
from pmctl.core.recording_chunks import read_columns
from pmctl.tools.twin.diagnose import diagnose
t0 = time.process_time()
meta, machine, cols = read_columns(sys.argv[1])
t1 = time.process_time()
rep, _ = diagnose(cols, machine)
t2 = time.process_time()
print(json.dumps({"read_cpu_s": t1 - t0, "diagnose_cpu_s": t2 - t1, "n": len(cols["t"]),
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "verdict": rep["verdict"],
                  "findings": [(f["effect"], f.get("axis"), f["parameters"], f["confidence"]) for f in rep["findings"]]}))
"""


def make(n, folder):
    import numpy as np
    from pmctl.core.config import load_machine
    from pmctl.tools.twin import synth
    m = load_machine()
    case = synth.synth_case(np.random.default_rng(5), [synth.Effect("backlash", {"axis": "X"}, {"width_mm": 0.02})],
                            run="calibration", duration_s=n / 1000.0, rate_hz=1000.0, machine=m, seed=5)
    synth.write_case(folder, f"n{n}", case)
    return Path(folder) / f"n{n}" / "recording"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="1e4,1e5,1e6")
    ap.add_argument("--keep", help="write the recordings here (default: a temporary folder)")
    a = ap.parse_args()
    tmp = a.keep or tempfile.mkdtemp(prefix="bench_diagnose_")
    print(f"load average {os.getloadavg()[0]:.1f} (2 cores)")
    print(f"{'samples':>9s} {'read cpu s':>10s} {'diag cpu s':>10s} {'µs/sample':>9s} {'peak RSS MB':>11s}  verdict, findings")
    for n in (int(float(s)) for s in a.sizes.split(",")):
        rec = Path(tmp) / f"n{n}" / "recording"
        if not (rec / "data.csv").exists():
            t0 = time.perf_counter()
            rec = make(n, tmp)
            print(f"  (made {rec} in {time.perf_counter() - t0:.0f} s)", flush=True)
        out = subprocess.run([sys.executable, "-c", CHILD, str(rec)], capture_output=True, text=True, check=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        tot = r["read_cpu_s"] + r["diagnose_cpu_s"]
        print(f"{r['n']:9d} {r['read_cpu_s']:10.2f} {r['diagnose_cpu_s']:10.2f} {1e6 * tot / r['n']:9.1f} "
              f"{r['peak_rss_mb']:11.0f}  {r['verdict']}, {r['findings']}", flush=True)
    print(f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
