"""Blind diagnosis of freshly generated concealed-effect recordings (issue 4 "Must show").

Each case is made by pmctl.tools.twin.synth; the diagnosis sees only the columns, the answer key is used
to score afterwards (pmctl.tools.twin.scoring: right effect and locator, parameters within ±20 %, held-out
RMS cut). Short runs keep the file fast; benchmarks/eval_diagnosis.py runs ≥ 20 cases per effect.
"""

import json

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pmctl.interfaces.cli import main
from pmctl.core.config import load_machine
from pmctl.tools.twin import synth
from pmctl.tools.twin.diagnose import diagnose
from pmctl.tools.twin.scoring import score

M = load_machine()
CAP = 3000


def _case(effects, seed, duration=15.0, rate=400.0, run=None):
    rng = np.random.default_rng(seed)
    return synth.synth_case(rng, effects, machine=M, seed=seed, duration_s=duration, rate_hz=rate, run=run)


def _diagnose(case):
    rep, ex = diagnose(case.columns, M, cap=CAP)
    return rep, score(rep, case.answer, noise=ex["ctx"].obs.sigma)


def test_clean_recording_is_consistent_with_the_nominal_twin():
    rep, sc = _diagnose(_case([], 11))
    assert rep["verdict"] == "consistent with the nominal twin"
    assert rep["findings"] == []


@pytest.mark.parametrize("effect,seed", [("backlash", 1), ("pitch_error", 3), ("servo_lag", 4),
                                         ("lost_steps", 5), ("sensor_offset", 6)])
def test_a_concealed_effect_is_named_fitted_and_cuts_the_heldout_residual(effect, seed):
    case = _case([effect], 100 + seed)
    rep, sc = _diagnose(case)
    r = sc["effects"][0]
    assert r["named"], (case.answer["effects"], rep["findings"])
    assert r["params_ok"], r["param_errors"]
    assert r["cut_ok"], r
    assert rep["verdict"] == "unmodelled physics found"


def test_two_simultaneous_effects_are_both_found():
    case = _case([synth.Effect("backlash", {"axis": "X"}, {"width_mm": 0.02}),
                  synth.Effect("pitch_error", {"axis": "L2"}, {"period_mm": 5.0, "amplitude_mm": 0.01},
                               {"phase_rad": 1.0})], 21, run="calibration")
    rep, sc = _diagnose(case)
    assert sc["all_found"], (sc, rep["findings"])
    assert sc["extra_findings"] == []


def test_cli_writes_the_recording_md_report_and_plots(tmp_path, capsys):
    case = _case(["backlash"], 31)
    synth.write_case(tmp_path, "c", case)
    js, plots = tmp_path / "r.json", tmp_path / "plots"
    assert main(["twin", "diagnose", str(tmp_path / "c" / "recording"), "--json", str(js),
                 "--plots", str(plots), "--cap", str(CAP), "--progress"]) == 0
    cap = capsys.readouterr()
    out = cap.out
    assert out.index("WHERE") < out.index("WHY")          # where first, then why
    assert "diagnosing [" in cap.err and "[" + "#" * 30 + "]" in cap.err   # the bar: on stderr, to its end
    assert "\r" not in out and "diagnosing [" not in js.read_text()
    rep = json.loads(js.read_text())
    assert set(rep) == {"recording", "verdict", "samples", "findings", "unexplained", "confidence_calibration",
                        "units"}
    assert rep["units"]["tip_x"] == "mm" and all(rep["units"][k] == "mm" for k in rep["findings"][0]["rms_before"])
    assert rep["samples"]["total"] == rep["samples"]["analysed"] == len(case.columns["t"])
    f = rep["findings"][0]
    assert set(f) == {"effect", "axis", "parameters", "uncertainty", "where", "evidence", "rms_before",
                      "rms_after", "heldout", "confidence"}
    truth = case.answer["effects"][0]["parameters"]["width_mm"]
    se = f["uncertainty"]["width_mm"]
    assert set(f["uncertainty"]) == {"width_mm"} and 0 < se < 0.2 * f["parameters"]["width_mm"]
    assert abs(f["parameters"]["width_mm"] - truth) < 5 * se + 0.02 * truth
    assert f"width_mm = {f['parameters']['width_mm']} ± " in out
    assert 0.5 < f["confidence"] <= 1.0
    assert set(f["where"]) >= {"channels", "time_windows_s", "direction_dependent", "frequency_hz"}
    assert f["effect"] == "backlash" and f["where"]["direction_dependent"] is True
    assert f["heldout"] is True and set(f["parameters"]) == {"width_mm"}
    for c in f["rms_before"]:
        assert f["rms_after"][c] <= f["rms_before"][c]
    for name in ("residual_before_after.png", "direction_split.png", "spectrum.png"):
        assert (plots / name).read_bytes()[:4] == b"\x89PNG"


