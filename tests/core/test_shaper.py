"""Input shapers (pmctl.core.shaper): residual vibration of a single-mode oscillator driven by the
shaped move against the analytic curve, amplitudes, and time-law shaping keeping the path."""

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.linalg import expm

from pmctl.core import shaper as S


def _move_accel(v=50.0, a=1500.0, dist=10.0):
    """Acceleration of a trapezoidal move as (switch times, accelerations on each interval)."""
    ta = v / a
    tc = dist / v - ta
    return np.array([0.0, ta, ta + tc, 2 * ta + tc]), np.array([a, 0.0, -a])


def residual_amplitude(f_hz, zeta, sh=None, v=50.0, a=1500.0, dist=10.0):
    """Exact response of y'' + 2 zeta w y' + w^2 y = -u'' (base-excited mode) to the move u, shaped by
    ``sh`` (sum of delayed copies), integrated piecewise exactly (constant u'' per interval); returns
    the free-vibration amplitude at the end of the shaped move (the last impulse's copy ends t_n late)."""
    sw, acc = _move_accel(v, a, dist)
    A, T = (np.array([1.0]), np.array([0.0])) if sh is None else (sh.A, sh.T)
    w = 2 * math.pi * f_hz
    breaks = np.unique(np.concatenate([sw[None, :] + T[:, None]]).ravel())
    M = np.array([[0.0, 1.0], [-w * w, -2 * zeta * w]])
    x = np.zeros(2)
    for t0, t1 in zip(breaks[:-1], breaks[1:]):
        tm = 0.5 * (t0 + t1)
        u2 = sum(Ai * acc[np.searchsorted(sw, tm - Ti) - 1] if sw[0] <= tm - Ti < sw[-1] else 0.0
                 for Ai, Ti in zip(A, T))
        yp = -u2 / (w * w)                  # particular solution (constant forcing)
        E = expm(M * (t1 - t0))
        x = E @ (x - [yp, 0.0]) + [yp, 0.0]
    wd = w * math.sqrt(1 - zeta ** 2)
    y, yd = x
    amp = math.hypot(y, (yd + zeta * w * y) / wd)
    return amp


@pytest.mark.parametrize("name", S.SHAPERS)
def test_amplitudes_sum_to_one_and_times_start_at_zero(name):
    for z in (0.0, 0.02, 0.1, 0.3):
        sh = S.make_shaper(name, 40.0, z)
        assert abs(sh.A.sum() - 1.0) < 1e-12
        assert np.all(sh.A > 0) and sh.T[0] == 0.0 and np.all(np.diff(sh.T) > 0)


@pytest.mark.parametrize("name", S.SHAPERS)
@pytest.mark.parametrize("ratio", [0.8, 1.0, 1.2])
def test_residual_matches_analytic_curve(name, ratio):
    """Oscillator at f = ratio x design frequency, damping 2 %, driven by the shaped move."""
    f0, z = 40.0, 0.02
    sh = S.make_shaper(name, f0, z)
    f = ratio * f0
    # V compares the shaped move's vibration when it ends with the unshaped move's when it ends
    ref = residual_amplitude(f, z)
    got = residual_amplitude(f, z, sh) / ref
    want = float(S.residual_vibration(sh, f, z))
    assert got == pytest.approx(want, rel=1e-6, abs=1e-9)
    if ratio == 1.0:
        assert got < 1e-6 if name in ("ZV", "ZVD", "MZV") else got <= S.EI_TOLERANCE * 1.05


def test_known_values_of_the_curves():
    # undamped ZV at +-20 %: |cos(pi/2 * 1.2)| = 0.309; ZVD: its square; EI: 5 % at the design frequency
    zv = S.make_shaper("ZV", 50.0, 0.0)
    assert float(S.residual_vibration(zv, 60.0, 0.0)) == pytest.approx(abs(math.cos(math.pi * 0.6)), rel=1e-12)
    zvd = S.make_shaper("ZVD", 50.0, 0.0)
    assert float(S.residual_vibration(zvd, 40.0, 0.0)) == pytest.approx(math.cos(math.pi * 0.4) ** 2, rel=1e-12)
    ei = S.make_shaper("EI", 50.0, 0.0)
    assert float(S.residual_vibration(ei, 50.0, 0.0)) == pytest.approx(S.EI_TOLERANCE, rel=1e-9)
    # more robust shapers: less vibration 20 % off, longer duration
    v = [float(S.residual_vibration(S.make_shaper(n, 50.0, 0.0), 60.0, 0.0)) for n in ("ZV", "ZVD", "2HUMP_EI", "3HUMP_EI")]
    assert v[0] > v[1] > v[2] > v[3]


