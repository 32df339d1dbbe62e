"""Detection at the noise floor (issue 12): small effects whose signal is still well above noise on
held-out samples are named with the right parameters, and a clean run stays clean. Each case is a
short synth run diagnosed blind; pmctl.tools.twin.scoring judges it against the answer key."""

import numpy as np
from hypothesis import given, settings, strategies as st

from pmctl.core.config import load_machine
from pmctl.tools.twin import effects as fx
from pmctl.tools.twin import synth
from pmctl.tools.twin.diagnose import build_context, diagnose, select_effects
from pmctl.tools.twin.observations import regular_times
from pmctl.tools.twin.scoring import score

M = load_machine()


def _case(effects, seed, *, run, duration, rate, imperfections=False):
    rng = np.random.default_rng(seed)
    return synth.synth_case(rng, effects, machine=M, seed=seed, run=run, duration_s=duration, rate_hz=rate,
                            imperfections=imperfections)


def _found(case, cap=2000):
    rep, ex = diagnose(case.columns, M, cap=cap)
    return rep, score(rep, case.answer, noise=ex["ctx"].obs.sigma)


def test_a_2_5_um_pitch_error_under_tracker_noise_is_found_at_the_lead():
    # 2.5 µm of sine amplitude under ~1.5 µm of tracker noise: no sample stands out, the many do
    e = synth.Effect("pitch_error", {"axis": "X"}, {"period_mm": 5.0, "amplitude_mm": 0.0025}, {"phase_rad": 2.0})
    case = _case([e], 31, run="calibration", duration=10.0, rate=250.0)
    rep, sc = _found(case)
    r = sc["effects"][0]
    assert r["named"] and r["params_ok"], (rep["findings"], r)
    assert sc["extra_findings"] == []


def test_a_2_um_pitch_error_in_a_250_hz_log_with_imperfections_passes_the_share_rule_beyond_chance():
    # blind case 14000/pitch_near/1 (seed 140705): 2.03 µm on L3 in a 14.7 s circle logged at 250 Hz
    # with dropped rows, jitter, coloured noise and a tracker drop-out. The pitch fit held out 4 x
    # the threshold but took only 20 % of what the flexible description removed, whose 50
    # coefficients a channel fit the noise too; beyond chance it takes 34 %, and it is named
    seed = 140705
    rng = np.random.default_rng(seed)
    ax = str(rng.choice(synth.AXES))
    e = synth.Effect("pitch_error", {"axis": ax}, {"period_mm": 5.0, "amplitude_mm": float(rng.uniform(0.002, 0.003))},
                     {"phase_rad": float(rng.uniform(0, 2 * np.pi))})
    case = synth.synth_case(rng, [e], machine=M, seed=seed, duration_s=float(rng.uniform(10, 20)), rate_hz=250.0,
                            imperfections=True)
    assert ax == "L3" and abs(e.parameters["amplitude_mm"] - 0.00203) < 1e-5
    rep, sc = _found(case)
    r = sc["effects"][0]
    assert r["named"] and r["params_ok"], (rep["findings"], r)
    assert sc["extra_findings"] == []


@settings(max_examples=6, deadline=None)
@given(st.integers(0, 2**31 - 1), st.sampled_from(["circle", "raster", "calibration"]), st.sampled_from([250.0, 1000.0]))
def test_the_flexible_description_removes_about_its_rank_from_white_noise(seed, run, rate):
    # the chance gain the share rule takes off: on whitened noise alone, the fit removes its rank on
    # average (chi-square with dof degrees of freedom). Averaged over 100 draws (sd sqrt(2 dof / 100)),
    # so counting the basis' columns instead (the hats of one variable sum to one) would fail
    from pmctl.tools.twin.unexplained import flexible_gain
    case = _case([], 7, run=run, duration=10.0, rate=rate)
    ctx = build_context(case.columns, M, cap=2000)
    rng = np.random.default_rng(seed)
    mask = np.zeros(len(ctx.obs.channels), bool)
    mask[[i for i, c in enumerate(ctx.obs.channels) if c.startswith("tip_")]] = True
    gains = [flexible_gain(ctx, rng.standard_normal(len(ctx.obs.y)), mask, with_dof=True) for _ in range(100)]
    dof = gains[0][1]
    mean = float(np.mean([g for g, _ in gains]))
    cols = ctx.extra[("flex_basis",)].shape[1] * int(mask.sum())
    assert 0 < dof < cols and abs(mean - dof) < 5 * np.sqrt(2 * dof / 100), (mean, dof, cols)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 2), st.floats(0.0, 300.0), st.integers(1, 200)), min_size=1, max_size=12),
       st.sampled_from([1.0, 1.25, 5.0, 7.3]))
