"""The software V-F converter (pmctl.core.vf, seed 004 2.2): conservation, saturation, symmetry."""

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pmctl.core import vf

finite = dict(allow_nan=False, allow_infinity=False)


@st.composite
def unsaturated_run(draw):
    """A bank of converters, a threshold, a pulse cap n and inputs with |u·dt| ≤ n·threshold, so the
    converter never has to drop input (|acc| < threshold after every sample)."""
    n_axes = draw(st.integers(1, 5))
    n_steps = draw(st.integers(1, 200))
    threshold = draw(st.floats(1e-3, 1e3, **finite))
    n_max = draw(st.sampled_from([1, 2, 7, 200]))
    dt = draw(st.sampled_from([1.0, 1e-3, 0.002, 5e-4]))
    frac = draw(st.lists(st.floats(-1.0, 1.0, **finite), min_size=n_steps * n_axes,
                         max_size=n_steps * n_axes))
    u = np.array(frac).reshape(n_steps, n_axes) * n_max * threshold / dt
    return u, dt, threshold, n_max


@settings(max_examples=150, deadline=None)
@given(unsaturated_run())
def test_pulses_plus_residue_equal_the_integral(run):
    u, dt, threshold, n_max = run
    acc = np.zeros(u.shape[1])
    total = np.zeros(u.shape[1], np.int64)
    for row in u:
        p, acc = vf.vf_step(acc, row, dt, threshold, n_max)
        assert p.dtype == np.int64
        assert np.all(np.abs(p) <= n_max)
        # the residue stays within one pulse (equal only where the pulse count is clamped to n_max
        # and rounding puts the accumulator exactly on the threshold)
        assert np.all(np.abs(acc) <= threshold)
        total += p
    integral = (u * dt).sum(axis=0)
    scale = np.abs(u * dt).sum(axis=0) + threshold
    np.testing.assert_allclose(total * threshold + acc, integral, rtol=0, atol=1e-12 * scale.max())


@settings(max_examples=60, deadline=None)
@given(st.floats(1e-3, 1e3, **finite), st.sampled_from([1, 3, 200]), st.floats(1.0, 50.0, **finite),
       st.integers(1, 30), st.sampled_from([1.0, 0.001]))
def test_saturation_caps_pulses_and_does_not_wind_up(threshold, n_max, overdrive, n_ticks, dt):
    u = overdrive * (n_max + 1) * threshold / dt          # more than n_max pulses' worth per tick
    acc = np.zeros(2)
    for _ in range(n_ticks):
        p, acc = vf.vf_step(acc, np.array([u, -u]), dt, threshold, n_max)
        assert p.tolist() == [n_max, -n_max]             # exactly the cap, with the input's sign
        assert np.all(np.abs(acc) <= threshold)
    # input stops: the clamped accumulator releases at most one more pulse, never the excess
    extra = np.zeros(2, np.int64)
    for _ in range(5):
        p, acc = vf.vf_step(acc, np.zeros(2), dt, threshold, n_max)
        extra += p
    assert np.all(np.abs(extra) <= 1)


def test_seed_one_pulse_mode_emits_one_pulse_per_sample_at_the_threshold():
    # seed 2.3.2: threshold = the largest input, which then fires every sample (max rate = F)
    acc = 0.0
    pulses = []
    for _ in range(50):
        p, acc = vf.vf_step(acc, 1.0, 1.0, threshold=1.0, max_pulses_per_tick=1)
        pulses.append(int(p))
    assert pulses == [1] * 50
    # half the threshold: one pulse every other sample
    acc, pulses = 0.0, []
    for _ in range(50):
        p, acc = vf.vf_step(acc, 0.5, 1.0, 1.0, 1)
        pulses.append(int(p))
    assert sum(pulses) == 25 and pulses[1::2] == [1] * 25


@settings(max_examples=100, deadline=None)
@given(st.floats(-0.999, 0.999, **finite), st.floats(-10, 10, **finite), st.floats(1e-2, 10, **finite),
       st.sampled_from([1, 4]))
def test_converter_is_odd_symmetric(acc_frac, u, threshold, n_max):
    acc = acc_frac * threshold
    p1, a1 = vf.vf_step(acc, u, 1.0, threshold, n_max)
    p2, a2 = vf.vf_step(-acc, -u, 1.0, threshold, n_max)
    assert int(p1) == -int(p2)
    assert float(a1) == -float(a2)


