"""Diagnosis: where and why a recording differs from the nominal twin (issue 4, items 3-5).

Pipeline (pure functions; the CLI at the bottom is a thin layer):

1. :func:`build_context`: residual = measured - nominal prediction for every observed channel
   (enc_*, tip_*, tool_*, strain_*), each channel's noise level estimated robustly from the data
   (signals.noise_level), whitened and stacked; kinematic Jacobians, geometry sensitivities and chain
   forces at the analysis rows (at most ``cap`` samples per channel, evenly spread).
2. :func:`pmctl.tools.twin.locate.locate`: where the mismatch lives.
3. :func:`select_effects`: greedy forward selection over the effect library
   (:mod:`pmctl.tools.twin.effects`). Each round fits every candidate to the current residual; a candidate
   is scored on held-out samples by blocked cross-validation in time (24 blocks, 3 interleaved
   folds: each fold is predicted by a fit on the other two). The best candidate is accepted only
   when its held-out improvement of the whitened sum of squares beats what noise gives,
   ``ΔSSE_cv > max(MIN_DSSE, BIC penalty p·ln N)``, ``ΔSSE_cv > REL_MIN`` of the residual energy
   in the channels it touches, and the effect reaches MIN_PEAK x noise on at least 1 % of its
   samples (sub-noise and sub-pulse structure is not physics). Candidates are ranked by
   ``ΔSSE_cv − ½ p·ln N``. Then the residual is updated and the next round runs. At the end the
   accepted effects are refitted with the others held (backfitting, two passes) and their held-out
   predictions recomputed; ``rms_after`` of finding k is cumulative over findings 1..k.
   Nonlinear parameters (backlash width, pitch period, lag τ, mode frequency/damping, step time)
   are refitted inside every training fold, so the held-out score includes their search.
4. :func:`diagnose` returns the report of docs/diagnosis-report.md (a dict) plus the locate summary;
   :func:`format_text` renders it, ``pmctl.tools.twin.plots`` draws it.

A recording of independent axes (``"machine": "axes"``, pmctl.core.recording_axes) takes the same
pipeline with its own context (pmctl.tools.twin.axes: enc = cmd, load = enc, effort = 0, acc =
cmd'') and catalogue (pmctl.tools.twin.drive: the drive's force model, servo tracking, load
compliance, cogging, with the catalogue's effects that apply to single axes).
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from pmctl.core import kinematics as kin
from pmctl.core.compensation import compensated_columns
from pmctl.core.config import load_machine
from pmctl.core.errors import InputError
from pmctl.core.recording import META_FILE, partial_path
from pmctl.core.recording_chunks import count_rows, plan_segments, read_columns
from pmctl.tools.twin import axes as gx, calibration, drive
from pmctl.tools.twin import effects as fx
from pmctl.tools.twin import lookalikes as lk
from pmctl.tools.twin import nominal
from pmctl.tools.twin.calibration import MIN_DSSE
from pmctl.tools.twin.catalogue import DEFAULT_CAP
from pmctl.tools.twin.effects import AXES, Context
from pmctl.tools.twin.fix import compensation_from_findings, write_compensation
from pmctl.tools.twin.locate import locate, windows
from pmctl.tools.twin.observations import observations, record_runs, regular_times, settled_rows, uniform_step
from pmctl.tools.twin.plots import write_plots
from pmctl.tools.twin.unexplained import flexible_gain, left_structure, unexplained

N_BLOCKS = 24
N_FOLDS = 3
REL_MIN = 0.04          # the effect must explain this fraction of its channels' residual energy
MIN_PEAK = 1.5         # ... and reach 1.5 x noise on at least 1 % of its samples
MAX_FINDINGS = 6
BACKFIT_GENERIC = 12    # a drive's force model is several linear terms on one channel: refit to convergence


def is_axes_machine(machine) -> bool:
    """A machine of independent axes (``"machine": "axes"``, pmctl.core.recording_axes)."""
    return getattr(machine, "name", None) == "axes" and hasattr(machine, "axes")



# ---------------------------------------------------------------- context

def _floor(name, machine):
    """Smallest credible noise level of a channel (a perfect channel still has quantisation)."""
    if name.startswith("enc_"):       # half a pulse: sub-pulse quantisation error is not physics
        return 0.5 / machine.resolution.chain_pulses_per_mm
    if name.startswith("tip_"):
        return 1e-6
    if name.startswith("tool_"):
        return 1e-9
    return 1e-6


def build_context(columns: dict, machine, *, cap=DEFAULT_CAP, bounds=None, direction_before=None) -> Context:
    """Residuals of the nominal twin (pmctl.tools.twin.nominal) at the analysis rows, whitened and stacked.
    ``bounds``: indices where contiguous runs of the rows start and end ([0, ..., n]; default one
    run), for a recording kept as runs (:func:`read_for_diagnosis`): no analysis row lies in the
    first MARGIN_S of a run (the state of lags and modes carried over a gap is unknown there), and
    the dynamic effects restart at every run (ctx.extra["bounds"]). ``direction_before``: per run,
    each axis' direction of motion before it (read from the rows skipped between runs): until an
    axis moves in a run, its play and friction keep that side (ctx.extra["direction_before"])."""
    t = np.asarray(columns["t"], float)
    n = len(t)
    bounds = np.asarray([0, n] if bounds is None else bounds, int)
    runs = len(bounds) > 2
    if not runs:        # (runs of a long recording: their gaps are no missing rows)
        t = regular_times(t)
    settled = settled_rows(t, bounds, runs)
    q_cmd = np.stack([fx.fill_gaps(t, np.asarray(columns[f"cmd_{a}"], float)) for a in AXES], 1)
    has_enc = np.array([f"enc_{a}" in columns and np.isfinite(columns[f"enc_{a}"]).any() for a in AXES])
    q_motor = q_cmd.copy()
    for i, a in enumerate(AXES):
        if has_enc[i]:
            q_motor[:, i] = fx.fill_gaps(t, np.asarray(columns[f"enc_{a}"], float))
    temps = {k: fx.fill_gaps(t, np.asarray(v, float)) for k, v in columns.items()
             if k.startswith("temp_") and np.isfinite(v).sum() >= 2}
    obs_names = [k for k in columns if k in nominal.PREDICTABLE]
    hold = {}

    def predict_at(rows_all, names):
        sub = {k: np.asarray(v, float)[rows_all] for k, v in columns.items()}
        hold["state"] = nominal.nominal_state(sub, machine, statics=True) if len(rows_all) else None
        pred = nominal.predict_columns(sub, machine, names, state=hold["state"]) if names else {}
        return sub, pred

    obs, rows, rows_all, sampled = observations(columns, obs_names, predict_at, settled, cap,
                                                lambda k: _floor(k, machine))
    state = hold.get("state")
    at = np.searchsorted(rows_all, rows)
    if len(rows):
        P, R = state.P[at], state.R[at]
        bad = ~np.all(np.isfinite(P), -1)
        if bad.any():                      # FK failed there: keep the rows but give them no leverage
            P[bad], R[bad] = P[~bad][0] if (~bad).any() else 0, np.eye(3)
        J = kin.jacobian_tool(P, R, machine.geometry)
        geo = fx.geometry_sensitivity(P, R, machine.geometry)
        forces = np.nan_to_num(state.axial[at])
    else:
        P, R = np.zeros((0, 3)), np.zeros((0, 3, 3))
        J, geo, forces = np.zeros((0, 6, 5)), {}, np.zeros((0, 3))
    ctx = Context(machine, t, q_cmd, q_motor, has_enc, temps, rows, J, geo, forces, obs, uniform_step(t, bounds))
    ctx.extra["P"], ctx.extra["R"] = P, R
    record_runs(ctx, bounds, sampled, direction_before)
    if len(rows) and state.tip_force is not None:
        ctx.extra["tip_force"] = np.nan_to_num(state.tip_force[at])
    return ctx


def folds_of(ctx: Context) -> np.ndarray:
    tt = ctx.t[ctx.obs.row]
    span = max(ctx.duration, 1e-12)
    block = np.minimum(((tt - ctx.t[0]) / span * N_BLOCKS).astype(int), N_BLOCKS - 1)
    return block % N_FOLDS


# ---------------------------------------------------------------- selection

class _Progress:
    def __init__(self, total, enabled, label="diagnosing"):
        self.total, self.enabled, self.label, self.k = max(total, 1), enabled, label, 0
        self.t0 = time.monotonic()

    def step(self, note=""):
        self.k += 1
        if self.enabled:
            frac = min(self.k / self.total, 1.0)
            bar = "#" * int(30 * frac) + "-" * (30 - int(30 * frac))
            sys.stderr.write(f"\r{self.label} [{bar}] {100 * frac:3.0f}% {time.monotonic() - self.t0:5.1f}s {note[:28]:28s}")
            sys.stderr.flush()

    def done(self):
        if self.enabled:
            self.k = self.total - 1        # (fewer selection rounds than budgeted: the work is done)
            self.step("done")
            sys.stderr.write("\n")
            sys.stderr.flush()


def _cv_pred(cand, ctx, y, folds, fold_params=None):
    pred = np.zeros_like(y)
    for k in range(N_FOLDS):
        test = folds == k
        if not test.any():
            continue
        f = cand.fit(ctx, y, ~test)
        if not f.ok:
            return None
        pred[test] = f.pred[test]
        if fold_params is not None:
            fp = dict(f.params)
            if "t_bracket" in f.internal:        # (the span of time the fold's data allow a step in)
                fp["_t_bracket"] = f.internal["t_bracket"]
            fold_params.append(fp)
    return pred


# how far a training fold's estimate may stray from the full fit, per parameter, before the
# parameter counts as not identifiable: (scale of the parameter, allowed deviation / scale)
DERIVED = {"t_ref_C", "screw_fixed_end_mm", "stribeck_speed_mm_s", "stribeck_mm", "channel",
           # a drive's friction: the Stribeck term (a grid speed and what it adds at low speed) and the
           # viscous coefficient of each direction are details of the friction, whose Coulomb and mean
           # viscous coefficients carry its identifiability; the bandwidth is the lag's reciprocal
           "stribeck_N", "stribeck_Nm", "stribeck_A", "stribeck_speed_deg_s", "bandwidth_hz",
           "viscous_pos_N_s_per_m", "viscous_neg_N_s_per_m", "viscous_pos_Nm_s_per_rad",
           "viscous_neg_Nm_s_per_rad", "viscous_pos_A_s_per_m", "viscous_neg_A_s_per_m",
           "viscous_pos_A_s_per_rad", "viscous_neg_A_s_per_rad"}


def fold_spread(params, fold_params, ctx) -> float:
    """Largest deviation of a fold's parameter from the full fit, in units of its tolerance
    (> 1: not identifiable). Tolerances: a frequency or period 5 %, a step time 1.5 time blocks,
    a gain deviation, an amplitude, width, stiffness or delay 50 % of its value. A step time is
    compared with the span between the fold's last sample before its step and first sample after
    it (``_t_bracket``): a fold that lacks the step's block, and maybe a tracker drop-out next to
    it, cannot tell where in that gap the step is, and a step anywhere in it agrees with the fold."""
    worst = 0.0
    for k, v in params.items():
        if k in DERIVED or isinstance(v, str):
            continue
        vv = np.atleast_1d(np.asarray(v, float))
        if k == "t_s":       # a fold without the step's block can only place it at that block's edge
            scale = 1.5 * max(ctx.duration, 1e-9) / N_BLOCKS
        elif k in ("freq_hz", "period_mm"):
            scale = 0.05 * float(np.linalg.norm(vv))
        elif k == "gain":
            scale = 0.5 * float(np.abs(vv - 1).max())
            vv = vv - 1
        else:
            scale = 0.5 * float(np.linalg.norm(vv))
        for fp in fold_params:
            if k not in fp:
                return float("inf")
            fv = np.atleast_1d(np.asarray(fp[k], float)) - (1 if k == "gain" else 0)
            if fv.shape != vv.shape:
                return float("inf")
            if k == "t_s" and "_t_bracket" in fp:
                lo, hi = fp["_t_bracket"]
                worst = max(worst, max(lo - float(vv[0]), float(vv[0]) - hi, 0.0) / max(scale, 1e-300))
                continue
            worst = max(worst, float(np.linalg.norm(fv - vv)) / max(scale, 1e-300))
    return worst


LOOSE = 0.2             # a parameter whose standard error exceeds this share of it is said to be loosely pinned


def fold_uncertainty(params, fold_params) -> dict:
    """Standard error of each scalar parameter by the delete-a-group jackknife over the K training
    folds (each leaves out one interleaved group of time blocks, so noise correlated within a block
    stays with its block): se² = (K − 1)/K · Σ(θ_k − θ̄)². With K = 3 it is a rough figure (two
    degrees of freedom): its order of magnitude, not its second digit. A step time is left out: a
    fold without the step's block cannot place it. So is a parameter that every fold kept at the
    full fit's value (a mode whose folds could not refute it): their scatter measured nothing."""
    K = len(fold_params)
    out = {}
    if K < 2:
        return out
    for k, v in params.items():
        if k in DERIVED or k == "t_s" or isinstance(v, (str, bool)) or np.ndim(v) != 0:
            continue
        vals = [fp.get(k) for fp in fold_params]
        if any(x is None or np.ndim(x) != 0 for x in vals):
            continue
        th = np.asarray(vals, float)
        se = float(np.sqrt((K - 1) / K * np.sum((th - th.mean()) ** 2))) if np.all(np.isfinite(th)) else 0.0
        # folds that all kept the full fit's value (a mode whose folds cannot refute it keeps it)
        # measured nothing: no figure rather than a standard error of 0
        if se > 1e-9 * abs(float(v)):
            out[k] = se
    return out


