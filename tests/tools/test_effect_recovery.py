"""The wider catalogue (issue 12): each new effect recovers its own physics from a short synth
run, and each effect's own checks refuse its look-alikes. Contexts are built once per case."""

import numpy as np

from pmctl.core.config import load_machine
from pmctl.tools.twin import effects as fx
from pmctl.tools.twin import synth
from pmctl.tools.twin.diagnose import build_context
from pmctl.tools.twin.locate import locate
from pmctl.tools.twin.unexplained import unexplained

M = load_machine()
_CACHE = {}


def _ctx(effect, seed=5, run="calibration", duration=8.0, rate=250.0, oddities=()):
    key = (repr(effect), seed, run, duration, rate, tuple(oddities))
    if key not in _CACHE:
        rng = np.random.default_rng(seed)
        case = synth.synth_case(rng, [effect] if effect else [], machine=M, seed=seed, run=run,
                                duration_s=duration, rate_hz=rate, oddities=oddities)
        _CACHE[key] = (build_context(case.columns, M, cap=2000), case)
    return _CACHE[key]


def _all(ctx):
    return np.ones(len(ctx.obs.y), bool)


FRICTION = synth.Effect("friction", {"axis": "X"}, {"coulomb_mm": 0.012},
                        {"stribeck_mm": 0.0, "stribeck_speed_mm_s": 2.0})


def test_friction_is_a_trailing_error_that_flips_at_reversals_and_is_not_a_servo_lag():
    ctx, case = _ctx(FRICTION)
    f = fx.Friction("X").fit(ctx, ctx.obs.y, _all(ctx))
    assert f.ok and abs(f.params["coulomb_mm"] - 0.012) < 0.0015
    lag = fx.ServoLag("X")
    fl = lag.fit(ctx, ctx.obs.y, _all(ctx))
    assert any("friction" in p for p in lag.check(ctx, fl, ctx.obs.y))


def test_a_servo_lag_is_not_refused_as_friction():
    ctx, _ = _ctx(synth.Effect("servo_lag", {"axis": "Y"}, {"tau_s": 0.01}))
    lag = fx.ServoLag("Y")
    fl = lag.fit(ctx, ctx.obs.y, _all(ctx))
    assert abs(fl.params["tau_s"] - 0.01) < 0.001 and lag.check(ctx, fl, ctx.obs.y) == []


def test_a_steady_line_is_forced_vibration_and_the_resonance_model_refuses_it():
    e = synth.Effect("forced_vibration", {"channel": "strain_2"}, {"freq_hz": 37.0, "amplitude": 3.0},
                     {"phase_rad": 0.4})
    ctx, _ = _ctx(e)
    fv = fx.ForcedVibration("strain_2", "channel")
    f = fv.fit(ctx, ctx.obs.y, _all(ctx))
    assert abs(f.params["freq_hz"] - 37.0) < 0.05 and abs(f.params["amplitude"] - 3.0) < 0.3
    res = fx.Resonance("strain_2", "channel")
    fr = res.fit(ctx, ctx.obs.y, _all(ctx))
    assert not fr.ok or res.check(ctx, fr, ctx.obs.y)       # no mode: a line of constant amplitude


def test_tracker_latency_is_one_delay_for_every_tracker_channel():
    ctx, _ = _ctx(synth.Effect("sensor_latency", {"channel": "tip_*"}, {"delay_s": 0.003}), run="circle")
    c = fx.SensorLatency("tip_*")
    f = c.fit(ctx, ctx.obs.y, _all(ctx))
    assert abs(f.params["delay_s"] - 0.003) < 0.0003 and c.check(ctx, f, ctx.obs.y) == []


def test_periodic_error_at_a_gear_period_and_the_lead_split_between_pitch_and_periodic():
    assert fx.lead_harmonic(5.0, 5.0) == 1 and fx.lead_harmonic(2.5, 5.0) == 2 and fx.lead_harmonic(3.3, 5.0) == 0
    e = synth.Effect("periodic_error", {"axis": "X"}, {"period_mm": 3.3, "amplitude_mm": 0.008}, {"phase_rad": 1.0})
    ctx, _ = _ctx(e)
    c = fx.PeriodicError("X")
    f = c.fit(ctx, ctx.obs.y, _all(ctx))
    assert abs(f.params["period_mm"] - 3.3) < 0.05 and abs(f.params["amplitude_mm"] - 0.008) < 0.0015
    assert c.check(ctx, f, ctx.obs.y) == []
    # a pitch error may only use the lead's lines: it explains little of a 3.3 mm line
    fp = fx.PitchError("X").fit(ctx, ctx.obs.y, _all(ctx))
    y = ctx.obs.y

    def gain(fit):
        return float(y @ y - (y - fit.pred) @ (y - fit.pred)) if fit.ok else 0.0
    assert gain(fp) < 0.3 * gain(f)


