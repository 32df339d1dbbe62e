"""Honesty of the diagnosis (issue 12): the signatures of what is left unexplained, and the calibrated
confidence (pmctl.tools.twin.unexplained, pmctl.tools.twin.calibration)."""

import math
import runpy
import shutil

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pmctl.core.config import load_machine
from pmctl.tools.twin import calibration as C
from pmctl.tools.twin import synth
from pmctl.tools.twin.diagnose import diagnose
from pmctl.tools.twin.unexplained import _bursts, _refined_line, _step

M = load_machine()


# ---------------------------------------------------------------- signatures

@settings(max_examples=40, deadline=None)
@given(n=st.integers(200, 3000), where=st.floats(0.15, 0.85), size=st.floats(5.0, 30.0),
       level=st.floats(-5.0, 5.0), seed=st.integers(0, 2**16))
def test_a_step_in_white_noise_is_found_at_its_instant(n, where, size, level, seed):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    ts = t[int(where * n)] - 0.005
    y = level + size * (t > ts) + rng.normal(0, 1, n)
    frac, at = _step(t, y)
    assert at is not None and abs(at - ts) <= 0.01 * max(3, 40 / size ** 2)
    # two levels leave only the noise (n samples of unit variance)
    assert frac >= 1 - 1.35 * n / float(y @ y)


def test_an_offset_or_a_slow_trend_is_no_step():
    t = np.linspace(0, 10, 2000)
    noise = np.random.default_rng(1).normal(0, 1, len(t))
    assert _step(t, 7.0 + noise) == (0.0, None)
    assert _step(t, 0.3 * t + noise) == (0.0, None)
    frac, at = _step(t, 5.0 * (t > 4.3) - 0.5 * t + noise)     # a step left over by a fitted drift is one
    assert abs(at - 4.3) < 0.02 and frac > 0.5


def test_bursts_carry_the_excess_of_an_intermittent_channel():
    t = np.linspace(0, 10, 2000)
    y = np.random.default_rng(2).normal(0, 1, len(t))
    wins = [[2.0, 2.1], [6.0, 6.15]]
    for a, b in wins:
        y[(t >= a) & (t <= b)] += 20.0
    frac, k = _bursts(t, y, wins, 10.0)
    assert k == 2 and frac > 0.9
    assert _bursts(t, y, wins[:1], 10.0) == (0.0, None)                 # one stretch: a transient
    assert _bursts(t, y, [[0.0, 2.0], [5.0, 7.0]], 10.0) == (0.0, None)  # 40 % of the run: not bursts


@settings(max_examples=40, deadline=None)
@given(f=st.floats(3.0, 30.0), off=st.floats(-1.0, 1.0), amp=st.floats(4.0, 20.0), span=st.floats(0.8, 3.0),
       seed=st.integers(0, 2**16))
def test_a_line_in_a_short_stretch_is_fitted_at_its_own_frequency_not_at_the_spectrums_bin(f, off, amp, span, seed):
    # a tracker's irregular samples (about 83 Hz) of a burst; the Welch peak of a stretch is on a grid of
    # 1/span, so up to a bin off (``off`` bins here; about 1 Hz on a one-second stretch). Blind 13000/oddity/1: a 14.4 Hz chatter burst, 7 x noise for 1 s,
    # fitted at the peak's 14.9 Hz took 38 % of the stretch and went unreported
    rng = np.random.default_rng(seed)
    t = np.sort(rng.uniform(0.0, span, int(83 * span)))
    y = amp * np.sin(2 * np.pi * f * t + 1.0) + rng.normal(0, 1, len(t))
    frac, fr = _refined_line(t, y, f + off / span)
    assert abs(fr - f) <= 0.25 / span
    # a line at its frequency leaves the noise: n samples of unit variance, up to 5 of chi-square's
    # standard deviations sqrt(2n)
    n = len(t)
    assert frac >= 1 - (n + 5 * math.sqrt(2 * n)) / float(y @ y)


# ---------------------------------------------------------------- calibration

def test_the_logistic_fit_recovers_known_coefficients():
    rng = np.random.default_rng(3)
    true = {"const": -2.0, "snr": 1.5, "spread": -2.0, "rel": 3.0, "share": 1.0, "left": -2.5}
    rows = []
    for _ in range(6000):
        f = {"snr": rng.uniform(-0.5, 2), "spread": rng.uniform(0, 1.5), "rel": rng.uniform(0, 1),
             "share": rng.uniform(0.3, 1.5), "left": rng.uniform(0, 2)}
        rows.append((f, rng.random() < C.confidence(f, true)))
    fit = C.fit_logistic(rows)
    for k, v in true.items():
        assert abs(fit[k] - v) < 0.35 * max(1.0, abs(v)), (k, fit[k], v)
    # calibrated by construction: the reliability table agrees with itself within sampling error
    bins = C.reliability(rows, fit)
    assert sum(b["n"] for b in bins) == len(rows) and C.ece(bins) < 0.03


