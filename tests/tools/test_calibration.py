"""Kinematic calibration: identification Jacobian, identification on simulated machines with known
random geometry errors and measurement noise (2 um tip, 10 urad axis), unidentifiable directions,
the calibrated config file, recordings with dwells, and the CLI end to end."""

import json
import math
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.errors import InputError
from pmctl.core.recording import write_recording
from pmctl.tools.calibrate import configio, data, identify as I, model as Mo

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

M = load_machine()
G = M.geometry


def measured(seed, n, *, noise=True, has_axis=True):
    rng = np.random.default_rng(seed)
    gt = Mo.random_geometry(G, rng)
    tip, ax = Mo.random_tool_poses(M, n, rng)
    q = K.ik_batch(tip, ax, M).q
    if noise:
        mt, ma = Mo.simulate_measurement(q, gt, rng)
    else:
        pr = Mo.predict(q, gt)
        mt, ma = pr.tip, pr.axis
    return gt, q, mt, (ma if has_axis else None), rng


def held_out_errors(geom, gt, rng, n=300):
    """Tool errors on the true machine when poses are commanded through IK of the given geometry."""
    tip, ax = Mo.random_tool_poses(M, n, rng)
    r = K.ik_batch(tip, ax, replace(M, geometry=geom))
    assert r.ok.all()
    return Mo.tool_errors(tip, ax, r.q, gt)


# ---------------------------------------------------------------- the model

@settings(max_examples=8, deadline=None)
@given(st.integers(0, 2**31))
def test_identification_jacobian_matches_finite_differences(seed):
    rng = np.random.default_rng(seed)
    g = Mo.random_geometry(G, rng)
    tip, ax = Mo.random_tool_poses(M, 6, rng)
    q = K.ik_batch(tip, ax, M).q
    pr = Mo.predict(q, g)
    S = Mo.identification_jacobian(pr.P, pr.R, g)
    h = 1e-6
    for j in range(Mo.N_PARAMS):
        dp = np.zeros(Mo.N_PARAMS)
        dp[j] = h
        a, b = Mo.predict(q, Mo.perturb(g, dp), (pr.P, pr.R)), Mo.predict(q, Mo.perturb(g, -dp), (pr.P, pr.R))
        Sn = np.concatenate([a.tip - b.tip, a.axis - b.axis], 1) / (2 * h)
        assert np.max(np.abs(S[:, :, j] - Sn)) < 1e-6, Mo.PARAM_NAMES[j]


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31))
def test_parameter_difference_inverts_perturb(seed):
    rng = np.random.default_rng(seed)
    g = Mo.random_geometry(G, rng)
    dp = rng.uniform(-1, 1, Mo.N_PARAMS)
    assert np.max(np.abs(Mo.difference(Mo.perturb(g, dp), g) - dp)) < 1e-10


# ---------------------------------------------------------------- identification

def test_noise_free_identification_reproduces_the_machine_exactly():
    """Without noise and without holding weak combinations, the identified model predicts the
    true machine to nanometres everywhere (the parameterisation covers the built geometry)."""
    gt, q, mt, ma, rng = measured(11, 40, noise=False)
    res = I.identify(q, mt, ma, G, max_sigma=1e9)
    assert res.tip_max_um < 1e-3
    e_tip, e_ax = held_out_errors(res.geometry, gt, rng)
    assert e_tip.max() < 1e-5 and e_ax.max() < 1e-9


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_identification_with_noise_meets_5um_on_held_out_poses(seed):
    gt, q, mt, ma, rng = measured(seed, 60)
    e0_tip, _ = held_out_errors(G, gt, np.random.default_rng(seed + 100))
    res = I.identify(q, mt, ma, G)
    e_tip, e_ax = held_out_errors(res.geometry, gt, np.random.default_rng(seed + 100))
    assert e0_tip.max() > 0.5                                # the built machine is far off nominal
    assert e_tip.max() < 5e-3, e_tip.max()                    # <= 5 um worst case
    assert np.sqrt(np.mean(e_tip**2)) < 2e-3
    assert np.degrees(np.sqrt(np.mean(e_ax**2))) < 0.001
    # residuals match the stated noise, and the predicted accuracy is of the size of the real one
    assert 0.6 < res.chi2_red < 1.5
    assert 0.3 < res.predicted_tip_um / (1e3 * np.sqrt(np.mean(e_tip**2)) / math.sqrt(3)) < 3.0