def _affected(ctx, pred):
    o = ctx.obs
    e = np.bincount(o.ch, pred * pred, minlength=len(o.channels))
    if e.max() <= 0:
        return np.zeros(len(o.channels), bool)
    return e >= 0.02 * e.max()


PREDICTS_MIN = 9.0      # whitened energy of a prediction on a channel that counts as predicting there (3 σ)


def _predicts(ctx, pred):
    """Channels where ``pred`` carries more than PREDICTS_MIN of whitened energy."""
    e = np.bincount(ctx.obs.ch, pred * pred, minlength=len(ctx.obs.channels))
    return e >= PREDICTS_MIN


def evaluate(cand, ctx, y, folds):
    """Full fit + held-out score of one candidate on residual y. None when it is no candidate."""
    o = ctx.obs
    N = len(y)
    allm = np.ones(N, bool)
    try:
        full = cand.fit(ctx, y, allm)
    except (np.linalg.LinAlgError, ValueError, FloatingPointError):
        return None
    if not full.ok or not np.all(np.isfinite(full.pred)):
        return None
    sse0 = float(y @ y)
    d_in = sse0 - float((y - full.pred) @ (y - full.pred))
    pen = full.nparams * math.log(max(N, 2))
    if d_in < max(MIN_DSSE, pen):
        return None
    fps = []
    cv = _cv_pred(cand, ctx, y, folds, fps)
    if cv is None or not np.all(np.isfinite(cv)):
        return None
    aff = _affected(ctx, full.pred)
    m = aff[o.ch]
    base = float(y[m] @ y[m])
    rel_gain = base - float((y[m] - cv[m]) @ (y[m] - cv[m]))
    # the held-out gain counts every channel the effect predicts beyond noise, not only its main
    # ones: a tool length error moves the tip along the tilted tool, mostly z but also x and y, and
    # those x and y predictions are what tells it from an offset of the z channel
    mw = (_predicts(ctx, full.pred) | aff)[o.ch]
    d_cv = float(y[mw] @ y[mw]) - float((y[mw] - cv[mw]) @ (y[mw] - cv[mw]))
    big = float(np.quantile(np.abs(full.pred[m]), 0.99)) if m.any() else 0.0
    # (a machine of independent axes counts its load side with a second encoder, load_<A>)
    encoders = ("enc_", "load_") if "axes" in ctx.extra else ("enc_",)
    enc_only = all(o.channels[i].startswith(encoders) for i in np.flatnonzero(aff))
    return {"cand": cand, "fit": full, "cv": cv, "d_cv": d_cv, "d_in": d_in, "pen": pen, "big": big,
            "enc_only": enc_only,
            "rel": rel_gain / base if base > 0 else 0.0, "affected": aff,
            "score": d_cv - 0.5 * pen, "fold_params": fps, "y": y}


