"""Library of physical effects the nominal twin leaves out (docs/diagnosis-report.md §2), as fit-able models.

Every effect is a physical model with physical parameters, mapped through the machine's
kinematics to the channels it touches:

- a *load-side* error δq_a(t) on actuator a (backlash, pitch error, thermal growth, compliance,
  lost steps, resonance of an axis) moves the tool by ``J_tool[:, a] · δq_a`` (kinematics.jacobian_tool);
  the motor-side encoders do not see it;
- a *motor-side* error (servo lag) shows in ``enc_a - cmd_a``; the tool only sees it where the
  twin had to predict it from ``cmd`` (no encoder for that axis);
- a geometry error δp (joint positions, actuator zero offsets, tool length / tilt) moves the tool by
  the parameter sensitivity of the closed loop: dX = -A⁻¹ ∂f/∂p δp, A = kinematics.constraint_jacobian;
- a sensor gain / offset scales / shifts one channel against its nominal prediction.

Fitting works on a :class:`Context`: the residual (measured - nominal) of every observed channel,
stacked into one vector and whitened by each channel's noise level, on a capped set of analysis rows.
Each :class:`Candidate` fits on a boolean training mask and predicts every element, so the caller
can score it on held-out samples. Pure math; no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, signal

from pmctl.core import kinematics as kin
from pmctl.core.plant_effects import direction, first_order_lag, play_error
from pmctl.core.plant_effects import mode_response as resonance_response

AXES = ("L1", "L2", "L3", "X", "Y")
MAX_ALPHA = 1e-4   # /K, no solid screw expands more
T_REF = 20.0                 # °C: the temperature a machine's geometry holds at (ISO 1's reference)
T_REF_RANGE = (-10.0, 50.0)  # °C: a workshop's
PRESCREEN = 10.0   # whitened SSE a start value of a nonlinear parameter must already remove
TOOL_ROWS = {"tip_x": 0, "tip_y": 1, "tip_z": 2, "tool_i": 3, "tool_j": 4, "tool_k": 5}
ENC = tuple(f"enc_{a}" for a in AXES)
CMD = tuple(f"cmd_{a}" for a in AXES)
STRAIN = ("strain_1", "strain_2", "strain_3")


# ---------------------------------------------------------------- the fitting context

@dataclass
class Obs:
    """The stacked, whitened residual of all observed channels at the analysis samples."""

    channels: list[str]          # channel names; ch indexes into this
    sigma: dict[str, float]      # noise level per channel (channel units)
    y: np.ndarray                # (N,) whitened residual
    ch: np.ndarray               # (N,) channel index
    row: np.ndarray              # (N,) index into the full-rate arrays
    pos: np.ndarray              # (N,) index into Context.rows
    w: np.ndarray                # (N,) 1/sigma of the element's channel
    pred: np.ndarray             # (N,) nominal prediction (channel units)

    def mask_of(self, name):
        return self.ch == self.channels.index(name) if name in self.channels else np.zeros(self.y.shape, bool)


@dataclass
class Context:
    machine: object
    t: np.ndarray                # (n,) s
    q_cmd: np.ndarray            # (n, 5) commanded actuator positions, mm
    q_motor: np.ndarray          # (n, 5) motor side (enc where recorded, else cmd)
    has_enc: np.ndarray          # (5,) bool
    temps: dict                  # name -> (n,) temperature, interpolated over gaps
    rows: np.ndarray             # (m,) analysis rows (sorted)
    J: np.ndarray                # (m, 6, 5) d(tip_W, axis)/dq at the analysis rows
    geo: dict                    # group name -> (m, 6, k) sensitivity, and names
    forces: np.ndarray           # (m, 3) chain axial force, compression positive, N
    obs: Obs
    uniform_dt: float | None     # sample interval when t is uniform
    extra: dict = field(default_factory=dict)

    @property
    def duration(self):
        return float(self.t[-1] - self.t[0]) if len(self.t) > 1 else 0.0


def geometry_sensitivity(P, R, geom):
    """d(tip_W, tool axis)/d(geometry parameters) at fixed actuator positions, per group.

    Groups: ``chain{i}:length_offset`` (1, mm), ``chain{i}:base_joint`` (2, mm: radial, z, i.e. in
    the chain plane, where the revolute axis keeps the chain),
    ``chain{i}:platform_joint`` (3, mm, platform frame), ``tool:length`` (1, mm),
    ``tool:tilt`` (2, deg). Returns {group: (..., 6, k)}."""
    A = kin.constraint_jacobian(P, R, geom)
    Ainv = np.linalg.inv(A)                                   # (..., 6, 6)
    rc = np.einsum("...ij,kj->...ki", R, geom.platform_joints)
    d = P[..., None, :] + rc - geom.base_joints
    u = d / np.linalg.norm(d, axis=-1, keepdims=True)          # (..., 3, 3)
    n = np.broadcast_to(geom.revolute_axes, u.shape)
    rt = np.einsum("...ij,j->...i", R, geom.tool_tip_p)
    v = np.einsum("...ij,j->...i", R, geom.tool_axis_p)

    def tool_of_dx(dX):                                       # dX (..., 6, k) -> (..., 6, k)
        dP, w = dX[..., :3, :], dX[..., 3:, :]
        dtip = dP + np.cross(w, rt[..., :, None], axisa=-2, axisb=-2, axisc=-2)
        dax = np.cross(w, v[..., :, None], axisa=-2, axisb=-2, axisc=-2)
        return np.concatenate([dtip, dax], -2)

    out = {}
    shape = P.shape[:-1]
    for i in range(3):
        df = np.zeros(shape + (6, 1))
        df[..., i, 0] = -1.0
        out[f"chain{i + 1}:length_offset"] = tool_of_dx(-Ainv @ df)
        # base joint moved within its chain plane: radially (along its horizontal direction) and in z
        ai = geom.base_joints[i]
        radial = np.array([ai[0], ai[1], 0.0]) / max(math.hypot(ai[0], ai[1]), 1e-12)
        basis = np.stack([radial, [0.0, 0.0, 1.0]], 1)                       # (3, 2)
        df = np.zeros(shape + (6, 2))
        df[..., i, :] = -u[..., i, :] @ basis
        df[..., 3 + i, :] = -n[..., i, :] @ basis
        out[f"chain{i + 1}:base_joint"] = tool_of_dx(-Ainv @ df)
        df = np.zeros(shape + (6, 3))
        df[..., i, :] = np.einsum("...j,...jk->...k", u[..., i, :], R)
        df[..., 3 + i, :] = np.einsum("...j,...jk->...k", n[..., i, :], R)
        out[f"chain{i + 1}:platform_joint"] = tool_of_dx(-Ainv @ df)
    a, b = np.radians(geom.tool_tilt_deg)
    ap = geom.tool_axis_p
    da = np.array([0.0, -math.cos(a) * math.cos(b), -math.sin(a) * math.cos(b)])
    db = np.array([math.cos(b), math.sin(a) * math.sin(b), -math.cos(a) * math.sin(b)])
    s = np.zeros(shape + (6, 1))
    s[..., :3, 0] = -np.einsum("...ij,j->...i", R, ap)
    out["tool:length"] = s
    s = np.zeros(shape + (6, 2))
    for k, dd in enumerate((da, db)):
        s[..., :3, k] = -geom.tool_length * np.einsum("...ij,j->...i", R, dd) * math.pi / 180
        s[..., 3:, k] = np.einsum("...ij,j->...i", R, dd) * math.pi / 180
    out["tool:tilt"] = s
    return out


# ---------------------------------------------------------------- signal helpers

def fill_gaps(t, x):
    """Linear interpolation over NaN gaps (edges held). All-NaN stays NaN."""
    ok = np.isfinite(x)
    if ok.all() or not ok.any():
        return x.astype(float)
    return np.interp(t, t[ok], x[ok])


def on_grid(tt, x, tu):
    """``x`` sampled at times ``tt`` (increasing; a fixed-rate log that lost rows) on the uniform grid
    ``tu``: the samples themselves where the grid meets them, a cubic through the two samples on
    either side where a row is missing. A straight line there puts a kink into the motion: a
    velocity jump and its opposite one step later, about a·dt/2 each, which rings a mode as much as
    the motion's own acceleration does (at 250 Hz, a 57 Hz mode after each lost row); the cubic
    follows a smooth command to its third derivative."""
    tt, x, tu = np.asarray(tt, float), np.asarray(x, float), np.asarray(tu, float)
    out = np.interp(tu, tt, x)
    n = len(tt)
    if n < 4 or len(tu) < 2:
        return out
    tol = 1e-3 * float(tu[1] - tu[0])
    j = np.clip(np.searchsorted(tt, tu), 1, n - 1)          # tt[j-1] < tu <= tt[j]
    hit = (np.abs(tt[j] - tu) <= tol) | (np.abs(tt[j - 1] - tu) <= tol)
    miss = np.flatnonzero(~hit & (j >= 2) & (j <= n - 2))
    if len(miss):
        jj = j[miss]
        idx = np.stack([jj - 2, jj - 1, jj, jj + 1])        # 4 samples, two on either side
        T, X, u = tt[idx], x[idx], tu[miss]
        val = np.zeros(len(miss))
        for a in range(4):                                   # Lagrange on the actual times
            w = np.ones(len(miss))
            for b in range(4):
                if b != a:
                    w *= (u - T[b]) / (T[a] - T[b])
            val += w * X[a]
        out[miss] = val
    return out


def axis_velocity(ctx, a) -> np.ndarray:
    """d cmd_a / dt at every row (mm/s), computed once per context."""
    key = ("velocity", a)
    if key not in ctx.extra:
        ctx.extra[key] = np.gradient(ctx.q_cmd[:, a], ctx.t)
    return ctx.extra[key]


def refine_max(f, q0, h, lo=-np.inf, hi=np.inf, xatol=1e-6):
    """(q, f(q)) at the maximum of f near a grid's best point q0: a bounded scalar search between
    q0's grid neighbours (q0 ± h, within [lo, hi]), kept only when it beats f(q0)."""
    sol = optimize.minimize_scalar(lambda q: -f(q), bounds=(max(q0 - h, lo), min(q0 + h, hi)),
                                   method="bounded", options={"xatol": xatol})
    return (float(sol.x), -float(sol.fun)) if -sol.fun >= f(q0) else (q0, f(q0))


def axis_direction(ctx, a) -> np.ndarray:
    """:func:`direction` of cmd_a at every row, computed once per context. A recording kept as
    runs: per run, no jump across a gap counts as motion, and until the axis moves in a run it
    keeps the direction it had before (ctx.extra["direction_before"]; 0 when unknown)."""
    key = ("direction", a)
    if key not in ctx.extra:
        d = per_run(ctx, direction, ctx.q_cmd[:, a])
        b, before = ctx.extra.get("bounds"), ctx.extra.get("direction_before")
        if b is not None and before is not None:      # (0 only before the axis' first move in a run)
            d = np.where(d == 0, before[np.repeat(np.arange(len(b) - 1), np.diff(b)), a], d)
        ctx.extra[key] = d
    return ctx.extra[key]