def test_sensor_drift_rate_is_recovered():
    ctx, _ = _ctx(synth.Effect("sensor_drift", {"channel": "strain_3"}, {"rate_per_s": 0.4}))
    f = fx.SensorDrift("strain_3").fit(ctx, ctx.obs.y, _all(ctx))
    assert abs(f.params["rate_per_s"] - 0.4) < 0.04


def test_thermal_growth_reports_the_fixed_bearing_end():
    e = synth.Effect("thermal_growth", {"axis": "X"}, {"alpha_per_K": 1.5e-5, "channel": "temp_screwX",
                                                      "screw_fixed_end_mm": 75.0}, {"t_ref_C": 20.0})
    ctx, _ = _ctx(e, run="warmup", duration=240.0, rate=50.0)
    c = fx.ThermalGrowth("X", "temp_screwX")
    f = c.fit(ctx, ctx.obs.y, _all(ctx))
    assert f.ok and abs(f.params["alpha_per_K"] - 1.5e-5) < 0.2e-5
    assert abs(f.params["screw_fixed_end_mm"] - 75.0) < 15.0


def test_unexplained_names_the_channel_and_the_signature_of_a_drift_nobody_fitted():
    ctx, _ = _ctx(synth.Effect("sensor_drift", {"channel": "strain_1"}, {"rate_per_s": 0.5}))
    u = unexplained(ctx, ctx.obs.y, locate(ctx))
    e = [x for x in u if "strain_1" in x["channels"]]
    assert e and e[0]["signature"] == "drift" and e[0]["excess_over_noise"] > 2
    assert not [x for x in u if x["channels"][0].startswith("strain_") and "strain_1" not in x["channels"]]


def test_a_clean_recording_leaves_nothing_unexplained():
    ctx, _ = _ctx(None, seed=8)
    assert unexplained(ctx, ctx.obs.y, locate(ctx)) == []


from hypothesis import assume, given, settings, strategies as st  # noqa: E402


@settings(max_examples=30, deadline=None)
@given(st.floats(0.001, 0.2), st.integers(0, 10_000), st.sampled_from([-1.0, 0.0, 1.0]))
def test_backlash_on_the_rows_and_turning_points_only_equals_backlash_on_the_whole_record(width, seed, start):
    # the play operator is rate-independent, which the backlash fit uses to skip most samples
    rng = np.random.default_rng(seed)
    x = np.cumsum(np.repeat(rng.normal(0, 1, 30), 60)) * 0.01 + np.linspace(0, 0.5, 1800)
    turn = np.flatnonzero(np.diff(fx.direction(x)) != 0)
    rows = np.sort(rng.choice(len(x), 200, replace=False))
    idx = np.unique(np.concatenate([[0], turn, turn + 1, rows, [len(x) - 1]]))
    full = fx.play_error(x, width, start)[rows]
    sub = fx.play_error(x[idx], width, start)[np.searchsorted(idx, rows)]
    assert np.allclose(full, sub, atol=1e-12)


def test_a_vibration_burst_is_not_a_steady_forced_vibration():
    ctx, case = _ctx(None, seed=9, run="circle", duration=10.0, oddities=("chatter_burst",))
    fv = fx.ForcedVibration("X", "axis")
    f = fv.fit(ctx, ctx.obs.y, _all(ctx))
    assert f.ok and abs(f.params["freq_hz"] - case.answer["oddities"][0]["freq_hz"]) < 0.3
    assert any("not steady" in p for p in fv.check(ctx, f, ctx.obs.y))


@settings(max_examples=40, deadline=None)
@given(st.floats(2.0, 60.0), st.floats(0.5, 30.0), st.floats(0, 2 * np.pi), st.integers(0, 10_000),
       st.sampled_from([250.0, 1000.0]))
def test_a_steady_line_in_white_noise_passes_the_steadiness_check(f, snr, phase, seed, rate):
    # one sinusoid of any amplitude (0.5-30 x the unit noise) at any phase: the windows scatter about
    # the whole record's line by their noise alone (chi^2 per degree of freedom ~ 1)
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 10.0, 1.0 / rate)
    y = snr * np.sin(2 * np.pi * f * t + phase) + rng.normal(0, 1, len(t))
    assert fx._steady_line_check(np.ones_like(t), t, y, f, t[0], t[-1]) == []


@settings(max_examples=25, deadline=None)
@given(st.floats(4.0, 10.0), st.floats(0.7, 2.5), st.floats(0.02, 0.05), st.floats(3.0, 20.0), st.integers(0, 10_000))
def test_periodic_knocks_fail_the_steadiness_check(f, period, zeta, snr, seed):
    # a ring restarted every period and dying away (synth's pulse_train), at its own frequency:
    # windows see it rise and die, far beyond their noise. (The ring's peak at 3x the per-sample
    # noise and up: the gentlest knock, 10 Hz every 0.7 s with zeta 0.023, then scatters 10x; at
    # 2x it is 5x, the rule's edge)
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 12.0, 1e-3)
    s = np.mod(t, period)
    w = 2 * np.pi * f
    y = snr * np.exp(-zeta * w * s) * np.sin(w * s) + rng.normal(0, 1, len(t))
    why = fx._steady_line_check(np.ones_like(t), t, y, f, t[0], t[-1])
    assert why and "not a steady source" in why[0]