def own_checks(ev, ctx) -> list[str]:
    """The effect's own checks plus identifiability across the training folds."""
    c, f = ev["cand"], ev["fit"]
    try:
        probs = list(c.check(ctx, f, ev["y"]))
    except (np.linalg.LinAlgError, ValueError, FloatingPointError) as e:
        probs = [f"check failed: {e}"]
    ev["spread"] = fold_spread(f.params, ev["fold_params"], ctx)
    if ev["spread"] > 1.0:
        probs.append("its parameters differ between time folds beyond tolerance (not identifiable)")
    return probs


SHARE_MIN = 0.3    # ... and it must describe at least this share of its channels' structure


def _share(ev, ctx, y):
    """The effect's in-sample gain on its channels over that of the flexible description (the
    ``share`` feature of the confidence); also sets ``ev["net_share"]``, the same ratio of the gains
    beyond chance (each less its number of coefficients, what a fit removes from white noise), which
    the SHARE_MIN rule judges: near the noise floor the flexible description's ~50 coefficients a
    channel fit noise as well, and a 2 µm pitch error under 1.5 µm of tracker noise came out at
    0.2 of it where its gain beyond chance is 0.34 of the flexible's."""
    m = ev["affected"][ctx.obs.ch]
    p = ev["fit"].pred
    d_eff = float(y[m] @ y[m] - (y[m] - p[m]) @ (y[m] - p[m]))
    d_flex, dof = flexible_gain(ctx, y, ev["affected"], with_dof=True)
    net_flex = d_flex - dof
    net_eff = d_eff - ev["fit"].nparams
    ev["net_share"] = min(net_eff / net_flex, 2.0) if net_flex > 0 else (2.0 if net_eff > 0 else 0.0)
    return min(d_eff / d_flex, 2.0) if d_flex > 0 else 2.0


BLOCK_RATIO = 1.5   # a refused effect this much stronger on the same channels blocks weaker names


STRONG = 3.0            # held-out gain over the threshold that counts as evidence by itself
DRIFT_REL_MIN = 0.08    # a sensor drift must remove this share of its channel's residual, strong or not: a
                        # clean gauge's slow wander (an amplifier's 1/f noise) fits a line at a few percent
                        # (blind hidden set: 0.018 µε/s at 4 % on a clean run, named; a smoothed random walk
                        # of 0.1 µε on strain_3 of a clean raster run: 0.025 µε/s at 4.6 %, named with 0.74).
                        # The true drifts of the sensor_drift suite remove 10 to 82 % (32 cases, 8 seed bases)
LINE_RATIO = 5.0        # a screw-position line this far above the spectrum's median is located evidence


def accept(ev) -> bool:
    """Held-out gain beyond noise, a real share of its channels, and a peak above noise; the peak
    rule is waived for a periodic error sitting on a line that the locate stage found against
    that screw's position, and for any effect whose held-out gain is STRONG x the threshold:
    many samples then carry it, however small each one is (a 2 µm pitch error, a 0.3 µm/s drift
    under 1.5 µm of tracker noise); a STRONG gain waives the REL_MIN share of the channels' energy
    as well (those channels are mostly noise). The own checks and the SHARE_MIN rule still apply."""
    # an encoder counts whole pulses: structure below its pulse is quantisation, never waived
    enc_only = ev["enc_only"]             # (evaluate's, always there)
    strong = not enc_only and ev["d_cv"] > STRONG * max(MIN_DSSE, ev["pen"])
    peak_ok = ev["big"] > MIN_PEAK or strong or (not enc_only and ev.get("line_evidence", False))
    # the share of the channels' energy: waived for a strong held-out gain too (a 2 µm pitch error
    # is 3 % of the energy of 10⁴ tracker samples that are mostly noise, and still 20 σ)
    if ev["cand"].effect == "sensor_drift" and ev["rel"] < DRIFT_REL_MIN:
        return False
    return ev["d_cv"] > max(MIN_DSSE, ev["pen"]) and (ev["rel"] > REL_MIN or strong) and peak_ok


def _line_evidence(ev, loc) -> bool:
    c = ev["cand"]
    if loc is None or c.effect not in ("pitch_error", "periodic_error"):
        return False
    info = loc["axes"].get(c.target, {})
    spec = info.get("_screw_spectrum")
    p = ev["fit"].params.get("period_mm")
    if spec is None or not p:
        return False
    f, amp = spec
    sel = (f > 0) & (np.abs(f * p - 1) < 0.03)
    med = float(np.median(amp[f > 0])) if np.any(f > 0) else 0.0
    return bool(sel.any() and med > 0 and amp[sel].max() >= LINE_RATIO * med)


OWN_MARGIN = (MIN_DSSE, 0.005)   # (absolute, relative) held-out gain another temperature must add


def _rank(ev, pool) -> float:
    """Sort key of an accepted candidate: its score, except that a thermal growth against another
    temperature than the screw's own (effects.own_temperature) gives way to the own one when that
    explains nearly as much: the screws of a machine warm together, so every screw temperature
    follows the same warm-up and the fit alone cannot tell them apart; physics says the screw grows
    with its own temperature."""
    c = ev["cand"]
    if c.effect != "thermal_growth" or c.channel in fx.own_temperature(c.target):
        return ev["score"]
    own = [e for e in pool if e["cand"].effect == "thermal_growth" and e["cand"].target == c.target
           and e["cand"].channel in fx.own_temperature(c.target)]
    if own and ev["score"] - own[0]["score"] < max(OWN_MARGIN[0], OWN_MARGIN[1] * abs(ev["d_cv"])):
        return min(ev["score"], own[0]["score"]) - 1e-9
    return ev["score"]


