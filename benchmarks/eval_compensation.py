"""From diagnosis to fix, end to end through the command line: `pmctl run` a job on a sim plant
with a load-side play and pitch error -> `pmctl twin diagnose --write-compensation` -> the machine
config names the table -> `pmctl run` again -> diagnose again. Prints the tool-tip error of both
runs (the plant's true tip against the programmed path), the findings and the table's notes.

The plant is the test plant of tests/core/test_compensation.py (the loopback sim plus a play operator
and a sinusoidal pitch error on the motor position, added to its truth), put in place of the
``sim`` backend for this process. Takes a few minutes (two diagnoses).

    .venv/bin/python benchmarks/eval_compensation.py [--backlash-axis L2] [--pitch-axis X] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from test_compensation import PlayPitchSim  # noqa: E402  (the test plant)

from pmctl import hal  # noqa: E402
from pmctl.core.config import CONFIG_DIR  # noqa: E402
from pmctl.interfaces.cli import main  # noqa: E402

AXES = ("L1", "L2", "L3", "X", "Y")
PLANT = {}
JOB = ("G21 G90 G17\nG0 X-12 Y-8 Z60\nG1 F900 X12 Y9 Z62\nX-6 Y10 Z57\nX10 Y-9 Z61\nX-12 Y-8 Z60\n"
       "X12 Y9 Z62\nX-6 Y10 Z57\nX10 Y-9 Z61\nX-12 Y-8 Z60\nM2\n")


class Plant(PlayPitchSim):
    def __init__(self, machine, dt, options=None):
        super().__init__(machine, dt, options=options, **PLANT)


def main_(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backlash-axis", default="L2", choices=AXES)
    ap.add_argument("--backlash-mm", type=float, default=0.02)
    ap.add_argument("--pitch-axis", default="X", choices=AXES)
    ap.add_argument("--pitch-mm", type=float, default=0.006)
    ap.add_argument("--out", default=None, help="work folder (default: a temporary one)")
    a = ap.parse_args(argv)
    bl, amp = [0.0] * 5, [0.0] * 5
    bl[AXES.index(a.backlash_axis)] = a.backlash_mm
    amp[AXES.index(a.pitch_axis)] = a.pitch_mm
    PLANT.update(backlash=bl, amp=amp, period=5.0, phase=[0.3, 1.2, 2.0, -0.7, 2.8])
    hal.BACKENDS["sim"] = f"{__name__}:Plant"
    d = Path(a.out or tempfile.mkdtemp(prefix="pmctl-comp-"))
    if d.exists():
        shutil.rmtree(d)
    d.mkdir(parents=True)
    (d / "service.toml").write_text("[hal.sim]\nseed = 4\nenc_noise_mm = 0.0002\nstrain_noise_ue = 0.02\n")
    (d / "job.ngc").write_text(JOB)
    shutil.copy(CONFIG_DIR / "prototype.toml", d / "machine.toml")
    print(f"plant: backlash {a.backlash_mm * 1e3:.1f} µm on {a.backlash_axis}, pitch error {a.pitch_mm * 1e3:.1f} µm "
          f"at 5 mm on {a.pitch_axis}; work folder {d}; load average {os.getloadavg()[0]:.1f}")

    def run_and_diagnose(tag, extra=()):
        rec = d / f"rec-{tag}"
        rc = main(["run", "--job", str(d / "job.ngc"), "--config", str(d / "machine.toml"), "--service",
                   str(d / "service.toml"), "--record", str(rec), "--state", "", "--no-realtime", "--quiet"])
        assert rc == 0, rc
        t0 = time.process_time()
        rc = main(["twin", "diagnose", str(rec), "--json", str(d / f"diag-{tag}.json"), "--no-progress", *extra])
        assert rc == 0, rc
        meta = json.loads((rec / "recording.json").read_text())
        rep = json.loads((d / f"diag-{tag}.json").read_text())
        return meta["run"]["tracking"], rep, time.process_time() - t0

    tr0, rep0, c0 = run_and_diagnose("before", ["--write-compensation", str(d / "comp.toml")])
    with open(d / "machine.toml", "a", encoding="utf-8") as f:
        f.write('\n[compensation]\nfile = "comp.toml"\n')
    tr1, rep1, c1 = run_and_diagnose("after")
    print("\n=== summary")
    for tag, tr, rep, c in (("without table", tr0, rep0, c0), ("with table", tr1, rep1, c1)):
        names = [f"{f['effect']}[{f.get('axis') or f.get('chain') or f.get('channel')}]" for f in rep["findings"]]
        print(f"{tag:14s} tip RMS {tr['tip_rms_um']:6.2f} µm, p99 {tr['tip_p99_um']:6.2f} µm, max "
              f"{tr['tip_max_um']:6.2f} µm; verdict {rep['verdict']!r}; findings {names}; "
              f"{len(rep['unexplained'])} unexplained; diagnosis {c:.0f} s CPU")
    print(f"tip RMS ratio {tr0['tip_rms_um'] / tr1['tip_rms_um']:.1f}x")


if __name__ == "__main__":
    main_()
