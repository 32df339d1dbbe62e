"""Seed 004 ch. 2-3 reproduced: eq. 3.1 roots and the paper's factors, Hurwitz, the V-F dead region
(eq. 2.2) and regions (Fig. 2.9) by simulation, strain feedback K_θ in the simulated loop, 3.6."""

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st

from pmctl.core import vf
from pmctl.tools.analysis import vibration as V

finite = dict(allow_nan=False, allow_infinity=False)
KJ = (2 * math.pi * 5) ** 2


# ---------------------------------------------------------------- eq. 3.1-3.5, seed numbers

def test_seed_parameters_are_those_of_section_3_5():
    cases = V.seed_eq31_cases()
    kJ, KG, Kt, kv500 = cases[500.0]
    assert kJ == pytest.approx((2 * math.pi * 5) ** 2) and KG == pytest.approx(1 / 0.628) and Kt == 3
    assert kv500 == pytest.approx(2.5 * 6 * math.pi) and cases[200.0][3] == pytest.approx(6 * math.pi)


def test_exact_roots_500_hz():
    r = V.eq31_roots(*V.seed_eq31_cases()[500.0])
    assert round(-r.real_pole, 1) == -213.4
    assert round(r.wn, 2) == 18.63
    assert round(r.zeta, 3) == 0.080


def test_exact_roots_200_hz():
    r = V.eq31_roots(*V.seed_eq31_cases()[200.0])
    assert round(-r.real_pole, 1) == -78.8
    assert round(r.wn, 2) == 19.39
    assert round(r.zeta, 3) == 0.200


def test_paper_approximate_factors_eq_3_4_and_3_5():
    a = V.eq33_approx_factors(*V.seed_eq31_cases()[500.0])
    assert round(a.real_pole, 1) == 216.4 and round(a.wn, 1) == 18.5 and round(a.zeta, 2) == 0.08
    b = V.eq33_approx_factors(*V.seed_eq31_cases()[200.0])
    assert round(b.real_pole, 2) == 86.56 and round(b.wn, 1) == 18.5 and round(b.zeta, 2) == 0.20


def test_approx_factors_match_eq_3_3_closed_form():
    kJ, KG, Kt, kv = V.seed_eq31_cases()[500.0]
    a = V.eq33_approx_factors(kJ, KG, Kt, kv)
    g = 1 + Kt / KG
    assert a.real_pole == pytest.approx(g * KG * kv)
    assert a.wn ** 2 == pytest.approx(kJ / g)
    assert 2 * a.zeta * a.wn == pytest.approx(kJ * Kt / KG / g ** 2 / (KG * kv))


@settings(max_examples=80, deadline=None)
@given(st.floats(1.0, 1e4, **finite), st.floats(0.1, 10, **finite), st.floats(0.0, 20, **finite),
       st.floats(1.0, 500, **finite))
def test_approx_factors_reproduce_the_cubic_when_the_real_root_is_large(kJ, KG, Kt, kv):
    """(s+p)(s²+qs+r) multiplied out keeps a1 and a0 exactly and a2 up to q (≪ p when p² ≫ k/J)."""
    a = V.eq33_approx_factors(kJ, KG, Kt, kv)
    _, a2, a1, a0 = V.eq31_char_poly(kJ, KG, Kt, kv)
    p, q, r = a.real_pole, 2 * a.zeta * a.wn, a.wn ** 2
    assert p * r == pytest.approx(a0, rel=1e-12)
    assert p * q + r == pytest.approx(a1, rel=1e-9)
    assert p + q - a2 == pytest.approx(q, rel=1e-9)
    # and the exact real root is near p when p dominates
    assume(p * p > 100 * kJ)
    assert V.eq31_roots(kJ, KG, Kt, kv).real_pole == pytest.approx(p, rel=0.05)


# ---------------------------------------------------------------- Hurwitz (eq. 3.2)

@settings(max_examples=150, deadline=None)
@given(st.floats(1.0, 1e4, **finite), st.floats(0.1, 10, **finite), st.floats(-20, 20, **finite),
       st.floats(0.5, 500, **finite))
def test_hurwitz_D2_is_the_stability_condition(kJ, KG, Kt, kv):
    c = V.eq31_char_poly(kJ, KG, Kt, kv)
    d2 = V.hurwitz_D2(kJ, KG, Kt, kv)
    assert d2 == pytest.approx(c[1] * c[2] - c[3], rel=1e-9, abs=1e-9 * abs(c[1] * c[2]))
    assume(abs(Kt) > 1e-3 and c[1] != 0)
    roots = np.roots(c)
    stable_by_roots = bool(np.all(roots.real < 0))
    assert V.hurwitz_stable(c) == stable_by_roots
    # for K_G, k/J, K_vK_R > 0 the loop is stable exactly when D2 = K_θ K_v K_R k/J > 0
    assert stable_by_roots == (d2 > 0)