def _passes(ev, ctx, y) -> bool:
    """Its own checks and the SHARE_MIN rule (once per evaluation; the reasons in ev["problems"])."""
    if "problems" not in ev:
        ev["problems"] = own_checks(ev, ctx)
        if not ev["problems"]:
            ev["share"] = _share(ev, ctx, y)
            if ev["net_share"] < SHARE_MIN:
                ev["problems"].append(
                    f"it removes only {100 * max(ev['net_share'], 0.0):.0f} % of what a flexible description "
                    "of time, position and direction removes beyond chance from its channels (a partial "
                    "fit of something else)")
    return not ev["problems"]


def _among_lookalikes(best, pool, ctx, y, refused=()):
    """The one to name among the candidates of other effects that predict what ``best`` predicts
    within noise (pmctl.tools.twin.lookalikes); the others go with it as its alternatives. (Another
    parametrisation of the same effect, or a thermal growth against another temperature, competes
    by score as before; a candidate that a stronger refused one blocks stays out.)"""
    group = [best]
    for ev in pool:
        if ev is best or ev["cand"].effect == best["cand"].effect:
            continue
        if any(r["score"] > BLOCK_RATIO * ev["score"] and np.any(r["affected"] & ev["affected"]) for r in refused):
            continue
        if lk.lookalike_d2(ev["fit"].pred, best["fit"].pred) > lk.LOOK_D2 or not _passes(ev, ctx, y):
            continue
        group.append(ev)
    if len(group) == 1:
        return best
    k, ws = lk.choose([{"effect": e["cand"].effect, "params": e["fit"].params, "score": e["score"]} for e in group])
    chosen = group[k]
    chosen["alternatives"] = [(e, w) for i, (e, w) in enumerate(zip(group, ws)) if i != k]
    chosen["weight_share"] = ws[k] / sum(ws) if sum(ws) > 0 else 1.0 / len(group)
    return chosen


SAME_INSTANT_S = 0.25   # lost steps of several axes this close in time share one cause


def _shared_step(ev, others) -> list:
    """The lost steps among ``others`` on other axes at the instant of lost step ``ev``."""
    if ev["cand"].effect != "lost_steps":
        return []
    t = ev["fit"].params["t_s"]
    return [e for e in others if e["cand"].effect == "lost_steps" and e["cand"].target != ev["cand"].target
            and abs(e["fit"].params["t_s"] - t) <= SAME_INSTANT_S]


def select_effects(ctx: Context, *, max_findings=MAX_FINDINGS, progress=False, candidates=None, loc=None,
                   backfit=2):
    """Greedy forward selection. Returns (accepted evaluations in order, final residual, refused
    evaluations). ``loc``: the locate stage's breakdown (its screw-position lines are evidence);
    ``backfit``: passes of the final refit of each accepted effect with the others held."""
    y0 = ctx.obs.y
    folds = folds_of(ctx)
    cands = fx.catalogue(ctx) if candidates is None else candidates
    y = y0.copy()
    accepted, rejected = [], []
    bar = _Progress(len(cands) * 2, progress)
    withdrawn = []          # lost steps that several axes shared (refused together)
    for rnd in range(max_findings + 4):
        if len(accepted) >= max_findings:
            break
        taken = {ev["cand"].key() for ev in accepted} | {ev["cand"].key() for ev in withdrawn}
        pool = []
        for c in cands:
            bar.step(c.label)
            if c.key() in taken:
                continue
            if hasattr(c, "reset"):
                c.reset()
            ev = evaluate(c, ctx, y, folds)
            if ev is not None:
                ev["line_evidence"] = _line_evidence(ev, loc)
                if accept(ev):
                    pool.append(ev)
        ranks = [_rank(e, pool) for e in pool]
        pool = [e for _, e in sorted(zip(ranks, pool), key=lambda re: -re[0])]
        best, refused = None, []
        for ev in pool:
            blocked = [r for r in refused if r["score"] > BLOCK_RATIO * ev["score"]
                       and np.any(r["affected"] & ev["affected"])]
            if blocked:
                continue
            if not _passes(ev, ctx, y):          # (a fresh evaluation: checked here for the first time)
                refused.append(ev)
                continue
            best = ev
            break
        if best is not None:
            best = _among_lookalikes(best, pool, ctx, y, refused)
        for r in refused:
            if r["cand"].key() not in {e["cand"].key() for e in rejected}:
                rejected.append(r)
        if best is None:
            break
        shared = _shared_step(best, accepted + withdrawn)
        if shared:
            # missed pulses are one drive's fault: steps of several axes at one instant have a
            # common cause (a collision, the measurement shifting) that the catalogue lacks
            for ev in [best] + shared:
                if ev in accepted:
                    accepted.remove(ev)
                    y = y + ev["fit"].pred
                others = ", ".join(e["cand"].target for e in [best] + shared if e is not ev)
                ev["problems"] = [f"a step at {ev['fit'].params['t_s']:.2f} s shared by {others} within "
                                  f"{SAME_INSTANT_S} s: not lost pulses of one drive but one common cause"]
                if ev not in withdrawn:
                    withdrawn.append(ev)
                    rejected[:] = [r for r in rejected if r["cand"].key() != ev["cand"].key()] + [ev]
            continue
        accepted.append(best)
        y = y - best["fit"].pred
    bar.done()
    # backfitting: refit each accepted effect with the others held at their current fits
    allm = np.ones(len(y0), bool)
    for _ in range(backfit if len(accepted) > 1 else 0):
        for j, ev in enumerate(accepted):
            others = sum((e["fit"].pred for k, e in enumerate(accepted) if k != j), np.zeros_like(y0))
            c = ev["cand"]
            if hasattr(c, "reset"):
                c.reset()
            f = c.fit(ctx, y0 - others, allm)
            if f.ok:
                ev["fit"] = f
    # held-out predictions for the report, each on the residual left by the others
    for j, ev in enumerate(accepted):
        others = sum((e["fit"].pred for k, e in enumerate(accepted) if k != j), np.zeros_like(y0))
        c = ev["cand"]
        cv = ev["cv"]
        if len(accepted) > 1:
            if hasattr(c, "reset"):
                c.reset()
            c.fit(ctx, y0 - others, allm)        # (the fit on all samples first, as in evaluate)
            cv = _cv_pred(c, ctx, y0 - others, folds)
        ev["cv"] = cv if cv is not None else ev["fit"].pred
    yfinal = y0 - sum((e["fit"].pred for e in accepted), np.zeros_like(y0))
    for ev in accepted + rejected:
        ev.pop("y", None)
    return accepted, yfinal, rejected


# ---------------------------------------------------------------- report

def _params_text(p: dict) -> str:
    return ", ".join(f"{k} = {v}" for k, v in p.items())


def _rms_by_channel(ctx, y, channels):
    o = ctx.obs
    out = {}
    for c in channels:
        m = o.ch == o.channels.index(c)
        out[c] = float(np.sqrt(np.mean((y[m] / o.w[m]) ** 2))) if m.any() else None
    return out


def _r(x, sig=4):
    """Round for the report (enough digits for gains near 1)."""
    if isinstance(x, float):
        return float(f"{x:.{sig}g}") if math.isfinite(x) else x
    if isinstance(x, list):
        return [_r(v, sig) for v in x]
    return x


def _fmt_um(mm):
    return f"{mm * 1000:.1f} µm" if abs(mm) < 1 else f"{mm:.3f} mm"


def _evidence(ev, ctx, loc, explained, channels=(), beyond_noise=False):
    """One or two sentences; ``explained`` is the share of the residual energy (whitened) the
    effect removes from its channels on held-out samples."""
    text = _evidence_core(ev, ctx, loc, explained)
    chans = ", ".join(channels[:4]) + (" ..." if len(channels) > 4 else "")
    if chans:
        text = text.rstrip(".") + f" (channels {chans})."
    if beyond_noise:
        text += (" That is more than the excess over the estimated noise: part of what the WHERE table "
                 "counted as noise is this effect (see its rms after).")
    return text


