"""Concealed-effect generator: layout, answer key apart, and each effect is the physics it claims.

Each physics test builds a short run, hides one effect, and recovers its parameter from the
nominal twin's residual by an independent route (direction split, screw-position regression,
lag fit, Jacobian regression, spectrum), within a stated tolerance.
"""

import argparse
import dataclasses
import json

import numpy as np
import pytest

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.errors import InputError
from pmctl.core.recording import read_recording
from pmctl.interfaces.commands.twin import add_synth_parser
from pmctl.tools.twin import nominal as N
from pmctl.tools.twin import synth as S

M = load_machine()


def _case(effects, run="calibration", duration=12.0, rate=500.0, seed=3, loads=None):
    rng = np.random.default_rng(seed)
    kind = run
    r = S.make_run(kind, rng, M, duration, rate, loads if loads is not None else kind != "circle")
    cols, noise = S.simulate(r, effects, rng, M, tracker_div=5)
    pred = N.predict_columns(cols, M)
    res = {c: cols[c] - p for c, p in pred.items()}
    return r, cols, res, noise


def _fit(x, y):
    """Least-squares slope and intercept of y on x over finite samples."""
    m = np.isfinite(x) & np.isfinite(y)
    A = np.stack([x[m], np.ones(m.sum())], -1)
    return np.linalg.lstsq(A, y[m], rcond=None)[0]


def test_layout_answer_key_apart_and_catalogue_names(tmp_path):
    dirs = S.generate(tmp_path, 2, effects=["backlash", "sensor_offset"], seed=7, duration_s=6.0, rate_hz=200.0)
    assert [d.name for d in dirs] == ["case-000", "case-001"]
    for d in dirs:
        assert sorted(p.name for p in (d / "recording").iterdir()) == ["data.csv", "recording.json"]
        ans = json.loads((d / "answer.json").read_text())
        rec = read_recording(d / "recording")
        assert rec.n == 1200 and rec.unknown_columns == []
        # the recording holds nothing of the answer
        text = (d / "recording" / "recording.json").read_text() + (d / "recording" / "data.csv").read_text()[:400]
        assert "backlash" not in text and "offset" not in text
        assert [e["effect"] for e in ans["effects"]] == ["backlash", "sensor_offset"]
        assert set(ans["effects"][0]["parameters"]) == {"width_mm"} and ans["effects"][0]["axis"] in S.AXES
        assert set(ans["effects"][1]["parameters"]) == {"offset"} and ans["effects"][1]["channel"] in rec
        # a 100 Hz tracker in a 200 Hz log: about half the tip cells are empty; the gauges log every row
        assert 0.4 < np.mean(np.isnan(rec["tip_x"])) < 0.7
        assert not np.isnan(rec["strain_1"]).any()
    assert json.loads((dirs[0] / "answer.json").read_text()) != json.loads((dirs[1] / "answer.json").read_text())


CATALOGUE_PARAMS = {
    "backlash": {"width_mm"}, "pitch_error": {"period_mm", "amplitude_mm"},
    "thermal_growth": {"alpha_per_K", "channel", "screw_fixed_end_mm"}, "compliance": {"stiffness_N_per_mm"},
    "servo_lag": {"tau_s"}, "resonance": {"freq_hz", "damping_ratio"}, "lost_steps": {"t_s", "offset_mm"},
    "sensor_gain": {"gain"}, "sensor_offset": {"offset"},
    "friction": {"coulomb_mm"}, "periodic_error": {"period_mm", "amplitude_mm"}, "sensor_latency": {"delay_s"},
    "sensor_drift": {"rate_per_s"}}
FORCED = ({"freq_hz", "amplitude_mm"}, {"freq_hz", "amplitude"})


@pytest.mark.parametrize("name", S.EFFECTS)
def test_every_effect_uses_catalogue_names(name):
    rng = np.random.default_rng(5)
    for _ in range(10):
        e = S.make_effect(name, rng).answer()
        locs = {"axis", "channel", "chain"} & set(e)
        assert len(locs) == 1
        if name == "geometry":
            assert e["chain"] in (1, 2, 3, "tool")
            assert set(e["parameters"]) in ({"length_offset_mm"}, {"tool_length_mm"},
                                            {"base_joint_radial_mm", "base_joint_z_mm"})
        elif name == "forced_vibration":
            assert set(e["parameters"]) == FORCED[0 if "axis" in e else 1]
        else:
            assert set(e["parameters"]) == CATALOGUE_PARAMS[name]


