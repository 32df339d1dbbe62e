"""`pmctl calibrate plan`: D-optimal measurement poses beat random ones; the job parses and plans."""

import math
import subprocess
import sys

import numpy as np

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.task.gcode import read_gcode
from pmctl.task.planner import plan as plan_job
from pmctl.tools.calibrate import identify as I, model as Mo, plan as Pl
import pytest

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

M = load_machine()


def test_d_optimal_poses_are_better_conditioned_than_random_ones():
    tip, axis, q = Pl.plan_poses(M, 30, candidates=600, seed=2)
    c_plan, rank, ld_plan = I.condition_number(q, M.geometry, max_sigma=math.inf)
    assert rank == 26                       # every combination but the 4 exact symmetries
    rng = np.random.default_rng(7)
    worse = 0
    for _ in range(5):
        rt, ra = Mo.random_tool_poses(M, 30, rng)
        c, _, ld = I.condition_number(K.ik_batch(rt, ra, M).q, M.geometry, max_sigma=math.inf)
        worse += (c > c_plan) and (ld < ld_plan)
    assert worse == 5
    assert K.ik_batch(tip, axis, M).ok.all()


def test_exchange_improves_on_greedy_and_never_picks_a_pose_twice():
    rng = np.random.default_rng(3)
    tip, axis = Mo.random_tool_poses(M, 300, rng)
    _, B = Pl.candidate_blocks(M, tip, axis)
    D, V = Pl._subspace(B)
    C = (B / D) @ V.T

    def logdet(idx):
        return np.linalg.slogdet(np.einsum("kmr,kms->rs", C[idx], C[idx]))[1]
    greedy = Pl.d_optimal(B, 20, rng, passes=0)
    full = Pl.d_optimal(B, 20, rng)
    assert len(set(full.tolist())) == 20
    assert logdet(full) >= logdet(greedy) - 1e-9


def test_plan_cli_writes_a_job_that_parses_and_plans(tmp_path):
    r = subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", "calibrate", "plan", "-n", "12",
                        "--candidates", "200", "--dwell-s", "1.5", "--out", str(tmp_path / "cal")],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "condition number" in r.stdout and "random 12 poses" in r.stdout
    job = read_gcode(tmp_path / "cal.ngc", M)
    traj = plan_job(job, M, 1e-2)
    rows = np.loadtxt(tmp_path / "cal.csv", delimiter=",", skiprows=1)
    assert rows.shape == (12, 14)
    # the trajectory dwells at every planned pose (tip to the G-code's 6 decimals)
    for tip in rows[:, 1:4]:
        assert np.min(np.linalg.norm(traj.tip - tip, axis=1)) < 1e-5
    assert sum(1 for ln in (tmp_path / "cal.ngc").read_text().splitlines() if ln.startswith("G4 P1.5")) == 12
    # the CSV joints are the IK of the CSV poses
    assert np.allclose(K.ik_batch(rows[:, 1:4], rows[:, 4:7], M).q, rows[:, 9:14], atol=1e-6)


def test_plan_refuses_too_few_poses(tmp_path):
    r = subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", "calibrate", "plan", "-n", "2",
                        "--out", str(tmp_path / "x")], capture_output=True, text=True)
    assert r.returncode == 1 and "at least 6 poses" in r.stderr
