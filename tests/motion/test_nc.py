"""The NC step (pmctl.motion.nc): single-pose model FK/Jacobian vs kinematics.py, pulse accounting, joint
velocity/acceleration limits in both V-F modes, stops with reasons."""

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.errors import KinematicsError
from pmctl.hal.base import Feedback
from pmctl.motion.nc import HALTED, NCParams, RUN, STOPPING, counts_of, initial_state, limit_rates, nc_step
from pmctl.core.model_fk import ModelFK

M = load_machine()
MODEL = ModelFK(M)


def _pose(x, y, z, roll, pitch):
    return np.array([x, y, z], float), K.axis_from_roll_pitch(np.radians(roll), np.radians(pitch))


poses = st.tuples(st.floats(-40, 40), st.floats(-40, 40), st.floats(10, 40),
                  st.floats(-12, 12), st.floats(-12, 12))


@settings(max_examples=40, deadline=None)
@given(poses, st.lists(st.floats(-0.2, 0.2), min_size=5, max_size=5))
def test_model_fk_and_jacobian_match_kinematics(p, dq):
    tip, axis = _pose(*p)
    r = K.ik_batch(tip, axis, M)
    assume(bool(r.ok))
    q = r.q + np.array(dq)
    P, R, tip_m, axis_m, J = MODEL.solve(q, r.P, r.R)          # warm start from a nearby pose
    ref = K.fk(q, M)
    assert np.abs(tip_m - ref.tip).max() < 1e-9
    assert np.abs(axis_m - ref.axis).max() < 1e-12
    Jref = K.jacobian_tool(ref.P, ref.R, M.geometry)
    # J is linearised at the warm start: relative error of order |dq| / chain length
    assert np.abs(J - Jref).max() < 5e-3 * max(1e-3, np.abs(dq).max()) / 0.2 + 1e-9
    _, _, _, _, J2 = MODEL.solve(q, P, R)                      # at the converged pose: exact
    assert np.abs(J2 - Jref).max() < 1e-9


def test_model_fk_failure_is_a_fault_not_an_answer():
    q = np.array([150.0, 570.0, 150.0, 0.0, 0.0])            # no assembly with these chain lengths
    with pytest.raises(KinematicsError):
        MODEL.solve(q, np.array([0.0, 0.0, 393.0]), np.eye(3))


class FB(Feedback):
    def __init__(self, q=None):
        super().__init__()
        if q is not None:
            self.enc[:] = q


def _run_ticks(params, st0, targets, ideal=True):
    """Drive nc_step directly with an ideal plant (encoders = counters)."""
    st = st0
    fb = FB()
    out_p, out_qd, modes = [], [], []
    for tg in targets:
        fb.enc[:] = st.counts / params.pulses_per_mm
        p, st = nc_step(st, tg, fb, params, MODEL)
        out_p.append(p)
        out_qd.append(st.qdot)
        modes.append(st.mode)
    return st, np.array(out_p), np.array(out_qd), modes


@pytest.mark.parametrize("mode", [1, None])       # the seed's one pulse per tick; multi-pulse
def test_velocity_and_acceleration_limits_hold_for_a_target_jump(mode):
    dt = 1e-3
    params = NCParams.from_machine(M, dt, max_pulses_per_tick=mode, kv=400.0, max_path_error_mm=100.0)
    tip, axis = _pose(0, 0, 10, 3, -2)
    st0 = initial_state(M, counts_of(K.ik(tip, axis, M).q, params))
    far = np.concatenate([tip + np.array([8.0, -5.0, 3.0]), axis, np.zeros(6)])   # a jump: the NC must ramp
    st, pulses, qd, modes = _run_ticks(params, st0, [far] * 400)
    assert all(m == RUN for m in modes)
    # commanded rates: velocity box and per-tick change box, exactly
    assert np.all(np.abs(qd) <= params.vmax * (1 + 1e-12))
    dqd = np.diff(np.vstack([np.zeros(5), qd]), axis=0)
    assert np.all(np.abs(dqd) <= params.amax * dt * (1 + 1e-9))
    # the pulse train itself: within one pulse per tick of the commanded rate (V-F residue < 1 pulse)
    assert np.all(np.abs(pulses) <= params.vmax * params.pulses_per_mm * dt + 1)
    assert np.all(np.abs(pulses) <= params.max_pulses_per_tick)
    # the limit was active (the test would pass vacuously otherwise)
    assert np.max(np.abs(qd) / params.vmax) > 0.99
    # pulses sent == counter
    assert np.array_equal(st0.counts + pulses.sum(0), st.counts)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-300, 300), min_size=5, max_size=5), st.lists(st.floats(-300, 300), min_size=5, max_size=5))