def test_clean_residual_is_noise():
    r, cols, res, noise = _case([])
    for c in ("tip_x", "tip_y", "tip_z"):
        rms = np.sqrt(np.nanmean(res[c] ** 2))
        assert 0.7 * noise["tip_mm"] < rms < 1.3 * noise["tip_mm"], c
    for c in ("strain_1", "strain_2", "strain_3"):
        assert abs(np.sqrt(np.mean(res[c] ** 2)) / noise["strain_ue"] - 1) < 0.2
    assert max(np.abs(res[c]).max() for c in res if c.startswith("enc_")) <= S.PULSE_MM / 2 + 1e-12


def test_backlash_flips_with_direction_by_its_width():
    e = S.Effect("backlash", {"axis": "X"}, {"width_mm": 0.02})
    r, cols, res, _ = _case([e], run="circle", duration=40.0, rate=200.0)
    v = np.gradient(cols["cmd_X"], r.t)
    up, down = v > 2.0, v < -2.0
    split = np.nanmean(res["tip_x"][up]) - np.nanmean(res["tip_x"][down])
    assert split == pytest.approx(0.02, rel=0.15)       # tip in W = T - table: +w/2 moving +, -w/2 moving -
    assert abs(np.nanmean(res["tip_y"][up]) - np.nanmean(res["tip_y"][down])) < 0.002


def test_pitch_error_is_periodic_in_the_screw_position():
    e = S.Effect("pitch_error", {"axis": "Y"}, {"period_mm": 5.0, "amplitude_mm": 0.008}, {"phase_rad": 1.0})
    r, cols, res, _ = _case([e], run="raster")
    ph = 2 * np.pi * cols["enc_Y"] / 5.0
    m = np.isfinite(res["tip_y"])
    A = np.stack([np.sin(ph), np.cos(ph), np.ones_like(ph)], -1)[m]
    s, c, _ = np.linalg.lstsq(A, res["tip_y"][m], rcond=None)[0]
    assert np.hypot(s, c) == pytest.approx(0.008, rel=0.2)


def test_servo_lag_enc_lags_cmd_by_tau_times_speed():
    e = S.Effect("servo_lag", {"axis": "L2"}, {"tau_s": 0.012})
    r, cols, res, _ = _case([e], run="circle")
    v = np.gradient(cols["cmd_L2"], r.t)
    tau = -_fit(v, res["enc_L2"])[0]
    assert tau == pytest.approx(0.012, rel=0.1)
    assert np.abs(res["enc_L1"]).max() <= S.PULSE_MM


def test_lost_steps_shift_the_load_side_not_the_motor_count():
    e = S.Effect("lost_steps", {"axis": "Y"}, {"t_s": 6.0, "offset_mm": 0.03})
    r, cols, res, _ = _case([e])
    before, after = r.t < 6.0, r.t >= 6.0
    jump = np.nanmean(res["tip_y"][after]) - np.nanmean(res["tip_y"][before])
    assert jump == pytest.approx(-0.03, rel=0.1)          # the table is 0.03 further: the tip in W is less
    assert np.abs(res["enc_Y"]).max() <= S.PULSE_MM


def test_thermal_growth_follows_temperature_times_screw_position():
    e = S.Effect("thermal_growth", {"axis": "X"}, {"alpha_per_K": 12e-6, "channel": "temp_screwX"},
                 {"t_ref_C": 20.0, "screw_fixed_end_mm": -75.0})
    r, cols, res, _ = _case([e], run="warmup", duration=300.0, rate=50.0)
    temp = N.ffill(cols["temp_screwX"])
    assert np.nanmax(temp) - np.nanmin(temp) > 2.0      # the screw warms up during the run
    x = (temp - 20.0) * (cols["enc_X"] + 75.0)
    alpha = -_fit(x, res["tip_x"])[0]
    assert alpha == pytest.approx(12e-6, rel=0.2)


def test_table_compliance_gives_way_to_the_tip_force():
    e = S.Effect("compliance", {"axis": "X"}, {"stiffness_N_per_mm": 3000.0})
    r, cols, res, _ = _case([e], loads=True)
    k = 1.0 / _fit(cols["load_fx"], res["tip_x"])[0]
    assert k == pytest.approx(3000.0, rel=0.2)