@settings(max_examples=30, deadline=None)
@given(name=st.sampled_from(S.SHAPERS), f=st.floats(5.0, 300.0), mode=st.sampled_from(["stop", "through"]),
       vel=st.floats(5.0, 100.0))
def test_time_law_keeps_every_sample_on_the_path(name, f, mode, vel):
    dt = 1e-3
    tip, axis = S.corner_trajectory(vel, 2000.0, 6.0, dt, stop=(mode == "stop"))
    sh = S.make_shaper(name, f, 0.05)
    p, a = S.shape_time_law(tip, axis, dt, sh)
    corner = np.array([[-6.0, 0, 0], [0, 0, 0], [0, 6.0, 0]])
    assert S.path_error(p, corner).max() <= 1e-9
    np.testing.assert_allclose(p[0], tip[0], atol=1e-12)
    np.testing.assert_allclose(p[-1], tip[-1], atol=1e-12)
    pieces = 1 + len(S.corner_samples(tip, axis))
    assert len(p) == len(tip) + pieces * math.ceil(sh.duration / dt - 1e-9)
    # the clock never runs backwards: the tool never reverses along the path
    sig = S.shaped_clock(tip, axis, dt, sh)
    assert np.all(np.diff(sig) >= -1e-12)


def test_cartesian_shaping_cuts_the_corner_time_law_does_not():
    dt = 1e-4
    sh = S.make_shaper("ZVD", 40.0, 0.05)
    tip, axis = S.corner_trajectory(50.0, 2000.0, 5.0, dt, stop=False)
    corner = np.array([[-5.0, 0, 0], [0, 0, 0], [0, 5.0, 0]])
    pc, _ = S.shape_cartesian(tip, axis, dt, sh)
    pt, _ = S.shape_time_law(tip, axis, dt, sh)
    ec, et = S.path_error(pc, corner).max(), S.path_error(pt, corner).max()
    # constant-speed corner, symmetric shaper: the cut is the average of the legs' offsets,
    # v * sum A_i |t_i - t_mean| / 2 at most; ZVD at 40 Hz, 50 mm/s cuts ~0.1 mm
    assert 0.05 < ec < 50.0 * sh.duration
    assert et <= 1e-9
    assert S.smoothing_mm(sh, 50.0) == pytest.approx(ec, rel=0.02)


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="unknown shaper"):
        S.make_shaper("XYZ", 40.0)
    with pytest.raises(ValueError, match="frequency"):
        S.make_shaper("ZV", 0.0)
    with pytest.raises(ValueError, match="damping"):
        S.make_shaper("ZV", 40.0, 1.0)


@pytest.mark.parametrize("name", S.SHAPERS)
def test_time_law_at_a_stop_corner_keeps_the_acceleration_bounded(name):
    """Shaped piece by piece, the tool still stops at the corner: the tip acceleration stays within
    the original trajectory's (a convex combination of its accelerations); one clock shaped across
    the corner would carry the tool through it at speed (a jump of velocity)."""
    dt = 1e-3
    tip, axis = S.corner_trajectory(50.0, 2000.0, 5.0, dt, stop=True)
    sh = S.make_shaper(name, 40.0, 0.02)
    acc0 = np.abs(np.diff(tip, 2, axis=0)).max() / dt ** 2
    p, _ = S.shape_time_law(tip, axis, dt, sh)
    acc = np.abs(np.diff(p, 2, axis=0)).max() / dt ** 2
    assert acc <= acc0 * (1 + 1e-9)
    p1, _ = S.shape_time_law(tip, axis, dt, sh, split_at_corners=False)
    assert np.abs(np.diff(p1, 2, axis=0)).max() / dt ** 2 > 2 * acc0
    # still on the path, and the corner point itself is a sample
    corner = np.array([[-5.0, 0, 0], [0, 0, 0], [0, 5.0, 0]])
    assert S.path_error(p, corner).max() <= 1e-9
    assert np.min(np.linalg.norm(p, axis=1)) == 0.0