@settings(max_examples=50, deadline=None)
@given(st.integers(1, 1000), st.floats(1e-3, 1e3, **finite))
def test_vf_min_amplitude_is_eq_2_2(k, sd):
    assert math.isclose(float(vf.vf_min_amplitude(sd, 1.0 / (2 * k))), sd * math.sin(math.pi / (2 * k)),
                        rel_tol=1e-12)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(-5e5, 5e5), min_size=1, max_size=6), st.integers(1, 300),
       st.floats(1e-4, 1e-2), st.floats(0.1, 10.0), st.integers(0, 2**31))
def test_per_tick_form_equals_the_batch_form(u, n_max, dt, threshold, seed):
    """vf_tick (the loop's plain-float form) gives the same pulses and residue as vf_step."""
    rng = np.random.default_rng(seed)
    acc = rng.uniform(-threshold, threshold, len(u))
    p1, a1 = vf.vf_step(acc, np.array(u), dt, threshold, n_max)
    p2, a2 = vf.vf_tick(acc.tolist(), u, dt, threshold, n_max)
    assert p1.tolist() == p2 and a1.tolist() == a2


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_whole_pulse_missed_by_rounding_is_reached_and_a_real_shortfall_is_not(sign):
    """The tie margin (vf.TIE = 1e-9 of the threshold): an accumulator a few units in the last place
    short of a whole pulse (how two ways of computing the same rate sum end) sends it, with the
    shortfall kept as a residue; one 2e-9 short does not. Both forms agree."""
    for a0, want in ((1.0 - 1e-15, 1), (1.0 - 5e-10, 1), (1.0 - 2e-9, 0), (2.0 - 3e-16, 2), (0.5, 0)):
        p1, r1 = vf.vf_step(np.array([sign * a0]), np.zeros(1), 1e-3, 1.0, 3)
        p2, r2 = vf.vf_tick([sign * a0], [0.0], 1e-3, 1.0, 3)
        assert int(p1[0]) == p2[0] == sign * want, a0
        assert r1[0] == r2[0] == sign * a0 - p2[0]             # pulses + residue = the integral


def test_the_defaults_are_the_seeds_converter():
    """Called without a threshold and a pulse cap, both forms are the seed's converter: threshold 1,
    at most one pulse per sample (the excess beyond one threshold dropped)."""
    p, a = vf.vf_step(np.zeros(2), np.array([1.5, 2.5]), 1.0)
    assert p.tolist() == [1, 1] and a.tolist() == [0.5, 1.0]
    p2, a2 = vf.vf_tick([0.0, 0.0], [1.5, 2.5], 1.0)
    assert p2 == [1, 1] and a2 == [0.5, 1.0]


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0, width=32, **finite), min_size=3, max_size=3), st.integers(20, 200),
       st.sampled_from([1e-3, 5e-4]), st.floats(0.1, 10.0, **finite))
def test_single_precision_rates_are_integrated_in_double(frac, n_ticks, dt, threshold):
    """Rates held in float32 (a recorder's samples) are integrated as the doubles they stand for: the
    pulses plus the residue equal the integral of those values to double precision, and every tick's
    pulses and residue are those of the same rates given as float64. (Integrated in single precision,
    each tick's u*dt would be rounded to 24 bits: a drift of 1e-8 of the travel.)"""
    u32 = (np.array(frac, np.float32) * np.float32(0.9 * threshold / dt)).astype(np.float32)
    u64 = u32.astype(np.float64)
    acc32, acc64 = np.zeros(3), np.zeros(3)
    total = np.zeros(3, np.int64)
    for _ in range(n_ticks):
        p32, acc32 = vf.vf_step(acc32, u32, dt, threshold, 1)
        p64, acc64 = vf.vf_step(acc64, u64, dt, threshold, 1)
        assert p32.tolist() == p64.tolist() and acc32.tolist() == acc64.tolist()
        total += p32
    integral = u64 * dt * n_ticks
    np.testing.assert_allclose(total * threshold + acc32, integral, rtol=0,
                               atol=1e-12 * (np.abs(integral).max() + threshold))