def _tip_jacobian_column(cols, chain):
    st = N.nominal_state(cols, M)
    J = K.jacobian_tool(st.P, st.R, M.geometry)       # d(tip, axis)/dq
    return st, J[:, :3, chain]


def test_chain_compliance_deflects_the_tip_by_force_over_stiffness():
    e = S.Effect("compliance", {"axis": "L3"}, {"stiffness_N_per_mm": 2500.0})
    r, cols, res, _ = _case([e], loads=True)
    st, col = _tip_jacobian_column(cols, 2)
    model = -(col * st.axial[:, 2:3])                   # tip shift per unit 1/k
    y = np.stack([res[c] for c in ("tip_x", "tip_y", "tip_z")], -1)
    m = np.all(np.isfinite(y), -1)
    inv_k = np.sum(model[m] * y[m]) / np.sum(model[m] ** 2)
    assert 1 / inv_k == pytest.approx(2500.0, rel=0.2)


def test_geometry_length_offset_moves_the_tip_along_the_chain_jacobian():
    e = S.Effect("geometry", {"chain": 1}, {"length_offset_mm": 0.08})
    r, cols, res, _ = _case([e])
    st, col = _tip_jacobian_column(cols, 0)
    y = np.stack([res[c] for c in ("tip_x", "tip_y", "tip_z")], -1)
    m = np.all(np.isfinite(y), -1)
    off = np.sum(col[m] * y[m]) / np.sum(col[m] ** 2)
    assert off == pytest.approx(0.08, rel=0.05)


def test_strain_resonance_rings_at_its_frequency():
    e = S.Effect("resonance", {"channel": "strain_2"}, {"freq_hz": 23.0, "damping_ratio": 0.03},
                 {"peak_ue": 10.0})
    r, cols, res, _ = _case([e], rate=1000.0)
    x = res["strain_2"] - res["strain_2"].mean()
    f = np.fft.rfftfreq(len(x), 1 / r.rate_hz)
    spec = np.abs(np.fft.rfft(x * np.hanning(len(x))))
    band = f > 3.0
    assert f[band][np.argmax(spec[band])] == pytest.approx(23.0, rel=0.05)
    assert np.std(res["strain_1"]) < 1.0


def test_sensor_gain_and_offset_scale_and_shift_one_channel():
    eg = S.Effect("sensor_gain", {"channel": "strain_1"}, {"gain": 1.06})
    eo = S.Effect("sensor_offset", {"channel": "tip_z"}, {"offset": -0.025})
    r, cols, res, _ = _case([eg, eo])
    pred = cols["strain_1"] - res["strain_1"]
    assert _fit(pred, cols["strain_1"])[0] == pytest.approx(1.06, abs=0.01)
    assert np.nanmean(res["tip_z"]) == pytest.approx(-0.025, abs=0.002)


def test_same_seed_same_case_and_cli_rejects_unknown_effects(tmp_path):
    a = S.synth_case(np.random.default_rng(11), ["pitch_error"], duration_s=5.0, rate_hz=200.0)
    b = S.synth_case(np.random.default_rng(11), ["pitch_error"], duration_s=5.0, rate_hz=200.0)
    assert a.answer == b.answer
    assert all(np.array_equal(a.columns[c], b.columns[c], equal_nan=True) for c in a.columns)
    with pytest.raises(InputError, match="unknown effect"):
        S.parse_effects("backlash,flux_capacitor")
    ap = argparse.ArgumentParser()
    add_synth_parser(ap.add_subparsers())
    args = ap.parse_args(["synth", str(tmp_path / "o"), "--clean", "--duration", "3", "--rate", "100"])
    assert args.func(args) == 0
    ans = json.loads((tmp_path / "o" / "case-000" / "answer.json").read_text())
    assert ans["effects"] == []