@settings(max_examples=40, deadline=None)
@given(st.floats(2.0, 60.0), st.floats(0.5, 30.0), st.floats(0, 2 * np.pi), st.integers(0, 10_000),
       st.sampled_from([50.0, 250.0, 1000.0]))
def test_a_steady_line_in_white_noise_leaves_no_sideband(f, snr, phase, seed, rate):
    # after the line, the band around it holds noise only: the best other line there explains
    # the maximum of a few hundred chi-square(2) draws, far under the threshold
    rate = max(rate, 3 * f)
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 10.0, 1.0 / rate)
    y = snr * np.sin(2 * np.pi * f * t + phase) + rng.normal(0, 1, len(t))
    assert fx._sideband_check(np.ones_like(t), t, y, f, t[0], t[-1]) == []


@settings(max_examples=30, deadline=None)
@given(st.floats(4.0, 10.0), st.floats(0.7, 2.5), st.floats(0.02, 0.05), st.floats(5.0, 20.0), st.integers(0, 10_000),
       st.sampled_from([50.0, 100.0, 1000.0]))
def test_periodic_knocks_at_a_trackers_rate_are_refused_as_a_steady_line(f, period, zeta, snr, seed, rate):
    # a knock train is a comb of lines 1/period apart. A steady-line fit takes the comb line nearest
    # the ring; at a tracker's 50 Hz, 2-cycle windows held 10 samples, too few to count, and the
    # windows' test passed by default (blind 11000/oddity/6). Windows now hold 16 samples, and the
    # comb's neighbouring lines refuse it where the windows cannot tell. (A knock that has not died
    # to a quarter by the next one, zeta*omega*period < 1.4, is a steady line modulated by less
    # than 20 %: as far as 12 s of a tracker can tell, it is one. The knock's peak is 5 x the noise
    # of a sample or more: at 3 x, 600 samples at 50 Hz put the comb's next line at the threshold)
    assume(zeta * 2 * np.pi * f * period >= 1.4)
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 12.0, 1.0 / rate)
    s = np.mod(t, period)
    w = 2 * np.pi * f
    y = snr * np.exp(-zeta * w * s) * np.sin(w * s) + rng.normal(0, 1, len(t))
    fl = round(f * period) / period
    g = np.ones_like(t)
    why = fx._steady_line_check(g, t, y, fl, t[0], t[-1]) or fx._sideband_check(g, t, y, fl, t[0], t[-1])
    assert why and ("not a steady source" in why[0] or "comb" in why[0])


def test_the_sideband_scan_of_a_long_record_kept_as_runs_still_tells_a_comb_from_a_line():
    # 48 runs of 20 s spread over 10^4 s (a 10^7-row recording as the diagnosis holds it): the scan
    # looks at the middle stretch its grid resolves (SIDEBAND_FREQS frequencies), not the whole span
    rng = np.random.default_rng(1)
    t = np.concatenate([np.arange(a, a + 20, 0.01) for a in np.linspace(0, 9980, 48)])
    g = np.ones_like(t)
    y = 3 * np.sin(2 * np.pi * 7.0 * t + 0.3) + rng.normal(0, 1, len(t))
    assert fx._sideband_check(g, t, y, 7.0, t[0], t[-1]) == []
    for fk in (7.3, 31.0):          # (at 31 Hz the scanned stretch, 111 s, is shorter than a gap)
        s, w = np.mod(t, 1.3), 2 * np.pi * fk
        yk = 8 * np.exp(-0.04 * w * s) * np.sin(w * s) + rng.normal(0, 1, len(t))
        why = fx._sideband_check(g, t, yk, round(fk * 1.3) / 1.3, t[0], t[-1])
        assert why and "comb" in why[0], fk


def test_periodic_knocks_are_located_not_named_a_forced_vibration():
    """A press next door knocks the tracker's stand every 1.9 s; each knock rings at 9.4 Hz and dies
    away. Its comb of lines passed the quarter-amplitude test, and the diagnosis named forced
    vibrations on X and Y with confidence 0.58-0.65. Now the windows' scatter rejects them and the
    line is left unexplained on the tracker's channels."""
    from pmctl.tools.twin.diagnose import diagnose
    rng = np.random.default_rng(7)
    case = synth.synth_case(rng, [], machine=M, seed=7, duration_s=12.0, rate_hz=1000.0, oddities=["pulse_train"])
    rep, _ = diagnose(case.columns, M, cap=2000)
    assert not [f for f in rep["findings"] if f["confidence"] >= 0.5], rep["findings"]
    assert not any(f["effect"] == "forced_vibration" for f in rep["findings"]), rep["findings"]
    assert any({"tip_x", "tip_y"} & set(u["channels"]) for u in rep["unexplained"]), rep["unexplained"]
