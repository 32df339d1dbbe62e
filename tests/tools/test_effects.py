"""Physical facts of the effect models and the locate helpers (pmctl.tools.twin.effects / locate)."""

import dataclasses
import math

import numpy as np
from hypothesis import given, settings, strategies as st

from pmctl.core import kinematics as kin
from pmctl.core.config import load_machine
from pmctl.tools.twin import effects as fx
from pmctl.tools.twin.signals import noise_level, spectrum_position

M = load_machine()


@settings(max_examples=40, deadline=None)
@given(st.floats(0.001, 0.1), st.integers(0, 10_000))
def test_play_error_stays_within_the_deadband_and_flips_with_direction(width, seed):
    rng = np.random.default_rng(seed)
    x = np.cumsum(rng.normal(0, 0.05, 400)) + np.repeat(rng.normal(0, 2, 8), 50)
    e = fx.play_error(x, width)
    assert np.all(np.abs(e) <= width / 2 + 1e-12)
    # after a long enough monotone move the load trails by exactly half the width
    ramp = np.concatenate([np.linspace(0, 1, 50), np.linspace(1, 0, 50)])
    er = fx.play_error(ramp, width)
    assert math.isclose(er[49], -width / 2, abs_tol=1e-12)
    assert math.isclose(er[-1], width / 2, abs_tol=1e-12)


def test_play_error_matches_the_sample_by_sample_operator():
    rng = np.random.default_rng(3)
    x = np.cumsum(rng.normal(0, 0.01, 2000))
    w = 0.03
    xl, ref = x[0], []
    for xk in x:
        xl = min(max(xl, xk - w / 2), xk + w / 2)
        ref.append(xl - xk)
    assert np.allclose(fx.play_error(x, w), ref, atol=1e-12)


def test_first_order_lag_trails_a_ramp_by_tau_times_speed():
    t = np.arange(0, 2, 1e-3)
    u = 30.0 * t                      # 30 mm/s
    y = fx.first_order_lag(t, u, 0.01)
    assert abs((u - y)[-1] - 0.3) < 1e-3


def test_resonance_response_rings_at_its_frequency():
    dt = 1e-3
    t = np.arange(0, 4, dt)
    x = np.where(t > 0.5, 10.0 * (t - 0.5) ** 2, 0.0)          # a step in acceleration
    x = np.where(t > 1.0, x[int(1.0 / dt)] + 10.0 * (t - 1.0), x)
    h = fx.resonance_response(x, dt, 12.0, 0.02)
    seg = h[int(1.05 / dt):int(3 / dt)]
    f = np.fft.rfftfreq(len(seg), dt)
    assert abs(f[np.argmax(np.abs(np.fft.rfft(seg - seg.mean())))] - 12.0) < 0.6


def _pose(z=400.0, t1=0.7, t2=0.12):
    P, R = kin.platform_pose(z, t1, t2, M.geometry.platform_radius)
    return P, R


def _tool(geom, L, table):
    sol = kin.solve_platform(L, geom)
    tip, ax = kin.tool_of_platform(sol.P, sol.R, table, geom)
    return np.concatenate([tip, ax])


def test_geometry_sensitivity_matches_finite_differences_of_fk():
    geom = M.geometry
    P, R = _pose()
    L = kin.chain_lengths(P, R, geom)
    table = np.array([5.0, -3.0])
    base = _tool(geom, L, table)
    S = fx.geometry_sensitivity(P, R, geom)
    h = 1e-4
    A = geom.base_joints.copy()
    e1 = A[1] / np.linalg.norm(A[1][:2]) * np.array([1, 1, 0])
    A[1] = A[1] + h * e1
    cases = {
        ("chain1:length_offset", 0): dataclasses.replace(geom, length_offsets=np.array([h, 0, 0]), nominal=False),
        ("chain2:base_joint", 0): dataclasses.replace(geom, base_joints=A, nominal=False),
        ("tool:length", 0): dataclasses.replace(geom, tool_length=geom.tool_length + h),
        ("tool:tilt", 1): dataclasses.replace(geom, tool_tilt_deg=(0.0, 1e-3), nominal=False),
    }
    for (grp, k), g2 in cases.items():
        step = 1e-3 if grp == "tool:tilt" else h
        fd = (_tool(g2, L, table) - base) / step
        assert np.allclose(S[grp][:, k], fd, atol=2e-4 * max(1, np.abs(fd).max())), grp
    C = geom.platform_joints.copy()
    C[2, 2] += h
    g2 = dataclasses.replace(geom, platform_joints=C, nominal=False)
    fd = (_tool(g2, L, table) - base) / h
    assert np.allclose(S["chain3:platform_joint"][:, 2], fd, atol=1e-4)


def test_noise_level_ignores_slow_signal_and_outliers():
    rng = np.random.default_rng(0)
    t = np.linspace(0, 10, 20000)
    x = 0.05 * np.sin(0.5 * t) + rng.normal(0, 0.002, t.size)
    x[::500] += 0.1
    assert abs(noise_level(x) / 0.002 - 1) < 0.05


def test_pitch_line_shows_at_the_inverse_period_in_the_screw_spectrum():
    x = np.linspace(100, 300, 40000)
    e = 0.01 * np.sin(2 * np.pi * x / 5.0)
    f, amp = spectrum_position(x, e, np.ones(x.size, bool))
    assert abs(f[np.argmax(amp)] - 0.2) < 0.01
    assert abs(amp.max() - 0.01) < 0.002