def test_samples_at_one_screw_position_count_as_at_most_20_per_channel(dwells, period):
    # each (channel, position, n) is a dwell of n samples of a channel at one screw position
    ch = np.concatenate([np.full(n, c) for c, _, n in dwells])
    x = np.concatenate([np.full(n, p) for _, p, n in dwells])
    w = fx.position_weights(ch, x, period)
    assert np.all((w > 0) & (w <= 1))
    b = np.floor(x / (period / fx.POSITION_BINS))
    for key in set(zip(ch.tolist(), b.tolist())):
        m = (ch == key[0]) & (b == key[1])
        assert abs(w[m].sum() - min(m.sum(), fx.PER_BIN)) < 1e-9        # a bin's samples weigh min(n, 20)
        assert np.ptp(w[m]) == 0                                          # equally


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10_000), st.floats(1e-7, 1e-2), st.floats(0.0, 1e3))
def test_the_noise_a_prediction_carries_is_told_from_its_smooth_signal(seed, sigma, amp):
    # a smooth signal (a few slow sines, any size) plus white noise sigma: the estimate is sigma
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 10.0, 3000)
    sig = amp * sigma * sum(rng.normal() * np.sin(2 * np.pi * f * t + rng.uniform(0, 6)) for f in (0.1, 0.37, 1.3))
    from pmctl.tools.twin.signals import noise_level  # what SensorGain.applicable measures a prediction with
    est = noise_level(sig + sigma * rng.normal(size=t.size))
    assert abs(est / sigma - 1) < 0.12


def test_two_dwells_do_not_outweigh_the_travel_in_a_pitch_fit():
    """Blind case 7000/pitch_error/1: a calibration run at 250 Hz with coloured tracker noise spends
    1600 of its 2960 tracker samples dwelling at two screw positions. They measured two values of
    the pitch error, with the dwell's slow noise shared among them, yet weighed as 1600 independent
    samples: a 6.2 µm error was fitted as 4.6 µm, out of tolerance."""
    case = _case(["pitch_error"], 30758, run=None, duration=10.0, rate=250.0, imperfections=True)
    (e,) = case.answer["effects"]
    assert e["axis"] == "L3" and case.answer["run"] == "calibration"
    rep, sc = _found(case)
    r = sc["effects"][0]
    assert r["named"] and r["params_ok"], (rep["findings"], r)
    f = [f for f in rep["findings"] if f["effect"] == "pitch_error"][0]
    assert abs(f["parameters"]["amplitude_mm"] / e["parameters"]["amplitude_mm"] - 1) < 0.1


def test_a_periodic_error_a_tenth_off_the_lead_is_no_pitch_error():
    # on a short travel a 5.57 mm line falls into the 5 mm bin of the position spectrum: the line
    # must be refined before it is told apart from the lead
    e = synth.Effect("periodic_error", {"axis": "X"}, {"period_mm": 5.57, "amplitude_mm": 0.006}, {"phase_rad": 1.5})
    case = _case([e], 32, run="calibration", duration=10.0, rate=250.0)
    rep, sc = _found(case)
    assert sc["all_found"], (rep["findings"], sc)
    assert not [f for f in rep["findings"] if f["effect"] == "pitch_error"]


def test_thermal_growth_of_a_2_5_K_warm_up_names_its_screw_alpha_and_fixed_end():
    # every screw warms in a warm-up, the others more than this one: the fit alone cannot tell the
    # temperatures apart, the screw's own is named; α within 20 %, the fixed bearing found
    e = synth.Effect("thermal_growth", {"axis": "L2"}, {"alpha_per_K": 1.2e-5, "channel": "temp_screw2",
                                                       "screw_fixed_end_mm": 480.0}, {"t_ref_C": 20.0, "rise_K": 2.5})
    case = _case([e], 33, run="warmup", duration=300.0, rate=50.0)
    ctx = build_context(case.columns, M, cap=2000)
    acc, _, _ = select_effects(ctx)
    th = [a for a in acc if a["cand"].effect == "thermal_growth"]
    assert th and th[0]["cand"].target == "L2" and th[0]["cand"].channel == "temp_screw2", \
        [a["cand"].label for a in acc]
    p = th[0]["fit"].params
    assert abs(p["alpha_per_K"] / 1.2e-5 - 1) < 0.2 and abs(p["screw_fixed_end_mm"] / 480.0 - 1) < 0.2, p