def test_limit_rates_keeps_direction_and_both_limits(des, prev):
    params = NCParams.from_machine(M, 1e-3)
    prev = np.clip(np.array(prev), -params.vmax, params.vmax)
    des = np.array(des)
    out = limit_rates(des, prev, params)
    assert np.all(np.abs(out) <= params.vmax * (1 + 1e-12))
    assert np.all(np.abs(out - prev) <= params.amax * params.dt * (1 + 1e-12))
    # the change is parallel to (clamped desired - prev): path direction kept
    s = min(1.0, 1.0 / max(1e-300, np.max(np.abs(des) / params.vmax)))
    d0 = des * s - prev
    d1 = out - prev
    if np.linalg.norm(d0) > 1e-9:
        assert abs(np.dot(d0, d1) - np.linalg.norm(d0) * np.linalg.norm(d1)) <= 1e-9 * np.linalg.norm(d0) ** 2 + 1e-12


def test_vf_residue_accounts_for_every_pulse():
    """Pulses emitted + accumulator residue == integral of the V-F input (nothing lost to rounding)."""
    dt = 1e-3
    params = NCParams.from_machine(M, dt)
    tip, axis = _pose(5, -5, 5, -4, 6)
    st0 = initial_state(M, counts_of(K.ik(tip, axis, M).q, params))
    rng = np.random.default_rng(3)
    targets = [np.concatenate([tip + 0.01 * k * np.array([1.0, 0.5, -0.2]) + 1e-4 * rng.standard_normal(3),
                               axis, [10.0, 5.0, -2.0], np.zeros(3)]) for k in range(300)]
    st, pulses, qd, _ = _run_ticks(params, st0, targets)
    integral = (qd * params.pulses_per_mm * dt).sum(0)
    assert np.allclose(pulses.sum(0) + st.acc, integral, atol=1e-6)


def test_soft_limit_stops_before_the_limit_with_a_reason():
    dt = 1e-3
    params = NCParams.from_machine(M, dt, kv=400.0, max_path_error_mm=1000.0)
    upper = params.upper.copy()
    upper[3] = 10.0                                            # table X soft limit at +10 mm
    params = replace(params, upper=upper)
    tip, axis = _pose(0, 0, 10, 0, 0)
    st0 = initial_state(M, counts_of(K.ik(tip, axis, M).q, params))
    # the table moves -x_tip: drive the tip toward -x so X grows past +10 mm
    tg = np.concatenate([tip + np.array([-30.0, 0, 0]), axis, np.zeros(6)])
    st, pulses, qd, modes = _run_ticks(params, st0, [tg] * 2000)
    assert st.mode == HALTED and st.reason.startswith("soft limit: X")
    assert STOPPING in modes
    assert st.counts[3] / params.pulses_per_mm[3] <= 10.0        # stopped before the limit
    assert st.counts[3] / params.pulses_per_mm[3] > 5.0          # and only near it
    assert np.all(np.abs(np.diff(qd, axis=0)) <= params.amax * dt * (1 + 1e-9))   # a braked stop


def test_following_error_halts_at_once_with_a_reason():
    dt = 1e-3
    params = NCParams.from_machine(M, dt)
    tip, axis = _pose(0, 0, 10, 0, 0)
    st0 = initial_state(M, counts_of(K.ik(tip, axis, M).q, params))
    fb = FB(st0.counts / params.pulses_per_mm)
    fb.enc[1] += 0.05                                          # the L2 motor is 50 um off at rest
    p, st = nc_step(st0, np.concatenate([tip, axis, np.zeros(6)]), fb, params, MODEL)
    assert st.mode == HALTED and st.reason.startswith("following error: L2")
    assert not p.any()


