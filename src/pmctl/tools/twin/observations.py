"""The observations of a diagnosis (pure math, no I/O): the stacked, whitened residual of the measured
channels (effects.Obs) and the sample bookkeeping (regular times, settled rows, runs) that the
prototype's context (pmctl.tools.twin.diagnose) and a generic machine's (pmctl.tools.twin.axes) share."""

from __future__ import annotations

import numpy as np

from pmctl.tools.twin.effects import Obs
from pmctl.tools.twin.signals import noise_level

MARGIN_S = 1.0          # analysis rows start this long (at most 10 %) after each run's first row


TOOL_SCALE_FLOOR = 0.25  # a tool_* element's noise scale is at least this share of the channel's median


def noise_scale(name, pred) -> np.ndarray:
    """Relative noise of each sample of a channel (1 for most). A ``tool_*`` channel is a component
    c of the measured unit tool axis: a tracker's angular noise σ, isotropic and renormalised onto
    the unit sphere, moves that component by σ·√(1 − c²). So tool_k of an axis near vertical is
    far quieter than tool_i and tool_j, and grows with the tilt: a calibration run that tilts the
    platform early and then stays near level has a tool_k noise that changes several-fold within
    the run. Returned relative to the channel's median (the median element is 1), floored at
    TOOL_SCALE_FLOOR of it (an axis exactly vertical still has the prediction's own error)."""
    pred = np.asarray(pred, float)
    if not name.startswith("tool_") or not len(pred):
        return np.ones(len(pred))
    s = np.sqrt(np.clip(1.0 - pred * pred, 0.0, 1.0))
    med = float(np.median(s[np.isfinite(s)])) if np.isfinite(s).any() else 0.0
    if not med > 0:
        return np.ones(len(pred))
    return np.maximum(np.nan_to_num(s / med, nan=1.0), TOOL_SCALE_FLOOR)


def _spread(idx, cap):
    if len(idx) <= cap:
        return idx
    return idx[np.linspace(0, len(idx) - 1, cap).round().astype(int)]


def _noise_rows(idx, n_chunks=8, chunk=2500):
    """Runs of consecutive sampled indices (for the noise estimate), spread over the record."""
    if len(idx) <= n_chunks * chunk:
        return [idx]
    starts = np.linspace(0, len(idx) - chunk, n_chunks).astype(int)
    return [idx[s:s + chunk] for s in starts]


JITTER_MAX = 0.25       # time stamps this close (in steps) to a fixed-rate grid are put onto it


def regular_times(t) -> np.ndarray:
    """The sample times of a fixed-rate log whose time stamps jitter (a logger's clock read late or
    early) and which may have lost rows: when every step is within JITTER_MAX of a whole number of
    the median step, the times on that grid (index by the rounded steps, step and origin by least
    squares), else ``t`` unchanged. The controller sampled cmd_* and the drives on its ticks, so the
    grid is when they were sampled; a derivative of cmd_* against the jittered stamps is noise (±10 %
    of a step at 50 mm/s is 20 µm of position, 10³ mm/s² of acceleration at 250 Hz)."""
    t = np.asarray(t, float)
    if len(t) < 3:
        return t
    d = np.diff(t)
    med = float(np.median(d))
    if not med > 0:
        return t
    k = np.rint(d / med)
    if np.any(k < 1) or np.max(np.abs(d / med - k)) > 2 * JITTER_MAX:
        return t
    idx = np.concatenate([[0.0], np.cumsum(k)])
    A = np.stack([np.ones_like(idx), idx], 1)
    (t0, step), *_ = np.linalg.lstsq(A, t, rcond=None)
    if not step > 0 or np.max(np.abs(t - (t0 + step * idx))) > JITTER_MAX * step:
        return t
    return t0 + step * idx