def test_bundled_examples_load_with_answers_beside():
    from pathlib import Path
    root = Path(__file__).resolve().parents[2] / "examples" / "recordings"
    cases = sorted(p for p in root.iterdir() if (p / "recording").is_dir())
    assert len(cases) >= 3
    for d in cases:
        rec = read_recording(d / "recording")
        ans = json.loads((d / "answer.json").read_text())
        assert not (d / "recording" / "answer.json").exists()
        assert all(e["effect"] in S.EFFECTS for e in ans["effects"])
        assert sum(p.stat().st_size for p in (d / "recording").iterdir()) < 2e6
        res = N.residuals(rec)
        rms = np.sqrt(np.nanmean(res["tip_x"] ** 2))
        if not ans["effects"]:                                   # clean: tracker noise only
            assert rms < 1.3 * ans["noise"]["tip_mm"]


from hypothesis import given, settings, strategies as st  # noqa: E402


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-50, 50), min_size=2, max_size=200), st.floats(0.001, 0.1))
def test_play_operator_is_a_deadband(xs, width):
    """Backlash: the load stays within w/2 of the motor and only moves when pushed at the edge."""
    x = np.array(xs)
    y = S.play(x, width)
    assert np.all(np.abs(y - x) <= width / 2 + 1e-12)
    moved = np.flatnonzero(np.diff(y) != 0) + 1
    assert np.allclose(np.abs(y[moved] - x[moved]), width / 2, atol=1e-9)


def test_first_order_lag_trails_a_ramp_by_tau_times_speed():
    dt, tau, v = 1e-3, 0.02, 30.0
    t = np.arange(5000) * dt
    y = S.first_order_lag(t, v * t, tau)
    assert np.mean(v * t[-1000:] - y[-1000:]) == pytest.approx(v * tau, rel=0.01)


def test_magnitude_and_noise_scale():
    rng = np.random.default_rng(2)
    e = S.make_effect("compliance", rng, axis="X")
    half = S.scale_effect(e, 0.5)
    assert half.parameters["stiffness_N_per_mm"] == pytest.approx(2 * e.parameters["stiffness_N_per_mm"])
    g = S.Effect("sensor_gain", {"channel": "tip_x"}, {"gain": 1.001})
    assert S.scale_effect(g, 3).parameters["gain"] == pytest.approx(1.003)
    r = S.make_run("calibration", np.random.default_rng(1), M, 5.0, 200.0, False)
    _, n1 = S.simulate(r, [], np.random.default_rng(4), M)
    c0, n0 = S.simulate(r, [], np.random.default_rng(4), M, noise_scale=0.0, enc=False)
    assert n0["tip_mm"] == 0.0 and n1["tip_mm"] > 0
    pred = N.predict_columns(c0, M)
    assert np.nanmax(np.abs(c0["tip_x"] - pred["tip_x"])) < 1e-9      # noiseless clean, no pulse quantisation = the twin


def test_recording_imperfections_keep_a_valid_recording_and_the_noise_is_coloured():
    rng = np.random.default_rng(4)
    case = S.synth_case(rng, [], machine=M, seed=4, duration_s=6.0, rate_hz=250.0, imperfections=True)
    t = case.columns["t"]
    assert np.all(np.diff(t) > 0) and 0.97 * 1500 < len(t) < 1500      # rows dropped, still increasing
    dt = np.diff(t)
    assert np.ptp(dt) > 0.1 / 250                                          # jittered stamps
    clean = S.synth_case(np.random.default_rng(4), [], machine=M, seed=4, duration_s=6.0, rate_hz=250.0)
    assert case.answer["imperfections"] is True and "imperfections" not in clean.answer


def test_an_oddity_is_kept_out_of_the_effects_of_the_answer_key():
    rng = np.random.default_rng(6)
    case = S.synth_case(rng, [], machine=M, seed=6, duration_s=6.0, rate_hz=250.0, oddities=["straightness"])
    assert case.answer["effects"] == [] and case.answer["oddities"][0]["kind"] == "straightness"
    base = S.synth_case(np.random.default_rng(6), [], machine=M, seed=6, duration_s=6.0, rate_hz=250.0)
    d = case.columns["tip_y"] - base.columns["tip_y"]                    # same noise: only the bump differs
    o = case.answer["oddities"][0]
    assert np.nanmax(np.abs(d)) <= abs(o["amplitude_mm"]) + 1e-9 and np.nanmax(np.abs(d)) > 0.3 * abs(o["amplitude_mm"])
    assert np.allclose(case.columns["tip_x"], base.columns["tip_x"], equal_nan=True)


# ---------------------------------------------------------------- one plant: the loop path and the batch path

