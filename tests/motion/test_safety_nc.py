"""The NC's safety rules pinned at their boundaries, in both implementations (the Python reference
pmctl.motion.nc and the compiled core pmctl.motion.ncore), so that a rule loosened in one of them,
or in both, fails here:

- the following-error limit at 0.95x and 1.05x, at rest (MIN_FERROR) and at speed (FERROR scaled
  with the rate): no trip, then a trip, with the reason naming the axis;
- a soft limit approached near top speed: both NCs send the same pulses tick for tick, the stop is
  the soft limit's, and the axis comes to rest inside its limit (a braking distance estimated 10 %
  short in either core leaves it beyond, or makes the two differ).

Direct calls and closed loops against the loopback sim; no clock.
"""

import math
from dataclasses import replace

import numpy as np
import pytest

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.hal.base import Feedback
from pmctl.motion.nc import HALTED, NCParams, PythonNC, RUN, STOPPING, counts_of, initial_state
from pmctl.motion.ncore import make_nc
from test_ncore import closed_loop

M = load_machine()
DT = 1e-3
NAMES = ("L1", "L2", "L3", "X", "Y")
HOME = np.array([M.geometry.z_home] * 3 + [0.0, 0.0])


def _one_tick(impl, params, axis, rate_share, fe_share):
    """One NC tick from the home counters with axis ``axis`` moving at ``rate_share`` x its speed
    limit (the previous tick's rate) and its encoder ``fe_share`` x the following-error limit
    behind the counters. Returns (mode, reason, limit mm)."""
    st0 = initial_state(M, counts_of(HOME, params))
    qdot = np.zeros(5)
    qdot[axis] = rate_share * params.vmax[axis]
    st0 = replace(st0, qdot=qdot)
    lim = max(params.min_ferror_mm, params.ferror_mm * abs(qdot[axis]) / params.vmax[axis])
    fb = Feedback()
    fb.enc[:] = st0.counts / params.pulses_per_mm
    fb.enc[axis] -= fe_share * lim
    tg = np.concatenate([st0.tip, st0.axis, np.zeros(6)])
    nc = PythonNC(M, params) if impl == "python" else make_nc(M, params, "compiled")
    pulses, st = nc.step(nc.load(st0), tg, fb)
    return st.mode, st.reason, lim, pulses


@pytest.mark.parametrize("impl", ["python", "compiled"])
@pytest.mark.parametrize("rate_share", [0.0, 0.6])
def test_following_error_trips_between_095_and_105_of_its_limit(impl, rate_share):
    """At rest the limit is MIN_FERROR (10 um), at 60 % of the speed limit FERROR x 0.6 (0.6 mm):
    an encoder 0.95 x the limit behind runs on, 1.05 x the limit behind halts at once with no pulse,
    the reason naming the axis, the error and the limit. Every axis, both cores."""
    params = NCParams.from_machine(M, DT, kv=400.0)
    for axis in range(5):
        mode, reason, lim, _ = _one_tick(impl, params, axis, rate_share, 0.95)
        assert mode == RUN, (NAMES[axis], reason)
        mode, reason, lim, pulses = _one_tick(impl, params, axis, rate_share, 1.05)
        assert mode == HALTED and not pulses.any(), NAMES[axis]
        assert reason.startswith(f"following error: {NAMES[axis]} off by {1.05 * lim:.4f} mm "
                                 f"(limit {lim:.4f} mm"), reason
    # the two limits really are the two regimes
    assert params.min_ferror_mm == pytest.approx(0.01) and params.ferror_mm * 0.6 > 10 * params.min_ferror_mm