def per_run(ctx, fn, *series):
    """``fn(*series)`` on every contiguous run of rows (ctx.extra["bounds"], a recording kept as
    runs: a filter restarts at each run instead of bridging the gap), concatenated; on one run
    simply ``fn(*series)``."""
    b = ctx.extra.get("bounds")
    if b is None:
        return fn(*series)
    return np.concatenate([fn(*(x[s:e] for x in series)) for s, e in zip(b[:-1], b[1:]) if e > s])


def welch_runs(tt, sig, cuts=None, nperseg=4096):
    """Welch spectrum (frequencies, power) of an irregularly sampled series after interpolation to
    its median step; with ``cuts`` (times where a new run of a recording kept as runs starts) the
    runs are interpolated and transformed apart and their spectra averaged, weighted by length, so
    no gap is bridged. None when there is nothing to transform."""
    dt = float(np.median(np.diff(tt)))
    if not dt > 0:
        return None
    pieces = np.split(np.arange(len(tt)), np.searchsorted(tt, cuts)) if cuts is not None and len(cuts) else \
        [np.arange(len(tt))]
    grids = []
    for ix in pieces:
        if len(ix) < 2:
            continue
        tu = np.arange(tt[ix[0]], tt[ix[-1]], dt)
        if len(tu):
            su = np.interp(tu, tt[ix], sig[ix])
            grids.append(su - su.mean())
    if not grids:
        return None
    nps = min(nperseg, max(len(g) for g in grids)) if len(grids) == 1 else \
        min(nperseg, int(np.median([len(g) for g in grids])))
    out, wsum = None, 0
    for g in grids:
        if len(g) < nps:
            continue
        fq, p = signal.welch(g, fs=1 / dt, nperseg=nps)
        out = p * len(g) if out is None else out + p * len(g)
        wsum += len(g)
    return (fq, out / wsum) if out is not None else None


# ---------------------------------------------------------------- fit results and candidates

@dataclass
class Fit:
    params: dict                 # report-named physical parameters
    pred: np.ndarray             # (N,) whitened prediction for every obs element
    nparams: int
    ok: bool = True
    note: str = ""
    internal: dict = field(default_factory=dict)


LSTSQ_COND = 1e10      # _lstsq solves the normal equations below this condition number ...
LSTSQ_RCOND = 1e-10    # ... else least squares keeps the directions above this share of the largest


def _scaled(X):
    sc = np.sqrt(np.einsum("ij,ij->j", X, X))
    sc[sc == 0] = 1.0
    return X / sc, sc


def _lstsq(X, y):
    """Least squares for few columns: scaled normal equations (lstsq fallback when singular)."""
    if X.shape[1] == 0 or X.shape[0] == 0:
        return np.zeros(X.shape[1])
    Xs, sc = _scaled(X)
    G = Xs.T @ Xs
    b = Xs.T @ y
    try:
        if np.linalg.cond(G) < LSTSQ_COND:
            return np.linalg.solve(G, b) / sc
    except np.linalg.LinAlgError:
        pass
    c, *_ = np.linalg.lstsq(Xs, y, rcond=LSTSQ_RCOND)
    return c / sc


def lstsq_rank(X) -> int:
    """The number of directions :func:`_lstsq` fits with X: what it removes on average from white
    noise of unit variance (all columns when it solves the normal equations; else the singular values
    its least squares keeps: nearly dependent columns, such as hats of axes that move together, add
    directions a numerical rank counts but the fit drops)."""
    if X.shape[1] == 0 or X.shape[0] == 0:
        return 0
    Xs, _ = _scaled(X)
    s = np.linalg.svd(Xs, compute_uv=False)
    if s[0] > 0 and (s[-1] / s[0]) ** 2 > 1.0 / LSTSQ_COND:
        return X.shape[1]
    return int(np.sum(s > LSTSQ_RCOND * s[0]))


class Candidate:
    """One effect on one target. Subclasses implement ``design`` (linear ones) or ``fit``."""

    effect = ""
    target_key = "axis"
    nparams = 1

    def __init__(self, target):
        self.target = target

    @property
    def label(self):
        return f"{self.effect}[{self.target}]"

    def key(self):
        return (self.effect, self.target_key, self.target)

    def applicable(self, ctx: Context) -> bool:
        return True

    def check(self, ctx: Context, fit: "Fit", y: np.ndarray) -> list[str]:
        """The effect's own checks on its full fit (physical range, identifiability against its
        nearest look-alike). Returns the reasons it fails; [] when it passes."""
        return []

    # linear models: columns (N, k) of whitened obs; params from coefficients
    def design(self, ctx: Context):
        raise NotImplementedError

    def params_of(self, c, ctx):
        raise NotImplementedError

    def cached_design(self, ctx: Context):
        """(X, rows where X is non-zero); computed once per context."""
        if getattr(self, "_dz", None) is None or self._dz[0] is not ctx:
            X = self.design(ctx)
            self._dz = (ctx, X, np.any(X != 0, 1))
        return self._dz[1], self._dz[2]

    def fit(self, ctx: Context, y: np.ndarray, train: np.ndarray) -> Fit:
        X, nz = self.cached_design(ctx)
        sel = train & nz
        c = _lstsq(X[sel], y[sel])
        return Fit(self.params_of(c, ctx), X @ c, X.shape[1], internal={"coef": c})


def axis_names(ctx: Context) -> tuple:
    """The axes of the context's machine: the prototype's L1..Y, or a generic recording's
    (``"machine": "axes"``: its cmd_<A> columns, pmctl.tools.twin.axes)."""
    return ctx.extra.get("axes", AXES)


def axis_index(ctx: Context, name: str) -> int:
    return list(axis_names(ctx)).index(name)


def excited_axis(ctx: Context, channel: str) -> int:
    """The axis whose motion drives a channel's mode: chain i for the prototype's strain_i; axis A
    for a generic machine's acc_<A> or effort_<A>."""
    if "axes" in ctx.extra:
        return axis_index(ctx, channel.split("_", 1)[1])
    return int(channel[-1]) - 1


def axis_gain(ctx: Context, a: int, site: str = "load") -> np.ndarray:
    """(N,) whitened obs response to a unit error on actuator a.

    load: the tool channels move by J[:, a]; motor: enc_a sees it, and the tool channels too when
    axis a has no encoder (the twin then predicted the tool from cmd). A machine of independent
    axes: the load side is its load_<A> encoder, the motor side its enc_<A> (and load_<A> when the
    axis has no enc_<A>, predicted from cmd_<A>)."""
    key = ("axis_gain", a, site)
    if key in ctx.extra:
        return ctx.extra[key]
    o = ctx.obs
    g = np.zeros(o.y.shape)
    if "axes" in ctx.extra:
        A = ctx.extra["axes"][a]
        names = [f"load_{A}"] if site == "load" else [f"enc_{A}"] + ([] if ctx.has_enc[a] else [f"load_{A}"])
        for name in names:
            if name in o.channels:
                m = o.ch == o.channels.index(name)
                g[m] = o.w[m]
        ctx.extra[key] = g
        return g
    for name, r in TOOL_ROWS.items():
        if name in o.channels and (site == "load" or not ctx.has_enc[a]):
            m = o.ch == o.channels.index(name)
            g[m] = ctx.J[o.pos[m], r, a] * o.w[m]
    if site == "motor":
        e = f"enc_{a}" if isinstance(a, str) else f"enc_{AXES[a]}"
        if e in o.channels:
            m = o.ch == o.channels.index(e)
            g[m] = o.w[m]
    ctx.extra[key] = g
    return g


class AxisSignal(Candidate):
    """Base: an error signal δq_a(t) on actuator a; design = axis_gain * signal at the rows."""

    site = "load"

    def __init__(self, axis, index=None):
        super().__init__(axis)
        self.a = AXES.index(axis) if index is None else index      # (index: a generic machine's axis)
        self._g = None

    def gain(self, ctx):
        if self._g is None or self._g[0] is not ctx:
            self._g = (ctx, axis_gain(ctx, self.a, self.site))
        return self._g[1]

    def applicable(self, ctx):
        return bool(np.any(self.gain(ctx) != 0)) and np.ptp(ctx.q_cmd[:, self.a]) > 0


class Backlash(AxisSignal):
    effect = "backlash"

    def reset(self):
        self._start_full = None      # where the fit on all samples put the load in the play at the start

    def fit(self, ctx, y, train):
        g = self.gain(ctx)
        x = ctx.q_cmd[:, self.a]
        rows = ctx.obs.row
        d = axis_direction(ctx, self.a)
        col = g * (-0.5 * d[rows])
        w0 = float(_lstsq(col[train, None], y[train])[0])
        if w0 <= 0:
            return Fit({"width_mm": 0.0}, np.zeros_like(y), 1, ok=False, note="negative width")

        sel = train & (g != 0)
        gs, ys, rs = g[sel], y[sel], rows[sel]
        # the play operator is rate-independent: its output at the analysis rows only depends on
        # the motor positions there and at the turning points between them, so it runs exactly
        # on that subsequence (a few thousand samples instead of the whole record)
        key = ("play_idx", self.a)
        if key not in ctx.extra:
            dd = axis_direction(ctx, self.a)
            turn = np.flatnonzero(np.diff(dd) != 0)
            b = ctx.extra.get("bounds")
            starts = np.asarray(b[:-1][np.diff(b) > 0] if b is not None else [], int)   # (each run's first row)
            idx = np.unique(np.concatenate([[0], turn, turn + 1, rows, [len(x) - 1], starts]))
            ctx.extra[key] = (idx, np.searchsorted(idx, np.arange(len(x))))
        idx, where = ctx.extra[key]
        xs = x[idx]
        rsi = where[rs]

        # the load's place in the deadband at the start is unknown: middle, or either flank
        sols = {}
        for st0 in (0.0, -1.0, 1.0):
            def res(p, st0=st0):
                return gs * self._play(ctx, xs, idx, p[0], st0)[rsi] - ys

            try:
                sols[st0] = optimize.least_squares(res, [w0], bounds=([0.0], [np.inf]), x_scale=[max(w0, 1e-6)],
                                                   diff_step=[1e-3], max_nfev=30)
            except ValueError:
                continue
        best = min(sols.items(), key=lambda kv: kv[1].cost) if sols else None
        # a training fold without the start of the run cannot tell where the load began (its costs
        # tie): it keeps the full fit's start instead of a guess that its held-out samples refute
        full = getattr(self, "_start_full", None)
        if best and full in sols and best[0] != full and sols[full].cost <= best[1].cost + max(1.0, 1e-3 * best[1].cost):
            best = (full, sols[full])
        w, st0 = (float(best[1].x[0]), best[0]) if best else (w0, 0.0)
        if bool(np.all(train)):
            self._start_full = st0
        pred = g * self._play(ctx, xs, idx, w, st0)[where[rows]]
        return Fit({"width_mm": w}, pred, 1, ok=w > 0, internal={"start": st0})

    def _play(self, ctx, xs, idx, w, st0):
        """The play's error at the rows ``idx`` (positions ``xs``), starting at ``st0`` (-1, 0, 1: the
        flank or the middle). A recording kept as runs with the directions before each run known
        (ctx.extra["direction_before"]): every later run starts on the flank its axis' last motion
        before it left the load on (a jump across the gap is no motion); else one play throughout."""
        b, before = ctx.extra.get("bounds"), ctx.extra.get("direction_before")
        if b is None or before is None:
            return play_error(xs, w, st0)
        cut = np.searchsorted(idx, b[:-1]).tolist() + [len(idx)]
        return np.concatenate([play_error(xs[s:e], w, st0 if k == 0 else -before[k, self.a])
                               for k, (s, e) in enumerate(zip(cut[:-1], cut[1:])) if e > s])