LOOP_EFFECTS = [S.Effect("backlash", {"axis": "X"}, {"width_mm": 0.02}),
                S.Effect("pitch_error", {"axis": "L2"}, {"period_mm": 5.0, "amplitude_mm": 0.005}, {"phase_rad": 1.0}),
                S.Effect("friction", {"axis": "Y"}, {"coulomb_mm": 0.01},
                         {"stribeck_mm": 0.005, "stribeck_speed_mm_s": 2.0}),
                S.Effect("servo_lag", {"axis": "L1"}, {"tau_s": 0.01})]


def test_the_control_loop_on_the_sim_and_the_batch_plant_agree_on_the_same_commands():
    """The run machined by the real ControlLoop on the sim backend carrying the effects, and the
    fast batch path fed the loop's commanded joints: encoders and load side equal within 1e-9 mm
    (measured 2e-13: the same pmctl.core.plant_effects physics, per tick and batch)."""
    r = S.make_run("circle", np.random.default_rng(1), M, 3.0, 1000.0, False)
    machined, (q_cmd, q_mot, q_load) = S.loop_plant(r, [dataclasses.replace(e) for e in LOOP_EFFECTS], M)
    assert len(machined.t) >= len(r.t) and np.max(np.abs(q_cmd[: len(r.t)] - r.q)) < 0.05   # it followed the run
    b_mot, b_load, _ = S.plant_batch(q_cmd, machined.t, LOOP_EFFECTS, None, M)
    assert np.max(np.abs(q_mot - b_mot)) < 1e-9 and np.max(np.abs(q_load - b_load)) < 1e-9
    assert np.ptp(q_load[:, 3] - q_mot[:, 3]) == pytest.approx(0.02)            # backlash flips by its width
    assert np.ptp(q_load[:, 1] - q_mot[:, 1]) > 0.009                           # pitch error ±5 µm
    # friction: at rest the motor stays behind its command by c + c_s, against its last motion (Y moves
    # one way in this run; a controller dithering at rest used to show both signs)
    assert np.max(np.abs(q_mot[:, 4] - q_cmd[:, 4])) == pytest.approx(0.015, abs=1e-3)


def test_a_loop_case_and_a_batch_case_diagnose_to_the_same_effect():
    from pmctl.tools.twin.diagnose import diagnose
    found = {}
    for plant in ("loop", "batch"):
        e = S.Effect("backlash", {"axis": "X"}, {"width_mm": 0.02})
        case = S.synth_case(np.random.default_rng(31), [e], machine=M, seed=31, duration_s=10.0, rate_hz=500.0,
                            run="raster", plant=plant)
        assert case.answer["plant"] == plant
        rep, _ = diagnose(case.columns, M, cap=3000)
        found[plant] = [(f["effect"], f.get("axis")) for f in rep["findings"]]
    assert found["loop"][:1] == found["batch"][:1] == [("backlash", "X")], found


def test_the_loop_path_refuses_effects_the_sim_does_not_carry():
    from pmctl.core.errors import InputError
    r = S.make_run("circle", np.random.default_rng(1), M, 1.0, 1000.0, False)
    with pytest.raises(InputError, match="does not carry thermal_growth"):
        S.loop_plant(r, [S.Effect("thermal_growth", {"axis": "X"}, {"alpha_per_K": 1e-5})], M)


def test_a_drawn_periodic_error_is_identifiable_in_its_run():
    """Identifiability rule: the screw travels >= 3 periods, and moves <= 1/4 period between the
    laser tracker's samples (the only channel that sees the load side)."""
    for seed in range(4):
        c = S.synth_case(np.random.default_rng(seed), ["periodic_error"], machine=M, seed=seed, duration_s=5.0,
                         rate_hz=500.0)
        e = c.answer["effects"][0]
        p, j = e["parameters"]["period_mm"], "cmd_" + e["axis"]
        assert e["details"]["identifiable"] and 0.8 <= p <= 8.0
        assert np.ptp(c.columns[j]) >= 3 * p - 1e-9
        tracked = np.isfinite(c.columns["tip_x"])
        ds = np.abs(np.diff(c.columns[j][tracked]))
        assert np.median(ds[ds > 1e-9]) <= 0.3 * p             # tracker drop-outs aside, within the rule
        assert all(abs(p * k / 5.0 - 1) > 0.08 for k in (1, 2, 3, 4))   # not a lead harmonic (a pitch error)