def observations(columns, obs_names, predict_at, settled, cap, floor):
    """The stacked, whitened residual of the measured channels (effects.Obs), shared by the
    prototype's context and a generic machine's (pmctl.tools.twin.axes). A channel counts when it
    has at least 10 settled samples that are not all one value; at most ``cap`` of them, evenly
    spread, are analysed. ``predict_at(rows, names) -> (columns at rows, {name: prediction})`` is
    the nominal twin at the given rows (``settled``: the rows that may be analysed, or a dict of
    them per channel); each channel's noise level is the median of the robust level
    of its residual over a few stretches (:func:`_noise_rows`), at least ``floor(name)``.
    Returns (obs, analysis rows, rows predicted, {channel: its sampled rows})."""
    sampled, ana, noi = {}, {}, {}
    for k in obs_names:
        col = np.asarray(columns[k], float)
        ok = np.flatnonzero(np.isfinite(col) & (settled[k] if isinstance(settled, dict) else settled))
        if len(ok) < 10 or np.ptp(col[ok]) == 0.0:
            continue        # not sampled: all empty, or one value throughout (a backend without gauges wrote 0)
        sampled[k] = ok
        ana[k] = _spread(ok, cap)
        noi[k] = _noise_rows(ok)
    names = list(sampled)
    rows_all = np.unique(np.concatenate([ana[k] for k in names] + [c for k in names for c in noi[k]])) \
        if names else np.zeros(0, int)
    sub, pred = predict_at(rows_all, names)
    sig, scale = {}, {}
    for k in names:
        scale[k] = noise_scale(k, pred[k])     # per sample, relative to the channel's noise sig[k]
        r = (sub[k] - pred[k]) / scale[k]
        parts = [r[np.searchsorted(rows_all, c)] for c in noi[k]]
        sig[k] = float(np.median([noise_level(p, floor(k)) for p in parts]))
    rows = np.unique(np.concatenate([ana[k] for k in names])) if names else np.zeros(0, int)
    ys, chs, rws, ws, preds = [], [], [], [], []
    for ci, k in enumerate(names):
        j = np.searchsorted(rows_all, ana[k])
        r = sub[k][j] - pred[k][j]
        good = np.isfinite(r)
        w = 1.0 / (sig[k] * scale[k][j][good])
        ys.append(r[good] * w)
        chs.append(np.full(good.sum(), ci))
        rws.append(ana[k][good])
        ws.append(w)
        preds.append(pred[k][j][good])

    def cat(lst, dt=float):
        return np.concatenate(lst) if lst else np.zeros(0, dt)

    row = cat(rws, int)
    obs = Obs(names, sig, cat(ys), cat(chs, int), row, np.searchsorted(rows, row), cat(ws), cat(preds))
    return obs, rows, rows_all, sampled


def settled_rows(t, bounds, runs):
    """Rows that may be analysed: all of one run; of a recording kept as runs, none in the first
    MARGIN_S (at most 10 %) of each run (what a lag or a mode carried over the gap is unknown)."""
    settled = np.ones(len(t), bool)
    if runs:
        for a, b in zip(bounds[:-1], bounds[1:]):
            if b > a:
                settled[a:np.searchsorted(t[a:b], t[a] + min(MARGIN_S, 0.1 * (t[b - 1] - t[a])), "left") + a] = False
    return settled


def uniform_step(t, bounds) -> float | None:
    """The sample step when ``t`` is uniform within its runs (a gap between two runs is no step)."""
    dt = np.diff(t)
    if len(bounds) > 2:
        dt = np.delete(dt, np.asarray(bounds[1:-1], int) - 1)
    return float(np.mean(dt)) if len(dt) and np.ptp(dt) <= 1e-6 * np.mean(dt) + 1e-12 else None


def record_runs(ctx, bounds, sampled, direction_before):
    """What a context keeps of how its rows were sampled: each channel's own step before the cap
    thinned it (``native_dt``: a tracker slower than the log, the Nyquist limit of what it saw) and,
    for a recording kept as runs, the run bounds, their start times and each axis' direction
    before each run."""
    t = ctx.t
    ctx.extra["native_dt"] = {k: float(np.median(np.diff(t[ok]))) for k, ok in sampled.items() if len(ok) > 2}
    if len(bounds) > 2:
        ctx.extra["bounds"] = bounds
        ctx.extra["cuts"] = t[bounds[1:-1]]
        if direction_before is not None:
            ctx.extra["direction_before"] = np.asarray(direction_before, float).reshape(len(bounds) - 1,
                                                                                      ctx.q_cmd.shape[1])