@pytest.mark.parametrize("k,has_axis", [(1.0, "all"), (2.0, "all"), (2.0, "some")])
def test_reported_uncertainties_match_the_spread_of_repeated_identifications(k, has_axis):
    """The same machine measured 60 times at the same 40 poses, with k x the stated noise (2 um tip,
    10 urad axis) while the identification is told the stated noise: the chi-square per degree of
    freedom is k^2 on average (an axis residual counts 2 degrees of freedom, not 3: counted as 3 it
    was 0.82 at the stated noise), and the reported 1-sigma of every identified parameter matches
    the spread of its estimates over the 60 runs -- at twice the noise because the covariance is
    scaled by chi^2 (scaled by sqrt(chi^2) the reported sigmas are 0.71 of the spread). The pooled
    (spread / sigma)^2 is 1 within 20 %, each parameter's ratio within 0.7..1.4. The predicted
    accuracy (the 1-sigma of the tool tip and axis the identified model predicts at the measured
    poses) is the RMS of what the 60 identified models actually predict there against the true
    machine, within 10 % (measured 0.99..1.02): the tip's in um from the tip's three variances alone,
    the axis' in urad from all three of its components."""
    rng = np.random.default_rng(5)
    gt = Mo.random_geometry(G, rng)
    tip, ax = Mo.random_tool_poses(M, 40, rng)
    q = K.ik_batch(tip, ax, M).q
    truth = Mo.predict(q, gt)
    e_tip, e_ax, p_tip, p_ax = [], [], [], []
    dps, sig, chi2, ranks = [], [], [], set()
    for _ in range(60):
        mt, ma = Mo.simulate_measurement(q, gt, rng, tip_sigma_mm=k * I.TIP_SIGMA_MM,
                                         axis_sigma_rad=k * I.AXIS_SIGMA_RAD)
        if has_axis == "some":
            ma = ma.copy()
            ma[::4] = np.nan              # a 6-DOF probe that dropped out at a quarter of the poses
        res = I.identify(q, mt, ma, G)
        dps.append(res.dp)
        sig.append(res.sigma)
        chi2.append(res.chi2_red)
        ranks.add(res.rank)
        pr = Mo.predict(q, res.geometry)
        e_tip.append(np.sum((pr.tip - truth.tip) ** 2, -1))
        e_ax.append(np.sum((pr.axis - truth.axis) ** 2, -1))
        p_tip.append(res.predicted_tip_um)
        p_ax.append(res.predicted_axis_urad)
        assert res.predicted_tip_max_um >= res.predicted_tip_um > 0      # the worst pose, the RMS over them
    tip_ratio = np.mean(p_tip) / (1e3 * np.sqrt(np.mean(e_tip)))
    ax_ratio = np.mean(p_ax) / (1e6 * np.sqrt(np.mean(e_ax)))
    assert 0.9 < tip_ratio < 1.1 and 0.9 < ax_ratio < 1.1, (tip_ratio, ax_ratio)
    dps, sig = np.array(dps), np.array(sig)
    assert len(ranks) == 1                       # the same combinations identified every time
    assert abs(np.mean(chi2) / k ** 2 - 1.0) < 0.08, np.mean(chi2)
    m = sig.min(0) > 0                           # identified (a part of) the parameter
    assert m.sum() >= 20
    spread = dps[:, m].std(0, ddof=1)
    ratio = spread / sig[:, m].mean(0)
    z2 = np.mean(((dps[:, m] - dps[:, m].mean(0)) / sig[:, m]) ** 2) * len(dps) / (len(dps) - 1)
    assert 0.8 < z2 < 1.2, (z2, np.round(ratio, 2))
    assert np.all((ratio > 0.7) & (ratio < 1.4)), np.round(ratio, 2)


def test_uncertainties_are_the_stated_noises_unless_the_fit_is_worse():
    """The same machine and poses measured at 0, 0.5, 1, 1.2 and 2 x the stated noise: where the
    residuals are within the stated noise (chi^2 <= 1) the reported 1-sigma of every parameter and
    of the weakest identified combinations is the stated noise's (the noise-free identification's,
    within 1 %), never smaller because the fit happened to be better; where they are worse
    (chi^2 = 1.31 at 1.2 x, 3.6 at 2 x) both are sqrt(chi^2) times that."""
    sig, weak, chi2 = {}, {}, {}
    for k in (0.0, 0.5, 1.0, 1.2, 2.0):
        gt, q, mt, ma, _ = measured(3, 40, noise=k > 0) if k in (0.0, 1.0) else _measured_at(3, 40, k)
        res = I.identify(q, mt, ma, G)
        sig[k], weak[k], chi2[k] = res.sigma, [d.sigma for d in res.weak], res.chi2_red
        assert res.rank + len(res.fixed) == Mo.N_PARAMS == len(res.sigma)
    m = sig[0.0] > 0
    assert chi2[0.0] < 1e-3 and chi2[0.5] < 0.5 and chi2[1.0] < 1.0 < chi2[1.2] < 2.0 < chi2[2.0]
    for k in (0.5, 1.0, 1.2, 2.0):
        f = math.sqrt(max(chi2[k], 1.0))
        assert np.allclose(sig[k][m] / sig[0.0][m], f, rtol=0.01), (k, f)
        assert np.allclose(np.array(weak[k]) / weak[0.0], f, rtol=0.01), (k, f)


