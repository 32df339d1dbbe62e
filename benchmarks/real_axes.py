"""The twin on a real ball-screw axis: the EMPS benchmark (Janot, Gautier, Brunot, "Data Set and
Reference Models of EMPS", Workshop on Nonlinear System Identification Benchmarks, 2019). Its data
files are not part of pmctl: download the benchmark's DATA_EMPS.mat (and DATA_EMPS_PULSES.mat), then

    .venv/bin/python benchmarks/real_axes.py DATA_EMPS.mat [DATA_EMPS_PULSES.mat] [--out DIR]

Each file is imported as a recording of independent axes (cmd_X = qg, enc_X = qm, effort_X =
vir * gtau, in m and N: what `pmctl twin import` does) and diagnosed; the table compares the named
mass and friction with the benchmark's published IDIM-LS identification."""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import pmctl  # noqa: F401,I001
from pmctl.core.recording_chunks import read_columns
from pmctl.tools.twin.diagnose import diagnose
from pmctl.tools.twin.importers import import_source

PUBLISHED = {"mass_kg": 95.1089, "coulomb_N": 20.3935, "viscous_N_s_per_m": 203.5034}   # M1, FC1, FV1
GOAL = {"mass_kg": 0.10, "coulomb_N": 0.15, "viscous_N_s_per_m": 0.15}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("files", nargs="+")
    ap.add_argument("--out", default=None, help="keep the recordings here (default: a temporary folder)")
    a = ap.parse_args()
    out = Path(a.out or tempfile.mkdtemp(prefix="emps-"))
    for f in a.files:
        rec = out / Path(f).stem
        import_source(f, rec, mapping={"cmd_X": "qg", "enc_X": "qm", "effort_X": "vir*gtau"},
                      units={"cmd_X": "m", "enc_X": "m", "effort_X": "N"}, time="t", overwrite=True)
        _, m, cols = read_columns(rec)
        t0 = time.process_time()
        rep, _ = diagnose(cols, m, name=rec.name)
        cpu = time.process_time() - t0
        got = {}
        for fd in rep["findings"]:
            got.update(fd["parameters"])
        print(f"{Path(f).name}: {len(cols['t'])} samples, diagnosis {cpu:.1f} CPU s, verdict: {rep['verdict']}")
        print(f"  {'parameter':22s} {'published':>10s} {'pmctl':>10s} {'error':>8s}  goal")
        for k, ref in PUBLISHED.items():
            v = got.get(k)
            err = (v - ref) / ref if v is not None else float("nan")
            ok = v is not None and abs(err) <= GOAL[k]
            print(f"  {k:22s} {ref:10.4g} {v if v is not None else float('nan'):10.4g} {100 * err:+7.1f} %  "
                  f"within {100 * GOAL[k]:.0f} %: {'yes' if ok else 'NO'}")
        for fd in rep["findings"]:
            ch = ", ".join(f"{c} {fd['rms_before'][c]:.4g} -> {fd['rms_after'][c]:.4g} {rep['units'][c]}"
                           for c in fd["rms_before"])
            print(f"  {fd['effect']:15s} {fd['parameters']}  held-out rms {ch}")
        for u in rep["unexplained"]:
            print(f"  unexplained {u['channels']}: {u['signature']} {u['excess_over_noise']} x noise")


if __name__ == "__main__":
    main()
