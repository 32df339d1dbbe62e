"""The sampled strain-feedback loop and the K_theta design (pmctl.core.strain_loop): the margins say
what the poles do, the design keeps its promises over the mode's error box, the closed loop of the
real NC and sim shows the damping the design asks for, and the stretch low-pass errs by its share."""

import math

import numpy as np
import pytest

from pmctl.core import strain_loop as SL

KV, DT, ZETA = 400.0, 1e-3, 0.02


def _delayed_poles(f, zeta, kth, kv, dt, leak, extra):
    """Closed-loop poles with ``extra`` more ticks of delay on the strain reading (a FIFO of the
    deflection between the plant's output and the feedback's input)."""
    A, B, C = SL.loop_matrices(f, zeta, kth, kv, dt, leak)
    n = 5 + extra
    M = np.zeros((n, n))
    M[:5, :5] = A
    if extra == 0:
        M[:5, :5] += np.outer(B, C)
    else:
        M[:5, 5 + extra - 1] = B              # the feedback reads the oldest stored deflection
        M[5, :5] = C                          # the newest is this tick's
        for i in range(1, extra):
            M[5 + i, 5 + i - 1] = 1.0
    return np.linalg.eigvals(M)


@pytest.mark.parametrize("f,kth,leak", [(40.0, 325.0, 0.15), (40.0, 200.0, 0.1), (20.0, 175.0, 0.15),
                                        (80.0, 500.0, 0.3), (80.0, 300.0, None), (246.6, 325.0, None)])
def test_delay_margin_says_how_many_ticks_of_delay_the_loop_takes(f, kth, leak):
    """The phase margin as ticks of extra strain delay (from the open loop's frequency response)
    against the closed-loop poles with those ticks of delay put in: stable with every whole number of
    ticks below it, unstable with the next."""
    lk = None if leak is None else leak * 2 * math.pi * f
    d = SL.loop_margins(f, ZETA, kth, KV, DT, lk).delay_margin_ticks
    assert 0.3 < d < 10 and abs(d - round(d)) > 0.05
    for extra in range(0, math.floor(d) + 1):
        assert np.max(np.abs(_delayed_poles(f, ZETA, kth, KV, DT, lk, extra))) < 1.0, extra
    assert np.max(np.abs(_delayed_poles(f, ZETA, kth, KV, DT, lk, math.ceil(d)))) > 1.0


@pytest.mark.parametrize("f,leak", [(40.0, 0.15), (80.0, None)])
def test_gain_margin_is_where_the_poles_leave_the_unit_circle(f, leak):
    lk = None if leak is None else leak * 2 * math.pi * f
    k = 300.0
    m = SL.loop_margins(f, ZETA, k, KV, DT, lk)
    assert 1.0 < m.gain_margin < 100.0
    assert np.max(np.abs(SL.closed_loop_poles(f, ZETA, 0.99 * m.gain_margin * k, KV, DT, lk))) < 1.0
    assert np.max(np.abs(SL.closed_loop_poles(f, ZETA, 1.01 * m.gain_margin * k, KV, DT, lk))) > 1.0


def test_design_for_the_soft_40hz_chain_keeps_its_promises_over_the_error_box():
    d = SL.design_k_theta(40.0, ZETA, KV, DT)
    assert d.reached and d.soft and 0 < d.k_theta * DT <= SL.MAX_KDT
    for r in (0.8, 0.9, 1.0, 1.1, 1.2):       # the box's corners and between them
        for zf in SL.DAMPING_SPAN + (1.0,):
            z = SL.closed_loop_poles(40.0 * r, ZETA * zf, d.k_theta, KV, DT, d.leak)
            assert np.min(SL.pole_damping(z, DT)[1]) >= SL.DAMPING_TARGET - 0.02
            m = SL.loop_margins(40.0 * r, ZETA * zf, d.k_theta, KV, DT, d.leak)
            assert m.gain_margin >= SL.MIN_GAIN_MARGIN and m.phase_margin_deg >= SL.MIN_PHASE_MARGIN_DEG - 1.0
    # the smallest such gain: one grid step less, no leak reaches the target
    k0 = d.k_theta - SL.KDT_STEP / DT
    assert all(SL._worst_damping(40.0, ZETA, k0, KV, DT, x * 2 * math.pi * 40.0, SL.MODE_ERROR, SL.DAMPING_SPAN)
               < SL.DAMPING_TARGET for x in SL.LEAK_STEPS)


def test_the_design_takes_the_plain_law_for_a_mode_of_fewer_than_four_ticks():
    d = SL.design_k_theta(300.0, ZETA, KV, DT)
    assert not d.soft and d.k_theta > 0 and not d.reached
    assert d.worst_gain_margin >= SL.MIN_GAIN_MARGIN and d.worst_phase_margin_deg >= SL.MIN_PHASE_MARGIN_DEG


@pytest.mark.parametrize("f", [10.0, 40.0, 120.0])
def test_stretch_lowpass_errs_by_its_share_at_the_mode(f):
    """The NC's one-pole filter of the planned acceleration (nc._kth_modal_l: af += c (a* - af)) with
    c from stretch_lowpass, run on a sampled sine at the mode: the steady error is STRETCH_ERROR."""
    w = SL.stretch_lowpass(f, DT)
    c = 1.0 - math.exp(-w * DT)
    t = np.arange(int(2.0 / DT)) * DT
    a = np.sin(2 * math.pi * f * t)
    af = np.zeros_like(a)
    for k in range(1, len(a)):
        af[k] = af[k - 1] + c * (a[k] - af[k - 1])
    tail = slice(len(t) // 2, None)
    e = a[tail] - af[tail]
    amp = math.sqrt(2.0 * np.mean(e ** 2))
    assert amp == pytest.approx(SL.STRETCH_ERROR, rel=0.02)


@pytest.mark.parametrize("ratio", [0.8, 1.2])
def test_the_designed_feedback_rings_a_mode_20_percent_off_down_within_a_period(ratio):
    """The NC designed for a 40 Hz chain (auto: its gain, leak and stretch low-pass) on a plant whose
    mode is 20 % off: the real loop (NC, sim, gauges, V-F) brings a 50 um deflection to within a few
    pulses (2 um) in one period and keeps it there; without the feedback it is still 30 um and more
    (2 % damping) -- the design's 0.7 damping at the box's corners, in the closed loop."""
    from kth_support import ringdown
    d = SL.design_k_theta(40.0, ZETA, KV, DT)
    f = 40.0 * ratio
    T = int(round(1.0 / (f * DT)))
    y = ringdown(f, d.k_theta, duration=4.0 / f, mode_hz=40.0, k_theta_leak=d.leak, k_theta_lp=d.acc_lp)
    assert np.abs(y[T:]).max() < 2e-3
    y0 = ringdown(f, 0.0, duration=4.0 / f)
    assert np.abs(y0[T:]).max() > 30e-3