def screw_lead(ctx: Context, a: int) -> float | None:
    """The lead of axis a's screw (mm); a generic machine's only when its recording gives it."""
    if "axes" in ctx.extra:
        return ctx.machine.lead_mm.get(ctx.extra["axes"][a])
    r = ctx.machine.resolution
    return float(r.screw_lead if a < 3 else r.table_screw_lead)


def lead_harmonic(period, lead, tol=0.04):
    """k when period is lead/k (k = 1..4) within ``tol`` relative, else 0 (and 0 without a lead)."""
    if not lead:
        return 0
    for k in (1, 2, 3, 4):
        if abs(period * k / lead - 1) <= tol:
            return k
    return 0


def sample_travel(ctx: Context, a: int) -> float:
    """Median travel of axis a between consecutive analysis samples of the channels that see it,
    while it moves (mm): the shortest period in its position that those samples can resolve is
    a few times this."""
    g = axis_gain(ctx, a)
    rows = np.unique(ctx.obs.row[g != 0])
    if len(rows) < 3:
        return float("inf")
    dx = np.abs(np.diff(ctx.q_cmd[rows, a]))
    mv = dx > 0
    return float(np.median(dx[mv])) if mv.any() else float("inf")


POSITION_BINS = 32      # a periodic error's period in bins of screw position ...
PER_BIN = 20            # ... in each of which this many samples of a channel count in full


def position_weights(ch, x, period) -> np.ndarray:
    """Weights of samples for a fit periodic in screw position x: in each bin of period/32 the
    samples of one channel count together as at most :data:`PER_BIN` samples. A dwell puts
    hundreds of samples at one screw position; they measure one value of the periodic error, and
    what they share (coloured tracker noise, a drift, the pose's own small mismatch) does not
    average out among them. Unweighted, a two-dwell run let those two positions outweigh the whole
    travel (a 6.2 µm pitch error fitted as 4.6 µm under coloured noise)."""
    b = np.floor(np.asarray(x) / (period / POSITION_BINS)).astype(np.int64)
    key = (b - b.min()) * (int(np.max(ch, initial=0)) + 1) + np.asarray(ch, np.int64)
    _, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
    return np.minimum(1.0, PER_BIN / cnt[inv])


def position_lines(x, e, v, moving_share, min_cycles, strongest_if_none=True) -> list[float]:
    """Periods (mm) of the strongest lines of the error ``e`` against the position ``x`` (samples
    moving faster than ``moving_share`` of the top speed ``v``), at least ``min_cycles`` over the
    travel and at least 0.2 mm, strongest first (at most 3); without a peak, the spectrum's
    maximum when ``strongest_if_none``."""
    from pmctl.tools.twin.locate import spectrum_position
    span = float(np.ptp(x)) if len(x) else 0.0
    sp = spectrum_position(x, e, np.abs(v) > moving_share * max(np.abs(v).max(initial=0.0), 1e-12))
    if sp is None:
        return []
    f, amp = sp
    ok = (f > min_cycles / max(span, 1e-9)) & (f < 1 / 0.2)
    if not ok.any():
        return []
    fo, ao = f[ok], amp[ok]
    pk, _ = signal.find_peaks(ao)
    if len(pk) == 0:
        if not strongest_if_none:
            return []
        pk = np.array([int(np.argmax(ao))])
    pk = pk[np.argsort(ao[pk])[::-1]]
    return [1.0 / float(fo[k]) for k in pk][:3]


class PitchError(AxisSignal):
    """Screw lead error periodic in the screw position x: δq = A·sin(2πx/p + φ).

    ``pitch_error`` is a period of the lead or one of its first harmonics (lead/2..lead/4: the
    screw's thread, once per turn); :class:`PeriodicError` takes every other period (a bearing, a
    gear or coupling between motor and screw)."""

    effect = "pitch_error"
    nparams = 3

    def reset(self):
        self._starts = None

    def _period_ok(self, ctx, p):
        return lead_harmonic(p, screw_lead(ctx, self.a)) > 0

    def check(self, ctx, fit, y):
        p = fit.params.get("period_mm")
        if p is None or not self._period_ok(ctx, p):
            return [f"period {p:.3f} mm is not the screw lead or one of its harmonics"] if p else ["no period"]
        span = float(np.ptp(ctx.q_cmd[:, self.a]))
        if span < p:        # the period is known in advance (the lead): one turn of travel shows it
            return [f"the screw moved {span:.2f} mm, less than one period of {p:.3f} mm"]
        step = sample_travel(ctx, self.a)
        if step > 0.25 * p:
            return [f"the screw travels {step:.3f} mm between samples, too far to see a {p:.3f} mm period "
                    "without aliasing"]
        return []

    def _start_periods(self, ctx, y):
        """Periods to start from. A pitch error sits at the lead or one of its first harmonics,
        known in advance: those lines, whatever the spectrum shows (a 2 µm error under 1.5 µm of
        tracker noise hardly stands out of it, and an axis that moves in few samples has no
        spectrum). A periodic error: the strongest lines of the axis-equivalent residual against
        screw position (binned, FFT), refined in :meth:`fit` before the lead-harmonic test (a line
        10 % off the lead falls into the lead's bin on a short travel)."""
        from pmctl.tools.twin.locate import axis_projection, spectrum_position
        _, e, rows = axis_projection(ctx, self.a, y)
        span = float(np.ptp(ctx.q_cmd[rows, self.a])) if len(rows) else 0.0
        if self.effect == "pitch_error":
            lead = screw_lead(ctx, self.a)
            return [lead / k for k in (1, 2, 3, 4) if span >= lead / k and k / lead < 5.0] if lead else []
        if len(e) < 64:
            return []
        return position_lines(ctx.q_cmd[rows, self.a], e, axis_velocity(ctx, self.a)[rows], 1e-3, 1.5)

    @staticmethod
    def _parabola(grid, cost):
        """Minimum of cost over grid, refined by a parabola through the best point's neighbours."""
        k = int(np.clip(np.argmin(cost), 1, len(grid) - 2))
        c0, c1, c2 = cost[k - 1:k + 2]
        den = c0 - 2 * c1 + c2
        h = grid[k + 1] - grid[k]
        return float(np.clip(grid[k] + (0.5 * h * (c0 - c2) / den if den > 0 else 0.0), grid[0], grid[-1]))

    def fit(self, ctx, y, train):
        g = self.gain(ctx)
        if getattr(self, "_starts", None) is None:
            self._starts = self._start_periods(ctx, y)
        if not self._starts:
            return Fit({}, np.zeros_like(y), 3, ok=False)
        sel = train & (g != 0)
        x = ctx.q_cmd[ctx.obs.row, self.a]
        gs, ys, xs, chs = g[sel], y[sel], x[sel], ctx.obs.ch[sel]

        def design(p, gg, xx):
            ph = 2 * np.pi * xx / p
            return np.stack([gg * np.sin(ph), gg * np.cos(ph)], 1)

        def loss(p, sw):
            """Minus the weighted squared residual a sine of period p removes (sw: √weights)."""
            X, yw = design(p, gs, xs) * sw[:, None], ys * sw
            r = X @ _lstsq(X, yw) - yw
            return float(r @ r - yw @ yw)

        found = []            # (loss, period, √weights)
        if self.effect == "pitch_error":
            # the period is a lead harmonic: the best of those lines, then a grid of ±2 % around
            # it refined by a parabola (a screw's lead is made within that)
            sws = {p0: np.sqrt(position_weights(chs, xs, p0)) for p0 in self._starts}
            p0 = min(self._starts, key=lambda q: loss(q, sws[q]))
            sw = sws[p0]
            grid = p0 * np.linspace(0.98, 1.02, 9)
            p = self._parabola(grid, np.array([loss(q, sw) for q in grid]))
            found.append((loss(p, sw), p, sw))
        else:
            # a local scan in spatial frequency around each line (± 1.5 resolution cells of the
            # travel), refined by a parabola; the best one that is no lead harmonic
            span = max(float(np.ptp(xs)), 1e-9)
            for p0 in self._starts:
                fgrid = 1 / p0 + np.linspace(-1.5, 1.5, 13) / span
                fgrid = fgrid[fgrid > 1.0 / span]
                if len(fgrid) < 3:
                    continue
                sw = np.sqrt(position_weights(chs, xs, p0))
                fr = self._parabola(fgrid, np.array([loss(1 / q, sw) for q in fgrid]))
                p = 1 / fr
                if self._period_ok(ctx, p):
                    found.append((loss(p, sw), p, sw))
        found = [fp for fp in found if -fp[0] > PRESCREEN]
        if not found:
            return Fit({}, np.zeros_like(y), 3, ok=False)
        _, p, sw = min(found, key=lambda fp: fp[0])
        c = _lstsq(design(p, gs, xs) * sw[:, None], ys * sw)
        pred = design(p, g, x) @ c
        amp = float(np.hypot(*c))
        return Fit({"period_mm": p, "amplitude_mm": amp}, pred, 3,
                   internal={"phase_rad": float(math.atan2(c[1], c[0]))})


class PeriodicError(PitchError):
    """A load-side error periodic in the screw position at a period that is not the lead's:
    a bearing (balls orbit at ~0.4 of the screw turn), a gear or belt stage between motor and
    screw (once per motor or pulley turn), a coupling. Same model as the pitch error,
    δq = A·sin(2πx/p + φ); identifiable when the screw travels at least two periods and the
    period is not a lead harmonic (else it is a pitch error)."""

    effect = "periodic_error"

    def _period_ok(self, ctx, p):
        return 0.2 <= p and not lead_harmonic(p, screw_lead(ctx, self.a), 0.06)

    def check(self, ctx, fit, y):
        p = fit.params.get("period_mm")
        if p is None or not self._period_ok(ctx, p):
            return [f"period {p:.3f} mm is a lead harmonic (a pitch error) or below 0.2 mm"] if p else ["no period"]
        span = float(np.ptp(ctx.q_cmd[:, self.a]))
        if span < 2 * p:
            return [f"the screw moved {span:.2f} mm, less than two periods of {p:.3f} mm"]
        step = sample_travel(ctx, self.a)
        if step > 0.25 * p:
            return [f"the screw travels {step:.3f} mm between samples, too far to see a {p:.3f} mm period "
                    "without aliasing"]
        return []


