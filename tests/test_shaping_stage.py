"""The time-law shaping stage between the planner and the loop (pmctl.motion.timescale.shape_trajectory):
on a planned job every sample stays on the planned path, the motion ends later by the shaper's
duration per stop, the job line follows the path position, and the shaped plan's acceleration has
no one-tick spikes at shallow junctions (the split rule, pmctl.core.shaper.SPLIT_DEG)."""

from pathlib import Path

import numpy as np
import pytest

from pmctl.core import kinematics as K
from pmctl.core import shaper as S
from pmctl.core.config import load_machine
from pmctl.motion.timescale import shape_trajectory
from pmctl.task.planner import home_pose, load_job, plan

M = load_machine()
COMB = Path(__file__).resolve().parents[1] / "examples" / "jobs" / "comb.ngc"


@pytest.fixture(scope="module")
def planned():
    tip, axis = home_pose(M)
    return plan(load_job(str(COMB), M, start=(tip, axis)), M, 1e-3, start=(tip, axis))


def error_behind(points, path, lag, block=512):
    """Distance of each shaped sample j from the polyline of the planned samples j - lag - 1 .. j + 1
    (shaping only delays: sample j lies at or behind planned sample j, by at most the ``lag`` samples
    added in all). A part of the path: never less than the distance from the whole path, so a bound
    on it is no looser; the whole-path search (M x N) took seconds per shaper."""
    out = np.empty(len(points))
    for s in range(0, len(points), block):
        lo, hi = max(0, s - lag - 1), min(len(path), s + block + 2)
        out[s:s + block] = S.path_error(points[s:s + block], path[lo:hi])
    return out


@pytest.mark.parametrize("name", ["ZV", "ZVD", "2HUMP_EI"])
def test_shaped_plan_stays_on_the_path(planned, name):
    sh = S.make_shaper(name, 40.0, 0.02)
    tr = shape_trajectory(planned, sh)
    pieces = 1 + len(S.corner_samples(planned.tip, planned.axis))
    extra = len(tr) - len(planned)
    assert 0 < extra <= pieces * (int(np.ceil(sh.duration / 1e-3)) + 1)
    assert np.max(error_behind(tr.tip, planned.tip, extra)) < 1e-9
    assert np.allclose(tr.tip[0], planned.tip[0]) and np.allclose(tr.tip[-1], planned.tip[-1])
    # the job line of each shaped sample is the line of the planned sample it lies on (or the next)
    i = np.array([np.argmin(np.linalg.norm(planned.tip - p, axis=1)) for p in tr.tip[::97]])
    lines = np.asarray(planned.line)
    ok = (tr.line[::97] == lines[i]) | (tr.line[::97] == lines[np.maximum(i - 1, 0)])
    assert ok.all()
    assert np.allclose(tr.tip_vel[:-1], np.diff(tr.tip, axis=0) / 1e-3)


def test_no_acceleration_spike_at_a_shallow_junction(planned):
    """The comb's G0/G1 junction turns by 6 deg at 4.5 mm/s: splitting there would stop the shaped clock
    and restart it (velocity steps of the shaper's amplitudes x 4.5 mm/s); it is not split."""
    tr = shape_trajectory(planned, S.make_shaper("ZVD", 40.0, 0.02))
    qa = K.ik_batch(planned.tip, planned.axis, M).q[:, :3]
    qb = K.ik_batch(tr.tip, tr.axis, M).q[:, :3]
    acc = lambda q: np.abs(q[2:] - 2 * q[1:-1] + q[:-2]).max() / 1e-6       # noqa: E731
    assert acc(qb) <= 1.05 * acc(qa)
    assert shape_trajectory(planned, None) is planned