@settings(max_examples=30, deadline=None)
@given(n_part=st.integers(1, 40), right=st.floats(0, 1), seed=st.integers(0, 2**16))
def test_a_partial_description_is_capped_at_the_fraction_right_among_partial_findings(n_part, right, seed):
    rng = np.random.default_rng(seed)
    whole = [({"snr": rng.uniform(0, 2), "share": 1.0, "left": 0.0}, bool(rng.random() < 0.8)) for _ in range(60)]
    k = int(round(right * n_part))
    part = [({"snr": 3.0, "share": rng.uniform(0.3, 0.54), "left": 0.1}, i < k) for i in range(n_part)]
    part += [({"snr": 3.0, "share": 1.0, "left": rng.uniform(0.56, 3)}, False) for _ in range(n_part)]
    coef = C.fit(whole + part)
    assert coef["partial_cap"] == round(k / (2 * n_part), 3)
    for f, _ in part:
        assert C.partial(f) and C.confidence(f, coef) <= coef["partial_cap"]
    logistic = {k: v for k, v in coef.items() if k != "partial_cap"}
    for f, _ in whole:           # the others keep the logistic, fitted on them alone
        assert not C.partial(f) and C.confidence(f, coef) == C.confidence(f, logistic)
    assert logistic == C.fit_logistic(whole)


def test_reliability_bins_and_expected_calibration_error_by_hand():
    coef = {"const": 0.0, "snr": 1.0}
    rows = [({"snr": math.log(9)}, True)] * 9 + [({"snr": math.log(9)}, False)]      # 0.9 predicted, 9/10 right
    rows += [({"snr": 0.0}, True)] * 1 + [({"snr": 0.0}, False)] * 3                  # 0.5 predicted, 1/4 right
    bins = C.reliability(rows, coef)
    assert [(b["bin"], b["n"], b["right"]) for b in bins] == [([0.5, 0.7], 4, 1), ([0.85, 0.95], 10, 9)]
    assert abs(C.ece(bins) - (4 * 0.25 + 10 * 0.0) / 14) < 1e-3


def test_write_fitted_replaces_only_the_fitted_block(tmp_path):
    p = tmp_path / "calibration_copy.py"
    shutil.copy(C.__file__, p)
    before = p.read_text(encoding="utf-8")
    coef = {"const": -1.25, "snr": 0.5, "spread": -1.0, "rel": 2.0, "share": 1.5, "left": -0.75}
    calib = {"fit": {"seed_bases": [1, 2], "cases": 10}, "heldout": {"seed_bases": [3], "ece": 0.05}}
    C.write_fitted(coef, calib, "a description", p)
    ns = runpy.run_path(str(p))
    assert ns["COEF"] == coef and ns["CALIBRATION"] == calib and ns["DESCRIPTION"] == "a description"
    after = p.read_text(encoding="utf-8")
    a, b = before.index("# BEGIN FITTED"), before.index("# END FITTED")
    assert after.startswith(before[:a]) and after.endswith(before[b:].split("\n", 1)[1])


def test_the_shipped_calibration_states_its_held_out_check():
    assert set(C.COEF) == {"const", "partial_cap", *C.KEYS} and 0 <= C.COEF["partial_cap"] < 0.5
    h = C.CALIBRATION["heldout"]
    assert h and not set(h["seed_bases"]) & set(C.CALIBRATION["fit"]["seed_bases"])   # other seeds
    assert h["findings"] == sum(b["n"] for b in h["bins"]) and 0 <= h["ece"] <= 1


# ---------------------------------------------------------------- a diagnosis

def test_a_crash_that_moves_an_axis_is_located_as_a_step_not_named():
    o = {"kind": "crash_step", "axis": "Y", "channels": ["enc_Y"], "t_s": 4.3, "offset_mm": 0.04}
    case = synth.synth_case(np.random.default_rng(5), [], machine=M, seed=5, duration_s=10.0, rate_hz=250.0,
                            run="calibration", oddities=[o])
    rep, _ = diagnose(case.columns, M, cap=1500)
    u = [e for e in rep["unexplained"] if "enc_Y" in e["channels"]]
    assert u and u[0]["signature"].startswith("step at"), rep["unexplained"]
    assert abs(float(u[0]["signature"].split()[2]) - 4.3) < 0.1 and u[0]["excess_over_noise"] > 10
    assert not [f for f in rep["findings"] if f["confidence"] >= 0.5], rep["findings"]