def _toward_limit(axis_idx, start, speed_share, beyond_mm, params, dt, sign=1.0):
    """Target rows that accelerate joint(s) ``axis_idx`` from ``start`` (joint positions) at 90 % of
    the acceleration limit to ``speed_share`` x the speed limit and keep going until ``beyond_mm`` past
    the upper limit (``sign`` -1: the lower one): the NC must stop on its own, by the soft limit."""
    ax = list(np.atleast_1d(axis_idx))
    v = speed_share * float(np.min(params.vmax[ax]))
    a = 0.9 * float(np.min(params.amax[ax]))
    room = params.upper[ax] - start[ax] if sign > 0 else start[ax] - params.lower[ax]
    dist = float(np.max(room)) + beyond_mm
    t_acc = v / a
    T = t_acc + (dist - 0.5 * a * t_acc ** 2) / v
    t = np.arange(int(T / dt) + 2) * dt
    s = np.where(t < t_acc, 0.5 * a * t ** 2, 0.5 * a * t_acc ** 2 + v * (t - t_acc))
    q = np.repeat(start[None], len(t), 0)
    for i in ax:
        q[:, i] = start[i] + sign * s
    pose, ok = K.fk_batch(q, M)
    assert np.all(ok)
    rows = np.zeros((len(t), 12))
    rows[:, :3], rows[:, 3:6] = pose.tip, pose.axis
    rows[:-1, 6:9] = np.diff(pose.tip, axis=0) / dt
    rows[:-1, 9:12] = np.diff(pose.axis, axis=0) / dt
    return rows


@pytest.mark.parametrize("case", ["X", "Y", "chains", "X-lower", "chains-lower", "X-slow"])
def test_a_soft_limit_approached_near_top_speed_stops_inside_it_in_both_cores(case):
    """X (or Y, or the three chains together) driven at 95 % of its top speed towards its upper soft
    limit (or its lower one) and on past it: both NCs send the same pulses tick for tick, stop for
    the soft limit while still at speed (the braking distance v^2/2a is 2.3 mm here, not
    negligible), and every joint comes to rest inside its limits, close to the limit. Slowly (X at
    0.5 mm/s): the same, the stop from under a micrometre of braking distance."""
    params = NCParams.from_machine(M, DT, kv=400.0)
    start = HOME.copy()
    sign, share = (-1.0 if case.endswith("lower") else 1.0), (0.005 if case.endswith("slow") else 0.95)
    if case.startswith("X"):
        axes = [3]
        start[3] = sign * (params.upper[3] - 0.3 if share < 0.1 else 40.0)
    elif case == "Y":
        axes, start[4] = [4], 40.0
    else:
        axes = [0, 1, 2]
        start[:3] = (params.upper[0] - 30.0) if sign > 0 else (params.lower[0] + 30.0)
    rows = _toward_limit(axes, start, share, 10.0 if share > 0.1 else 0.2, params, DT, sign)
    ticks, sp, sc, moved = closed_loop(M, params, rows, start, {}, every=1)
    assert sp.mode == sc.mode == HALTED
    assert sp.reason.startswith("soft limit: ") and sp.reason == sc.reason
    # the stop began at speed: the reason's rate is near the speed of the approach
    v_stop = float(sp.reason.split(" moving at ")[1].split(" mm/s")[0])
    assert sign * v_stop > 0.8 * share * params.vmax[axes[0]], sp.reason
    q_end = sp.counts / params.pulses_per_mm
    assert np.all(q_end <= params.upper) and np.all(q_end >= params.lower), (q_end, params.upper)
    # ... and close to it: the stop did not brake early either (within the margin of two ticks and
    # the rounding of the stop's start to a tick, at least a few pulses)
    gap = (params.upper[axes] - q_end[axes]) if sign > 0 else (q_end[axes] - params.lower[axes])
    assert np.all(gap < np.maximum(4 * share * params.vmax[axes] * DT, 5 / params.pulses_per_mm[axes])), gap


@pytest.mark.parametrize("impl", ["python", "compiled"])
@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
@pytest.mark.parametrize("sensor", ["encoder", "strain gauge"])
def test_a_dead_sensor_halts_at_once_with_its_name(impl, bad, sensor):
    """An encoder or a strain gauge reading NaN or infinite (a lost or broken sensor) must not blind
    the supervision (NaN compares false): a halt at once, no pulse, the sensor named. Every one."""
    params = NCParams.from_machine(M, DT, kv=400.0, k_theta=200.0)
    st0 = initial_state(M, counts_of(HOME, params))
    tg = np.concatenate([st0.tip, st0.axis, np.zeros(6)])
    names = NAMES if sensor == "encoder" else ("1", "2", "3")
    for i, name in enumerate(names):
        fb = Feedback()
        fb.enc[:] = st0.counts / params.pulses_per_mm
        (fb.enc if sensor == "encoder" else fb.strain)[i] = bad
        nc = PythonNC(M, params) if impl == "python" else make_nc(M, params, "compiled")
        pulses, st = nc.step(nc.load(st0), tg, fb)
        assert st.mode == HALTED and not pulses.any()
        assert st.reason == f"feedback fault: {sensor} {name} reads {bad}", st.reason


