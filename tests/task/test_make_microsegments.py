"""benchmarks/make_microsegments.py: the planner's V-carve-like micro-segment program is reproducible
from its seed, is made of steps of 1 um and smaller, and stays inside the machine's workspace."""

from __future__ import annotations

import math
import re
import sys
from pathlib import Path

from pmctl.core.config import load_machine
from pmctl.task.job import load_job

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import make_microsegments as mm  # noqa: E402


def _cuts(text):
    """The G1 steps of the strokes (after each plunge, not the plunge itself): their 3-D lengths in mm,
    and the feeds."""
    pos, steps, feeds, cutting = [0.0, 0.0, 0.0], [], set(), False
    for line in text.splitlines():
        w = dict(re.findall(r"([XYZF])(-?[\d.]+)", line))
        if "F" in w:
            feeds.add(float(w["F"]))
        new = [float(w.get(k, v)) for k, v in zip("XYZ", pos)]
        if line.startswith("G0"):
            cutting = False
        elif "X" in w and cutting:
            steps.append(math.dist(pos, new))
        elif "X" not in w and "Z" in w:          # the plunge at the start of a stroke
            cutting = True
        pos = new
    return steps, feeds


def test_same_seed_same_program_other_seed_another():
    a, _ = mm.program(7, 40_000)
    b, _ = mm.program(7, 40_000)
    c, _ = mm.program(8, 40_000)
    assert a == b and a != c


def test_steps_are_one_micrometre_and_smaller_down_to_a_microinch():
    text, st = mm.program(3, 300_000)
    steps, feeds = _cuts(text)
    assert len(steps) == st["steps"] > 5000
    assert max(steps) <= 1.0e-3 + 2e-6          # 1 um, within the 1 nm of the 6 decimals written
    assert min(steps) < 0.05e-3                 # down to about a micro-inch
    assert sum(s < 0.9e-3 for s in steps) > len(steps) / 4
    assert feeds <= {100.0, 200.0, 300.0, 500.0, 800.0, 1000.0, 1500.0, 2000.0, 2500.0, 3000.0}


def test_default_size_is_over_a_megabyte():
    _, st = mm.program(1, 1_100_000)
    assert st["bytes"] >= 1_000_000


def test_every_pose_is_reachable_for_todays_reader(tmp_path):
    text, st = mm.program(5, 60_000)
    p = tmp_path / "micro.ngc"
    p.write_text(text)
    job = load_job(p, load_machine())
    assert len(job) >= st["steps"]