def _evidence_core(ev, ctx, loc, explained):
    c, p = ev["cand"], ev["fit"].params
    pct = f"{100 * explained:.0f} %"
    eff = c.effect
    if eff == "backlash":
        dirs = fx.axis_direction(ctx, c.a)
        moving = dirs[dirs != 0]
        if not np.any(moving[1:] != moving[:-1]):
            return (f"{c.target} travels one way only, and the tool error along it is an offset of "
                    f"{_fmt_um(p['width_mm'] / 2)} on the side that this travel sets; a {p['width_mm']:.4f} mm "
                    f"backlash on {c.target} explains {pct} of it on held-out samples.")
        d = loc["direction"].get(c.target, {})
        jump = abs(d.get("jump_mm", p["width_mm"]))
        return (f"the tool error along {c.target} flips by {_fmt_um(jump)} when {c.target} reverses "
                f"(t-statistic {abs(d.get('t_value', 0)):.0f}), independent of pose; a {p['width_mm']:.4f} mm backlash "
                f"on {c.target} explains {pct} of it on held-out samples.")
    if eff == "pitch_error":
        return (f"the error along {c.target} is periodic in the screw position with a period of "
                f"{p['period_mm']:.3f} mm ({1 / p['period_mm']:.3f} /mm) and {_fmt_um(p['amplitude_mm'])} amplitude; "
                f"a screw pitch error explains {pct} of it on held-out samples.")
    if eff == "thermal_growth":
        T = ctx.temps[p["channel"]]
        x = np.abs(ctx.q_cmd[:, fx.axis_index(ctx, c.target)]).max()
        return (f"the error along {c.target} grows with {p['channel']} (ΔT = {np.ptp(T):.1f} K) and with the screw "
                f"position; α = {p['alpha_per_K']:.3g} /K ({_fmt_um(abs(p['alpha_per_K']) * np.ptp(T) * x)} at "
                f"{x:.0f} mm), growing from a fixed bearing at {p['screw_fixed_end_mm']:.0f} mm, explains {pct} of it "
                f"on held-out samples.")
    if "axes" in ctx.extra and eff in GENERIC_EFFECTS and "coulomb_mm" not in p:
        return _generic_evidence(ev, ctx, pct)
    if eff == "compliance":
        a = AXES.index(c.target)
        if a >= 3:
            F = ctx.extra.get("tip_force", np.zeros((1, 3)))[:, a - 3]
            return (f"the table gives way along {c.target} in proportion to the tip force F{'xy'[a - 3]} "
                    f"({F.min():.0f} … {F.max():.0f} N); a stiffness of {p['stiffness_N_per_mm']:.0f} N/mm explains "
                    f"{pct} of it on held-out samples.")
        f = ctx.forces[:, a]
        return (f"the tool deflects along chain {c.target} in proportion to its axial force "
                f"({f.min():.0f} … {f.max():.0f} N); a stiffness of {p['stiffness_N_per_mm']:.0f} N/mm explains "
                f"{pct} of it on held-out samples.")
    if eff == "servo_lag":
        v = np.abs(np.gradient(ctx.q_cmd[:, fx.axis_index(ctx, c.target)], ctx.t)).max()
        return (f"enc_{c.target} trails cmd_{c.target} in proportion to speed ({_fmt_um(v * p['tau_s'])} at "
                f"{v:.0f} mm/s); a first-order servo lag τ = {1000 * p['tau_s']:.2f} ms explains {pct} of it "
                f"on held-out samples.")
    if eff == "resonance":
        return (f"{c.target} rings at {p['freq_hz']:.2f} Hz (damping ratio {p['damping_ratio']:.3f}) after "
                f"accelerations; a base-excited mode explains {pct} of the residual on held-out samples.")
    if eff == "lost_steps":
        return (f"the load side of {c.target} steps by {_fmt_um(p['offset_mm'])} at t = {p['t_s']:.3f} s while the "
                f"motor-side count runs on, and stays; a lost-step offset explains {pct} of it on held-out samples.")
    if eff == "sensor_gain":
        return (f"{c.target} reads {1e6 * (p['gain'] - 1):+.0f} ppm of its predicted value across its range; a "
                f"gain of {p['gain']:.6f} explains {pct} of its residual on held-out samples.")
    if eff == "sensor_offset":
        unit = {"tip": " mm", "enc": " mm", "str": " µε"}.get(c.target[:3], "")
        return (f"{c.target} is shifted by {p['offset']:+.4g}{unit} against its prediction at every pose and speed; "
                f"an offset explains {pct} of its residual on held-out samples.")
    if eff == "geometry":
        who = "the tool" if c.target == "tool" else f"chain {c.target}"
        pp = ", ".join(f"{k} = {np.round(np.atleast_1d(v), 4).tolist()}" for k, v in p.items())
        return (f"the tool error is a smooth function of pose; kinematic deltas of {who} ({pp}) explain {pct} of it "
                f"on held-out samples.")
    return f"explains {pct} of the residual on held-out samples."


GENERIC_EFFECTS = ("inertia", "friction", "force_offset", "servo_tracking", "cogging", "compliance")


def _generic_evidence(ev, ctx, pct):
    """Evidence of the effects of a machine of independent axes (pmctl.tools.twin.drive)."""
    c, p = ev["cand"], ev["fit"].params
    A, eff = c.target, c.effect
    m = ctx.machine
    fu = m.effort_unit(A) if hasattr(m, "effort_unit") else "N"
    pu = m.pos_unit(A) if hasattr(m, "pos_unit") else "mm"
    v = ", ".join(f"{k} = {val:.4g}" for k, val in p.items() if isinstance(val, float))
    if eff == "inertia":
        return (f"effort_{A} follows the acceleration of {A} ({v}); the moving {'inertia' if m.rotary.get(A) else 'mass'} "
                f"explains {pct} of it on held-out samples.")
    if eff == "friction":
        kind = "by direction" if any("_pos_" in k for k in p) else "the same both ways"
        return (f"effort_{A} flips with the direction of motion of {A} and grows with its speed ({v}; viscous "
                f"{kind}); Coulomb and viscous friction explain {pct} of it on held-out samples.")
    if eff == "force_offset":
        return (f"effort_{A} holds a constant {next(iter(p.values())):+.4g} {fu} whatever the motion (gravity, a "
                f"counterweight, a cable's pull or the sensor's zero); it explains {pct} of it on held-out samples.")
    if eff == "servo_tracking":
        return (f"enc_{A} trails cmd_{A} by {1000 * p['lag_s']:.3g} ms of its velocity (a first-order loop of "
                f"{p['bandwidth_hz']:.3g} Hz) and {p['accel_lag_s2']:.3g} s² of its acceleration; that following "
                f"error explains {pct} of it on held-out samples.")
    if eff == "cogging":
        per = p.get("period_mm")
        return (f"effort_{A} is periodic in the position of {A} with a period of {per:.4g} {pu} ({v}): cogging or "
                f"a once-per-turn force; it explains {pct} of it on held-out samples.")
    if eff == "compliance":
        return (f"load_{A} gives way against enc_{A} in proportion to effort_{A} ({v}): the screw, nut, bearings "
                f"and coupling act as a spring; it explains {pct} of it on held-out samples.")
    return f"explains {pct} of the residual on held-out samples."