def test_only_commands_and_encoders_still_diagnose_a_servo_lag():
    case = _case(["servo_lag"], 3, duration=10.0, rate=500.0)
    cmd_only = {k: v for k, v in case.columns.items() if k == "t" or k.startswith("cmd_")}
    rep, _ = diagnose(cmd_only, M, cap=CAP)
    assert rep["findings"] == []                      # nothing measured: nothing to explain
    enc = {k: v for k, v in case.columns.items() if k == "t" or k.startswith(("cmd_", "enc_"))}
    rep, _ = diagnose(enc, M, cap=CAP)
    sc = score(rep, case.answer)
    assert sc["all_found"], (rep["findings"], case.answer["effects"])


def test_table_compliance_under_a_known_tip_force_is_found():
    case = _case([synth.Effect("compliance", {"axis": "X"}, {"stiffness_N_per_mm": 3000.0})], 41, run="calibration")
    rep, sc = _diagnose(case)
    assert sc["all_found"], (rep["findings"], sc)
    assert "tip force" in rep["findings"][0]["evidence"]


def test_physics_outside_the_catalogue_is_located_as_unexplained_not_named():
    rng = np.random.default_rng(8)
    case = synth.synth_case(rng, [], machine=M, seed=8, duration_s=15.0, rate_hz=400.0, oddities=["straightness"])
    rep, _ = diagnose(case.columns, M, cap=CAP)
    assert rep["verdict"] == "unexplained mismatch"
    u = [e for e in rep["unexplained"] if "tip_y" in e["channels"]]
    assert u and u[0]["excess_over_noise"] > 1.0 and u[0]["signature"] == "position-dependent" and u[0]["axis"] == "X"
    assert not any(f["effect"] == "sensor_offset" for f in rep["findings"])


def test_a_steady_line_is_named_forced_vibration_not_a_resonance():
    e = synth.Effect("forced_vibration", {"channel": "strain_1"}, {"freq_hz": 47.0, "amplitude": 3.0}, {"phase_rad": 0.2})
    case = _case([e], 52, duration=10.0)
    rep, sc = _diagnose(case)
    assert sc["all_found"], rep["findings"]
    assert not any(f["effect"] == "resonance" for f in rep["findings"])


def test_a_gauge_mode_is_named_on_its_channel_not_on_the_axis():
    """A 48.7 Hz plate-link mode that only strain_1 sees, in a 250 Hz log thinned to 2000 rows (8 ms
    apart on the gauge: its band ends at 62.5 Hz). The axis candidate L1 (tool channels + that gauge,
    one gain each) fitted it with the gauge's gain alone and took the name; the gauge's own
    candidate failed to start, its only spectral start sitting at the band's edge. The tool does
    not see it (the tool column's gain is within its noise), so the name is the channel's."""
    e = synth.Effect("resonance", {"channel": "strain_1"}, {"freq_hz": 48.7, "damping_ratio": 0.03},
                     {"peak_ue": 12.5})
    case = _case([e], 31, duration=12.0, rate=250.0, run="circle")
    rep, ex = diagnose(case.columns, M, cap=2000)
    sc = score(rep, case.answer, noise=ex["ctx"].obs.sigma)
    assert sc["all_found"], rep["findings"]
    assert not any(f["effect"] == "resonance" and f.get("axis") for f in rep["findings"]), rep["findings"]


