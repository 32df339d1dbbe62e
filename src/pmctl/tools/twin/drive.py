"""Effects of real drives on a machine of independent axes (``"machine": "axes"``), as fit-able models.

The same contract as :mod:`pmctl.tools.twin.effects` (a :class:`Candidate` fits on a training mask
of the stacked, whitened residual and predicts every element), for what a bench log of one axis
shows:

- **the drive's force model** on ``effort_<A>`` (the nominal twin predicts no force: an ideal
  drive moves a massless axis without friction): ``inertia`` (moving mass or inertia, F = m·a),
  ``friction`` (Coulomb and viscous, the viscous part by direction when the data says so, a
  Stribeck rise at low speed when it says so), ``force_offset`` (a constant load: gravity on a
  vertical axis, a counterweight, a current sensor's zero). Speed and acceleration are those of
  the motor side (``enc_<A>``, else ``cmd_<A>``) through a zero-phase low-pass and central
  differences (what inverse-dynamics identification of robots does): the force follows the motion
  that happened, and an encoder's counts differentiated twice would be noise;
- **servo tracking** on ``enc_<A>`` against ``cmd_<A>``: the following error per velocity (the lag,
  and the bandwidth of a first-order loop with it) and per acceleration;
- **compliance** of the load side against the motor side (``load_<A>`` − ``enc_<A>`` = −effort/k);
- **cogging**: a force periodic in the motor position (magnet pitch, a screw's once-per-turn);
- resonance and forced vibration in ``acc_<A>`` and ``effort_<A>`` use the catalogue's classes
  (pmctl.tools.twin.effects, with the excitation of the channel's own axis).

Parameters are physical and carry their unit in the name: ``mass_kg``, ``coulomb_N``,
``viscous_N_s_per_m``, ``offset_N`` (linear axis, effort in N); ``inertia_kg_m2``, ``coulomb_Nm``,
``viscous_Nm_s_per_rad`` (rotary axis, effort in N m); with an effort in A (a motor current
without its constant) the same names in A (``coulomb_A``, ``mass_A_s2_per_m``, ...).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal

from pmctl.core.plant_effects import moving_sign
from pmctl.tools.twin.effects import (AxisSignal, Candidate, Fit, PeriodicError, _lstsq, axis_names,
                                      axis_velocity, per_run, position_lines)

DRIVE_FILTER_HZ = 100.0      # the motion's low-pass: at most this, and at most a tenth of the log's rate
DEAD_SHARE = 1e-3            # standing still: |v| below this share of the 99th percentile of |v|


def drive_motion(ctx, a, source="motor"):
    """(v, acc) of axis a's motor side at every row (units/s, units/s²): enc_<A> (else cmd_<A>)
    through a zero-phase 4th-order Butterworth low-pass at min(DRIVE_FILTER_HZ, fs/10), then
    central differences; per run of a recording kept as runs. ``source="cmd"``: of the command."""
    key = ("drive_motion", a, source)
    if key not in ctx.extra:
        dt = float(np.median(np.diff(ctx.t))) if len(ctx.t) > 1 else 1.0
        b, aa = signal.butter(4, min(filter_hz(ctx.t) * 2 * dt, 0.99))

        def vel(tt, x):
            xf = signal.filtfilt(b, aa, x) if len(x) > 30 else x
            return np.gradient(xf, tt) if len(x) > 1 else np.zeros_like(x)

        def acc(tt, v):
            return np.gradient(v, tt) if len(v) > 1 else np.zeros_like(v)
        v = per_run(ctx, vel, ctx.t, (ctx.q_cmd if source == "cmd" else ctx.q_motor)[:, a])
        ctx.extra[key] = (v, per_run(ctx, acc, ctx.t, v))
    return ctx.extra[key]


SETTLED_S = 0.1              # the command at rest this long: the motor stands still, whatever its counts say


def filter_hz(t) -> float:
    """The motion's low-pass cut-off for a log with these time stamps."""
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    return min(DRIVE_FILTER_HZ, 0.1 / dt)


EDGE_PERIODS = 3.0      # of the low-pass: rows this many periods from a run's ends are edge transients