def _measured_at(seed, n, k):
    """``measured`` with k x the stated noise (2 um tip, 10 urad axis)."""
    rng = np.random.default_rng(seed)
    gt = Mo.random_geometry(G, rng)
    tip, ax = Mo.random_tool_poses(M, n, rng)
    q = K.ik_batch(tip, ax, M).q
    mt, ma = Mo.simulate_measurement(q, gt, rng, tip_sigma_mm=k * I.TIP_SIGMA_MM, axis_sigma_rad=k * I.AXIS_SIGMA_RAD)
    return gt, q, mt, ma, rng


def test_chi_square_counts_three_degrees_of_freedom_per_tip_less_the_identified_ones():
    """Measured tips only (2 um): chi^2 per degree of freedom is the whitened residual sum (n tips x
    their squared RMS / (2 um)^2) over 3n less the identified combinations; with 6 poses the fit
    takes all but one of the 18 measured values and chi^2 is the whole residual sum."""
    for n in (40, 6):
        gt, q, mt, ma, _ = measured(3, n)
        res = I.identify(q, mt, None, G)
        ss = n * (res.tip_rms_um / (1e3 * I.TIP_SIGMA_MM)) ** 2
        dof = 3 * n - res.rank if n == 40 else 1
        assert res.chi2_red * dof == pytest.approx(ss, rel=1e-9), (n, res.rank)


def test_the_reported_directions_keep_to_the_callers_limits():
    """A combination is identified when its relative singular value is at least ``rcond`` and its
    1-sigma at most ``max_sigma``, for the limits the caller gives (here tighter than the defaults,
    so that combinations the defaults identify are fixed): none of the reported weak ones breaks
    them, every fixed one breaks one, and rank + fixed = the 30 parameters."""
    gt, q, mt, ma, _ = measured(3, 40)
    ranks = {}
    for rcond, max_sigma in ((I.RCOND, I.MAX_SIGMA), (0.006, I.MAX_SIGMA), (I.RCOND, 0.02)):
        res = I.identify(q, mt, ma, G, rcond=rcond, max_sigma=max_sigma)
        assert res.rank + len(res.fixed) == Mo.N_PARAMS
        assert all(d.singular_value >= rcond and d.sigma <= max_sigma for d in res.weak), res.weak
        assert all(d.singular_value < rcond or d.sigma > max_sigma for d in res.fixed)
        ranks[rcond, max_sigma] = res.rank
    assert ranks[0.006, I.MAX_SIGMA] < ranks[I.RCOND, I.MAX_SIGMA] and ranks[I.RCOND, 0.02] < ranks[I.RCOND, I.MAX_SIGMA]


def test_a_poor_axis_probe_adds_nothing_to_the_predicted_tip_accuracy():
    """The tool axis measured 1000 x worse than usual (10 mrad) tells nothing about the tip that the
    tips do not: the predicted tip accuracy (um, from the tip's variances) is the tip-only
    identification's within 1 % (1.449 um both), though the predicted axis accuracy is 2.2 mrad."""
    gt, q, mt, ma, _ = _measured_at(3, 40, 1.0)
    rng = np.random.default_rng(30)
    ma = Mo.simulate_measurement(q, gt, rng, axis_sigma_rad=1e-2)[1]
    poor = I.identify(q, mt, ma, G, axis_sigma_rad=1e-2)
    tip_only = I.identify(q, mt, None, G)
    assert poor.predicted_axis_urad > 1000.0
    assert poor.predicted_tip_um == pytest.approx(tip_only.predicted_tip_um, rel=0.01)