def test_a_screw_that_shrinks_as_it_warms_is_no_thermal_growth():
    # the same warm-up with the sign of α flipped: the fit follows it, its own check refuses it
    e = synth.Effect("thermal_growth", {"axis": "L2"}, {"alpha_per_K": -1.2e-5, "channel": "temp_screw2",
                                                       "screw_fixed_end_mm": 480.0}, {"t_ref_C": 20.0, "rise_K": 6.0})
    case = _case([e], 33, run="warmup", duration=300.0, rate=50.0)
    ctx = build_context(case.columns, M, cap=2000)
    c = fx.ThermalGrowth("L2", "temp_screw2")
    f = c.fit(ctx, ctx.obs.y, np.ones(len(ctx.obs.y), bool))
    assert f.params["alpha_per_K"] < 0 and any("grows when it warms" in p for p in c.check(ctx, f, ctx.obs.y))


def test_a_resonance_in_a_250_Hz_log_with_jittered_time_stamps_is_found():
    # ±10 % of a step of time-stamp jitter turns the commanded acceleration against the stamps into
    # noise; on the log's grid the mode shows
    e = synth.Effect("resonance", {"axis": "L1"}, {"freq_hz": 26.0, "damping_ratio": 0.045}, {"peak_mm": 0.045})
    case = _case([e], 34, run="raster", duration=10.0, rate=250.0, imperfections=True)
    rep, sc = _found(case)
    r = sc["effects"][0]
    assert r["named"] and r["params_ok"], (rep["findings"], r)


def test_a_clean_run_with_recording_imperfections_gets_no_finding():
    case = _case([], 35, run="calibration", duration=10.0, rate=250.0, imperfections=True)
    rep, _ = _found(case)
    assert rep["findings"] == [], rep["findings"]


@settings(max_examples=40, deadline=None)
@given(st.sampled_from([100.0, 250.0, 1000.0]), st.integers(0, 10_000), st.floats(0.0, 0.2))
def test_jittered_time_stamps_of_a_fixed_rate_log_go_back_on_its_grid(rate, seed, jitter):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(50, 3000))
    t_true = 12.5 + np.arange(n) / rate
    keep = rng.random(n) > 0.02
    keep[0] = keep[-1] = True
    t = t_true[keep] + rng.uniform(-jitter, jitter, keep.sum()) / rate
    r = regular_times(t)
    # exactly on a grid: origin + step x the sample's true index (the lost rows skipped) ...
    idx = np.flatnonzero(keep).astype(float)
    A = np.stack([np.ones_like(idx), idx], 1)
    (a, b), *_ = np.linalg.lstsq(A, r, rcond=None)
    assert np.allclose(r, a + b * idx, rtol=0, atol=1e-9)
    # ... and that grid is the true one within what a least-squares line through jitter of std
    # jitter/sqrt(3) samples can place (6 standard errors at the ends: 2/sqrt(n) of the std)
    tol = 6 * (jitter / np.sqrt(3)) * 2 / np.sqrt(keep.sum()) / rate
    assert np.allclose(r, t_true[keep], rtol=0, atol=1e-9 + tol)


def test_irregular_time_stamps_are_left_alone():
    t = np.cumsum(np.random.default_rng(3).uniform(0.5e-3, 1.5e-3, 500))
    assert np.array_equal(regular_times(t), t)


