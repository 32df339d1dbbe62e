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
COMB = Path(__file__).resolve().parents[2] / "examples" / "jobs" / "comb.ngc"


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


MODES = (35.0, 40.0, 48.0)          # a chain mode per chain (they differ under load and across the workspace)


def _chain_shaping(modes, name="ZV*MA"):
    from functools import partial

    from pmctl.motion.service_config import _chain_lengths
    w = 2 * np.pi * np.asarray(modes)
    half = 0.5 / 2000.0                                   # half a pulse, mm
    return S.ChainShaping(tuple(S.make_shaper(name, f, 0.02) for f in modes), partial(_chain_lengths, machine=M),
                          tuple(w * half), tuple(w * w * half))


def test_per_chain_shaping_keeps_the_path_and_shapes_only_the_pieces_that_move_chains(planned):
    """The comb with a shaper per chain: every sample on the planned path (1e-9 mm); its X steps move
    the table only and keep the planned clock; its Z strokes move all three chains and take the
    three shapers convolved (the time they add is their sum, per piece)."""
    cs = _chain_shaping(MODES)
    tr = shape_trajectory(planned, cs)
    extra = len(tr) - len(planned)
    assert np.max(error_behind(tr.tip, planned.tip, extra)) < 1e-9
    assert np.allclose(tr.tip[0], planned.tip[0]) and np.allclose(tr.tip[-1], planned.tip[-1])
    cuts, chosen, kinks = cs.plan(planned.tip, planned.axis, 1e-3)
    assert not kinks and set(chosen) == {(), (0, 1, 2)}
    z = [(a, b) for (a, b), c in zip(zip(cuts[:-1], cuts[1:]), chosen) if c]
    x = [(a, b) for (a, b), c in zip(zip(cuts[:-1], cuts[1:]), chosen) if not c]
    assert len(x) == 8 and np.allclose(np.ptp(planned.tip[x[0][0]:x[0][1] + 1, 2]), 0.0)
    d = sum(S.make_shaper("ZV*MA", f, 0.02).duration for f in MODES)
    assert cs.combined((0, 1, 2)).duration == pytest.approx(d)
    assert extra == len(z) * int(np.ceil(d / 1e-3 - 1e-9))
    sig = cs.index(planned.tip, planned.axis, 1e-3)
    for a, b in x:                                          # the table's pieces: the planned clock, delayed
        k = int(np.searchsorted(sig, a + 0.5)) - 1           # the shaped piece's end, a to rounding
        np.testing.assert_allclose(sig[k:k + b - a + 1], np.arange(a, b + 1, dtype=float), atol=1e-6)


def test_each_chain_mode_is_left_still_by_its_own_shaper(planned):
    """The free vibration each chain's mode (its own frequency, 2 % damping) is left with after the
    comb: shaped per chain, under 5 % of the unshaped plan's for every chain; one shaper at 40 Hz for
    all leaves the 35 and 48 Hz chains several times more."""
    from pmctl.core.plant_effects import mode_response

    def residual(tr, f):
        q = K.ik_batch(tr.tip, tr.axis, M).q[:, :3]
        q = np.concatenate([q, np.repeat(q[-1:], 300, 0)])     # held after the end: the free decay
        return [np.abs(mode_response(q[:, i], 1e-3, f[i], 0.02)[-300:]).max() for i in range(3)]
    ref = residual(planned, MODES)
    per_chain = residual(shape_trajectory(planned, _chain_shaping(MODES)), MODES)
    one = residual(shape_trajectory(planned, _chain_shaping((40.0,) * 3)), MODES)
    for i in range(3):
        assert per_chain[i] < 0.05 * ref[i]
    assert one[0] > 3 * per_chain[0] and one[2] > 3 * per_chain[2]


def test_a_kink_of_the_chains_is_brought_to_rest_over_two_periods():
    """The cone's first G0 ends in a plunge: the tip turns 11 deg (no corner), the chains' velocity
    vector 19 deg with a jump of 1.75 mm/s in one tick. Per-chain shaping stops the clock there and
    smooths the stop (MA over two periods on top): around it no chain's velocity changes by more in a
    tick than the plan's own accelerations do away from the kink."""
    job = COMB.parent / "cone.ngc"
    tip, axis = home_pose(M)
    pl = plan(load_job(str(job), M, start=(tip, axis)), M, 1e-3, start=(tip, axis))
    cs = _chain_shaping((40.0,) * 3)
    cuts, chosen, kinks = cs.plan(pl.tip, pl.axis, 1e-3)
    assert len(kinks) >= 1
    k = min(kinks)
    q0 = K.ik_batch(pl.tip[k - 150:k + 150], pl.axis[k - 150:k + 150], M).q[:, :3]
    dv0 = np.abs(np.diff(q0, 2, axis=0)).max(axis=1) / 1e-3          # mm/s a tick, at samples k - 149 ..
    i = int(np.argmax(dv0))
    jump, rest = dv0[i], np.delete(dv0, [i - 1, i, i + 1]).max()
    assert abs(i - 149) <= 1
    assert jump > 1.5 and jump > 3 * rest
    tr = shape_trajectory(pl, cs)
    sig = cs.index(pl.tip, pl.axis, 1e-3)
    j = int(np.searchsorted(sig, k - 1e-6))
    q = K.ik_batch(tr.tip[j - 200:j + 200], tr.axis[j - 200:j + 200], M).q[:, :3]
    assert np.abs(np.diff(q, 2, axis=0)).max() / 1e-3 <= 1.05 * rest