def edge_rows(t, bounds) -> np.ndarray:
    """Rows within EDGE_PERIODS periods of the motion filter from either end of a run."""
    t = np.asarray(t, float)
    edge = np.zeros(len(t), bool)
    w = EDGE_PERIODS / filter_hz(t)
    for s, e in zip(bounds[:-1], bounds[1:]):
        if e > s:
            tt = t[s:e]
            edge[s:e] = (tt < tt[0] + w) | (tt > tt[-1] - w)
    return edge


def moving(ctx, a):
    """sign of axis a's motor speed, 0 at standstill: |v| at most 3 x the rms of the filtered speed
    where the command has rested for SETTLED_S (an encoder's counts, differentiated, are not
    motion), and at least DEAD_SHARE of the speed's 99th percentile."""
    key = ("drive_sign", a)
    if key not in ctx.extra:
        v = drive_motion(ctx, a)[0]
        dead = DEAD_SHARE * float(np.quantile(np.abs(v), 0.99)) if len(v) else 0.0
        rest = resting(ctx, a)
        if rest.sum() >= 20:
            dead = max(dead, 3.0 * float(np.sqrt(np.mean(v[rest] ** 2))))
        ctx.extra[key] = moving_sign(v, dead)
    return ctx.extra[key]


def resting(ctx, a):
    """Rows where axis a's command has not moved for SETTLED_S."""
    x = ctx.q_cmd[:, a]
    still = np.r_[False, np.diff(x) == 0]
    # time since the command last moved
    idx = np.where(~still, np.arange(len(x)), 0)
    np.maximum.accumulate(idx, out=idx)
    return still & (ctx.t - ctx.t[idx] >= SETTLED_S)


def effort_mask(ctx, axis):
    return ctx.obs.mask_of(f"effort_{axis}")


def _names(ctx, axis):
    """Units of the parameters of an axis' force model: (force unit, position unit, rotary?)."""
    m = ctx.machine
    rot = bool(m.rotary.get(axis))
    u = m.effort_unit(axis)
    fu = {"N": "N", "N m": "Nm", "A": "A"}[u]
    return fu, rot


class DriveTerm(Candidate):
    """A linear term of the force model on ``effort_<A>``: columns = features of the motion at the
    effort samples, whitened."""

    target_key = "axis"

    def __init__(self, axis, index):
        super().__init__(axis)
        self.a = index

    def applicable(self, ctx):
        return bool(effort_mask(ctx, self.target).any()) and np.ptp(ctx.q_cmd[:, self.a]) > 0

    def features(self, ctx):
        raise NotImplementedError

    def design(self, ctx):
        return self._on_effort(ctx, self.features(ctx))

    def _on_effort(self, ctx, F):
        o = ctx.obs
        m = effort_mask(ctx, self.target)
        return np.where(m[:, None], F[o.row] * o.w[:, None], 0.0)

    # the force model's terms, each fitted with the others alongside (and left out of its prediction):
    # acceleration, direction, speed and a constant are correlated over a bang-bang run, and a term
    # fitted alone takes the others in. Alone, friction fitted on a force still holding m·a swung
    # between training folds and was refused as not identifiable, and that refusal, stronger than
    # the inertia, blocked every name on the channel (a synth bench run, 37.6 kg, 39.7 N, 91.6 N s/m)
    NUISANCE = ()

    def nuisance(self, ctx):
        key = ("drive_nuisance", self.a, type(self).__name__)
        if key not in ctx.extra:
            v, acc = drive_motion(ctx, self.a)
            feats = {"acc": acc, "sign": moving(ctx, self.a), "vel": v, "one": np.ones(len(ctx.t))}
            cols = [feats[k] for k in self.NUISANCE]
            ctx.extra[key] = self._on_effort(ctx, np.stack(cols, 1)) if cols else np.zeros((len(ctx.obs.y), 0))
        return ctx.extra[key]

    def fit(self, ctx, y, train):
        X, nz = self.cached_design(ctx)
        Z = self.nuisance(ctx)
        sel = train & nz
        c = _lstsq(np.concatenate([X, Z], 1)[sel], y[sel])[:X.shape[1]]
        return Fit(self.params_of(c, ctx), X @ c, X.shape[1], internal={"coef": c})