@pytest.mark.parametrize("impl", ["python", "compiled"])
@pytest.mark.parametrize("rate_sign", [0.0, -1.0])
def test_a_joint_beyond_its_soft_limit_is_stopped_whichever_way_it_moves(impl, rate_sign):
    """Counters past X's upper limit (a restart after the limits were narrowed), the joint at rest
    or already moving back: the NC stops for the soft limit, naming the axis, and sends only the
    braking pulses (none at rest)."""
    params = NCParams.from_machine(M, DT, kv=400.0)
    q = HOME.copy()
    q[3] = params.upper[3] + 0.2
    st0 = initial_state(M, counts_of(q, params))
    st0 = replace(st0, qdot=np.array([0.0, 0.0, 0.0, rate_sign * 5.0, 0.0]))
    fb = Feedback()
    fb.enc[:] = st0.counts / params.pulses_per_mm
    tg = np.concatenate([st0.tip, st0.axis, np.zeros(6)])
    nc = PythonNC(M, params) if impl == "python" else make_nc(M, params, "compiled")
    pulses, st = nc.step(nc.load(st0), tg, fb)
    assert st.reason.startswith("soft limit: X = "), st.reason
    assert st.mode == (HALTED if rate_sign == 0.0 else STOPPING)


@pytest.mark.parametrize("impl", ["python", "compiled"])
def test_the_path_error_stop_trips_between_095_and_105_of_its_limit(impl):
    """The target 0.95 x max_path_error away from the model tool tip: the NC runs on (correcting);
    1.05 x: a controlled stop naming the path error (from rest it is at rest at once: HALTED)."""
    params = NCParams.from_machine(M, DT, kv=400.0)
    st0 = initial_state(M, counts_of(HOME, params))
    fb = Feedback()
    fb.enc[:] = st0.counts / params.pulses_per_mm
    for share, mode in ((0.95, RUN), (1.05, HALTED)):
        tg = np.concatenate([st0.tip + [share * params.max_path_error_mm, 0.0, 0.0], st0.axis, np.zeros(6)])
        nc = PythonNC(M, params) if impl == "python" else make_nc(M, params, "compiled")
        pulses, st = nc.step(nc.load(st0), tg, fb)
        assert st.mode == mode, (share, st.reason)
        if mode == HALTED:
            assert not pulses.any()
            assert st.reason.startswith(f"path error {share * params.max_path_error_mm:.4f} mm over"), st.reason


@pytest.mark.parametrize("impl", ["python", "compiled"])
@pytest.mark.parametrize("side", [-1.0, 1.0])
def test_a_joint_just_inside_its_limit_moving_away_runs_on(impl, side):
    """X one pulse inside its lower (upper) limit, moving away from it at 0.5 mm/s towards a target
    that moves away too: no stop (the braking distance counts only towards the limit it approaches)."""
    params = NCParams.from_machine(M, DT, kv=400.0)
    q = HOME.copy()
    q[3] = (params.lower[3] + 0.0005) if side < 0 else (params.upper[3] - 0.0005)      # one pulse inside
    v = -side * 0.5
    st0 = initial_state(M, counts_of(q, params))
    st0 = replace(st0, qdot=np.array([0.0, 0.0, 0.0, v, 0.0]))
    fb = Feedback()
    fb.enc[:] = st0.counts / params.pulses_per_mm
    tg = np.concatenate([st0.tip - [v * DT, 0.0, 0.0], st0.axis, [-v, 0.0, 0.0], np.zeros(3)])
    nc = PythonNC(M, params) if impl == "python" else make_nc(M, params, "compiled")
    pulses, st = nc.step(nc.load(st0), tg, fb)
    assert st.mode == RUN, st.reason