def own_temperature(axis: str) -> tuple[str, ...]:
    """Names a recording may give the temperature of axis ``axis``'s own screw (docs/recording.md:
    ``temp_screw1`` for L1, ``temp_screwX`` for X; or ``temp_L1``, ``temp_X``)."""
    return (f"temp_screw{axis.removeprefix('L')}", f"temp_{axis}")


class ThermalGrowth(AxisSignal):
    """Screw growth δ = α·(T − T_ref)·(x − x_fixed) on actuator a: x the screw coordinate, T a
    temperature, x_fixed the screw's fixed-bearing end (growth is zero there), T_ref the temperature
    the geometry was calibrated at.

    Three physical parameters, none known to the twin. The model is linear in α, so x_fixed and
    T_ref are searched (a grid over the screw's travel and beyond × workshop temperatures, refined)
    with α solved exactly at each step, from the moments of four basis columns. T_ref is the
    reference temperature of ISO 1, 20 °C, unless freeing it gains more than one parameter's
    worth (BIC, ln N): a warm-up of a kelvin or two cannot tell α from T_ref (α·(T − T_ref) is
    what it sees), and a free T_ref would trade one against the other. The constraint matters at
    small temperature rises:
    the growth leaves a strong drift of the axis offset with T and a static scale error about
    x_fixed, and only a weak T·x cross term; a free constant (four linear terms) would throw the
    first two away against each other."""

    effect = "thermal_growth"
    nparams = 3

    def __init__(self, axis, channel, index=None):
        super().__init__(axis, index)
        self.channel = channel

    @property
    def label(self):
        return f"thermal_growth[{self.target},{self.channel}]"

    def key(self):
        return (self.effect, "axis", self.target, self.channel)

    def applicable(self, ctx):
        T = ctx.temps.get(self.channel)
        return super().applicable(ctx) and T is not None and np.ptp(T) > 0

    def xf_range(self, ctx):
        """Where the fixed bearing may be: the screw's travel (config limits, else the recorded
        range) and half of it again on either side."""
        lim = getattr(ctx.machine, "limits", None)
        rng = None
        if lim is not None:
            rng = (lim.chain_length, lim.chain_length, lim.chain_length, lim.table_x, lim.table_y)[self.a]
        x = ctx.q_cmd[:, self.a]
        lo, hi = (float(rng[0]), float(rng[1])) if rng is not None else (float(x.min()), float(x.max()))
        lo, hi = min(lo, float(x.min())), max(hi, float(x.max()))
        return lo - 0.5 * (hi - lo), hi + 0.5 * (hi - lo)

    def _basis(self, ctx):
        """(g·T·x, g·T, g·x, g) at every obs element; T centred on its mean (conditioning)."""
        key = ("thermal_basis", self.a, self.channel)
        if key not in ctx.extra:
            r = ctx.obs.row
            T = ctx.temps[self.channel][r]
            Tm = float(np.mean(ctx.temps[self.channel]))
            x = ctx.q_cmd[r, self.a]
            g = self.gain(ctx)
            ctx.extra[key] = (np.stack([g * (T - Tm) * x, g * (T - Tm), g * x, g], 1), Tm)
        return ctx.extra[key]

    @staticmethod
    def _gain(G, b, xf, tr, Tm):
        """SSE drop and α of the column (T − T_ref)(x − x_f) for arrays of (x_f, T_ref), from the
        moments of the basis (T − Tm)·x, T − Tm, x, 1."""
        d = tr - Tm
        m = np.stack([np.ones_like(xf), -xf, -d, d * xf], -1)
        num = m @ b
        den = np.maximum(np.einsum("...i,ij,...j->...", m, G, m), 1e-300)
        return num * num / den, num / den

    def fit(self, ctx, y, train):
        B, Tm = self._basis(ctx)
        sel = train & (B[:, 3] != 0)
        Bs, ys = B[sel], y[sel]
        G, b = Bs.T @ Bs, Bs.T @ ys
        lo, hi = self.xf_range(ctx)
        xgrid = np.linspace(lo, hi, 49)

        def refine(f, q0, h):
            return refine_max(f, q0, h, lo, hi, xatol=1e-4 * (hi - lo))

        # T_ref at the reference temperature (ISO 1: 20 °C) ...
        def g_ref(q):
            return float(self._gain(G, b, np.asarray(q, float), np.asarray(T_REF), Tm)[0])
        gains = self._gain(G, b, xgrid, np.full_like(xgrid, T_REF), Tm)[0]
        xf, best = refine(g_ref, float(xgrid[int(np.argmax(gains))]), xgrid[1] - xgrid[0])
        t_ref = T_REF
        # ... or free, when the data say so beyond what one more parameter gains from noise
        XF, TR = np.meshgrid(xgrid, np.arange(T_REF_RANGE[0], T_REF_RANGE[1] + 0.5, 1.0))
        gfree = self._gain(G, b, XF, TR, Tm)[0]
        k = np.unravel_index(int(np.argmax(gfree)), XF.shape)
        q0 = np.array([XF[k], TR[k]])
        sol = optimize.minimize(lambda q: -float(self._gain(G, b, np.asarray(q[0]), np.asarray(q[1]), Tm)[0]), q0,
                                method="Nelder-Mead",
                                options={"xatol": 1e-3, "fatol": 1e-3, "maxiter": 200,
                                         "initial_simplex": [q0, q0 + [0.02 * (hi - lo), 0], q0 + [0, 0.5]]})
        if -sol.fun > best + math.log(max(len(ys), 2)) and lo <= sol.x[0] <= hi:
            xf, t_ref = float(sol.x[0]), float(sol.x[1])
        dsse, al = (float(v) for v in self._gain(G, b, np.asarray(xf), np.asarray(t_ref), Tm))
        d = t_ref - Tm
        pred = al * ((B[:, 0] - xf * B[:, 1]) - d * (B[:, 2] - xf * B[:, 3]))
        # the temperature must carry the fit: a static scale error about a point (a·x + c, what a
        # wrong lead or a length error leaves) must do clearly worse
        c2 = _lstsq(Bs[:, 2:], ys)
        r2 = ys - Bs[:, 2:] @ c2
        dsse_static = float(ys @ ys - r2 @ r2)
        # physical sanity: the temperature must really change (20 x its noise)
        from pmctl.tools.twin.locate import noise_level
        key = ("temp_ok", self.channel)
        if key not in ctx.extra:
            Tfull = ctx.temps[self.channel]
            ctx.extra[key] = bool(np.ptp(Tfull) > 20 * max(noise_level(Tfull[np.isfinite(Tfull)]), 1e-3))
        params = {"alpha_per_K": float(al), "channel": self.channel, "screw_fixed_end_mm": xf, "t_ref_C": float(t_ref)}
        edge = 0.02 * (hi - lo)
        ok = bool(ctx.extra[key] and np.isfinite(al) and np.ptp(ctx.q_cmd[:, self.a]) > 0
                  and dsse - dsse_static > PRESCREEN)
        return Fit(params, pred, 3, ok=ok,
                   internal={"dsse_T": dsse - dsse_static, "at_edge": not lo + edge < xf < hi - edge,
                             "xf_range": (lo, hi)})

    def check(self, ctx, fit, y):
        p = fit.params
        al, tr = p.get("alpha_per_K", 0.0), p.get("t_ref_C", float("nan"))
        out = []
        if not 0 < al < MAX_ALPHA:
            out.append(f"α = {al:.3g} /K: a screw grows when it warms, by less than {MAX_ALPHA:g} /K")
        if fit.internal.get("at_edge"):
            lo, hi = fit.internal["xf_range"]
            out.append(f"the fixed bearing lands at {p['screw_fixed_end_mm']:.0f} mm, the edge of where it can be "
                       f"({lo:.0f} … {hi:.0f} mm): not a screw growing from its bearing")
        if not T_REF_RANGE[0] < tr < T_REF_RANGE[1]:
            out.append(f"a calibration temperature of {tr:.1f} °C is no workshop's")
        return out


class Compliance(AxisSignal):
    """Chain i shortens by a_i / k under its axial compression a_i (statics of the nominal twin);
    table axis X/Y gives way by −F/k to the known tool-tip force F (load_f*)."""

    effect = "compliance"

    def _force(self, ctx):
        if self.a < 3:
            return ctx.forces[:, self.a]
        F = ctx.extra.get("tip_force")
        return None if F is None else F[:, self.a - 3]

    def applicable(self, ctx):
        f = self._force(ctx)
        return f is not None and super().applicable(ctx) and np.ptp(f) > 0

    def design(self, ctx):
        f = self._force(ctx)[ctx.obs.pos]
        return (self.gain(ctx) * -f)[:, None]

    def params_of(self, c, ctx):
        k = 1.0 / c[0] if c[0] > 0 else float("inf")
        return {"stiffness_N_per_mm": float(k)}

    def fit(self, ctx, y, train):
        f = super().fit(ctx, y, train)
        f.ok = bool(f.internal["coef"][0] > 0)
        return f


class ServoLag(AxisSignal):
    """The drive follows cmd through a first-order lag: enc = lag_tau(cmd)."""

    effect = "servo_lag"
    site = "motor"

    def fit(self, ctx, y, train):
        g = self.gain(ctx)
        u = ctx.q_cmd[:, self.a]
        rows = ctx.obs.row
        v = axis_velocity(ctx, self.a)
        col = g * -v[rows]
        tau0 = float(_lstsq(col[train, None], y[train])[0])
        if tau0 <= 0:
            return Fit({"tau_s": 0.0}, np.zeros_like(y), 1, ok=False)

        sel = train & (g != 0)
        gs, ys, rs = g[sel], y[sel], rows[sel]

        def res(p):
            return gs * (per_run(ctx, lambda tt, uu: first_order_lag(tt, uu, p[0]), ctx.t, u) - u)[rs] - ys

        tau = tau0
        if ctx.uniform_dt is not None:
            try:
                sol = optimize.least_squares(res, [tau0], bounds=([1e-9], [np.inf]), x_scale=[tau0],
                                             diff_step=[1e-3], max_nfev=20)
                tau = float(sol.x[0])
            except ValueError:
                pass
        pred = g * (per_run(ctx, lambda tt, uu: first_order_lag(tt, uu, tau), ctx.t, u) - u)[rows]
        return Fit({"tau_s": tau}, pred, 1)

    def check(self, ctx, fit, y):
        tau = fit.params.get("tau_s", 0.0)
        if not 1e-4 <= tau <= 0.5:
            return [f"τ = {tau * 1000:.3g} ms is outside a drive's 0.1-500 ms"]
        # a lag trails in proportion to speed; a constant trailing error that only flips at
        # reversals (friction) fits a lag too, but a sign-of-velocity column fits it better
        g = self.gain(ctx)
        d = axis_direction(ctx, self.a)[ctx.obs.row]
        col = (g * -d)[:, None]
        c = _lstsq(col, y)
        r_sign = y - col @ c
        r_lag = y - fit.pred
        if float(r_sign @ r_sign) < float(r_lag @ r_lag):
            return ["the trailing error is constant in speed and flips at reversals (friction-like), "
                    "not proportional to speed"]
        return []