def test_moving_average_leaves_no_vibration_at_the_mode_and_its_harmonics():
    """MA: a damped period's taps; zero residual at f, 2 f, .. (MA_TAPS - 1) f for its damping, and the
    undamped sinc between: sin(pi r) / (n sin(pi r / n)) at r = f / f0."""
    for z in (0.0, 0.02, 0.1):
        sh = S.make_shaper("MA", 40.0, z)
        assert len(sh.A) == S.MA_TAPS and sh.duration == pytest.approx((1 - 1 / S.MA_TAPS) / (40.0 * math.sqrt(1 - z * z)))
        for k in (1, 2, 5):
            fk = 40.0 * k if z == 0.0 else 40.0
            assert float(S.residual_vibration(sh, fk, z)) < 1e-12
    sh = S.make_shaper("MA", 40.0, 0.0)
    n = S.MA_TAPS
    for r in (0.5, 0.8, 1.2, 1.5):
        want = abs(math.sin(math.pi * r) / (n * math.sin(math.pi * r / n)))
        assert float(S.residual_vibration(sh, 40.0 * r, 0.0)) == pytest.approx(want, rel=1e-9)


def test_combination_is_the_product_of_the_curves_and_the_sum_of_the_durations():
    zv, ma, both = (S.make_shaper(n, 40.0, 0.02) for n in ("ZV", "MA", "zv*ma"))
    assert both.name == "ZV*MA" and both.duration == pytest.approx(zv.duration + ma.duration)
    f = np.linspace(20.0, 80.0, 61)
    np.testing.assert_allclose(S.residual_vibration(both, f, 0.02),
                               S.residual_vibration(zv, f, 0.02) * S.residual_vibration(ma, f, 0.02), rtol=1e-9,
                               atol=1e-12)
    with pytest.raises(ValueError, match="joined by"):
        S.make_shaper("ZV*XX", 40.0)


def test_a_shaped_velocity_step_ramps_over_the_period():
    """A piece of the path that starts at speed v (the planner's corner speed) is shaped from rest:
    with the impulse shaper alone the velocity jumps by A_0 v in one tick; with MA it rises over a
    period, at A_0 v dt f a tick on average (at most 2.5 times that: taps 0.78 ms apart fall two
    into some ticks), a tenth of the step or less."""
    dt, v, f = 1e-3, 2.0, 40.0
    tip = np.c_[np.arange(400) * v * dt, np.zeros(400), np.zeros(400)]
    axis = np.tile([0.0, 0.0, 1.0], (400, 1))
    jumps = {}
    for name in ("ZV", "ZV*MA"):
        sh = S.make_shaper(name, f, 0.02)
        p = S.path_at_index(tip, axis, S.shaped_clock(tip, axis, dt, sh))[0]
        jumps[name] = np.abs(np.diff(np.diff(p[:, 0]) / dt)).max()
    a0 = S.make_shaper("ZV", f, 0.02).A[0]
    assert jumps["ZV"] == pytest.approx(a0 * v, rel=1e-6)
    assert jumps["ZV*MA"] <= 2.5 * a0 * v * dt * f and jumps["ZV*MA"] <= 0.1 * jumps["ZV"]


def test_auto_takes_the_moving_average_with_the_shortest_impulse_shaper_that_covers_the_drift():
    cands = S.candidates()
    assert cands[0] == "MA" and all(c == "MA" or c.endswith("*MA") for c in cands)
    d = [S.make_shaper(c, 40.0, 0.02).duration for c in cands]
    assert d == sorted(d)
    for drift, zeta in ((0.1, 0.02), (0.2, 0.02), (0.1, 0.2)):
        name = S.recommend(40.0, zeta, drift)
        band = np.linspace(1 - drift, 1 + drift, 81) * 40.0
        worst = lambda n: float(np.max(S.residual_vibration(S.make_shaper(n, 40.0, zeta), band, zeta)))  # noqa: E731
        assert worst(name) <= S.AUTO_REMAINING
        assert all(worst(c) > S.AUTO_REMAINING for c in cands[:cands.index(name)])
    assert S.recommend(40.0, 0.02) == "ZV*MA"
