"""Diagnosis cost against recording length: CPU time, wall time and peak memory (10^4 ... 10^7 samples).

    .venv/bin/python benchmarks/bench_diagnose.py [--sizes 1e4,1e5,1e6,1e7] [--keep DIR]

Recordings (pmctl-recording/1 folders at 1 kHz, one hidden backlash of 0.02 mm on X):

- up to 10^6 samples: one synth calibration run of that length, written whole;
- beyond: a 200 s synth run written by pmctl.core.recording.write_recording, whose rows are then
  repeated with continuing times, one tile of text at a time (no more than one tile is ever in
  memory). At each join the positions jump back to the run's start in one sample, in the commands
  and the measurements alike. The simulated play restarts on the side the run's first motion
  pushes, so the run is cut where X's last motion and that jump go the same way (``_seamless``):
  uncut, a join was a reset of the play that no continuous machine can do, and the diagnosis
  rightly flagged the kept runs holding one (tip_x 4 x its noise until X moved).

Each size is then diagnosed in a fresh child process exactly as ``pmctl twin diagnose`` does
(pmctl.tools.twin.diagnose.read_for_diagnosis, then diagnose with the default cap), and the child
reports its CPU time (read and diagnose apart), its wall time and its peak resident memory
(VmHWM of /proc/self/status), so sizes do not share an allocator. Not ru_maxrss: Linux carries it
across fork and exec, so a child forked while this process held the 10^6 synth run reported that
run's memory (1302 MB, where the diagnosis itself peaks at 820 MB). The machine's load average is printed per size:
the CPU and wall time of a loaded 2-core machine vary more than its memory. The recordings are
removed at the end unless --keep names a folder for them.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default, pmctl/__init__.py)
import numpy as np

CHILD = r"""
import json, sys, time
from pmctl.tools.twin.diagnose import diagnose, read_for_diagnosis
def peak_mb():      # this process's own peak resident set (VmHWM is reset by exec; ru_maxrss is not)
    with open("/proc/self/status") as f:
        return next(int(ln.split()[1]) for ln in f if ln.startswith("VmHWM:")) / 1024
w0, t0 = time.perf_counter(), time.process_time()
meta, machine, cols, span = read_for_diagnosis(sys.argv[1])
t1 = time.process_time()
rep, extras = diagnose(cols, machine, span=span)
t2, w2 = time.process_time(), time.perf_counter()
print(json.dumps({"read_cpu_s": t1 - t0, "diagnose_cpu_s": t2 - t1, "wall_s": w2 - w0,
                  "n": span["rows_total"], "analysed": len(cols["t"]),
                  "peak_rss_mb": peak_mb(),
                  "verdict": rep["verdict"],
                  "findings": [(f["effect"], f.get("axis"), f["parameters"], f["confidence"]) for f in rep["findings"]]}))
"""

EFFECT = ("backlash", {"axis": "X"}, {"width_mm": 0.02})
TILE_S = 200.0


def _synth(duration_s, seed=5):
    import numpy as np
    from pmctl.core.config import load_machine
    from pmctl.tools.twin import synth
    return synth.synth_case(np.random.default_rng(seed), [synth.Effect(*EFFECT)], run="calibration",
                            duration_s=duration_s, rate_hz=1000.0, machine=load_machine(), seed=seed)


def _seamless(cols):
    """The run cut at its last row from which repeating it keeps the play continuous. The synth starts
    X's play on the side X's first motion pushes, so at a join X's last motion and the jump back to
    the run's start must both go that way (or the jump be none): the join then reads as one more
    motion in that direction, and the play's side needs no reset a continuous machine cannot do."""
    from pmctl.core.plant_effects import direction, first_direction
    x = np.asarray(cols["cmd_X"], float)
    d0 = first_direction(x)
    ok = (direction(x) == d0) & (np.sign(x[0] - x) * d0 >= 0)
    e = int(np.flatnonzero(ok)[-1]) + 1
    return {k: np.asarray(v)[:e] for k, v in cols.items()}


def make(n, folder):
    """Write the recording of n samples under folder; returns its path."""
    from pmctl.core.recording import DATA_FILE, META_FILE, write_recording
    rec = Path(folder) / f"n{n}" / "recording"
    if n <= 1_000_000:
        case = _synth(n / 1000.0)
        write_recording(rec, case.columns, sample_rate_hz=1000.0, description=f"bench {n}")
        return rec
    # one tile written by the recording writer, then its rows repeated with new times, one tile
    # of text at a time
    tile = Path(folder) / f"n{n}" / "tile"
    case = _synth(TILE_S)
    write_recording(tile, _seamless(case.columns), sample_rate_hz=1000.0,
                    description=f"bench {n}: a {TILE_S:g} s synth run repeated")
    with open(tile / DATA_FILE, "rb") as fh:
        head = fh.readline()
        rest = [ln.split(b",", 1)[1] for ln in fh.read().splitlines()]
    rec.mkdir(parents=True)
    (rec / META_FILE).write_bytes((tile / META_FILE).read_bytes())
    m = len(rest)
    with open(rec / DATA_FILE, "wb") as out:
        out.write(head)
        for done in range(0, n, m):
            take = min(m, n - done)
            t = ((done + np.arange(take)) * 1e-3).round(6).tolist()
            out.write(b"".join(b"%r,%s\n" % (tv, r) for tv, r in zip(t, rest[:take])))
    shutil.rmtree(tile)
    return rec


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="1e4,1e5,1e6,1e7")
    ap.add_argument("--keep", help="write the recordings here and keep them (default: a temporary folder, removed)")
    a = ap.parse_args()
    tmp = a.keep or tempfile.mkdtemp(prefix="bench_diagnose_")
    try:
        print(f"load average {os.getloadavg()[0]:.1f} (2 cores)")
        print(f"{'samples':>9s} {'analysed':>9s} {'read cpu s':>10s} {'diag cpu s':>10s} {'wall s':>7s} "
              f"{'µs/sample':>9s} {'peak RSS MB':>11s} {'load':>5s}  verdict, findings")
        for n in (int(float(s)) for s in a.sizes.split(",")):
            rec = Path(tmp) / f"n{n}" / "recording"
            if not (rec / "data.csv").exists():
                t0 = time.perf_counter()
                rec = make(n, tmp)
                mb = (rec / "data.csv").stat().st_size / 2**20
                print(f"  (made {rec}, {mb:.0f} MB, in {time.perf_counter() - t0:.0f} s)", flush=True)
            out = subprocess.run([sys.executable, "-c", CHILD, str(rec)], capture_output=True, text=True)
            if out.returncode:
                print(out.stderr[-2000:])
                raise SystemExit(f"size {n}: the child failed")
            r = json.loads(out.stdout.strip().splitlines()[-1])
            tot = r["read_cpu_s"] + r["diagnose_cpu_s"]
            print(f"{r['n']:9d} {r['analysed']:9d} {r['read_cpu_s']:10.2f} {r['diagnose_cpu_s']:10.2f} "
                  f"{r['wall_s']:7.1f} {1e6 * tot / r['n']:9.2f} {r['peak_rss_mb']:11.0f} "
                  f"{os.getloadavg()[0]:5.1f}  {r['verdict']}, {r['findings']}", flush=True)
    finally:
        if not a.keep:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