class Friction(AxisSignal):
    """Coulomb + Stribeck friction seen as the drive's following error: the motor side trails the
    command by e(v) = sign(v)·(e_c + e_s·exp(−(v/v_s)²)) (the friction force over the position
    loop's stiffness), held through stops, flipping at every reversal. Motor-side: the encoder sees
    it, and the tool too where the axis has no encoder. Parameters: ``coulomb_mm`` (e_c > 0),
    ``stribeck_mm`` (extra at low speed, ≥ 0), ``stribeck_speed_mm_s`` (v_s, from a grid). A lag
    trails in proportion to speed, backlash is load-side (the encoder does not see it)."""

    effect = "friction"
    site = "motor"
    nparams = 3
    VS = (0.5, 1.0, 2.0, 3.5, 6.0, 10.0)

    def _cols(self, ctx, vs):
        d = axis_direction(ctx, self.a)[ctx.obs.row]
        v = axis_velocity(ctx, self.a)[ctx.obs.row]
        g = self.gain(ctx)
        return np.stack([g * -d, g * -d * np.exp(-(v / vs) ** 2)], 1)

    def fit(self, ctx, y, train):
        def cost(lv):
            # both terms are friction, never negative: non-negative least squares on 2 columns
            X = self._cols(ctx, math.exp(lv))
            nz = train & np.any(X != 0, 1)
            Xs, ys = X[nz], y[nz]
            G, b = Xs.T @ Xs, Xs.T @ ys
            c = np.zeros(2)
            for act in ((0, 1), (0,), (1,)):
                a = list(act)
                try:
                    sol = np.linalg.solve(G[np.ix_(a, a)], b[a])
                except np.linalg.LinAlgError:
                    continue
                if np.all(sol >= 0):
                    c = np.zeros(2)
                    c[a] = sol
                    break
            r = ys - Xs @ c
            return float(r @ r), c, X

        # the Stribeck term must fade within the motion, else it is the Coulomb term again: v_s at
        # most 0.8 x the median moving speed
        v = np.abs(axis_velocity(ctx, self.a))
        vmax = 0.8 * float(np.median(v[v > 1e-3 * max(v.max(), 1e-12)])) if np.any(v > 0) else 0.0
        grid = [vs for vs in self.VS if vs <= vmax]
        if not grid:
            X = self._cols(ctx, 1.0)
            X[:, 1] = 0.0
            nz = train & (X[:, 0] != 0)
            c0 = max(float(_lstsq(X[nz][:, :1], y[nz])[0]), 0.0)
            return Fit({"coulomb_mm": c0, "stribeck_mm": 0.0, "stribeck_speed_mm_s": 0.0},
                       X[:, 0] * c0, 1, ok=c0 > 0)
        best = None
        for vs in grid:
            sse, c, X = cost(math.log(vs))
            if best is None or sse < best[0]:
                best = (sse, vs, c, X)
        # refine the Stribeck speed between the grid's neighbours (golden section on log v_s)
        lv0 = math.log(best[1])
        sol = optimize.minimize_scalar(lambda lv: cost(lv)[0], bounds=(lv0 - 0.7, min(lv0 + 0.7, math.log(vmax))),
                                       method="bounded", options={"maxiter": 12, "xatol": 0.02})
        sse, c, X = cost(float(sol.x))
        best = (sse, math.exp(float(sol.x)), c, X) if sse < best[0] else best
        _, vs, c, X = best
        return Fit({"coulomb_mm": float(c[0]), "stribeck_mm": float(c[1]), "stribeck_speed_mm_s": vs},
                   X @ c, 3, ok=bool(c[0] > 0))

    def check(self, ctx, fit, y):
        if fit.params.get("coulomb_mm", 0) <= 0:
            return ["the error leads the command (friction can only make the drive trail)"]
        return []


class LostSteps(AxisSignal):
    effect = "lost_steps"
    nparams = 2

    def fit(self, ctx, y, train):
        g = self.gain(ctx)
        o = ctx.obs
        tt = ctx.t[o.row]
        idx = np.nonzero(train & (g != 0))[0]
        if len(idx) < 4:
            return Fit({}, np.zeros_like(y), 2, ok=False)
        order = idx[np.argsort(tt[idx], kind="stable")]
        gy = (g * y)[order][::-1].cumsum()[::-1]
        gg = (g * g)[order][::-1].cumsum()[::-1]
        # a step at the time of element k (first affected element), excluding the very first
        score = np.where(gg > 0, gy * gy / np.where(gg > 0, gg, 1), 0)
        score[0] = 0
        k = int(np.argmax(score))
        # every split whose gain is within noise of the best is as likely (a step inside a tracker
        # drop-out: one noisy sample at the gap's edge must not pin it there): the data place the
        # step anywhere from the last sample before the first such split to the first sample
        # after the last one, and the fit takes the middle of that bracket
        near = score >= score[k] - self.TIE
        k0, k1 = k, k
        while k0 > 1 and near[k0 - 1]:
            k0 -= 1
        while k1 + 1 < len(score) and near[k1 + 1]:
            k1 += 1
        hi = float(tt[order[k1]])
        before = tt[order[:k0]]
        before = before[before < tt[order[k0]]]
        lo = float(before.max()) if len(before) else hi      # (elements of one row share its time)
        if k0 == k1:
            ts = float(0.5 * (tt[order[k - 1]] + hi))
        else:
            ts = float(0.5 * (lo + hi))
            k = min(max(int(np.searchsorted(tt[order], ts, side="left")), 1), len(order) - 1)
        off = float(gy[k] / gg[k])
        # between the last sample before the step and the first after, the step's time is unknown:
        # a sample there (a held-out one: the fit's own samples are all outside) is predicted by
        # the expected value of a step placed anywhere in that span, a ramp across it
        ramp = np.clip((tt - lo) / (hi - lo), 0.0, 1.0) if hi > lo else (tt >= ts).astype(float)
        pred = g * off * ramp
        return Fit({"t_s": ts, "offset_mm": off}, pred, 2, internal={"t_bracket": (lo, hi)})

    TIE = 4.0      # whitened SSE: splits of the record this close to the best one are as likely (2 σ)

    EDGE = 0.02     # share of the record (and at least EDGE_N samples) the step needs on each side
    EDGE_N = 10

    def check(self, ctx, fit, y):
        ts = fit.params.get("t_s")
        if ts is None:
            return []
        g = self.gain(ctx)
        tt = ctx.t[ctx.obs.row][g != 0]
        t0, t1 = float(ctx.t[0]), float(ctx.t[-1])
        n_before, n_after = int(np.sum(tt < ts)), int(np.sum(tt >= ts))
        if min(ts - t0, t1 - ts) < self.EDGE * (t1 - t0) or min(n_before, n_after) < self.EDGE_N:
            return [f"the step at t = {ts:.3g} s is at the record's edge ({n_before} samples before it, "
                    f"{n_after} after): it cannot be told from an offset"]
        return []


TOOL_T_MIN = 5.0      # an axis resonance's tool-channel gain, in standard errors, below which only the gauge rings


ALIAS_D2 = 25.0    # whitened SSE by which a mode above the tool channels' Nyquist limit must fit better
FOLD_TIE_D2 = 9.21  # whitened SSE within which a training fold does not refute the full fit's mode (χ²₂ 99 %)