@pytest.mark.parametrize("impl", ["python", "compiled"])
def test_a_chain_offset_beyond_its_bound_is_clipped_and_a_nan_one_holds(impl):
    """The chain-length offset input (slow compensation) at rest: -1 mm on L1 with a bound of
    0.2 mm slews down at 2 mm/s to -0.2 mm and stays; NaN on L2 holds its offset (0); +0.1 mm on L3
    slews up to it. The applied offset moves at most the slew step a tick."""
    params = NCParams.from_machine(M, DT, kv=400.0, chain_offset_max_mm=0.2, chain_offset_rate_mm_s=2.0)
    st = initial_state(M, counts_of(HOME, params))
    tg = np.concatenate([st.tip, st.axis, np.zeros(6)])
    nc = PythonNC(M, params) if impl == "python" else make_nc(M, params, "compiled")
    s = nc.load(st)
    step = 2.0 * DT
    prev = np.zeros(3)
    for k in range(1, 160):
        fb = Feedback()
        fb.enc[:] = s.counts / params.pulses_per_mm if impl == "python" else s.snapshot().counts / params.pulses_per_mm
        _, s = nc.step(s, tg, fb, np.array([-1.0, math.nan, 0.1]))
        off = (s if impl == "python" else s.snapshot()).offset
        assert np.all(np.abs(off - prev) <= step * (1 + 1e-12)) and s.mode == RUN
        prev = off
        want = [-min(k * step, 0.2), 0.0, min(k * step, 0.1)]
        assert np.allclose(off, want, atol=1e-12), (k, off, want)


@pytest.mark.parametrize("impl", ["python", "compiled"])
def test_the_tilt_stop_trips_between_095_and_105_of_its_limit(impl):
    """The measured pose tilted 6 deg, at rest on its target: with the tilt limit at 6/0.95 deg the NC
    runs on; at 6/1.05 deg it stops (from rest: HALTED at once, no pulse) naming the tilt and the limit."""
    st_home = initial_state(M, counts_of(HOME, NCParams.from_machine(M, DT, kv=400.0)))
    tilt = math.radians(6.0)
    axis = np.array([math.sin(tilt), 0.0, math.cos(tilt)])
    q = K.ik(st_home.tip, axis, M).q
    for share, mode in ((0.95, RUN), (1.05, HALTED)):
        params = replace(NCParams.from_machine(M, DT, kv=400.0), theta2_max_rad=tilt / share)
        st0 = initial_state(M, counts_of(q, params))
        fb = Feedback()
        fb.enc[:] = st0.counts / params.pulses_per_mm
        tg = np.concatenate([st0.tip, st0.axis, np.zeros(6)])
        nc = PythonNC(M, params) if impl == "python" else make_nc(M, params, "compiled")
        pulses, st = nc.step(nc.load(st0), tg, fb)
        assert st.mode == mode, (share, st.reason)
        if mode == HALTED:
            assert not pulses.any()
            assert st.reason == f"soft limit: tilt 6.000 deg over {math.degrees(tilt / share):g} deg", st.reason


@pytest.mark.parametrize("impl", ["python", "compiled"])
def test_the_chain_offset_stops_slewing_once_the_nc_is_stopping(impl):
    """A chain-length offset slews in at chain_offset_rate_mm_s while the NC runs; once it is stopping
    (braking for a fault) the applied offset stays where it was: no length change during a stop."""
    params = NCParams.from_machine(M, DT, kv=400.0)
    st = initial_state(M, counts_of(HOME, params))
    fb = Feedback()
    fb.enc[:] = st.counts / params.pulses_per_mm
    tg = np.concatenate([st.tip, st.axis, np.zeros(6)])
    nc = PythonNC(M, params) if impl == "python" else make_nc(M, params, "compiled")
    st = nc.load(st)
    want = np.array([0.1, 0.0, 0.0])
    for _ in range(10):
        _, st = nc.step(st, tg, fb, want)
    moved = float(st.offset[0])
    assert moved == pytest.approx(10 * params.chain_offset_rate_mm_s * DT, rel=1e-9)
    st = nc.load(replace(st.snapshot(), mode=STOPPING, reason="following error: X"))
    for _ in range(10):
        _, st = nc.step(st, tg, fb, want)
    assert float(st.offset[0]) == moved