def test_a_spike_after_the_one_reversal_of_a_short_run_is_located_as_a_burst_not_named():
    """Blind case 6000/oddity/2: a pocket run whose table reverses once; the load lurches ahead after
    that reversal (stick-slip, outside the catalogue) for 17 tracker samples at 3.7 x noise. Too short
    for its structure to be judged, it used to go unreported; it is now a burst after that reversal."""
    seed = 6000 + 7919 * 20 + 2               # eval_diagnosis's seed of that case
    rng = np.random.default_rng(seed)
    case = synth.synth_case(rng, [], machine=M, seed=seed, duration_s=10.0, rate_hz=1000.0,
                            oddities=["reversal_spike"])
    odd = case.answer["oddities"][0]
    assert case.answer["run"] == "raster"
    rep, _ = diagnose(case.columns, M, cap=2000)
    u = [e for e in rep["unexplained"] if set(e["channels"]) & set(odd["channels"])]
    assert u and u[0]["signature"] == f"burst after a reversal of {odd['axis']}", rep["unexplained"]
    assert not rep["findings"], rep["findings"]


def _blind_oddity(base, k):
    """eval_diagnosis's oddity case k of a seed base (its seed, rate, imperfections and kind)."""
    seed = base + 7919 * 20 + k
    rng = np.random.default_rng(seed)
    case = synth.synth_case(rng, [], machine=M, seed=seed, duration_s=10.0, rate_hz=1000.0 if k % 2 == 0 else 250.0,
                            imperfections=k % 3 == 1, oddities=[synth.ODDITIES[k % len(synth.ODDITIES)]])
    return case, case.answer["oddities"][0]


def test_knocks_seen_by_a_100_hz_tracker_are_not_named_a_steady_vibration():
    """Blind 12000/oddity/6: a press knocks every 0.76 s and rings at 9.2 Hz. The steady-line fit on X
    took the comb line at 9.25 Hz; its windows scattered only 2.2 x their noise (the knock's X share is
    weak), and forced vibration on X was named with 0.91. The comb's next line, 1.3 Hz away, now
    refuses it."""
    case, odd = _blind_oddity(12000, 6)
    assert odd["kind"] == "pulse_train"
    rep, _ = diagnose(case.columns, M, cap=2000)
    assert not any(f["effect"] == "forced_vibration" for f in rep["findings"]), rep["findings"]
    assert not [f for f in rep["findings"] if f["confidence"] >= 0.5], rep["findings"]
    assert any(set(odd["channels"]) & set(u["channels"]) for u in rep["unexplained"]), rep["unexplained"]


@pytest.mark.parametrize("base", [12000, 13000])
def test_a_chatter_burst_is_located_with_its_line_and_not_named_a_mode(base):
    """Blind 12000/oddity/1 and 13000/oddity/1 (250 Hz logs with imperfections): a 1-2 s burst of
    13.6 / 14.4 Hz in tip_x. The first was named a resonance of X with damping ratio 0.004 (0.92):
    that mode needs gains from -0.2 to 1.8 across the record's eighths. The second went unreported:
    the stretch's line, fitted at its Welch bin's 14.9 Hz, took 38 % of its energy."""
    case, odd = _blind_oddity(base, 1)
    assert odd["kind"] == "chatter_burst"
    rep, _ = diagnose(case.columns, M, cap=2000)
    assert not [f for f in rep["findings"] if f["confidence"] >= 0.5], rep["findings"]
    u = [e for e in rep["unexplained"] if "tip_x" in e["channels"]]
    assert u and u[0]["signature"].startswith("spectral line"), rep["unexplained"]
    assert abs(float(u[0]["signature"].split()[2]) - odd["freq_hz"]) < 0.2
    (a, b), = u[0]["time_windows_s"]
    assert abs(a - odd["t0_s"]) < 0.15 and abs(b - odd["t0_s"] - odd["length_s"]) < 0.15


def test_steps_of_two_axes_at_one_instant_are_not_named_lost_steps():
    """Missed pulses are one drive's fault. Two axes stepping at the same instant have a common cause
    the catalogue lacks (a collision; in blind runs a sagging table, seen as steps when the table
    reached its overhang): neither is named, both are refused with that reason, and the residual
    is left to ``unexplained``."""
    effects = [synth.Effect("lost_steps", {"axis": "L1"}, {"t_s": 5.0, "offset_mm": 0.03}),
               synth.Effect("lost_steps", {"axis": "X"}, {"t_s": 5.0, "offset_mm": -0.025})]
    case = synth.synth_case(np.random.default_rng(11), effects, machine=M, seed=11, duration_s=10.0, rate_hz=1000.0,
                            run="calibration")
    rep, ex = diagnose(case.columns, M, cap=1500)
    assert not [f for f in rep["findings"] if f["effect"] == "lost_steps"], rep["findings"]
    refused = [ev for ev in ex["rejected"] if ev["cand"].effect == "lost_steps"
               and any("one common cause" in p for p in ev["problems"])]
    assert {ev["cand"].target for ev in refused} >= {"L1", "X"}
    assert all(abs(ev["fit"].params["t_s"] - 5.0) < 0.1 for ev in refused)
    assert rep["unexplained"] and rep["verdict"] == "unexplained mismatch"