class Resonance(Candidate):
    """A lightly damped mode excited by the axis accelerations (base excitation, docs/diagnosis-report.md §2).

    Target an axis (load-side deflection of that axis, seen at the tool) or a channel (e.g. a
    strain gauge; excited by every moving axis, one gain each)."""

    effect = "resonance"
    nparams = 3

    def __init__(self, target, key):
        super().__init__(target)
        self.target_key = key        # "axis" or "channel"
        self._starts = None
        self._full = None            # (f, z) of the fit on all samples since the reset

    def reset(self):
        """Forget the start frequencies (taken from the residual of the first fit after a reset)
        and the full fit's mode."""
        self._starts = None
        self._full = None

    def applicable(self, ctx):
        if ctx.uniform_dt is None and len(ctx.t) < 16:
            return False
        if self.target_key == "axis":
            a = axis_index(ctx, self.target)
            return bool(np.any(axis_gain(ctx, a) != 0)) and np.ptp(ctx.q_cmd[:, a]) > 0
        return self.target in ctx.obs.channels and np.ptp(ctx.q_cmd[:, excited_axis(ctx, self.target)]) > 0

    def _uniform(self, ctx):
        if "uniform" not in ctx.extra:
            if ctx.uniform_dt is not None:
                ctx.extra["uniform"] = (ctx.t, ctx.uniform_dt, None)
            else:                # (a uniform grid per run, made in _bases)
                dt = float(np.median(np.diff(ctx.t)))
                ctx.extra["uniform"] = (None, dt, True)
        return ctx.extra["uniform"]

    def _weights(self, ctx):
        """(axis whose motion excites the mode, (k, N) element weights of each column, support)."""
        key = ("res_w", self.target_key, self.target)
        if key not in ctx.extra:
            o = ctx.obs
            # an axis mode is excited by that axis; a gauge's plate-link mode by its own chain
            a = axis_index(ctx, self.target) if self.target_key == "axis" else excited_axis(ctx, self.target)
            ws = []
            if self.target_key == "axis":
                ws.append(axis_gain(ctx, a))
                sg = f"strain_{a + 1}"
                if a < 3 and sg in o.channels:     # the mode's spring force reaches the gauge
                    ws.append(np.where(o.ch == o.channels.index(sg), o.w, 0.0))
            else:
                ws.append(np.where(o.ch == o.channels.index(self.target), o.w, 0.0))
            W = np.stack(ws)
            ctx.extra[key] = (a, W, np.any(W != 0, 0))
        return ctx.extra[key]

    def _bases(self, ctx, f, z, idx=None):
        """Columns of the fit at obs elements ``idx`` (default: all)."""
        _, dt, resample = self._uniform(ctx)
        a, W, _ = self._weights(ctx)
        if resample is None:
            h = per_run(ctx, lambda x: resonance_response(x, dt, f, z), ctx.q_cmd[:, a])
        else:
            h = np.concatenate([np.interp(tt, tu, resonance_response(xu, dt, f, z))
                                for tt, tu, xu in self._gridded(ctx, a, dt)])
        if self.target_key == "channel" and self.target.startswith("acc_") and "axes" in ctx.extra:
            # an accelerometer on the axis reads the mode's acceleration, y'' (its base part, the
            # commanded acceleration, is the nominal prediction)
            h = per_run(ctx, lambda tt, x: np.gradient(np.gradient(x, tt), tt) if len(x) > 2 else 0 * x, ctx.t, h)
        o = ctx.obs
        if idx is None:
            return (W * h[o.row]).T
        return (W[:, idx] * h[o.row[idx]]).T

    @staticmethod
    def _gridded(ctx, a, dt):
        """Per run of rows: (its times, the uniform grid, axis a's command on it), made once."""
        key = ("res_grid", a)
        if key not in ctx.extra:
            pieces = []

            def one(tt, x):
                tu = np.arange(tt[0], tt[-1] + dt / 2, dt)
                pieces.append((tt, tu, on_grid(tt, x, tu)))
                return x
            per_run(ctx, one, ctx.t, ctx.q_cmd[:, a])
            ctx.extra[key] = pieces
        return ctx.extra[key]

    def _f_candidates(self, ctx, y):
        """Peaks of the spectrum of the target residual (uniform grid), strongest first."""
        o = ctx.obs
        if self.target_key == "axis":
            g = axis_gain(ctx, axis_index(ctx, self.target))
            m = g != 0
            sig = np.zeros(len(ctx.t))
            tt = ctx.t[o.row[m]]
            # project onto the axis: per row, the LS axis error from the tool channels present
            num = np.bincount(o.row[m], g[m] * y[m], minlength=len(ctx.t))
            den = np.bincount(o.row[m], g[m] ** 2, minlength=len(ctx.t))
            ok = den > 0
            sig = num[ok] / den[ok]
            tt = ctx.t[ok]
        else:
            m = o.ch == o.channels.index(self.target)
            order = np.argsort(o.row[m])
            sig, tt = y[m][order], ctx.t[o.row[m][order]]
        if len(sig) < 32:
            return []
        sp = welch_runs(tt, sig, ctx.extra.get("cuts"))
        if sp is None:
            return []
        fq, p = sp
        base = signal.medfilt(p, 31) if len(p) > 31 else np.full_like(p, np.median(p))
        ratio = p / np.maximum(base, 1e-300)
        ratio[fq < 0.5] = 0
        pk, _ = signal.find_peaks(ratio)
        pk = pk[np.argsort(ratio[pk])[::-1]][:3]
        return [float(fq[k]) for k in pk if ratio[k] > 6]

    def _nyquist(self, ctx, rows_mask, native=True):
        """Nyquist frequency of the elements ``rows_mask``: of the channels as recorded
        (``native``: a tracker slower than the log), or of the analysis samples the cap kept."""
        nyq = 0.5 / self._uniform(ctx)[1]
        nd = ctx.extra.get("native_dt")
        if native and nd is not None:
            chans = np.unique(ctx.obs.ch[rows_mask])
            steps = [nd[ctx.obs.channels[c]] for c in chans if ctx.obs.channels[c] in nd]
            return min([nyq] + [0.5 / d for d in steps if d > 0])
        rows = np.unique(ctx.obs.row[rows_mask])
        if len(rows) > 2:
            nyq = min(nyq, 0.5 / float(np.median(np.diff(ctx.t[rows]))))
        return nyq

    def fit(self, ctx, y, train):
        # the channels that see the mode may be sampled slower than the log (a 100 Hz tracker):
        # above their Nyquist frequency a mode aliases, so the search stops below it. An axis mode
        # is searched below its tool channels' limit first; its gauge, at the log's rate, may see
        # higher, but a mode there is taken only when it fits clearly better (ALIAS_D2): where
        # the gauge does not tell, a 15 Hz mode seen by a 125 Hz tracker fits as well at its 110 Hz
        # alias. Below both comes the limit of the samples the cap kept (every 3rd row of a long
        # 1 kHz log): the mode is filtered on the full grid, so above that limit it is still told
        # from its alias by its forced part, but only with enough signal. So the bands are the kept
        # samples', the tool channels', the gauge's, each wider one taken only when clearly better
        _, W, sup = self._weights(ctx)
        nyq_all = self._nyquist(ctx, sup)
        nyq_own = min(nyq_all, self._nyquist(ctx, W[0] != 0))
        nyq_thin = min(nyq_own, self._nyquist(ctx, W[0] != 0, native=False))
        if self._starts is None:
            # (a coarser start grid on long records: each start filters the whole record)
            ng = 20 if len(ctx.t) <= 200_000 else 10
            grid = np.geomspace(1.0, 0.8 * nyq_all, ng) if nyq_all > 2.5 else np.array([])
            # (a spectral peak at the very edge of the band, an artefact of a thinned log, starts
            # inside the fit's bounds)
            self._starts = [(min(f, 0.85 * nyq_all), z) for f in self._f_candidates(ctx, y) if f > 1.0
                            for z in (0.02, 0.1)] + [(float(f), 0.05) for f in grid]
        fs = self._starts
        if not fs:
            return Fit({}, np.zeros_like(y), 3, ok=False)
        sel = np.flatnonzero(train & sup)
        yt = y[sel]

        def res(p):
            X = self._bases(ctx, math.exp(p[0]), p[1], sel)
            c = _lstsq(X, yt)
            return X @ c - yt

        # prescreen: a start must already explain something, else this is no resonance
        base = float(yt @ yt)
        screened = []
        for f0, z0 in fs:
            r = res([math.log(f0), z0])
            screened.append((base - float(r @ r), f0, z0))

        def search(nyq):
            top = max([s for s in screened if s[1] < 0.9 * nyq], default=None)
            if top is None or top[0] <= 3 * PRESCREEN or nyq <= 1.2:
                return None
            x0s = [(top[1], top[2])]
            if self._full is not None and not train.all() and self._full[0] < 0.9 * nyq:
                # a training fold also starts at the full fit's mode and keeps the better minimum:
                # it disagrees when its own data prefer another mode, not when its best start on the
                # coarse grid lies in another basin (a 16 Hz mode: folds at 22, 49 and 16 Hz)
                x0s.append(self._full)
            best = None
            for f0, z0 in x0s:
                try:
                    sol = optimize.least_squares(
                        res, [math.log(f0), z0],
                        bounds=([math.log(1.0), 1e-3], [math.log(0.9 * nyq), 0.9]),
                        diff_step=[1e-4, 1e-3], max_nfev=15)
                except ValueError:
                    continue
                if best is None or sol.cost < best.cost:
                    best = sol
            if best is not None and self._full is not None and not train.all() and self._full[0] < 0.9 * nyq:
                # the fold's data do not refute the full fit's mode when their cost there is within
                # FOLD_TIE_D2 of their own best (a 2-parameter 99 % region): the fold keeps it. A
                # fold of a circle run without the block that rings (the rest of a circle looks
                # like a geometry error) cannot pin the mode and went to 23 Hz for 13 Hz, at 6.6
                r = res([math.log(self._full[0]), self._full[1]])
                if 0.5 * float(r @ r) <= best.cost + 0.5 * FOLD_TIE_D2:
                    best = optimize.OptimizeResult(x=np.array([math.log(self._full[0]), self._full[1]]),
                                                   cost=0.5 * float(r @ r))
            return best
        best, nyq = search(nyq_thin), nyq_thin
        for band in (nyq_own, nyq_all):
            if band > 1.05 * nyq:
                wide = search(band)
                if wide is not None and (best is None or wide.cost < best.cost - 0.5 * ALIAS_D2):
                    best, nyq = wide, band
        if best is None:
            return Fit({}, np.zeros_like(y), 3, ok=False)
        f, z = math.exp(best.x[0]), float(best.x[1])
        if train.all():
            self._full = (f, z)
        X = self._bases(ctx, f, z)
        c = _lstsq(X[sel], yt)
        return Fit({"freq_hz": f, "damping_ratio": z}, X @ c, 2 + X.shape[1],
                   internal={"gains": c.tolist(), "nyq": nyq})

    def check(self, ctx, fit, y):
        f, z = fit.params.get("freq_hz"), fit.params.get("damping_ratio")
        if f is None:
            return ["no mode"]
        out = []
        if z <= 0.003:
            out.append(f"damping ratio {z:.4f} at its lower bound: a steady line, not a ringing mode")
        if z >= 0.8:
            out.append(f"damping ratio {z:.2f}: overdamped, nothing rings")
        if f < 2.0:
            out.append(f"{f:.2f} Hz is below any structural mode of the machine (a slow error or a "
                       "transient at reversals, not ringing)")
        if f > 0.85 * fit.internal.get("nyq", np.inf):
            out.append(f"{f:.1f} Hz at the Nyquist limit of the log")
        if out:
            return out
        _, W, sup = self._weights(ctx)
        if self.target_key == "axis" and W.shape[0] == 2:
            # an axis mode moves the tool: the tool channels' column must carry it. A mode that only
            # the chain's gauge sees is that channel's (the gauge's plate link), not the axis's
            X = self._bases(ctx, f, z)[sup]
            try:
                cov = np.linalg.inv(X.T @ X)          # whitened residual: unit noise
                t_tool = abs(fit.internal["gains"][0]) / math.sqrt(max(cov[0, 0], 1e-300))
            except (np.linalg.LinAlgError, KeyError, IndexError):
                t_tool = np.inf
            if t_tool < TOOL_T_MIN:
                gauge = f"strain_{axis_index(ctx, self.target) + 1}"
                return [f"the tool does not see it ({t_tool:.1f} standard errors on the tool channels): only "
                        f"{gauge} rings, a mode of that channel, not of axis {self.target}"]
        if "axes" in ctx.extra:
            qs = _quasi_static_check(self, ctx, fit, y, f, sup)
            if qs:
                return qs
        # ringing decays after each acceleration; a line of constant amplitude at the same
        # frequency (forced vibration) must not explain as much
        t = ctx.t[ctx.obs.row]
        X = np.concatenate([(W * np.sin(2 * np.pi * f * t)).T, (W * np.cos(2 * np.pi * f * t)).T], 1)
        c = _lstsq(X[sup], y[sup])
        r_line = y[sup] - X[sup] @ c
        r_mode = y[sup] - fit.pred[sup]
        gain_line = float(y[sup] @ y[sup] - r_line @ r_line)
        gain_mode = float(y[sup] @ y[sup] - r_mode @ r_mode)
        if gain_line > 0.7 * gain_mode:
            out.append(f"a steady {f:.2f} Hz line of constant amplitude explains it as well: forced "
                       "vibration, not a mode excited by the motion")
        return out + _gain_over_time_check(ctx, fit.pred, y)


QS_SHARE = 0.7             # a mode whose quasi-static part alone explains this share of it does not ring


def _quasi_static_check(res, ctx, fit, y, f, sup):
    """Far below its frequency a mode's response is quasi-static, −a/ω²: a column proportional to
    the acceleration. On a drive's force that is an inertia term (or what the force model's filtered
    acceleration left of it), on an accelerometer the command's fourth derivative. When that column
    alone explains QS_SHARE of what the mode explains, nothing rings: it is no resonance."""
    a, W, _ = res._weights(ctx)
    key = ("qs_col", a)
    if key not in ctx.extra:
        acc = per_run(ctx, lambda tt, x: np.gradient(np.gradient(x, tt), tt) if len(x) > 2 else 0 * x,
                      ctx.t, ctx.q_cmd[:, a])
        ctx.extra[key] = acc
    h = ctx.extra[key]
    if res.target_key == "channel" and res.target.startswith("acc_"):
        h = per_run(ctx, lambda tt, x: np.gradient(np.gradient(x, tt), tt) if len(x) > 2 else 0 * x, ctx.t, h)
    X = (W * h[ctx.obs.row]).T[sup]
    c = _lstsq(X, y[sup])
    g_qs = float(y[sup] @ y[sup] - (y[sup] - X @ c) @ (y[sup] - X @ c))
    r = y[sup] - fit.pred[sup]
    g_mode = float(y[sup] @ y[sup] - r @ r)
    if g_mode > 0 and g_qs >= QS_SHARE * g_mode:
        return [f"its quasi-static part alone (a term in the acceleration, as a mode far above the motion "
                f"gives) explains {100 * g_qs / g_mode:.0f} % of it: nothing rings at {f:.1f} Hz"]
    return []


