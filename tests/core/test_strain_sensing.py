"""Load at the tool from the three strain gauges, and the strain touch-off (pmctl.core.strain_sensing)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.linalg import null_space

from pmctl.core import statics
from pmctl.core import strain_sensing as SS
from pmctl.core.config import load_machine
from pmctl.core.kinematics import constraint_jacobian, forward_platform, ik
from pmctl.task.planner import home_pose

M = load_machine("prototype")


def _pose(dx=0.0, dy=0.0, dz=-100.0, tilt_deg=0.0, az_deg=0.0):
    tip, _ = home_pose(M)
    t, a = math.radians(tilt_deg), math.radians(az_deg)
    axis = np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)])
    q = ik(np.asarray(tip, float) + [dx, dy, dz], axis, M).q
    return forward_platform(q[:3], M.geometry)


@settings(max_examples=40, deadline=None)
@given(dx=st.floats(-20, 20), dy=st.floats(-20, 20), dz=st.floats(-110, -20), tilt=st.floats(0, 12),
       az=st.floats(0, 360), f=st.lists(st.floats(-500, 500), min_size=3, max_size=3))
def test_tip_load_inverts_the_statics_exactly(dx, dy, dz, tilt, az, f):
    P, R = _pose(dx, dy, dz, tilt, az)
    strain = statics.static_strain(P, R, M, tip_force=f)          # what the gauges read (with gravity)
    est = SS.tip_load(strain, P, R, M)
    np.testing.assert_allclose(est, f, atol=1e-7 * (1 + np.abs(f).max()))


def test_tip_load_batch_and_without_gravity():
    P, R = _pose()
    fs = np.array([[0, 0, 100.0], [50, 0, 0], [0, -80, 10]])
    Pb, Rb = np.broadcast_to(P, (3, 3)), np.broadcast_to(R, (3, 3, 3))
    s = statics.static_strain(Pb, Rb, M, tip_force=fs) - statics.static_strain(Pb, Rb, M)
    np.testing.assert_allclose(SS.tip_load(s, Pb, Rb, M, gravity=False), fs, atol=1e-8)


def test_a_moment_at_the_tool_is_not_observable():
    """Three gauges, six wrench components: a wrench with a couple exists that the gauges do not see
    at all (and the load estimate reports zero force for it)."""
    P, R = _pose(tilt_deg=5.0)
    A = constraint_jacobian(P, R, M.geometry)
    # axial forces of an external wrench w (about P): [a; b] = -A^-T w; gauges see the a rows
    amap = -np.linalg.inv(A.T)[:3]
    N = null_space(amap)                      # wrenches that leave every gauge unchanged
    assert N.shape[1] == 3
    # one of them has a moment about the tool axis (spindle torque) with no force
    axis = R[:, 2]
    torque = np.r_[np.zeros(3), 1000.0 * axis]        # 1 N·m about the tool axis
    da = amap @ torque
    # the couple does change the gauges unless it lies in the null space: it is then mistaken for a
    # tip force -- the estimate is not the (zero) force actually applied
    s = statics.strain_of_axial(da, M)
    est = SS.tip_load(s, P, R, M, gravity=False)
    if np.abs(da).max() > 1e-9:
        assert np.linalg.norm(est) > 1e-3
    null_w = N[:, 0]
    assert np.abs(amap @ null_w).max() < 1e-9 and np.linalg.norm(null_w[3:]) > 0


def test_touch_off_repeatability_and_bounded_overtravel():
    P, R = _pose()
    dt, v, dec, kc, thr, noise_ue = 1e-3, 2.0, 500.0, 2000.0, 5.0, 0.05
    share = float(np.abs(SS.chain_share(P, R, M, [0, 0, -1])).max())
    noise_N = noise_ue / M.strain_gain
    bound = SS.overtravel_bound(v, dec, dt, thr, kc, debounce=2, latency_ticks=1, noise_N=noise_N, share=share)
    rng = np.random.default_rng(7)
    errs, overs = [], []
    for i in range(25):
        z0 = 0.5 + rng.uniform(0.0, v * dt)         # contact at a random phase of the tick
        r = SS.simulate_probe(P, R, M, start=[0, 0, 0], direction=[0, 0, -1], surface_mm=z0, speed_mm_s=v,
                              decel_mm_s2=dec, dt=dt, contact_stiffness_N_per_mm=kc, threshold_N=thr,
                              noise_ue=noise_ue, rng=rng)
        assert r.detected
        errs.append(-r.contact[2] - z0)
        overs.append(r.overtravel_mm)
    errs, overs = np.array(errs), np.array(overs)
    assert np.all(overs > 0) and np.all(overs <= bound)
    # contact point: within a few micrometres, repeatable to ~1 um (v dt = 2 um per tick)
    assert np.abs(errs).max() < 5e-3
    assert errs.std() < 1.5e-3


def test_no_contact_no_detection_and_bad_threshold():
    P, R = _pose()
    r = SS.simulate_probe(P, R, M, start=[0, 0, 0], direction=[0, 0, -1], surface_mm=100.0, speed_mm_s=2.0,
                          decel_mm_s2=500.0, dt=1e-3, contact_stiffness_N_per_mm=2000.0, threshold_N=5.0,
                          noise_ue=0.05, max_ticks=2000)
    assert not r.detected
    with pytest.raises(ValueError):
        SS.detect_contact(np.zeros((5, 3)), 0.0)


def test_tip_load_of_joints_batch_with_gravity_and_nan_rows():
    """The recording sinks' form: joints in, load out, gravity off, NaN where the inputs are NaN."""
    rng = np.random.default_rng(5)
    tip, axis = home_pose(M)
    qs, fs, ss = [], [], []
    for _ in range(6):
        q = ik(np.asarray(tip, float) + [rng.uniform(-10, 10), rng.uniform(-10, 10), rng.uniform(-60, -10)],
               axis, M).q
        P, R = forward_platform(q[:3], M.geometry)
        f = rng.uniform(-200, 200, 3)
        qs.append(q)
        fs.append(f)
        ss.append(statics.static_strain(P, R, M, tip_force=f))
    qs, fs, ss = np.array(qs), np.array(fs), np.array(ss)
    qs[2] = np.nan
    ss[4, 1] = np.nan
    est = SS.tip_load_of_joints(ss, qs, M)
    bad = np.zeros(6, bool)
    bad[[2, 4]] = True
    assert np.all(np.isnan(est[bad]))
    np.testing.assert_allclose(est[~bad], fs[~bad], atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(c=st.floats(-3.0, 20.0), slope=st.floats(0.5, 20.0), window=st.integers(1, 12),
       signs=st.lists(st.sampled_from([-1.0, 1.0]), min_size=3, max_size=3))
def test_contact_onset_recovers_the_ramp_start_through_the_moving_average(c, slope, window, signs):
    n = 32
    k = np.arange(-window + 1, n)
    raw = np.maximum(0.0, k - c)[:, None] * slope * np.array(signs) * np.array([1.0, 0.6, 0.3])
    filt = np.stack([np.convolve(raw[:, i], np.ones(window) / window, mode="valid") for i in range(3)], -1)
    assert filt.shape == (n, 3)
    assert SS.contact_onset(filt, window) == pytest.approx(c, abs=0.03)