def test_without_strain_feedback_the_load_mode_is_undamped():
    r = np.roots(V.eq31_char_poly(KJ, 1 / 0.628, 0.0, 15.7))
    assert V.hurwitz_D2(KJ, 1 / 0.628, 0.0, 15.7) == 0
    assert np.sort(np.abs(r.imag))[-1] == pytest.approx(2 * math.pi * 5, rel=1e-9)
    assert np.min(r.real) == pytest.approx(-15.7 / 0.628, rel=1e-9)
    assert np.max(np.abs(r.real[np.abs(r.imag) > 1])) < 1e-9 * 2 * math.pi * 5


# ---------------------------------------------------------------- V-F dead region (eq. 2.2) by simulation

@settings(max_examples=25, deadline=None)
@given(st.integers(1, 60), st.floats(1e-2, 100, **finite), st.floats(0.0, 0.999, **finite))
def test_simulated_min_amplitude_matches_the_closed_form_for_every_phase(k, sd, phase):
    """Bisection with vf_step (rel. 1e-7) vs SD sin(π/2k)/cos((φ−½)π/k), to 1e-6 relative."""
    assume(not (k == 1 and abs(phase) < 1e-3))           # f/F = ½ sampled at the zeros: no signal
    sim = float(V.vf_min_amplitude_sim(1 / (2 * k), sd, phase))
    assert sim == pytest.approx(float(V.vf_min_amplitude_exact(sd, k, phase)), rel=1e-6)


@settings(max_examples=15, deadline=None)
@given(st.integers(1, 60), st.floats(1e-2, 100, **finite))
def test_eq_2_2_is_the_minimum_over_sampling_phases(k, sd):
    """min over φ of the simulated smallest amplitude = SD sin(π/2k) = vf.vf_min_amplitude (1e-6)."""
    phases = np.linspace(0, 1, 8, endpoint=False)          # contains φ = ½
    sims = V.vf_min_amplitude_sim(np.full(8, 1 / (2 * k)), sd, phases)
    assert sims.min() == pytest.approx(float(vf.vf_min_amplitude(sd, 1 / (2 * k))), rel=1e-6)
    # φ = 0 (the seed's sum from i = 1) gives the exact form of eq. 2.2 at its best n: SD tan(π/2k)
    if k > 1:
        assert sims[0] == pytest.approx(sd * math.tan(math.pi / (2 * k)), rel=1e-6)


@settings(max_examples=25, deadline=None)
@given(st.floats(0.01, 0.5, **finite), st.floats(0.0, 0.999, **finite), st.floats(0.1, 10, **finite))
def test_no_sine_below_eq_2_2_ever_pulses(ratio, phase, sd):
    """Any f/F (not only 1/2k), any phase: the simulated threshold amplitude is ≥ SD sin(π f/F)."""
    sim = float(V.vf_min_amplitude_sim(ratio, sd, phase, n_periods=6))
    assert sim >= sd * math.sin(math.pi * ratio) * (1 - 1e-6)


def test_seed_2_3_examples():
    # 50 Hz at 500 Hz, SD 1: nothing at level 0.2 (seed 2.3.4); 4 Hz: nothing at 0.02, pulses at 0.03
    assert V.vf_min_amplitude_sim(0.1, 1.0, 0.0) > 0.2
    assert 0.02 < V.vf_min_amplitude_sim(0.008, 1.0, 0.0) < 0.03
    # level 1 stops producing pulses near f/F = 0.3 (150 Hz @ 500 Hz, 300 Hz @ 1 kHz; seed 2.3.3)
    assert V.vf_min_amplitude_sim(0.32, 1.0, 0.0, n_periods=40) > 1.0
    assert V.vf_min_amplitude_sim(0.25, 1.0, 0.0, n_periods=40) <= 1.0 + 1e-6


def test_region_map_points():
    levels = np.array([0.01, 0.05, 0.5, 1.5])
    ratios = np.array([0.008, 0.1])
    codes, _ = V.vf_region_map(levels, ratios)
    I, II, III, SAT = V.REGION_CORRECT, V.REGION_NOISY, V.REGION_NONE, V.REGION_SATURATED
    assert codes[:, 0].tolist() == [III, II, I, SAT]      # 4 Hz @ 500 Hz (seed 2.3.4)
    assert codes[:, 1].tolist() == [III, III, II, SAT]    # 50 Hz @ 500 Hz: distorted or nothing


def test_equivalent_input_conserves_pulses():
    p = np.array([0, 0, 1, 0, 0, 1, 1, 0, -1, 0, 0, 0])
    eq = V.equivalent_input(p, threshold=2.0)
    # between two pulses the level integrates to exactly the later pulse(s) × SD
    assert eq[3:6].tolist() == [2 / 3] * 3 and eq[6] == 2.0 and eq[7:9].tolist() == [-1.0, -1.0]
    assert eq.sum() == pytest.approx(2.0 * p[3:].sum())


# ---------------------------------------------------------------- strain feedback in the simulated loop