MODE_BLOCKS = 8            # a mode's gain fitted on each eighth of the record ...
MODE_GAIN_CHI2 = 25.0      # ... scatters about 1 by at most this, per block, in units of its noise. Measured:
                           # 48 synth modes (8 bases, 250 Hz and 1 kHz, imperfections) 0.0-10.6; chatter bursts
                           # that a lightly damped mode half fitted 94-1060
MODE_GAIN_OFF = 0.5        # ... or no eighth's gain is this far from 1 (a strong mode whose gain varies a little
                           # with the pose passes; the chatter burst's eighths needed -0.16 to 1.84)


def _gain_over_time_check(ctx, pred, y):
    """A mode rings after every acceleration that excites it: the fitted response, scaled to each
    eighth of the record on its own, needs the same gain (1) in every eighth where it predicts more
    than noise. A burst of vibration in one stretch (chatter in one cut) that a lightly damped mode
    half fits needs a large gain there and none elsewhere."""
    tt = ctx.t[ctx.obs.row]
    b = np.minimum(((tt - ctx.t[0]) / max(ctx.duration, 1e-12) * MODE_BLOCKS).astype(int), MODE_BLOCKS - 1)
    pp = np.bincount(b, pred * pred, MODE_BLOCKS)
    py = np.bincount(b, pred * y, MODE_BLOCKS)
    ok = pp > 4.0                       # (whitened: the block's prediction is above its noise)
    if ok.sum() < 3:
        return []
    s = py[ok] / pp[ok]                 # each block's gain; its variance is 1/pp (unit noise)
    chi = float(np.mean((s - 1.0) ** 2 * pp[ok]))
    if chi <= MODE_GAIN_CHI2 or np.max(np.abs(s - 1.0)) <= MODE_GAIN_OFF:
        return []
    return [f"its amplitude does not follow the motion: scaled to each eighth of the record on its own, the "
            f"mode needs gains from {s.min():.2f} to {s.max():.2f} ({chi:.0f}x their noise; a mode: about 1): a "
            f"burst in one stretch of the run (chatter), not a mode that every acceleration excites"]


def channel_group(ctx: Context, target: str) -> list[str]:
    """Channels of a latency/drift target: ``tip_*`` is the tracker (tip_* and tool_*)."""
    if target == "tip_*":
        return [c for c in ctx.obs.channels if c.startswith(("tip_", "tool_"))]
    return [target] if target in ctx.obs.channels else []


class SensorLatency(Candidate):
    """A channel (or the tracker, ``tip_*`` = tip_* and tool_*) is time-stamped late by d: it
    reads the true value of t − d, so its residual is −d·(d prediction / dt). Linear in d for
    delays much shorter than the motion's time scale. Parameter ``delay_s`` (positive: late).
    Identifiable when the channel's prediction moves (its residual follows the speed, in every
    channel of the group with the one delay)."""

    effect = "sensor_latency"
    target_key = "channel"

    def applicable(self, ctx):
        return bool(channel_group(ctx, self.target))

    def design(self, ctx):
        o = ctx.obs
        col = np.zeros(len(o.y))
        for c in channel_group(ctx, self.target):
            m = np.flatnonzero(o.ch == o.channels.index(c))
            order = m[np.argsort(o.row[m], kind="stable")]
            tt, pp = ctx.t[o.row[order]], o.pred[order]
            if len(tt) < 3:
                continue
            dp = np.gradient(pp, tt)
            # a gap in the channel (tracker drop-out) is no derivative: no leverage there
            dt = np.diff(tt)
            med = float(np.median(dt))
            gap = np.zeros(len(tt), bool)
            gap[1:] |= dt > 3 * med
            gap[:-1] |= dt > 3 * med
            col[order] = np.where(gap, 0.0, -dp * o.w[order])
        return col[:, None]

    def params_of(self, c, ctx):
        return {"delay_s": float(c[0])}

    def check(self, ctx, fit, y):
        d = fit.params.get("delay_s", 0.0)
        if not 0 < abs(d) <= 0.2:
            return [f"delay {d * 1000:.3g} ms outside 0-200 ms"]
        return []


class SensorDrift(Candidate):
    """A channel's zero creeps linearly in time: measured = true + r·(t − t_mid). Parameter
    ``rate_per_s`` (channel units per second). Identifiable against thermal growth and geometry
    because it does not depend on pose or on a temperature; against an offset because it changes
    sign over the record."""

    effect = "sensor_drift"
    target_key = "channel"

    def applicable(self, ctx):
        return self.target in ctx.obs.channels and ctx.duration > 0

    def design(self, ctx):
        o = ctx.obs
        t = ctx.t[o.row]
        tm = 0.5 * (ctx.t[0] + ctx.t[-1])
        return np.where(o.mask_of(self.target), o.w * (t - tm), 0.0)[:, None]

    def params_of(self, c, ctx):
        return {"rate_per_s": float(c[0])}


def _line_frequencies(tt, sig, fmin=0.5, k=3, ratio_min=6.0, cuts=None):
    """Peaks of the Welch spectrum of an (irregular) series, strongest first, above fmin
    (``cuts``: see :func:`welch_runs`)."""
    if len(sig) < 32:
        return []
    sp = welch_runs(tt, sig, cuts)
    if sp is None:
        return []
    fq, p = sp
    base = signal.medfilt(p, 31) if len(p) > 31 else np.full_like(p, np.median(p))
    ratio = p / np.maximum(base, 1e-300)
    ratio[fq < fmin] = 0
    pk, _ = signal.find_peaks(ratio)
    pk = pk[np.argsort(ratio[pk])[::-1]][:k]
    return [float(fq[j]) for j in pk if ratio[j] > ratio_min]


class ForcedVibration(Candidate):
    """A steady vibration from a source that does not care how the machine moves (a spindle, a
    pump, the floor): a line of constant amplitude A·sin(2πft + φ) on an axis (load side, seen by
    the tool) or in one channel. Parameters ``freq_hz``, ``amplitude_mm`` (axis) or ``amplitude``
    (channel units). Identifiable against a resonance because its amplitude does not follow the
    accelerations (the same in every time fold)."""

    effect = "forced_vibration"
    nparams = 3

    def __init__(self, target, key):
        super().__init__(target)
        self.target_key = key
        self._starts = None

    def reset(self):
        self._starts = None

    def _w(self, ctx):
        o = ctx.obs
        if self.target_key == "axis":
            return axis_gain(ctx, axis_index(ctx, self.target))
        return np.where(o.ch == o.channels.index(self.target), o.w, 0.0)

    def applicable(self, ctx):
        if self.target_key == "axis":
            return bool(np.any(axis_gain(ctx, axis_index(ctx, self.target)) != 0))
        return self.target in ctx.obs.channels

    def _series(self, ctx, y):
        o = ctx.obs
        g = self._w(ctx)
        m = g != 0
        num = np.bincount(o.row[m], g[m] * y[m], minlength=len(ctx.t))
        den = np.bincount(o.row[m], g[m] ** 2, minlength=len(ctx.t))
        ok = den > 0
        return ctx.t[ok], num[ok] / den[ok]

    def fit(self, ctx, y, train):
        if self._starts is None:
            tt, sig = self._series(ctx, y)
            self._starts = _line_frequencies(tt, sig, fmin=1.0, cuts=ctx.extra.get("cuts")) if len(tt) else []
        if not self._starts:
            return Fit({}, np.zeros_like(y), 3, ok=False)
        g = self._w(ctx)
        t = ctx.t[ctx.obs.row]
        sel = train & (g != 0)
        gs, ys, ts = g[sel], y[sel], t[sel]

        def res(p):
            X = np.stack([gs * np.sin(2 * np.pi * p[0] * ts), gs * np.cos(2 * np.pi * p[0] * ts)], 1)
            return X @ _lstsq(X, ys) - ys

        best = None
        df = 1.0 / max(ctx.duration, 1e-9)
        for f0 in self._starts[:2]:
            try:
                sol = optimize.least_squares(res, [f0], bounds=([max(f0 - 3 * df, 1e-3)], [f0 + 3 * df]),
                                             x_scale=[df * 0.1], diff_step=[1e-7], max_nfev=20)
            except ValueError:
                continue
            if best is None or sol.cost < best.cost:
                best = sol
        if best is None:
            return Fit({}, np.zeros_like(y), 3, ok=False)
        f = float(best.x[0])
        X = np.stack([g * np.sin(2 * np.pi * f * t), g * np.cos(2 * np.pi * f * t)], 1)
        c = _lstsq(X[sel], ys)
        amp = float(np.hypot(*c))
        key = "amplitude_mm" if self.target_key == "axis" else "amplitude"
        return Fit({"freq_hz": f, key: amp}, X @ c, 3)

    def check(self, ctx, fit, y):
        f = fit.params.get("freq_hz")
        if f is None:
            return ["no line"]
        if f * ctx.duration < 10:
            return [f"{f:.2f} Hz completes fewer than 10 cycles in the record"]
        # a steady source keeps its amplitude: fitted on each quarter of the record it must not
        # vanish in one of them (a burst, chatter in one cut, is something else)
        g = self._w(ctx)
        t = ctx.t[ctx.obs.row]
        edges = np.linspace(ctx.t[0], ctx.t[-1], 5)
        amps = []
        for a, b in zip(edges, edges[1:]):
            m = (g != 0) & (t >= a) & (t <= b)
            if m.sum() < 8:
                continue
            X = np.stack([g[m] * np.sin(2 * np.pi * f * t[m]), g[m] * np.cos(2 * np.pi * f * t[m])], 1)
            amps.append(float(np.hypot(*_lstsq(X, y[m]))))
        if len(amps) >= 3 and min(amps) < 0.33 * max(amps):
            return [f"its amplitude is not steady over the record (quarters: "
                    f"{', '.join(f'{x / max(amps):.2f}' for x in amps)} of the largest): a burst, not a steady source"]
        return _steady_line_check(g, t, y, f, ctx.t[0], ctx.t[-1]) or _sideband_check(g, t, y, f, ctx.t[0], ctx.t[-1])


SIDEBAND = (40.0, 0.15)    # a second line near a steady one refuses it when it explains this many times the
                           # noise (whitened squared error) and has this share of its amplitude. Measured on
                           # 32 synth forced vibrations (8 bases): 0.1-18.6 (shares 0.01-0.30); periodic knocks
                           # 68-5600 (shares 0.26-0.87): a knock train is a comb of lines 1/period apart


SIDEBAND_FREQS = 4000       # at most this many frequencies in the scan (a 10^7-row record spans 10^4 s)