# ---------------------------------------------------------------- more physics outside the catalogue

def _odd(kind, seed=6, duration=6.0, rate=250.0, run="raster"):
    """The case with the oddity, and the same case without it (same run, same noise)."""
    kw = dict(machine=M, seed=seed, duration_s=duration, rate_hz=rate, run=run)
    case = S.synth_case(np.random.default_rng(seed), [], oddities=[kind], **kw)
    base = S.synth_case(np.random.default_rng(seed), [], **kw)
    return case, base, case.answer["oddities"][0]


def test_every_oddity_stays_out_of_the_effects_and_names_its_channels():
    for kind in S.ODDITIES:
        case, _, o = _odd(kind)
        assert case.answer["effects"] == [] and o["kind"] == kind and o["channels"]
        assert all(c in case.columns for c in o["channels"]), (kind, o["channels"])


def test_a_crash_step_moves_the_drive_count_at_its_instant_and_stays():
    case, base, o = _odd("crash_step", seed=8, run="calibration")
    t = case.columns["t"]
    d = case.columns[f"enc_{o['axis']}"] - base.columns[f"enc_{o['axis']}"]
    assert np.all(np.abs(d[t < o["t_s"] - 0.01]) <= S.PULSE_MM)                     # nothing before
    assert np.all(np.abs(d[t > o["t_s"] + 0.01] - o["offset_mm"]) <= S.PULSE_MM)    # the offset after, kept
    assert np.array_equal(case.columns[f"cmd_{o['axis']}"], base.columns[f"cmd_{o['axis']}"])


def test_an_encoder_glitch_shows_in_its_bursts_only_and_the_axis_does_not_move():
    case, base, o = _odd("encoder_glitch", seed=12)
    t = case.columns["t"]
    d = case.columns[f"enc_{o['axis']}"] - base.columns[f"enc_{o['axis']}"]
    inside = np.zeros(len(t), bool)
    for a, b in o["bursts_s"]:
        inside |= (t >= a) & (t < b)
    assert np.all(np.abs(d[inside] - o["offset_mm"]) <= S.PULSE_MM) and np.all(np.abs(d[~inside]) <= S.PULSE_MM)
    assert np.allclose(case.columns["tip_x"], base.columns["tip_x"], equal_nan=True)     # the tool did not move


def test_a_reversal_spike_rises_after_each_reversal_on_the_load_side_only():
    free = S.synth_case(np.random.default_rng(10), [], machine=M, seed=10, duration_s=2.0, rate_hz=100.0,
                        oddities=["reversal_spike"])
    assert free.answer["run"] == "raster"                    # drawn with a run of many reversals
    case, base, o = _odd("reversal_spike", seed=10, duration=20.0, rate=100.0)
    j = S.AXES.index(o["axis"])
    rev = S._reversals(case.columns[f"cmd_{o['axis']}"])
    assert len(rev) >= 4
    assert np.array_equal(case.columns[f"enc_{o['axis']}"], base.columns[f"enc_{o['axis']}"])
    t = case.columns["t"]
    q_cmd = np.stack([case.columns[f"cmd_{a}"] for a in S.AXES], 1)
    _, q_load = S.axis_oddities([o], t, q_cmd, q_cmd.copy(), q_cmd.copy())
    bump = q_load[:, j] - q_cmd[:, j]
    i0 = rev[len(rev) // 2]
    k = np.searchsorted(t, t[i0] + o["tau_s"])               # the peak: amplitude at tau after the reversal
    assert abs(abs(bump[k]) - o["amplitude_mm"]) < 0.05 * o["amplitude_mm"]
    assert np.all(np.abs(bump) <= o["amplitude_mm"] + 1e-12)


def test_a_table_sag_lowers_the_tip_with_the_square_of_the_x_overhang():
    case, base, o = _odd("table_sag", seed=11)
    dz = case.columns["tip_z"] - base.columns["tip_z"]
    x = case.columns["enc_X"] if "enc_X" in case.columns else case.columns["cmd_X"]
    ok = np.isfinite(dz)
    pred = -o["amplitude_mm"] * ((x - o["center_mm"]) / o["half_span_mm"]) ** 2
    assert np.abs(dz[ok] - pred[ok]).max() < 1e-6 + 1e-3 * o["amplitude_mm"]