def test_a_backlash_with_one_reversal_is_named_though_a_fold_lacks_the_start_of_the_run():
    """Blind case 6000/backlash/1: a circle run logged at 250 Hz with recording imperfections, one
    reversal of L3. The training fold without the run's first block cannot tell where in the play
    the load began; it used to guess the wrong flank, its held-out error grew by 65 %, and the
    backlash lost to a Coulomb friction. It now keeps the full fit's start where its costs tie."""
    seed = 21839
    case = synth.synth_case(np.random.default_rng(seed), ["backlash"], machine=M, seed=seed, duration_s=10.0,
                            rate_hz=250.0, imperfections=True)
    truth = case.answer["effects"][0]
    assert truth["axis"] == "L3" and case.answer["run"] == "circle"
    rep, _ = diagnose(case.columns, M, cap=2000)
    f = [f for f in rep["findings"] if f.get("axis") == "L3"]
    assert f and f[0]["effect"] == "backlash", rep["findings"]
    assert abs(f[0]["parameters"]["width_mm"] / truth["parameters"]["width_mm"] - 1) < 0.2


def test_a_lost_step_inside_a_tracker_drop_out_is_placed_in_the_middle_of_the_gap():
    """Blind case 5000/lost_steps/4: the step (t = 7.22 s) fell inside a 1.9 s tracker drop-out, and
    one noisy sample at the gap's edge pinned the fit to the gap's start (6.19 s). Every split within
    noise of the best is as likely: the bracket is the gap, and the fit takes its middle."""
    seed = 68356
    case = synth.synth_case(np.random.default_rng(seed), ["lost_steps"], machine=M, seed=seed, duration_s=10.0,
                            rate_hz=1000.0, imperfections=True)
    truth = case.answer["effects"][0]["parameters"]
    t = case.columns["t"]
    tip = np.isfinite(np.asarray(case.columns["tip_x"], float))
    tt = t[tip]
    i = int(np.argmax(np.diff(tt)))
    gap = (float(tt[i]), float(tt[i + 1]))
    assert gap[1] - gap[0] > 1.0 and gap[0] < truth["t_s"] < gap[1]       # the premise: a step in a drop-out
    ctx = build_context(case.columns, M, cap=2000)
    f = fx.LostSteps(case.answer["effects"][0]["axis"]).fit(ctx, ctx.obs.y, np.ones(len(ctx.obs.y), bool))
    lo, hi = f.internal["t_bracket"]
    assert lo <= gap[0] + 0.02 and hi >= gap[1] - 1e-9                     # the data allow the whole gap
    assert abs(f.params["t_s"] - 0.5 * (gap[0] + gap[1])) < 0.02
    assert abs(f.params["offset_mm"] / truth["offset_mm"] - 1) < 0.05


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10_000), st.floats(0.0, 0.05), st.sampled_from([250.0, 1000.0]))
def test_a_smooth_command_is_put_back_on_the_grid_where_rows_were_lost(seed, lost, rate):
    """fx.on_grid: the kept samples unchanged; at a lost row a cubic, which a piecewise-linear fill
    is not (its kink rings a mode). A cubic in time is reproduced to rounding."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(8, 2000))
    tu = 3.0 + np.arange(n) / rate
    keep = rng.random(n) > lost
    keep[:2] = keep[-2:] = True
    c = rng.normal(0, 5, 4)
    x = np.polyval(c, tu - tu.mean())
    got = fx.on_grid(tu[keep], x[keep], tu)
    assert np.array_equal(got[keep], x[keep])
    assert np.allclose(got, x, rtol=0, atol=1e-9 * (1 + np.abs(x).max()))


def test_a_gauge_mode_in_a_250_Hz_log_that_lost_rows_keeps_its_frequency_and_damping():
    # blind case 9000/resonance/1: a 57 Hz gauge mode at 250 Hz with 1 % of the rows lost was named
    # at 51.9 Hz with a damping ratio of 0.29 (truth 0.098): the lost rows, filled by straight
    # lines, rang the mode in the model and not in the data
    e = synth.Effect("resonance", {"channel": "strain_3"}, {"freq_hz": 56.8, "damping_ratio": 0.098},
                     {"peak_ue": 14.0})
    case = _case([e], 64434, run="calibration", duration=10.0, rate=250.0, imperfections=True)
    rep, sc = _found(case)
    r = sc["effects"][0]
    assert r["named"] and r["params_ok"], (rep["findings"], r)
    assert abs(r["param_errors"]["damping_ratio"]) < 0.1, r


def test_an_axis_mode_is_not_fitted_above_the_tracker_nyquist_frequency():
    # blind case 7000/resonance/1: a 15.5 Hz mode of L1 in a 250 Hz log with a 125 Hz tracker was
    # fitted at its 110 Hz alias, below the log's Nyquist limit but above the tracker's
    case = _case(["resonance"], 62434, run=None, duration=10.0, rate=250.0, imperfections=True)
    (e,) = case.answer["effects"]
    assert e["axis"] == "L1" and abs(e["parameters"]["freq_hz"] - 15.54) < 0.01
    ctx = build_context(case.columns, M, cap=2000)
    tool_rows = ctx.obs.row[np.isin(ctx.obs.ch, [i for i, c in enumerate(ctx.obs.channels) if c.startswith("tip_")])]
    tracker_nyq = 0.5 / float(np.median(np.diff(ctx.t[np.unique(tool_rows)])))
    assert tracker_nyq < 100.0          # the case has a slow tracker
    c = fx.Resonance("L1", "axis")
    f = c.fit(ctx, ctx.obs.y, np.ones(len(ctx.obs.y), bool))
    assert f.ok and f.params["freq_hz"] < tracker_nyq
    assert abs(f.params["freq_hz"] / 15.54 - 1) < 0.05, f.params
    # the training folds, each started at its best point of the coarse grid, went to 22, 49 and
    # 16 Hz (not identifiable); each also starts at the full fit's mode and keeps the better fit
    from pmctl.tools.twin.diagnose import evaluate, folds_of, own_checks
    c.reset()
    ev = evaluate(c, ctx, ctx.obs.y, folds_of(ctx))
    assert own_checks(ev, ctx) == [], ev["fold_params"]


def test_a_mode_above_the_thinned_samples_nyquist_frequency_is_found_at_its_own():
    # a 180 Hz mode of gauge 1 in a 1 kHz log: the cap keeps every 5th row (a 100 Hz Nyquist limit),
    # but the gauge was sampled at 1 kHz and the mode is filtered on the full grid. It was searched
    # below 0.9 x 100 Hz only and missed. (So were the 246.6 Hz chain modes of the README's demo
    # run, whose 1 kHz tool channels the cap thins to every 3rd row: refused at the band's edge,
    # their static part was named a table compliance with confidence 0.95.)
    e = synth.Effect("resonance", {"channel": "strain_1"}, {"freq_hz": 180.0, "damping_ratio": 0.03},
                     {"peak_ue": 15.0})
    case = _case([e], 41, run="circle", duration=10.0, rate=1000.0)
    rep, sc = _found(case, cap=2000)
    r = sc["effects"][0]
    assert r["named"] and r["params_ok"], (rep["findings"], r)
    assert sc["extra_findings"] == [], rep["findings"]


def _blind_mode_named_right(seed, rate, axis, freq_hz):
    """The blind eval's resonance case of ``seed`` (10 s, with recording imperfections), checked to
    be the mode of ``axis`` at ``freq_hz``, is named with every parameter within tolerance."""
    case = _case(["resonance"], seed, run=None, duration=10.0, rate=rate, imperfections=True)
    (e,) = case.answer["effects"]
    assert e["axis"] == axis and abs(e["parameters"]["freq_hz"] - freq_hz) < 0.01
    rep, sc = _found(case)
    r = sc["effects"][0]
    assert r["named"] and r["params_ok"], (rep["findings"], r)
    return rep


def test_no_training_fold_fits_an_axis_mode_at_an_alias_above_the_tracker_nyquist_frequency():
    # blind case 6000/resonance/1: one training fold fitted a 27 Hz mode of L2 at 77 Hz, above the
    # 62.5 Hz Nyquist limit of its 125 Hz tracker; the mode was refused as not identifiable and its
    # gauge's mode named instead
    _blind_mode_named_right(61434, 250.0, "L2", 27.05)


def test_a_mode_in_a_circle_run_is_named_not_its_static_part_as_a_geometry_error():
    # blind case 5000/resonance/4: in a circle run a mode's quasi-static deflection -a/w^2 follows
    # the position like a geometry error; only the block where it rings pins the mode. The training
    # fold without it went to 23 Hz for 13 Hz (its cost at 13 Hz only 6.6 higher), the mode was
    # refused as not identifiable and a platform joint named with confidence 0.96
    rep = _blind_mode_named_right(60437, 1000.0, "L3", 13.10)
    assert not any(f["effect"] == "geometry" for f in rep["findings"]), rep["findings"]