def _sideband_check(g, t, y, f, t0, t1, oversample=2):
    """A steady source is one line: after it is fitted, the band around it (±max(1.5 Hz, 30 %)) holds
    noise only. A ring that restarts every P seconds (a knock train, a press next door) is a comb of
    lines 1/P apart, all locked together; a single line takes one of them and leaves its neighbours,
    which a scan of the residual finds far above noise (``y`` whitened: a line of pure noise explains
    about 2). Far more sensitive than the windows of :func:`_steady_line_check` where the tracker
    sees a few samples per cycle. On a record longer than the scan's grid resolves with
    :data:`SIDEBAND_FREQS` frequencies (667 s for a line under 5 Hz), it scans the stretch of that
    length about the record's middle sample, where a comb 1/period apart shows as well. Returns the
    reasons (empty: one line)."""
    m = g != 0
    ts, gs, ys = t[m], g[m], y[m]
    T = float(t1 - t0)
    if T <= 0 or len(ts) < 24:
        return []
    w = 2 * np.pi * f
    X = np.stack([gs * np.sin(w * ts), gs * np.cos(w * ts)], 1)
    c = _lstsq(X, ys)
    amp0 = float(np.hypot(*c))
    r = ys - X @ c
    half = max(1.5, 0.3 * f)
    longest = SIDEBAND_FREQS / (2 * half * oversample)     # the record the scan's grid resolves
    if T > longest:        # a long record: the scan looks at a stretch of that length about its
        k = len(ts) // 2                  # middle sample (a recording kept as runs: not in a gap)
        mid = float(np.partition(ts, k)[k])
        inside = np.abs(ts - mid) <= 0.5 * longest
        ts, gs, r, T = ts[inside], gs[inside], r[inside], longest
        if len(ts) < 24:
            return []
    fr = np.arange(max(f - half, 1.0 / T), f + half, 1.0 / (oversample * T))
    fr = fr[np.abs(fr - f) > 1.5 / T]
    if not len(fr) or amp0 <= 0:
        return []
    best = (0.0, 0.0, 0.0)
    for lo in range(0, len(fr), 128):         # frequencies in chunks: (128, n) at a time
        ph = 2 * np.pi * fr[lo:lo + 128, None] * ts[None, :]
        S, C = gs * np.sin(ph), gs * np.cos(ph)
        a11, a12, a22 = (S * S).sum(1), (S * C).sum(1), (C * C).sum(1)
        b1, b2 = S @ r, C @ r
        det = a11 * a22 - a12 ** 2
        ok = det > 1e-12 * np.maximum(a11 * a22, 1e-300)
        det = np.where(ok, det, 1.0)
        cs, cc = (a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det
        gain = np.where(ok, cs * b1 + cc * b2, 0.0)      # the squared error the line removes
        i = int(np.argmax(gain))
        if gain[i] > best[0]:
            best = (float(gain[i]), float(fr[lo + i]), float(np.hypot(cs[i], cc[i])))
    gain, fq, amp = best
    if gain < SIDEBAND[0] or amp < SIDEBAND[1] * amp0:
        return []
    return [f"it is not alone: a second line at {fq:.2f} Hz, {abs(fq - f):.2f} Hz away with {amp / amp0:.2f} of its "
            f"amplitude, explains {gain:.0f}x the noise (a line of noise: about 2). A steady source is one line; "
            f"a ring that restarts every {1 / abs(fq - f):.2f} s (periodic knocks) is a comb of them"]


STEADY_CHI2 = (2.5, 5.0)   # windows' scatter about the whole record's line, per degree of freedom: above the
                           # first with an amplitude that visibly rises and dies (10th percentile of the
                           # windows under STEADY_P10 of the 90th), or above the second alone, a line is not
                           # one steady sinusoid. Measured: steady synth lines 0.06-1.4 (2.9 under coloured
                           # noise and jitter, amplitudes 0.60); periodic knocks 3.2-62 (amplitudes 0.12-0.43)
STEADY_P10 = 0.5


STEADY_WIN_ROWS = 16       # a window holds at least this many of the line's samples (a 50 Hz tracker saw a
                           # 10 Hz knock train at 10 samples per 2-cycle window: every window was too thin to
                           # count, and the check passed by default)


def _steady_line_check(g, t, y, f, t0, t1, cycles=2.0, min_window_s=0.2):
    """A steady source is one sinusoid: its phase and amplitude hold over the record. Fitted on short
    windows (``cycles`` periods, at least ``min_window_s`` and STEADY_WIN_ROWS samples), every window's sine and cosine
    coefficients are the whole record's, up to the window's noise (``y`` is whitened: unit noise, so
    a window's coefficient covariance is (A^T A)^-1 of its 2x2 normal matrix A^T A). Rings that
    restart and die away (periodic knocks, a press next door) scatter the windows far beyond that,
    even where one window's line is at its noise. Returns the reasons it is not steady (empty: steady)."""
    m_all = g != 0
    ts, gs, ys = t[m_all], g[m_all], y[m_all]
    wl = max(cycles / f, min_window_s, STEADY_WIN_ROWS * (t1 - t0) / max(len(ts), 1))
    nwin = int((t1 - t0) // wl)
    if nwin < 4:
        return []
    k = np.minimum(((ts - t0) // wl).astype(int), nwin - 1)
    w = 2 * np.pi * f
    S, C = gs * np.sin(w * ts), gs * np.cos(w * ts)
    # per-window 2x2 normal equations, all windows at once
    a11 = np.bincount(k, S * S, nwin)
    a12 = np.bincount(k, S * C, nwin)
    a22 = np.bincount(k, C * C, nwin)
    b1 = np.bincount(k, S * ys, nwin)
    b2 = np.bincount(k, C * ys, nwin)
    det = a11 * a22 - a12 ** 2
    ok = (np.bincount(k, minlength=nwin) >= 12) & (det > 1e-12 * np.maximum(a11 * a22, 1e-300))
    if ok.sum() < 4:
        return []
    a11, a12, a22, b1, b2, det = (v[ok] for v in (a11, a12, a22, b1, b2, det))
    cs = (a22 * b1 - a12 * b2) / det
    cc = (a11 * b2 - a12 * b1) / det
    cg = _lstsq(np.stack([S, C], 1), ys)
    ds, dc = cs - cg[0], cc - cg[1]
    chi = float(np.mean(a11 * ds * ds + 2 * a12 * ds * dc + a22 * dc * dc) / 2.0)
    if chi <= STEADY_CHI2[0]:
        return []
    amp = np.hypot(cs, cc)
    p10, p90 = np.percentile(amp, [10, 90])
    if chi <= STEADY_CHI2[1] and p10 >= STEADY_P10 * p90:
        return []
    return [f"its phase and amplitude do not hold over the record: {wl:.2g} s windows scatter about the whole "
            f"record's line {chi:.1f}x their noise (steady: about 1; window amplitudes from {p10 / max(p90, 1e-300):.2f} "
            f"to 1 of the largest): rings that restart, such as periodic knocks, not a steady source"]


class Geometry(Candidate):
    """Kinematic parameter deltas of one chain (a parameter group) or of the tool."""

    effect = "geometry"
    target_key = "chain"
    NAMES = {"length_offset": ["length_offset_mm"], "base_joint": ["base_joint_radial_mm", "base_joint_z_mm"],
             "platform_joint": ["platform_joint_mm"], "length": ["tool_length_mm"], "tilt": ["tool_tilt_deg"]}

    def __init__(self, group):
        who, what = group.split(":")
        super().__init__(int(who[5:]) if who.startswith("chain") else "tool")
        self.group, self.what = group, what

    @property
    def label(self):
        return f"geometry[{self.group}]"

    def key(self):
        return (self.effect, "chain", self.target, self.what)

    def applicable(self, ctx):
        return any(c in ctx.obs.channels for c in TOOL_ROWS)

    def design(self, ctx):
        o = ctx.obs
        S = ctx.geo[self.group]
        X = np.zeros((len(o.y), S.shape[-1]))
        for name, r in TOOL_ROWS.items():
            if name in o.channels:
                m = o.ch == o.channels.index(name)
                X[m] = S[o.pos[m], r, :] * o.w[m, None]
        return X

    def params_of(self, c, ctx):
        v = [float(x) for x in c]
        names = self.NAMES[self.what]
        if len(names) == len(v):
            return dict(zip(names, v))
        return {names[0]: v[0] if len(v) == 1 else v}


GAIN_SIGNAL_MIN = 3.0    # a gain is tried where the predicted signal is this many times its own noise


class SensorGain(Candidate):
    """A channel reads g times the signal: δ = (g − 1)·prediction.

    Applicable only where the predicted signal (its rms about zero: a steady level counts, and a
    gain on it is an offset's look-alike) is more than :data:`GAIN_SIGNAL_MIN` times the noise the
    prediction itself carries. Where it is not (the i component of a tool direction that a job
    without tilts keeps vertical, predicted from encoders with their noise), a "gain" of about 0
    would explain that noise, not the sensor (a sim run read tool_i as "−1000007 ppm of its
    predicted value" with confidence 0.97)."""

    effect = "sensor_gain"
    target_key = "channel"

    def applicable(self, ctx):
        o = ctx.obs
        if self.target not in o.channels:
            return False
        from pmctl.tools.twin.locate import noise_level     # (locate imports this module)
        m = o.mask_of(self.target)
        p = o.pred[m][np.argsort(o.row[m], kind="stable")]     # in time order: its own noise from 2nd differences
        return np.ptp(p) > 0 and float(np.sqrt(np.mean(p * p))) > GAIN_SIGNAL_MIN * noise_level(p)

    def design(self, ctx):
        o = ctx.obs
        m = o.mask_of(self.target)
        return (np.where(m, o.pred * o.w, 0.0))[:, None]

    def params_of(self, c, ctx):
        return {"gain": 1.0 + float(c[0])}


class SensorOffset(Candidate):
    effect = "sensor_offset"
    target_key = "channel"

    def applicable(self, ctx):
        return self.target in ctx.obs.channels

    def design(self, ctx):
        o = ctx.obs
        return np.where(o.mask_of(self.target), o.w, 0.0)[:, None]

    def params_of(self, c, ctx):
        return {"offset": float(c[0])}


def catalogue(ctx: Context) -> list[Candidate]:
    """Every applicable candidate for this recording (effect × target)."""
    cands: list[Candidate] = []
    for grp in ctx.geo:
        cands.append(Geometry(grp))
    for ax in AXES:
        cands += [Backlash(ax), PitchError(ax), PeriodicError(ax), ServoLag(ax), Friction(ax), LostSteps(ax),
                  Resonance(ax, "axis"), ForcedVibration(ax, "axis")]
        cands.append(Compliance(ax))
        for tc in ctx.temps:
            cands.append(ThermalGrowth(ax, tc))
    for c in ctx.obs.channels:
        if c.startswith("strain_"):
            cands += [Resonance(c, "channel"), ForcedVibration(c, "channel"), SensorLatency(c)]
        cands += [SensorGain(c), SensorOffset(c), SensorDrift(c)]
    cands.append(SensorLatency("tip_*"))
    return [c for c in cands if c.applicable(ctx)]