def test_the_identified_directions_of_a_known_jacobian():
    """analyse on whitened Jacobians whose answer is known. Independent parameters measured with
    gains c (columns of norm c, any units): each one's 1-sigma is 1/c (least squares with unit
    noise), it is identified iff 1/c <= max_sigma (0.4 yes, 0.5 yes, 2 and 10 no), and every one has
    relative singular value 1 (the column scaling makes the decision independent of units: a gain
    of 0.1 next to one of 1e7 is not a numerical rank loss). A parameter no measurement sees (a zero
    column) is unidentifiable (sigma inf), the others unchanged. Two parameters measured only nearly
    together (columns at an angle theta, gain 1e8: their difference known to 0.004 at theta = 4e-6)
    are both identified when the relative singular value of the difference, theta/2, is 2e-6, and
    the difference is fixed at 8e-7, below rcond = 1e-6 (lost in rounding), though its sigma would
    be small (0.009)."""
    gains = np.array([1e7, 2.5, 0.1, 2.0, 1e3, 0.5, 40.0, 1.0] * 4)[:Mo.N_PARAMS]
    J = np.zeros((Mo.N_PARAMS + 6, Mo.N_PARAMS))
    J[np.arange(Mo.N_PARAMS), np.arange(Mo.N_PARAMS)] = gains

    def by_param(J):
        D, U, s, Vt, keep, dirs = I.analyse(J)
        out = {}
        for d, kept in zip(dirs, keep):
            (name, w), = d.terms if len(d.terms) == 1 else [(None, None)]
            out[name] = (d.sigma, bool(kept), d.singular_value)
        return out

    got = by_param(J)
    for j, c in enumerate(gains):
        sigma, kept, rel = got[Mo.PARAM_NAMES[j]]
        assert sigma == pytest.approx(1.0 / c, rel=1e-12) and rel == pytest.approx(1.0, rel=1e-12)
        assert kept == (1.0 / c <= I.MAX_SIGMA)
    J0 = J.copy()
    J0[:, 6] = 0.0
    got0 = by_param(J0)
    assert got0[Mo.PARAM_NAMES[6]][:2] == (math.inf, False)
    assert all(got0[n] == pytest.approx(got[n], rel=1e-12) for n in Mo.PARAM_NAMES if n != Mo.PARAM_NAMES[6])
    for theta, identified in ((4e-6, True), (1.6e-6, False)):
        Jp = np.zeros((Mo.N_PARAMS + 6, Mo.N_PARAMS))
        Jp[np.arange(Mo.N_PARAMS), np.arange(Mo.N_PARAMS)] = 1e8
        Jp[:, 1] = 1e8 * (math.cos(theta) * np.eye(Mo.N_PARAMS + 6)[0] + math.sin(theta) * np.eye(Mo.N_PARAMS + 6)[1])
        D, U, s, Vt, keep, dirs = I.analyse(Jp)
        k = int(np.argmin(s))
        assert dirs[k].singular_value == pytest.approx(theta / 2, rel=1e-3)
        if identified:
            assert dirs[k].sigma == pytest.approx(1e-8 / (math.sqrt(2) * math.sin(theta / 2)), rel=1e-3)
            assert dirs[k].sigma < 0.01
        else:
            assert dirs[k].sigma == math.inf
        assert keep.sum() == Mo.N_PARAMS - (not identified) and bool(keep[k]) == identified


def test_unidentifiable_directions_are_reported_and_not_fitted_to_noise():
    """The platform frame is a free choice (its joints and the tool move together): these exact
    symmetries are reported and the estimate has no component along them, for any noise."""
    gt, q, mt, ma, rng = measured(4, 60)
    res = I.identify(q, mt, ma, G)
    exact = [d for d in res.fixed if not math.isfinite(d.sigma)]
    assert len(exact) == 4                          # 3 rotations + a shift along the tool axis
    for d in exact:
        assert all(n.startswith(("chain", "tool")) and ("platform_joint" in n or n.startswith("tool"))
                   for n, _ in d.terms)
    pr = Mo.predict(q, G)
    J = I._jac(pr, G, True, (I.TIP_SIGMA_MM, I.AXIS_SIGMA_RAD))
    D, U, s, Vt, keep, _ = I.analyse(J)
    null = Vt[~keep]
    p_true = null @ (D * Mo.difference(gt, G))
    for k in range(2):
        mt2, ma2 = Mo.simulate_measurement(q, gt, np.random.default_rng(50 + k))
        r2 = I.identify(q, mt2, ma2, G)
        p_est = null @ (D * r2.dp)
        assert np.linalg.norm(p_est) < 0.02 * np.linalg.norm(p_true)
    # tip-only measurement: more combinations cannot be seen (rotations about the tool axis ...)
    r_tip = I.identify(q, mt, None, G)
    assert len([d for d in r_tip.fixed if not math.isfinite(d.sigma)]) > len(exact)