# per unit of motion in mm (linear) or deg (rotary): the factor to SI per m or per rad
def _si(rot):
    return 180.0 / math.pi if rot else 1000.0


class Inertia(DriveTerm):
    """F = m·a: the moving mass (linear axis) or inertia (rotary), as the drive feels it."""

    effect = "inertia"
    NUISANCE = ("sign", "vel", "one")

    def features(self, ctx):
        return drive_motion(ctx, self.a)[1][:, None]

    def params_of(self, c, ctx):
        fu, rot = _names(ctx, self.target)
        k = float(c[0]) * _si(rot)
        if fu == "A":
            return {("inertia_A_s2_per_rad" if rot else "mass_A_s2_per_m"): k}
        return {("inertia_kg_m2" if rot else "mass_kg"): k}

    def check(self, ctx, fit, y):
        v = next(iter(fit.params.values()))
        return [] if v > 0 else [f"a negative mass or inertia ({v:.3g}): the force does not follow the acceleration"]


class ForceOffset(DriveTerm):
    """A constant force: gravity on a vertical axis, a counterweight, a cable chain, a sensor's zero."""

    effect = "force_offset"
    NUISANCE = ("acc", "sign", "vel")

    def features(self, ctx):
        return np.ones((len(ctx.t), 1))

    def params_of(self, c, ctx):
        fu, _ = _names(ctx, self.target)
        return {f"offset_{fu}": float(c[0])}


class DriveFriction(DriveTerm):
    """sign(v)·(F_c + F_s·exp(−(v/v_s)²)) + F_v·v, the viscous coefficient by direction of motion
    when the data says so (it gains more than ln N, one parameter's worth, over one coefficient),
    the Stribeck term when it gains more than 2 ln N. Coulomb and Stribeck are never negative
    (friction opposes the motion); a negative viscous coefficient is refused."""

    effect = "friction"
    nparams = 2

    def reset(self):
        self._full = None         # the form (by direction or not, Stribeck speed) the full fit chose

    def _base(self, ctx):
        v = drive_motion(ctx, self.a)[0]
        d = moving(ctx, self.a)
        return v, d

    def _cols(self, ctx, kind, vs=None):
        v, d = self._base(ctx)
        o = ctx.obs
        m = effort_mask(ctx, self.target)
        if kind == "asym":
            feats = [d, np.where(v > 0, v, 0.0), np.where(v < 0, v, 0.0)]
        else:
            feats = [d, v]
        if vs is not None:
            feats.append(d * np.exp(-(v / vs) ** 2))
        F = np.stack(feats, 1)
        return np.where(m[:, None], F[o.row] * o.w[:, None], 0.0)

    def fit(self, ctx, y, train):
        N = max(int(train.sum()), 2)
        best = None
        v = np.abs(self._base(ctx)[0])
        vmax = float(np.quantile(v, 0.99)) if len(v) else 0.0
        options = [("sym", None), ("asym", None)]
        if vmax > 0:          # a Stribeck speed well inside the motion (else it is the Coulomb term again)
            options += [(k, vmax * f) for k in ("sym", "asym") for f in (0.01, 0.03, 0.1)]
        full = getattr(self, "_full", None)
        if full is not None and not train.all():
            options = [full]          # a training fold fits the full fit's form, so their parameters compare
        # a constant and the acceleration ride along in the fit (and are left out of the prediction,
        # see DriveTerm.NUISANCE): a constant load is |v|'s look-alike wherever the axis moves at a
        # steady speed, so without it a viscous coefficient by direction would take the offset in
        # (the EMPS bench: 165/244 N s/m and an offset of -0.3 N, against 204 and -3.2 N with the
        # offset kept apart)
        const = np.concatenate([ForceOffset(self.target, self.a).design(ctx), Inertia(self.target, self.a).design(ctx)], 1)
        for kind, vs in options:
            X = self._cols(ctx, kind, vs)
            Xc = np.concatenate([X, const], 1)
            c = _nonneg_first(Xc[train], y[train], [0] + ([X.shape[1] - 1] if vs is not None else []))
            r = y[train] - Xc[train] @ c
            sse = float(r @ r)
            k = X.shape[1]
            crit = sse + k * math.log(N)          # BIC: a term stays when it gains more than ln N
            if best is None or crit < best[0]:
                best = (crit, kind, vs, c[:X.shape[1]], X)
        _, kind, vs, c, X = best
        if train.all():
            self._full = (kind, vs)
        fu, rot = _names(ctx, self.target)
        si = _si(rot)
        vu = "rad" if rot else "m"
        p = {f"coulomb_{fu}": float(c[0])}
        if kind == "asym":
            p[f"viscous_{fu}_s_per_{vu}"] = 0.5 * float(c[1] + c[2]) * si
            p[f"viscous_pos_{fu}_s_per_{vu}"] = float(c[1]) * si
            p[f"viscous_neg_{fu}_s_per_{vu}"] = float(c[2]) * si
        else:
            p[f"viscous_{fu}_s_per_{vu}"] = float(c[1]) * si
        if vs is not None:
            p[f"stribeck_{fu}"] = float(c[-1])
            p[f"stribeck_speed_{'deg' if rot else 'mm'}_s"] = float(vs)
        return Fit(p, X @ c, X.shape[1], ok=bool(c[0] > 0), internal={"kind": kind})

    def check(self, ctx, fit, y):
        bad = [f"{k} = {v:.3g}" for k, v in fit.params.items() if k.startswith("viscous") and v < 0]
        out = []
        if not next(iter(fit.params.values())) > 0:
            out.append("no Coulomb friction: the force does not flip with the direction of motion")
        if bad:
            out.append(f"negative viscous friction ({', '.join(bad)}): the force falls with speed")
        return out


