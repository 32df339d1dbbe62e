"""Regenerate the bundled example recordings (small enough for git: 200 Hz, 20-30 s).

    .venv/bin/python examples/recordings/make_examples.py

Each example is NAME/recording/ (pmctl-recording/1) with NAME/answer.json beside it, exactly as
``pmctl twin synth`` writes cases. Seeds are fixed, so the files are reproducible.
"""

from pathlib import Path

import numpy as np

from pmctl.core.config import load_machine
from pmctl.tools.twin import synth as S

HERE = Path(__file__).resolve().parent


def main():
    m = load_machine()
    rng = np.random.default_rng(20261122)
    examples = [
        ("clean-raster", "raster", [], 20.0),
        ("backlash-circle", "circle", [S.Effect("backlash", {"axis": "X"},
                                                 {"width_mm": float(rng.uniform(0.012, 0.025))})], 30.0),
        ("pitch-and-offset-calibration", "calibration",
         [S.make_effect("pitch_error", rng, axis="L2"),
          S.Effect("sensor_offset", {"channel": "strain_1"}, {"offset": float(rng.uniform(3, 8))})], 20.0),
    ]
    for k, (name, run, effects, duration) in enumerate(examples):
        case = S.synth_case(np.random.default_rng(k + 1), effects, run=run, duration_s=duration,
                            rate_hz=200.0, machine=m, seed=k + 1)
        d = S.write_case(HERE, name, case)
        size = sum(p.stat().st_size for p in d.rglob("*") if p.is_file())
        print(f"{d.relative_to(HERE.parents[1])}: {len(case.columns['t'])} samples, {size / 1e6:.2f} MB, "
              f"effects: {[e['effect'] for e in case.answer['effects']] or 'none'}")


if __name__ == "__main__":
    main()