def test_a_tool_axis_component_is_whitened_with_the_noise_its_tilt_gives_it():
    """The tracker measures the tool axis as a unit vector: an angular noise σ moves its component
    c by σ·√(1 − c²), so tool_k (c = cos tilt) is quiet near level and grows with the tilt. A clean
    calibration run tilts the platform in its first seconds and then stays near level: with one
    noise level for the whole channel, tool_k looked 2.3 x noisy early and 0.6 x late, and the
    early stretch was reported as an unexplained 'intermittent' mismatch. Whitened per sample,
    both stretches are noise and the run is consistent with the twin."""
    from pmctl.tools.twin.observations import TOOL_SCALE_FLOOR, noise_scale
    tilt = np.radians(np.array([0.0, 1.0, 2.0, 4.0, 8.0]))
    s = noise_scale("tool_k", np.cos(tilt))
    assert s[2] == pytest.approx(1.0)                                    # relative to the median
    assert s[4] / s[3] == pytest.approx(np.sin(tilt[4]) / np.sin(tilt[3]), rel=1e-9)
    assert s[0] == TOOL_SCALE_FLOOR                                      # exactly vertical: floored
    assert np.all(noise_scale("tip_x", np.cos(tilt)) == 1.0)
    seed = 155461                   # a clean 10 s calibration run at 1 kHz (eval seed base 5000)
    rng = np.random.default_rng(seed)
    case = synth.synth_case(rng, [], machine=M, seed=seed, duration_s=10.0, rate_hz=1000.0)
    assert case.answer["run"] == "calibration"
    rep, ex = diagnose(case.columns, M, cap=2000)
    ctx, y = ex["ctx"], ex["y_final"]
    m = ctx.obs.mask_of("tool_k")
    t = ctx.t[ctx.obs.row[m]]
    early, late = y[m][t < 3.0], y[m][t > 5.0]
    for part in (early, late):
        assert 0.7 < np.sqrt(np.mean(part ** 2)) < 1.4
    assert rep["findings"] == [] and rep["unexplained"] == [], (rep["findings"], rep["unexplained"])
    assert rep["verdict"] == "consistent with the nominal twin"


def test_a_lost_step_inside_a_folds_gap_agrees_with_that_fold():
    """A fold that holds out the step's time block, next to a tracker drop-out, sees no sample for
    two seconds around the step: it can only say the step lies in that gap, and its argmax puts it
    at the gap's far edge. The fold check compares the full fit's time with that gap, not with the
    edge (this 250 Hz run with recording imperfections was refused as 'not identifiable' and its
    17 µm step read as a geometry error and a tracker drift)."""
    from pmctl.tools.twin.diagnose import fold_spread
    ctx = type("C", (), {"duration": 24.0})()          # a time block of 1 s: tolerance 1.5 s
    full = {"t_s": 10.0, "offset_mm": 0.02}
    far = {"t_s": 13.0, "offset_mm": 0.02}
    assert fold_spread(full, [far], ctx) == pytest.approx(2.0)                                # edge: 3 s off
    assert fold_spread(full, [{**far, "_t_bracket": (9.5, 13.0)}], ctx) == pytest.approx(0.0)  # in its gap
    assert fold_spread(full, [{**far, "_t_bracket": (12.0, 13.0)}], ctx) == pytest.approx(2 / 1.5)
    seed = 68353                    # eval seed base 5000, lost_steps case 1: 250 Hz, imperfections
    rng = np.random.default_rng(seed)
    case = synth.synth_case(rng, ["lost_steps"], machine=M, seed=seed, duration_s=10.0, rate_hz=250.0,
                            imperfections=True)
    rep, ex = diagnose(case.columns, M, cap=2000)
    sc = score(rep, case.answer, noise=ex["ctx"].obs.sigma)
    assert sc["all_found"], (case.answer["effects"], rep["findings"])


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-1e3, 1e3), min_size=2, max_size=8))
def test_the_fold_uncertainty_of_a_mean_is_the_standard_error_of_the_group_means(g):
    # K groups with means g_j; leaving group k out, the mean is that of the others. The
    # delete-a-group jackknife then gives exactly the standard error of the mean of the K groups.
    from pmctl.tools.twin.diagnose import fold_uncertainty
    g = np.asarray(g)
    K = len(g)
    folds = [{"v": float((g.sum() - g[k]) / (K - 1)), "t_s": 1.0, "period_mm": [1.0, 2.0]} for k in range(K)]
    se = fold_uncertainty({"v": float(g.mean()), "t_s": 1.0, "period_mm": [1.0, 2.0]}, folds)
    want = np.std(g, ddof=1) / np.sqrt(K)
    if want <= 1e-9 * abs(g.mean()) or want == 0:      # every fold at the full fit's value: no figure
        assert se == {}
        return
    assert set(se) == {"v"}                             # a step time and a list are left out
    assert se["v"] == pytest.approx(want, rel=1e-9, abs=1e-9)