def _nonneg_first(X, y, nonneg):
    """Least squares with the columns ``nonneg`` kept ≥ 0 (an active set over those few columns)."""
    c = _lstsq(X, y)
    if all(c[j] >= 0 for j in nonneg):
        return c
    best = None
    from itertools import combinations
    for r in range(1, len(nonneg) + 1):
        for drop in combinations(nonneg, r):
            keep = [j for j in range(X.shape[1]) if j not in drop]
            cc = np.zeros(X.shape[1])
            cc[keep] = _lstsq(X[:, keep], y)
            if any(cc[j] < 0 for j in nonneg):
                continue
            rr = y - X @ cc
            if best is None or float(rr @ rr) < best[0]:
                best = (float(rr @ rr), cc)
    return best[1] if best else np.zeros(X.shape[1])


class ServoTracking(AxisSignal):
    """The drive's following error against the command: enc − cmd = −(τ·v + κ·a), v and a of the
    command. τ (``lag_s``) is the velocity error constant, 1/K_v of the position loop, with the
    bandwidth 1/(2πτ) of a first-order loop (``bandwidth_hz``); κ (``accel_lag_s2``) the error per
    acceleration (positive: the loop trails more while accelerating; a first-order lag gives −τ²,
    acceleration feed-forward near 0)."""

    effect = "servo_tracking"
    site = "motor"
    nparams = 2

    def applicable(self, ctx):
        return bool(ctx.has_enc[self.a]) and super().applicable(ctx)

    def design(self, ctx):
        g = self.gain(ctx)
        r = ctx.obs.row
        v, acc = drive_motion(ctx, self.a, "cmd")      # (filtered: a logged reference's rounding, differentiated
        return np.stack([g * -v[r], g * -acc[r]], 1)   # twice, is noise the error model would carry)

    def params_of(self, c, ctx):
        tau = float(c[0])
        return {"lag_s": tau, "accel_lag_s2": float(c[1]),
                "bandwidth_hz": 1.0 / (2 * math.pi * tau) if tau > 0 else float("inf")}

    def check(self, ctx, fit, y):
        tau = fit.params.get("lag_s", 0.0)
        if not 1e-5 <= tau <= 0.5:
            return [f"a lag of {tau * 1000:.3g} ms is outside a drive's 0.01-500 ms"]
        return []


