"""The effect catalogue's forward physics (pmctl.core.plant_effects): per tick and batch agree,
and each effect has its physical signature."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pmctl.core import plant_effects as PE

TOL = 1e-12


@st.composite
def paths(draw, n_max=300, axes=5):
    """Random motor-side paths: steps, holds and reversals, a few hundred mm from zero."""
    n = draw(st.integers(2, n_max))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    steps = rng.normal(0, 0.05, (n, axes)) * (rng.random((n, axes)) < 0.8)
    x0 = rng.uniform(-400, 400, axes)
    return x0 + np.cumsum(steps, axis=0)


def _ticks(obj, x):
    return np.array([obj.step(row) for row in x[1:]])


@settings(max_examples=60, deadline=None)
@given(paths(), st.floats(0.0, 0.1), st.floats(-1, 1))
def test_play_per_tick_equals_batch(x, width, start):
    p = PE.Play(width, x[0], start)
    e0 = p.error
    ticks = np.vstack([e0, _ticks(p, x)])
    batch = np.stack([PE.play_error(x[:, j], width, start) for j in range(x.shape[1])], 1)
    assert np.max(np.abs(ticks - batch)) <= TOL
    assert np.all(np.abs(batch) <= width / 2 + TOL)            # the load never leaves the deadband


def test_play_flips_by_the_width_at_a_reversal():
    x = np.concatenate([np.linspace(0, 1, 50), np.linspace(1, 0, 50)])
    y = PE.play(x, 0.02)
    assert y[49] == pytest.approx(1 - 0.01) and y[-1] == pytest.approx(0.01)   # trails by w/2 each way


@settings(max_examples=40, deadline=None)
@given(paths(), st.floats(1e-4, 0.05), st.floats(0.5, 20), st.floats(0, 2 * math.pi))
def test_periodic_error_is_one_function_for_ticks_and_arrays(x, amp, period, phase):
    batch = PE.periodic_error(x, amp, period, phase)
    ticks = np.array([PE.periodic_error(row, amp, period, phase) for row in x])
    assert np.max(np.abs(batch - ticks)) <= TOL
    assert np.allclose(PE.periodic_error(x + period, amp, period, phase), batch, atol=1e-9)   # one period on: the same


def test_thermal_growth_is_zero_at_the_fixed_bearing_and_linear_in_distance():
    s = np.array([150.0, 250.0, 350.0])
    g = PE.thermal_growth(s, 12e-6, 5.0, 150.0)
    assert g[0] == 0.0 and g[2] == pytest.approx(2 * g[1]) and g[1] == pytest.approx(12e-6 * 5 * 100)


@settings(max_examples=60, deadline=None)
@given(paths(), st.floats(0.0, 0.03), st.floats(0.0, 0.03), st.floats(0.5, 10))
def test_friction_per_tick_equals_batch(x, c, cs, vs):
    dt = 1e-3
    f = PE.Friction(x[0], dt, c, cs, vs)
    ticks = np.vstack([np.zeros(x.shape[1]), _ticks(f, x)])
    batch = PE.friction_offset(x, dt, c, cs, vs)
    assert np.max(np.abs(ticks - batch)) <= TOL
    d = PE.direction(x)
    assert np.all(batch * d <= 0) and np.all(batch[d == 0] == 0)   # against the motion; none before it


@settings(max_examples=60, deadline=None)
@given(paths(), st.floats(0.0, 0.05))
def test_servo_lag_per_tick_equals_batch(x, tau):
    dt = 1e-3
    lag = PE.FirstOrderLag(tau, dt, x[0])
    ticks = np.vstack([x[0], _ticks(lag, x)])
    t = np.arange(len(x)) * dt
    batch = np.stack([PE.first_order_lag(t, x[:, j], tau) for j in range(x.shape[1])], 1)
    assert np.max(np.abs(ticks - batch)) <= TOL


def test_servo_lag_trails_a_ramp_by_tau_times_speed_at_any_rate():
    for dt in (1e-3, 4e-3):
        t = np.arange(int(0.5 / dt)) * dt
        y = PE.first_order_lag(t, 30.0 * t, 0.02)
        assert 30.0 * t[-1] - y[-1] == pytest.approx(30.0 * 0.02, rel=1e-9)


@settings(max_examples=40, deadline=None)
@given(paths(n_max=200, axes=3), st.floats(2, 80), st.floats(0.0, 0.3))
def test_mode_per_tick_equals_batch(x, f, zeta):
    dt = 1e-3
    m = PE.Mode(f, zeta, dt, x[0])
    ticks = np.vstack([np.zeros(3), _ticks(m, x)])
    batch = np.stack([PE.mode_response(x[:, j], dt, f, zeta) for j in range(3)], 1)
    assert np.max(np.abs(ticks - batch)) <= TOL * max(1.0, np.max(np.abs(batch)))


def test_mode_rings_at_its_frequency_after_a_velocity_step():
    dt, f = 1e-3, 20.0
    x = np.arange(2000) * 0.05                                  # from rest to 50 mm/s at once
    y = PE.mode_response(x, dt, f, 0.0)
    zc = np.flatnonzero(np.diff(np.sign(y)) != 0)
    period = 2 * np.mean(np.diff(zc)) * dt
    assert period == pytest.approx(1 / f, rel=1e-3)
    assert np.max(np.abs(y)) == pytest.approx(50.0 / (2 * math.pi * f), rel=1e-2)   # v/ω after the jump


def test_lost_steps_offset_from_its_time_on():
    t = np.arange(10) * 0.1
    assert np.array_equal(PE.step_offset(t, 0.45, 0.03), np.where(t >= 0.45, 0.03, 0.0))