def test_poses_without_a_measured_axis_still_count_for_their_tip():
    """A 6-DOF probe that dropped out at some poses: those poses give the tip only."""
    gt, q, mt, ma, rng = measured(7, 60)
    ma = ma.copy()
    ma[::3] = np.nan
    res = I.identify(q, mt, ma, G)
    assert res.has_axis and len([d for d in res.fixed if not math.isfinite(d.sigma)]) == 4
    e_tip, e_ax = held_out_errors(res.geometry, gt, np.random.default_rng(70))
    assert e_tip.max() < 5e-3 and np.degrees(e_ax.max()) < 0.002
    assert np.isfinite(res.axis_rms_urad) and res.axis_rms_urad < 30


def test_too_few_poses_is_an_error():
    gt, q, mt, ma, rng = measured(5, 2)
    with pytest.raises(I.IdentificationError, match="too few"):
        I.identify(q, mt, ma, G)


# ---------------------------------------------------------------- the calibrated config

def test_written_config_loads_and_carries_the_geometry_exactly(tmp_path):
    gt = Mo.random_geometry(G, np.random.default_rng(8))
    m = configio.write_machine(tmp_path / "cal.toml", configio.calibrated_dict(M, gt), "a header\nline 2")
    g = m.geometry
    assert not g.nominal
    for f in ("base_joints", "platform_joints", "length_offsets"):
        assert np.array_equal(getattr(g, f), getattr(gt, f))
    assert np.max(np.abs(g.revolute_axes - gt.revolute_axes)) < 1e-15
    assert g.tool_length == gt.tool_length and g.tool_tilt_deg == gt.tool_tilt_deg
    assert m.limits == M.limits and m.resolution == M.resolution and m.strain_gain == M.strain_gain
    assert (tmp_path / "cal.toml").read_text().startswith("# a header\n# line 2\n")


def test_toml_writer_round_trips_nested_tables_and_strings():
    import tomllib
    d = {"a": {"x": 1.5, "s": 'q"uo\\te', "l": [[1.0, 2.0], [3.0, -4e-17]], "b": True},
         "svc": {"loop": {"rate_hz": 1000}, "nc": {"k": [1, 2]}}}
    assert tomllib.loads(configio.dumps(d)) == d


def test_a_config_the_loader_would_refuse_is_not_written(tmp_path):
    d = configio.calibrated_dict(M, G)
    d["geometry"]["tool_tilt_deg"] = [20.0, 0.0]
    with pytest.raises(Exception, match="tool_tilt"):
        configio.write_machine(tmp_path / "bad.toml", d)
    assert not (tmp_path / "bad.toml").exists()


# ---------------------------------------------------------------- recordings

def _dwell_recording(folder, q, tip, ax, *, rows=6, move_rows=4):
    """A recording that moves between the poses and dwells `rows` samples at each; the tool is
    still settling in the first samples of a dwell (offset 50 um), settled in the second half."""
    cols = {c: [] for c in ("cmd_L1", "cmd_L2", "cmd_L3", "cmd_X", "cmd_Y",
                            "tip_x", "tip_y", "tip_z", "tool_i", "tool_j", "tool_k")}
    prev = q[0]
    for k in range(len(q)):
        for s in range(1, move_rows + 1 if k else 0):          # motion rows, no measurement
            qq = prev + (q[k] - prev) * s / (move_rows + 1)
            for j, c in enumerate(list(cols)[:5]):
                cols[c].append(qq[j])
            for c in list(cols)[5:]:
                cols[c].append(np.nan)
        for s in range(rows):
            settling = 0.05 if s < rows // 2 else 0.0
            for j, c in enumerate(list(cols)[:5]):
                cols[c].append(q[k, j])
            for j, c in enumerate(("tip_x", "tip_y", "tip_z")):
                cols[c].append(tip[k, j] + settling)
            for j, c in enumerate(("tool_i", "tool_j", "tool_k")):
                cols[c].append(ax[k, j])
        prev = q[k]
    n = len(cols["cmd_L1"])
    cols = {"t": np.arange(n) * 0.1, **{c: np.array(v) for c, v in cols.items()}}
    return write_recording(folder, cols, sample_rate_hz=10.0, exact=True)