class LoadCompliance(AxisSignal):
    """The load side gives way to the drive's force: load − enc = −F/k, F the recorded effort."""

    effect = "compliance"

    def applicable(self, ctx):
        A = self.target
        return (f"effort_{A}" in ctx.extra.get("effort", {}) and f"load_{A}" in ctx.obs.channels
                and ctx.has_enc[self.a] and super().applicable(ctx))

    def design(self, ctx):
        F = ctx.extra["effort"][f"effort_{self.target}"]
        return (self.gain(ctx) * -F[ctx.obs.row])[:, None]

    def params_of(self, c, ctx):
        fu, rot = _names(ctx, self.target)
        k = 1.0 / c[0] if c[0] > 0 else float("inf")
        return {f"stiffness_{fu}_per_{'deg' if rot else 'mm'}": float(k)}

    def fit(self, ctx, y, train):
        f = super().fit(ctx, y, train)
        f.ok = bool(f.internal["coef"][0] > 0)
        return f


class Cogging(PeriodicError):
    """A force periodic in the motor position: a motor's cogging (magnet pitch), a screw's or a
    coupling's once-per-turn. F = A·sin(2πs/P + φ) on ``effort_<A>``, s the motor position."""

    effect = "cogging"

    def __init__(self, axis, index):
        super().__init__(axis, index)

    def gain(self, ctx):
        o = ctx.obs
        return np.where(effort_mask(ctx, self.target), o.w, 0.0)

    def applicable(self, ctx):
        return bool(effort_mask(ctx, self.target).any()) and np.ptp(ctx.q_cmd[:, self.a]) > 0

    def _period_ok(self, ctx, p):
        return p >= 0.2

    def _start_periods(self, ctx, y):
        o = ctx.obs
        m = effort_mask(ctx, self.target)
        rows = o.row[m]
        return position_lines(ctx.q_cmd[rows, self.a], y[m] / o.w[m], axis_velocity(ctx, self.a)[rows], 0.05, 2.5,
                              strongest_if_none=False)

    def fit(self, ctx, y, train):
        f = super().fit(ctx, y, train)
        if "amplitude_mm" in f.params:
            fu, _ = _names(ctx, self.target)
            f.params[f"amplitude_{fu}"] = f.params.pop("amplitude_mm")
        return f

    def check(self, ctx, fit, y):
        p = fit.params.get("period_mm")
        if p is None:
            return ["no period"]
        span = float(np.ptp(ctx.q_cmd[:, self.a]))
        if span < 3 * p:
            return [f"the axis moved {span:.2f}, less than three periods of {p:.3f}"]
        return []


def catalogue(ctx) -> list:
    """Every applicable candidate for a recording of independent axes."""
    from pmctl.tools.twin import effects as fx
    cands = []
    o = ctx.obs
    for i, A in enumerate(axis_names(ctx)):
        has_effort = f"effort_{A}" in o.channels
        cands += [Inertia(A, i), DriveFriction(A, i), ForceOffset(A, i), Cogging(A, i), ServoTracking(A, i),
                  LoadCompliance(A, i), fx.Backlash(A, i), fx.PeriodicError(A, i), fx.PitchError(A, i),
                  fx.LostSteps(A, i), fx.Resonance(A, "axis"), fx.ForcedVibration(A, "axis")]
        if not has_effort:        # the following error flipping at reversals: friction, seen by the loop
            cands.append(fx.Friction(A, i))
        for tc in ctx.temps:
            cands.append(fx.ThermalGrowth(A, tc, i))
        for ch in (f"acc_{A}", f"effort_{A}"):
            if ch in o.channels:
                cands += [fx.Resonance(ch, "channel"), fx.ForcedVibration(ch, "channel")]
    for c in o.channels:
        if not c.startswith("effort_"):       # a constant or a scale of a force is the force model's
            cands += [fx.SensorGain(c), fx.SensorOffset(c)]
        cands.append(fx.SensorDrift(c))
    return [c for c in cands if c.applicable(ctx)]