def _finding(ev, ctx, y_before, y0, y_after_cum, loc_before):
    c, f = ev["cand"], ev["fit"]
    o = ctx.obs
    aff = [o.channels[i] for i in np.nonzero(ev["affected"])[0]]
    m = ev["affected"][o.ch]
    sse_b = float(y_before[m] @ y_before[m])
    r_after = y_before - ev["cv"]
    sse_a = float(r_after[m] @ r_after[m])
    excess = max(sse_b - m.sum(), 1e-12)
    explained = min(max((sse_b - sse_a) / excess, 0.0), 1.0)
    # for the text: the share of the residual energy removed, and whether that is more than the
    # excess over the estimated noise (then part of what was counted as noise was this effect)
    share = min(max((sse_b - sse_a) / max(sse_b, 1e-12), 0.0), 1.0)
    beyond_noise = (sse_b - sse_a) > 1.5 * excess
    # where: spans where the effect's contribution exceeds 2 x noise
    tt = ctx.t[o.row]
    pred = np.abs(f.pred)
    flag = pred > 2.0
    tw = windows(np.sort(tt[flag]), np.ones(int(flag.sum()), bool), ctx.duration / 50) if flag.any() else []
    target_key = c.target_key
    tgt = c.target
    params = {k: _r(v, 7 if k == "gain" else 4) for k, v in f.params.items()}
    unc = {k: _r(v, 2) for k, v in fold_uncertainty(f.params, ev.get("fold_params", [])).items()}
    item = {"effect": c.effect, target_key: tgt, "parameters": params, "uncertainty": unc,
            "where": {"channels": aff, "time_windows_s": [[round(a, 3), round(b, 3)] for a, b in tw],
                      "direction_dependent": c.effect == "backlash",
                      "frequency_hz": _r(f.params["freq_hz"]) if c.effect == "resonance" else None},
            "evidence": _evidence(ev, ctx, loc_before, share, aff, beyond_noise),
            "rms_before": {k: _r(v) for k, v in _rms_by_channel(ctx, y0, aff).items()},
            "rms_after": {k: _r(v) for k, v in _rms_by_channel(ctx, y_after_cum, aff).items()},
            "heldout": True}
    if c.effect == "pitch_error":
        item["where"]["spatial_frequency_per_mm"] = _r(1 / f.params["period_mm"])
    loose = []
    for k, se in unc.items():
        ref = abs(f.params[k] - (1.0 if k == "gain" else 0.0))
        if ref > 0 and se > LOOSE * ref:
            loose.append(f"{k} only to ± {100 * se / ref:.0f} %")
    if loose:
        item["evidence"] += f" This run pins {', '.join(loose)} (the scatter of its training folds)."
    if ev.get("alternatives"):
        item["alternatives"] = [{"effect": e["cand"].effect, e["cand"].target_key: e["cand"].target,
                                 "parameters": {k: _r(v, 7 if k == "gain" else 4) for k, v in e["fit"].params.items()},
                                 "weight": _r(w, 3)} for e, w in ev["alternatives"]]
        how = lk.separate_by([c.effect] + [e["cand"].effect for e, _ in ev["alternatives"]])
        alt = "; ".join(f"{a['effect']} on {e['cand'].target_key} {a[e['cand'].target_key]} ({_params_text(a['parameters'])})"
                        for a, (e, _) in zip(item["alternatives"], ev["alternatives"]))
        item["evidence"] += (f" This recording cannot tell it from {alt}: they predict the same data within "
                             f"noise; it is named for its physics (pmctl.tools.twin.lookalikes)"
                             + (f"; {how} would separate them." if how else "."))
        if how:
            item["separate_by"] = how
    return item, explained


def diagnose(columns: dict, machine, *, name="recording", progress=False,
             cap=DEFAULT_CAP, span=None) -> tuple[dict, dict]:
    """Run the whole diagnosis. Returns (report per docs/diagnosis-report.md, extras for text and plots).
    ``span``: how the rows were kept of a longer recording (:func:`read_for_diagnosis`)."""
    generic = is_axes_machine(machine)
    kw = dict(cap=cap, bounds=span["bounds"] if span else None,
              direction_before=span.get("direction_before") if span else None)
    if generic:           # a machine of independent axes (pmctl.tools.twin.axes, .drive)
        ctx = gx.build_context(columns, machine, **kw)
        cands = drive.catalogue(ctx)
        limit = min(MAX_FINDINGS + 4 * len(machine.axes), 20)
    else:
        columns = compensated_columns(columns, getattr(machine, "compensation", None))     # the NC's joints
        ctx = build_context(columns, machine, **kw)
        cands, limit = None, MAX_FINDINGS
    if span:
        ctx.extra["span"] = span
    loc0 = locate(ctx)
    accepted, yfinal, rejected = select_effects(ctx, progress=progress, loc=loc0, candidates=cands,
                                                max_findings=limit, backfit=BACKFIT_GENERIC if generic else 2)
    y0 = ctx.obs.y
    findings, cum, y_before = [], np.zeros_like(y0), y0.copy()
    for ev in accepted:
        loc_b = locate(ctx, y_before) if ev["cand"].effect == "backlash" else loc0
        y_after = y0 - cum - ev["cv"]
        item, expl = _finding(ev, ctx, y_before, y0, y_after, loc_b)
        findings.append(item)
        cum = cum + ev["fit"].pred
        y_before = y0 - cum
    for item, ev in zip(findings, accepted):
        ev["left"] = left_structure(ctx, yfinal, ev["affected"])     # structure its channels keep
        item["confidence"] = round(calibration.confidence(calibration.features(ev)), 2)
    loc_after = locate(ctx, yfinal)
    unexp = unexplained(ctx, yfinal, loc_after, rejected)
    if unexp:
        verdict = "unexplained mismatch"
    elif findings:
        verdict = "unmodelled physics found"
    else:
        verdict = "consistent with the nominal twin"
    kept = len(ctx.t)
    samples = {"total": int(span["rows_total"]) if span else kept, "analysed": kept,
               "runs": len(span["bounds"]) - 1 if span else 1}
    report = {"recording": name, "verdict": verdict, "samples": samples, "findings": findings, "unexplained": unexp,
              "confidence_calibration": calibration.DESCRIPTION}
    report["units"] = {k: channel_unit(k, machine) for k in ctx.obs.channels}
    extras = {"ctx": ctx, "locate": loc0, "accepted": accepted, "y_final": yfinal,
              "columns": columns, "machine": machine,
              "locate_after": loc_after, "rejected": rejected,
              "features": [calibration.features(ev) for ev in accepted]}
    return report, extras


def _axes_of(machine):
    return machine.axes if is_axes_machine(machine) else AXES


MAX_ROWS = 1_000_000    # rows of a recording the diagnosis holds at once (the working set)
N_SEGMENTS = 48         # ... as this many contiguous runs spread over a longer recording