def test_ferror_limit_scales_with_speed():
    """LinuxCNC semantics: limit = max(MIN_FERROR, FERROR * |v| / v_max)."""
    dt = 1e-3
    params = NCParams.from_machine(M, dt, ferror_mm=1.0, min_ferror_mm=0.01)
    tip, axis = _pose(0, 0, 10, 0, 0)
    st0 = initial_state(M, counts_of(K.ik(tip, axis, M).q, params))
    moving = replace(st0, qdot=np.array([0.0, 50.0, 0.0, 0.0, 0.0]))      # L2 at half speed: limit 0.5 mm
    tg = np.concatenate([tip, axis, np.zeros(6)])
    fb = FB(st0.counts / params.pulses_per_mm)
    fb.enc[1] -= 0.4
    _, st = nc_step(moving, tg, fb, params, MODEL)
    assert not st.reason.startswith("following error")
    fb.enc[1] -= 0.2
    _, st = nc_step(moving, tg, fb, params, MODEL)
    assert st.reason.startswith("following error: L2")


def test_lost_model_pose_is_a_fault():
    dt = 1e-3
    params = NCParams.from_machine(M, dt)
    tip, axis = _pose(0, 0, 10, 0, 0)
    st0 = initial_state(M, counts_of(K.ik(tip, axis, M).q, params))
    bad = replace(st0, counts=counts_of([150.0, 570.0, 150.0, 0.0, 0.0], params))
    fb = FB(bad.counts / params.pulses_per_mm)
    p, st = nc_step(bad, np.concatenate([tip, axis, np.zeros(6)]), fb, params, MODEL)
    assert st.mode == HALTED and st.reason.startswith("model pose lost")
    assert not p.any()


def test_orientation_error_ignores_spin_about_the_tool():
    """A target axis equal to the model axis gives no rotation demand whatever the yaw: rates only
    from the position error."""
    dt = 1e-3
    params = NCParams.from_machine(M, dt)
    tip, axis = _pose(2, 3, 8, 6, -4)
    st0 = initial_state(M, counts_of(K.ik(tip, axis, M).q, params))
    fb = FB(st0.counts / params.pulses_per_mm)
    tg = np.concatenate([st0.tip, st0.axis, np.zeros(6)])
    p, st = nc_step(st0, tg, fb, params, MODEL)
    assert not p.any() and st.path_error < 1e-9


def test_damped_pseudo_inverse_is_exact_when_regular_and_bounded_at_a_singularity():
    from pmctl.motion.nc import _damped_pinv_apply
    params = NCParams.from_machine(M, 1e-3)
    tip, axis = _pose(3, -2, 12, 5, 7)
    r = K.ik(tip, axis, M)
    J = MODEL.solve(r.q, r.P, r.R)[4]
    J[3:] *= params.orient_weight_mm
    x = np.array([1.0, -2.0, 0.5, 0.3, -0.1, 0.0])
    # the workspace is far from singular (smallest singular value ~0.25 > threshold 0.05): plain LS
    assert np.linalg.svd(J, compute_uv=False)[-1] > params.sv_threshold
    assert np.allclose(_damped_pinv_apply(J, x, params), np.linalg.lstsq(J, x, rcond=None)[0], atol=1e-12)
    # a rank-deficient Jacobian (two equal columns): undamped LS would need huge opposite rates
    Js = J.copy()
    Js[:, 1] = Js[:, 0] + 1e-9 * Js[:, 1]
    qd = _damped_pinv_apply(Js, x, params)
    assert np.all(np.isfinite(qd)) and np.abs(qd).max() < 100 * np.abs(x).max()


@pytest.mark.parametrize("which", ["enc", "strain"])
def test_a_dead_sensor_halts_with_a_reason(which):
    """A NaN reading compares false against every limit; it must halt, not blind the supervision."""
    dt = 1e-3
    params = NCParams.from_machine(M, dt, k_theta=100.0)
    tip, axis = _pose(0, 0, 10, 0, 0)
    st0 = initial_state(M, counts_of(K.ik(tip, axis, M).q, params))
    fb = FB(st0.counts / params.pulses_per_mm)
    getattr(fb, which)[0] = float("nan")
    p, st = nc_step(st0, np.concatenate([tip + [1.0, 0, 0], axis, np.zeros(6)]), fb, params, MODEL)
    assert st.mode == HALTED and st.reason.startswith("feedback fault")
    assert not p.any() and np.array_equal(st.counts, st0.counts)