def test_dwells_are_found_and_averaged_after_settling(tmp_path):
    gt, q, mt, ma, rng = measured(6, 12)
    rec = _dwell_recording(tmp_path / "rec", q, mt, ma)
    p = data.read_poses(rec)
    assert p.dwells and p.joints_from == "cmd" and len(p.q) == 12
    assert np.max(np.abs(p.q - q)) < 1e-9
    assert np.max(np.abs(p.tip - mt)) < 1e-9                   # the settling half is left out
    assert np.max(np.abs(p.axis - ma)) < 1e-12


def test_a_recording_without_a_measured_tip_is_refused(tmp_path):
    n = 5
    cols = {"t": np.arange(n) * 1.0, **{c: np.full(n, 393.0) for c in ("cmd_L1", "cmd_L2", "cmd_L3")},
            "cmd_X": np.zeros(n), "cmd_Y": np.zeros(n)}
    write_recording(tmp_path / "r", cols, sample_rate_hz=1.0)
    with pytest.raises(InputError, match="tip_x"):
        data.read_poses(tmp_path / "r")


# ---------------------------------------------------------------- end to end through the CLI

def pmctl(*args):
    return subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", *args], capture_output=True, text=True)


def test_identify_then_kin_ik_on_held_out_poses_end_to_end(tmp_path):
    """The outside check: a 60-pose recording of a machine with hidden geometry errors ->
    `pmctl calibrate identify` -> `pmctl kin ik --config CALIBRATED.toml` on held-out poses."""
    gt, q, mt, ma, rng = measured(21, 60)
    cols = {"t": np.arange(60.0), **{f"cmd_{a}": q[:, j] for j, a in enumerate(("L1", "L2", "L3", "X", "Y"))},
            "tip_x": mt[:, 0], "tip_y": mt[:, 1], "tip_z": mt[:, 2],
            "tool_i": ma[:, 0], "tool_j": ma[:, 1], "tool_k": ma[:, 2]}
    write_recording(tmp_path / "rec", cols, sample_rate_hz=1.0, digits=12)
    out = tmp_path / "cal.toml"
    r = pmctl("calibrate", "identify", str(tmp_path / "rec"), "--config", "prototype", "--out", str(out), "--json")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    assert rep["poses"] == 60 and rep["rank"] + len(rep["not_identifiable"]) == 30
    assert sum(d["exact_symmetry"] for d in rep["not_identifiable"]) == 4
    assert rep["tip_rms_um"] < 5 and 0.6 < rep["chi2_red"] < 1.5
    tips, axes = Mo.random_tool_poses(M, 200, np.random.default_rng(99))
    worst_tip = worst_ang = 0.0
    for tip, ax in zip(tips[:3], axes[:3]):                   # through the command line ...
        r = pmctl("kin", "ik", "--config", str(out), "--tip", ",".join(repr(float(x)) for x in tip),
                  "--axis", ",".join(repr(float(x)) for x in ax), "--json")
        assert r.returncode == 0, r.stderr
        o = json.loads(r.stdout)
        qh = np.array(o["L"] + o["table"])[None]
        et, ea = Mo.tool_errors(tip[None], ax[None], qh, gt)
        worst_tip, worst_ang = max(worst_tip, et[0]), max(worst_ang, ea[0])
    assert worst_tip < 5e-3 and np.degrees(worst_ang) < 0.001, (worst_tip, np.degrees(worst_ang))
    # ... and, for many more held-out poses, the same IK in-process on the written file
    mc = load_machine(out)
    r_all = K.ik_batch(tips, axes, mc)
    assert r_all.ok.all() and np.allclose(r_all.q[2], qh[0], atol=1e-9)
    et, ea = Mo.tool_errors(tips, axes, r_all.q, gt)
    assert et.max() < 5e-3 and np.degrees(ea.max()) < 0.001, (et.max(), np.degrees(ea.max()))
    # and the file is a machine config like any other: fk accepts it too
    r = pmctl("kin", "fk", "--config", str(out), "--joints", ",".join(repr(float(x)) for x in qh[0]), "--json")
    assert r.returncode == 0, r.stderr
    assert np.allclose(json.loads(r.stdout)["tip"], tips[2], atol=1e-8)


def test_identify_refuses_a_bad_recording_with_one_line(tmp_path):
    r = pmctl("calibrate", "identify", str(tmp_path / "nope"), "--out", str(tmp_path / "x.toml"))
    assert r.returncode == 1 and "nope" in r.stderr and not (tmp_path / "x.toml").exists()