def read_for_diagnosis(folder, *, progress=False, max_rows=MAX_ROWS, n_segments=N_SEGMENTS):
    """(meta, machine, columns, span) of a recording folder read in bounded memory
    (pmctl.core.recording_chunks: 16 MB blocks, only the channels the twin uses, measured channels
    in float32), with a progress bar on stderr when ``progress``.

    A recording of more than ``max_rows`` rows is kept as ``n_segments`` contiguous runs of
    ``max_rows // n_segments`` rows spread evenly over it (every row is still read and checked):
    each run is long enough for the dynamic effects (lags, modes, reversals) to show in full, and
    the runs span the whole record for the slow ones (drift, thermal growth, a step). ``span``:
    {"rows_total", "rows": [(start, stop), ...] file rows kept, "bounds": run boundaries as
    indices into the kept rows, "direction_before": per run, the direction of each axis' last
    commanded motion before it (AXES order; 0: none)}, for :func:`diagnose`."""
    bar = _Progress(1000, progress, "reading   ")

    def cb(done, total):            # one redraw per 16 MB block
        bar.k = int(1000 * done / max(total, 1)) - 1
        bar.step()
    n_est = count_rows(folder)
    plan = plan_segments(n_est, max_rows, n_segments)
    info = {}
    meta, machine, cols = read_columns(folder, progress=cb if progress else None,
                                       rows=None if len(plan) == 1 else plan, info=info)
    bar.done()
    kept = len(cols["t"])
    if len(plan) == 1:
        plan, bounds, before = [(0, kept)], [0, kept], [[0.0] * len(_axes_of(machine))]
    else:      # (blank lines make the estimate high: the last runs may end short)
        before = [[d.get(f"cmd_{a}", 0.0) for a in _axes_of(machine)]
                  for (a0, _), d in zip(plan, info["cmd_direction_before"]) if a0 < info["rows_total"]]
        plan = [(a, min(b, info["rows_total"])) for a, b in plan if a < info["rows_total"]]
        bounds = np.concatenate([[0], np.cumsum([b - a for a, b in plan])]).tolist()
    return meta, machine, cols, {"rows_total": info["rows_total"], "rows": plan, "bounds": bounds,
                                 "direction_before": before}


def channel_unit(name, machine) -> str:
    """The unit of a measured channel as the report gives it: the prototype's mm (enc, tip), 1
    (tool axis components), µε (strain); a generic machine's from its recording's notes."""
    if is_axes_machine(machine):
        return machine.units.get(name, "")
    return {"tool": "1", "strain": "µε"}.get(name.split("_")[0], "mm")


def format_text(report, extras) -> str:
    ctx, loc = extras["ctx"], extras["locate"]
    smp = report.get("samples") or {"total": len(ctx.t), "analysed": len(ctx.t), "runs": 1}
    held = (f"; kept {smp['analysed']} of them as {smp['runs']} runs of {smp['analysed'] // smp['runs']} "
            f"spread over the record") if smp["runs"] > 1 else ""
    L = [f"recording: {report['recording']}  ({smp['total']} samples, {ctx.duration:.1f} s{held})", "",
         "WHERE the recording differs from the nominal twin", ""]
    after = extras.get("locate_after", {}).get("channels", {}) if report["findings"] else {}
    units = report.get("units") or {}
    L.append(f"  {'channel':10s} {'unit':>7s} {'samples':>8s} {'rms':>11s} {'noise':>11s} {'excess/noise':>12s}"
             + (f" {'rms after':>11s}" if after else "") + "  windows (s)")
    hidden = []
    for k, v in loc["channels"].items():
        win = ", ".join(f"{a:.1f}-{b:.1f}" for a, b in v["windows_s"][:3]) or "-"
        col = ""
        if after:
            ra = after.get(k, {}).get("rms")
            mark = ""
            if ra is not None and v["noise"] > 0 and ra < 0.5 * v["noise"] <= v["rms"]:
                mark = "*"
                hidden.append(k)
            col = f" {ra:10.4g}{mark or ' '}" if ra is not None else f" {'-':>11s}"
        L.append(f"  {k:10s} {units.get(k, ''):>7s} {v['n']:8d} {v['rms']:11.4g} {v['noise']:11.3g} {v['excess']:12.1f}"
                 f"{col}  {win}")
    L.append("  (rms, noise and rms after in the channel's unit; noise: estimated from each channel's own residual"
             + ("; rms after: with all the findings below" if after else "") + ")")
    if hidden:
        L.append(f"  * {', '.join(hidden)}: the findings bring the rms far below the estimated noise, so what "
                 "looked like noise there is explained structure (e.g. a mode ringing faster than the "
                 "noise estimate can tell from noise).")
    L.append("")
    if is_axes_machine(ctx.machine):
        L.append("  by axis (motor side enc-cmd; load side load-enc; direction split; spectrum against position)")
    else:
        L.append("  by axis (load-side equivalent seen by the tool; direction split; spectrum against screw position)")
    for ax, v in loc["axes"].items():
        parts = []
        if "enc_rms_mm" in v:
            parts.append(f"enc-cmd rms {_fmt_um(v['enc_rms_mm'])}")
        if "tool_equiv_rms_mm" in v:
            parts.append(f"tool-equivalent rms {_fmt_um(v['tool_equiv_rms_mm'])}")
        d = loc["direction"].get(ax)
        if d:
            parts.append(f"+/- motion jump {_fmt_um(d['jump_mm'])} (t-statistic {d['t_value']:.1f})")
        if v.get("screw_peak_per_mm"):
            parts.append(f"screw-position peak {v['screw_peak_per_mm']:.3f} /mm "
                         f"(period {v['screw_peak_period_mm']:.2f} mm, {v['screw_peak_ratio']:.0f}x median)")
        if parts:
            L.append(f"  {ax:3s} " + "; ".join(parts))
    servo = loc.get("servo") or {}
    if servo:
        L.append("")
        L.append("  servo tracking (following error enc - cmd, and its fit -(lag·v + k_a·a) on the command)")
        for ax, v in servo.items():
            pu = ctx.machine.pos_unit(ax)
            L.append(f"  {ax:3s} rms {v['fe_rms']:.4g} {pu}, largest {v['fe_max']:.4g} {pu}; lag {1000 * v['lag_s']:.3g} ms "
                     f"({v['lag_s'] * v['v_max']:.3g} {pu} at its top speed {v['v_max']:.4g} {pu}/s), "
                     f"k_a {v['accel_lag_s2']:.3g} s²")
    if loc["regions"]:
        L.append("")
        L.append("  by pose region (rms of residual / noise, terciles)")
        for k, regs in loc["regions"].items():
            L.append(f"  {k:9s} " + "  ".join(f"[{r['range'][0]:.1f},{r['range'][1]:.1f}]: {r['rms_over_noise']:.2f}"
                                             for r in regs))
    sp = [(k, v["spectrum_peak_hz"], v["spectrum_peak_ratio"]) for k, v in loc["channels"].items()
          if v.get("spectrum_peak_hz") and v["spectrum_peak_hz"] >= 1.0 and v["spectrum_peak_ratio"] > 50]
    if sp:
        L.append("")
        L.append("  spectral lines against time: " + ", ".join(f"{k} {f:.2f} Hz ({r:.0f}x)" for k, f, r in sp))
    if loc["windows_s"]:
        L.append("  residual above noise in: " + ", ".join(f"{a:.1f}-{b:.1f} s" for a, b in loc["windows_s"]))
    L += ["", "WHY: " + report["verdict"], ""]
    if report["findings"]:
        L += ["  (\"explains N %\": of the residual its channels still held after the findings listed above it,",
              "   on held-out samples, not cumulative; \"held-out rms a -> b\": the nominal twin's residual -> the",
              "   residual with this finding and all those above it, cumulative, in the channel's unit)", ""]
    for i, f in enumerate(report["findings"], 1):
        tk = "chain" if "chain" in f else ("channel" if "channel" in f else "axis")
        unc = f.get("uncertainty", {})
        L.append(f"  {i}. {f['effect']} on {tk} {f[tk]}: " +
                 ", ".join(f"{k} = {v}" + (f" ± {unc[k]:.2g}" if k in unc else "") for k, v in f["parameters"].items()))
        L.append(f"     {f['evidence']}")
        L.append("     held-out rms: " + ", ".join(
            f"{k} {f['rms_before'][k]:.3g} -> {f['rms_after'][k]:.3g}{(' ' + units[k]) if units.get(k) else ''}"
            for k in f["rms_before"])
            + (f"; confidence {f['confidence']:.2f}" if "confidence" in f else ""))
    for u in report.get("unexplained", []):
        where = u["region"] or ", ".join(f"{a:.1f}-{b:.1f} s" for a, b in u["time_windows_s"][:3]) or "-"
        L.append(f"  unexplained: {', '.join(u['channels'])}"
                 f"{' (axis ' + u['axis'] + ')' if u['axis'] else ''}: {u['signature']}, "
                 f"{u['excess_over_noise']:.1f} x noise, {where}")
        L.append(f"     {u['evidence']}")
    if not ctx.obs.channels:
        L.append("  The recording carries no measured channel (enc_*, tip_*, tool_*, strain_*): nothing to compare.")
    elif not report["findings"]:
        L.append("  No effect improves the held-out fit by more than noise would.")
    return "\n".join(L)