def _step(F, Kt, f_load=5.0):
    th, te = V.step_command(F, 3.0)
    sim = V.simulate_vf_loop(th, F, K_theta=Kt, f_load=f_load)
    return sim, V.response_metrics(sim, te)


def test_strain_feedback_suppresses_residual_vibration_of_the_step():
    s0, m0 = _step(500.0, 0.0)
    s3, m3 = _step(500.0, 3.0)
    # both runs end on the commanded 20 pulses, every pulse counted
    assert s0.pulses.sum() == s3.pulses.sum() == 20
    assert math.isinf(m0.settling_time) and m3.settling_time < 1.0
    assert m0.residual_pp / m3.residual_pp > 20            # measured 36×
    assert m0.residual_rms / m3.residual_rms > 20
    # at 200 Hz sampling too (seed Fig. 3.3 (c)); measured 6.3×
    _, m0c = _step(200.0, 0.0)
    _, m3c = _step(200.0, 3.0)
    assert m0c.residual_pp / m3c.residual_pp > 4


def test_strain_feedback_suppresses_resonance_of_the_ramp():
    out = {}
    for Kt in (0.0, 3.0):
        th, te = V.ramp_command(500.0, 7.0)
        sim = V.simulate_vf_loop(th, 500.0, K_theta=Kt)
        out[Kt] = V.response_metrics(sim, te)
        assert sim.pulses.sum() == 20
    assert out[0.0].moving_rms_deflection / out[3.0].moving_rms_deflection > 10    # measured 18×
    assert out[0.0].residual_pp / out[3.0].residual_pp > 50                        # measured 211×


@pytest.mark.parametrize("F,f_load,guaranteed", [(500.0, 5.0, True), (200.0, 5.0, True),
                                                   (500.0, 50.0, False)])
def test_residual_vibration_is_within_the_vf_dead_region_bound(F, f_load, guaranteed):
    """With K_θ the loop acts until the strain signal falls into the V-F dead region (eq. 2.2):
    residual amplitude ≤ 2 SD sin(π f_load/F)/K_θ. For the 5 Hz load the bound is far below the
    unsuppressed vibration (suppression guaranteed); for the 50 Hz load of Fig. 3.3(d) it is not
    (seed: large dead region, little suppression to be expected)."""
    _, m3 = _step(F, 3.0, f_load)
    _, m0 = _step(F, 0.0, f_load)
    bound = V.residual_amplitude_bound(F, f_load, 3.0)
    assert m3.residual_pp / 2 <= bound * 1.02
    assert (m0.residual_pp / 2 > 2 * bound) == guaranteed


def test_simulation_follows_the_linear_model_with_the_literal_vf_gain():
    """First overshoot of the V-F simulation vs eq. 3.1 with K_vK_R = F·K_R/SD (15.7 rad/s) and with
    the paper's 2.5·6π: the literal gain explains the simulated response, the paper's does not."""
    sim, _ = _step(500.0, 3.0)
    peak = sim.theta_L.max()
    lit = V.linear_step_response(sim.t, KJ, V.K_G_SEED, 3.0, 500 * V.K_R_SEED, 0.628).max()
    paper = V.linear_step_response(sim.t, KJ, V.K_G_SEED, 3.0, V.KVKR_PAPER[500.0], 0.628).max()
    assert abs(peak - lit) < 0.05 < abs(peak - paper) - 0.1


def test_undamped_load_without_feedback_keeps_its_energy():
    s, _ = _step(500.0, 0.0)
    e = s.theta_L - 0.628
    late = e[s.t > 1.0]
    # after the last pulse the free oscillation neither grows nor decays (exact discretisation)
    assert np.ptp(late[: len(late) // 2]) == pytest.approx(np.ptp(late[len(late) // 2:]), rel=1e-3)


# ---------------------------------------------------------------- seed 3.6 noise claim

def test_seed_3_6_strain_noise_falls_in_the_dead_region():
    chk = V.seed36_noise_check(freqs=np.arange(100.0, 196.0, 1.0), n_phases=4, duration=5.0)
    assert chk["vf_input_amplitude"] == pytest.approx(0.75)
    assert np.all(chk["pulses_per_freq"] == 0)             # 100-195 Hz: no pulse at all
    assert chk["random_pulses"] == 0
    # the limit of the claim: noise aliasing to within F/π·asin(K_θ x/SD) of DC does pulse
    assert chk["alias_limit_hz"] == pytest.approx(200 / math.pi * math.asin(0.075))
    near = V.seed36_noise_check(freqs=np.array([199.0, 200.0, 201.0]), n_phases=4, duration=5.0)
    assert np.all(near["pulses_per_freq"] > 0)


# ---------------------------------------------------------------- CLI

def test_cli_vibration_writes_figures(tmp_path, capsys):
    from pmctl.interfaces.cli import main
    assert main(["analyze", "vibration", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "-213.4" in out and "18.63" in out and "-78.8" in out and "216.41" in out and "86.56" in out
    for name in ("vibration_step.png", "vibration_ramp.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