# ---------------------------------------------------------------- CLI

def _display_name(folder: Path) -> str:
    """How the report names a recording: its folder's name, with the parent's when the folder has a
    generic name (``case-003/recording``, not ``recording``)."""
    folder = Path(folder).absolute()
    if folder.name.lower() in ("recording", "data", "rec", "") and folder.parent.name:
        return f"{folder.parent.name}/{folder.name}"
    return folder.name


def find_recording(folder) -> Path:
    """The recording folder a user meant: ``folder`` itself, or the one recording one or two levels
    below it (``OUT/case-000`` holds ``recording/``). Raises InputError saying what is there."""
    folder = Path(folder)
    if folder.is_file() and folder.name in (META_FILE, "data.csv"):
        return folder.parent
    if not folder.exists():
        part = partial_path(folder)
        if part.is_dir():
            raise InputError(folder, None, f"no such folder, but {part} is there: the recording of a run that "
                                           f"did not finish; diagnose it with: pmctl twin diagnose {part}")
        raise InputError(folder, None, "no such folder")
    if not folder.is_dir() or (folder / META_FILE).is_file():
        return folder
    found = sorted({p.parent for p in folder.glob(f"*/{META_FILE}")} | {p.parent for p in folder.glob(f"*/*/{META_FILE}")})
    if len(found) == 1:
        return found[0]
    if found:
        shown = ", ".join(str(p) for p in found[:5]) + (" ..." if len(found) > 5 else "")
        raise InputError(folder, None, f"not a recording folder (no {META_FILE}); it holds {len(found)} "
                                       f"recordings: {shown}; name one of them")
    raise InputError(folder, None, f"not a recording folder: no {META_FILE} here or in its sub-folders")


def plant_notes(report, meta) -> list[str]:
    """Findings that are the recorded simulation's own physics: a resonance on chain i (or strain_i)
    at the simulated plant's chain-mode frequency (recording.json ``run.plant``, written by
    ``pmctl run`` on the sim backend). Each matching finding's evidence says so; returns the notes."""
    run = meta.get("run") if isinstance(meta.get("run"), dict) else {}
    plant = run.get("plant") if isinstance(run.get("plant"), dict) else {}
    modes = plant.get("chain_mode_hz") or []
    notes = []
    for f in report["findings"]:
        if f["effect"] != "resonance":
            continue
        tgt = str(f.get("axis") or f.get("channel") or "")
        i = {"L1": 0, "L2": 1, "L3": 2, "strain_1": 0, "strain_2": 1, "strain_3": 2}.get(tgt)
        fr = f["parameters"].get("freq_hz")
        if i is None or i >= len(modes) or not fr:
            continue
        if abs(fr - modes[i]) <= 0.03 * modes[i]:
            z = plant.get("chain_mode_damping_ratio") or []
            zs = f", damping ratio {z[i]:g}" if i < len(z) else ""
            note = (f"It matches the simulated plant's chain-{i + 1} mode ({modes[i]:.1f} Hz{zs}; "
                    f"recording.json run.plant): expected, not a fault.")
            f["evidence"] = f["evidence"] + " " + note
            notes.append(f"{tgt}: {fr:g} Hz matches the simulated chain mode {modes[i]:.1f} Hz")
    return notes


def _run(args) -> int:
    folder = find_recording(args.folder)
    if Path(folder) != Path(args.folder) and not Path(args.folder).is_file():
        print(f"pmctl: {args.folder} holds one recording, in {folder}: diagnosing that", file=sys.stderr)
    # a progress bar on stderr: on long work when stderr is a terminal, always with --progress
    forced = getattr(args, "progress", False)
    show = forced or (not args.no_progress and sys.stderr.isatty())
    data = Path(folder) / "data.csv"
    big = data.is_file() and data.stat().st_size >= 16 << 20        # ~10^5 rows and more
    meta, rec_machine, columns, span = read_for_diagnosis(folder, progress=forced or (show and big))
    n = span["rows_total"]
    if meta.get("complete") is False:
        why = meta.get("incomplete_reason") or "the run that wrote it did not finish"
        print(f"pmctl: warning: {folder} is an incomplete recording ({why}); diagnosing the "
              f"{n} samples it holds", file=sys.stderr)
    if args.config and is_axes_machine(rec_machine):
        raise InputError(args.config, None, f"{folder} is a recording of independent axes (\"machine\": \"axes\"): "
                                            "it is compared with no machine config; leave --config out")
    machine = load_machine(args.config) if args.config else rec_machine
    prog = forced or (show and n >= 100_000)
    report, extras = diagnose(columns, machine, name=_display_name(folder), progress=prog, cap=args.cap,
                              span=span)
    notes = plant_notes(report, meta)
    to_stdout = args.json == "-"          # --json alone: the JSON report is what stdout carries
    out = sys.stderr if to_stdout else sys.stdout
    print(format_text(report, extras), file=out)
    if notes:
        print("\n  Simulated recording: " + "; ".join(notes) + ". The findings are the simulation's flexible "
              "chain modes (config/service.toml [hal.sim]), which the nominal twin does not model.", file=out)
    if to_stdout:
        print(json.dumps(report, indent=2, ensure_ascii=False))
    elif args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(report, indent=2, ensure_ascii=False) + "\n", encoding="utf-8")
    if getattr(args, "write_compensation", None):
        _write_compensation(args, report, extras, machine, folder)
    if args.plots:
        for pth in write_plots(report, extras, args.plots):
            print(f"plot: {pth}", file=out)
    return 0


def _write_compensation(args, report, extras, machine, folder):
    """--write-compensation FILE (pmctl.tools.twin.fix)."""
    if is_axes_machine(machine):
        print(f"\n  A recording of independent axes has no machine config to compensate: "
              f"{args.write_compensation} not written.", file=sys.stderr)
        return
    comp, notes = compensation_from_findings(machine, extras["accepted"], getattr(machine, "compensation", None))
    if comp is None:
        print(f"\n  No backlash, pitch or periodic error to write: {args.write_compensation} not written."
              + "".join(f"\n    {n}" for n in notes), file=sys.stderr)
        return
    write_compensation(args.write_compensation, comp, recording=_display_name(folder),
                       machine_source=getattr(machine, "source", "?"), notes=notes)
    print(f"\n  Compensation table written to {args.write_compensation}:" + "".join(f"\n    {n}" for n in notes),
          file=sys.stderr if args.json == "-" else sys.stdout)
