"""Where does the recording differ from the nominal twin? (issue 4, item 3). Pure math, no I/O.

Works on the fitting :class:`pmctl.tools.twin.effects.Context` (residual = measured - nominal, per
channel; tracker channels sparse). Breakdowns, all in channel units:

- per channel: RMS, robust noise level (MAD of the second difference of the sampled residual, so
  slow errors do not count as noise), excess over noise;
- per axis: the motor-side residual (enc - cmd) and the equivalent load-side error along the axis
  seen by the tool channels (least-squares projection through J_tool);
- per time window: where the moving RMS of a channel's residual exceeds 2.5 x its noise;
- per pose region: terciles of platform height Z, tilt |θ2| and table X, Y;
- per direction of motion of each axis: mean residual while moving + and -, with its t-value;
- spectrum against time (Welch on a uniform grid) and against each screw's position (the
  axis-projected residual binned on a uniform grid of screw position while that screw moves).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal

from pmctl.tools.twin.effects import Context, axis_gain, axis_names, axis_velocity, welch_runs

MAD_K = 1.4826


def noise_level(x, floor=0.0):
    """Robust white-noise level of a sequence (NaN ignored): MAD of second differences / √6."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if len(x) < 5:
        return max(float(np.std(x)) if len(x) else 0.0, floor)
    d2 = x[2:] - 2 * x[1:-1] + x[:-2]
    s = MAD_K * float(np.median(np.abs(d2 - np.median(d2)))) / math.sqrt(6)
    return max(s, floor)


def moving_rms(x, n):
    n = max(1, int(n))
    c = np.concatenate([[0.0], np.cumsum(x * x)])
    k = np.arange(len(x))
    lo = np.clip(k - n // 2, 0, len(x))
    hi = np.clip(k + n // 2 + 1, 0, len(x))
    return np.sqrt((c[hi] - c[lo]) / np.maximum(hi - lo, 1))


def windows(t, flag, min_gap, max_n=6):
    """Contiguous [start, end] time spans where flag is true, merging gaps shorter than min_gap."""
    if not np.any(flag):
        return []
    idx = np.nonzero(flag)[0]
    breaks = np.nonzero(np.diff(t[idx]) > min_gap)[0]
    starts = np.concatenate([[idx[0]], idx[breaks + 1]])
    ends = np.concatenate([idx[breaks], [idx[-1]]])
    spans = [[float(t[a]), float(t[b])] for a, b in zip(starts, ends)]
    spans.sort(key=lambda s: s[1] - s[0], reverse=True)
    return sorted(spans[:max_n])


def channel_series(ctx: Context, name, y=None):
    """(t, residual in channel units) of one channel at its analysis samples, time-ordered."""
    o = ctx.obs
    m = o.ch == o.channels.index(name)
    yy = (o.y if y is None else y)[m] / o.w[m]
    order = np.argsort(o.row[m], kind="stable")
    return ctx.t[o.row[m][order]], yy[order]


def axis_projection(ctx: Context, a, y=None, site="load"):
    """Per analysis row: the error on actuator a that best explains the residual by itself (mm)."""
    o = ctx.obs
    yy = o.y if y is None else y
    g = axis_gain(ctx, a, site)
    m = g != 0
    if not np.any(m):
        return np.array([]), np.array([]), np.array([], int)
    num = np.bincount(o.row[m], g[m] * yy[m], minlength=len(ctx.t))
    den = np.bincount(o.row[m], g[m] ** 2, minlength=len(ctx.t))
    rows = np.nonzero(den > 0)[0]
    return ctx.t[rows], num[rows] / den[rows], rows


def spectrum_time(t, x, cuts=None):
    """Welch spectrum of an (irregularly sampled) series after interpolation to its median step
    (``cuts``: run starts of a recording kept as runs, see effects.welch_runs)."""
    if len(x) < 64:
        return None
    return welch_runs(t, x, cuts)


def spectrum_position(pos, x, moving):
    """Spectrum of x against screw position: bin means on a uniform position grid (moving samples),
    then a periodogram. Returns (cycles/mm, amplitude mm) or None."""
    pos, x = pos[moving], x[moving]
    if len(pos) < 64 or np.ptp(pos) <= 0:
        return None
    steps = np.abs(np.diff(np.sort(np.unique(pos))))
    d = max(float(np.median(steps)) if len(steps) else 0.0, np.ptp(pos) / 20000)
    nb = int(np.ptp(pos) / d) + 1
    b = np.minimum(((pos - pos.min()) / d).astype(int), nb - 1)
    cnt = np.bincount(b, minlength=nb)
    s = np.bincount(b, x, minlength=nb)
    ok = cnt > 0
    if ok.sum() < 32:
        return None
    grid = np.arange(nb) * d
    xu = np.interp(grid, grid[ok], s[ok] / cnt[ok])
    xu = signal.detrend(xu)
    spec = np.abs(np.fft.rfft(xu * np.hanning(len(xu)))) * 2 / (0.5 * len(xu))
    f = np.fft.rfftfreq(len(xu), d)
    return f, spec


def _peak(f, p, fmin):
    m = f >= fmin
    if not np.any(m):
        return None, 0.0
    fm, pm = f[m], p[m]
    k = int(np.argmax(pm))
    med = float(np.median(pm)) or 1e-300
    return float(fm[k]), float(pm[k] / med)


def locate(ctx: Context, y=None) -> dict:
    """All breakdowns of the residual ``y`` (whitened, default: the nominal residual)."""
    o = ctx.obs
    yy = o.y if y is None else y
    out = {"channels": {}, "axes": {}, "regions": {}, "direction": {}, "windows_s": []}
    tspan = max(ctx.duration, 1e-9)
    all_flags_t = []
    for name in o.channels:
        t, r = channel_series(ctx, name, yy)
        sig = o.sigma[name]
        # excess and windows against each sample's own noise (the whitened residual: a tool_*
        # component's noise changes with the tilt, diagnose.noise_scale)
        m = o.ch == o.channels.index(name)
        rw = yy[m][np.argsort(o.row[m], kind="stable")]
        rms = float(np.sqrt(np.mean(r * r))) if len(r) else 0.0
        msw = float(np.mean(rw * rw)) if len(rw) else 0.0
        excess = math.sqrt(max(msw - 1.0, 0.0)) if sig > 0 else 0.0
        info = {"n": int(len(r)), "rms": rms, "noise": sig, "excess": excess, "mean": float(np.mean(r)) if len(r) else 0}
        nwin = max(5, len(r) // 100)
        flag = moving_rms(rw, nwin) > 2.5 if len(r) else np.zeros(0, bool)
        info["windows_s"] = windows(t, flag, tspan / 50)
        if flag.any():
            all_flags_t.append(t[flag])
        sp = spectrum_time(t, r, ctx.extra.get("cuts"))
        if sp is not None:
            f, p = sp
            fpk, ratio = _peak(f, p, 2 * (f[1] - f[0]) if len(f) > 1 else 0)
            info["spectrum_peak_hz"] = fpk
            info["spectrum_peak_ratio"] = ratio
        out["channels"][name] = info
    if all_flags_t:
        tt = np.sort(np.concatenate(all_flags_t))
        out["windows_s"] = windows(tt, np.ones(len(tt), bool), tspan / 50)
    # per axis: motor side and load side as the tool sees it
    for a, ax in enumerate(axis_names(ctx)):
        info = {}
        enc = f"enc_{ax}"
        if enc in o.channels:
            _, r = channel_series(ctx, enc, yy)
            info["enc_rms_mm"] = float(np.sqrt(np.mean(r * r)))
        tp, e, rows = axis_projection(ctx, a, yy)
        if len(e):
            info["tool_equiv_rms_mm"] = float(np.sqrt(np.mean(e * e)))
            x = ctx.q_cmd[rows, a]
            v = axis_velocity(ctx, a)[rows]
            vs = np.abs(v) > 1e-3 * max(np.max(np.abs(v)), 1e-12)
            plus, minus = vs & (v > 0), vs & (v < 0)
            if plus.sum() > 3 and minus.sum() > 3:
                d = float(np.mean(e[plus]) - np.mean(e[minus]))
                se = math.sqrt(np.var(e[plus]) / plus.sum() + np.var(e[minus]) / minus.sum()) or 1e-300
                out["direction"][ax] = {"mean_plus_mm": float(np.mean(e[plus])),
                                        "mean_minus_mm": float(np.mean(e[minus])),
                                        "jump_mm": d, "t_value": d / se}
            sp = spectrum_position(x, e, vs)
            if sp is not None:
                f, amp = sp
                fpk, ratio = _peak(f, amp, 2 * (f[1] - f[0]))
                if fpk:
                    info["screw_peak_per_mm"] = fpk
                    info["screw_peak_period_mm"] = 1 / fpk
                    info["screw_peak_ratio"] = ratio
                info["_screw_spectrum"] = (f, amp)
        out["axes"][ax] = info
    # pose regions: terciles of Z, |theta2|, X, Y; whitened total residual energy per region
    P = ctx.extra.get("P")
    R = ctx.extra.get("R")
    feats = {}
    if P is not None:
        feats["Z_mm"] = P[:, 2]
        feats["tilt_deg"] = np.degrees(np.arccos(np.clip(R[:, 2, 2], -1, 1)))
    if "axes" in ctx.extra:          # a machine of independent axes: each axis' position
        for a, ax in enumerate(ctx.extra["axes"]):
            feats[f"{ax}_{ctx.machine.pos_unit(ax)}"] = ctx.q_cmd[ctx.rows, a]
        out["servo"] = servo_tracking(ctx, yy)
    else:
        feats["X_mm"] = ctx.q_cmd[ctx.rows, 3]
        feats["Y_mm"] = ctx.q_cmd[ctx.rows, 4]
    for k, v in feats.items():
        vals = v[o.pos]
        if len(vals) == 0 or np.ptp(vals) <= 0:
            continue
        q = np.quantile(vals, [0, 1 / 3, 2 / 3, 1])
        regs = []
        for i in range(3):
            m = (vals >= q[i]) & (vals <= q[i + 1])
            if m.sum():
                regs.append({"range": [float(q[i]), float(q[i + 1])],
                             "rms_over_noise": float(np.sqrt(np.mean(yy[m] ** 2)))})
        out["regions"][k] = regs
    return out


def servo_tracking(ctx: Context, y) -> dict:
    """Per axis with an encoder (a machine of independent axes): the following error enc − cmd, its
    rms and its least-squares dependence on the command's velocity and acceleration
    (fe ≈ −(lag·v + k_a·a)): the servo's tracking as a table, before any finding."""
    o = ctx.obs
    out = {}
    for a, ax in enumerate(axis_names(ctx)):
        name = f"enc_{ax}"
        if name not in o.channels:
            continue
        m = o.ch == o.channels.index(name)
        r = o.row[m]
        e = y[m] / o.w[m]
        v = axis_velocity(ctx, a)[r]
        acc = np.gradient(axis_velocity(ctx, a), ctx.t)[r]
        X = np.stack([-v, -acc, np.ones_like(v)], 1)
        ok = np.all(np.isfinite(X), 1)
        c = np.linalg.lstsq(X[ok], e[ok], rcond=None)[0] if ok.sum() > 3 else np.zeros(3)
        vmax = float(np.max(np.abs(v))) if len(v) else 0.0
        out[ax] = {"fe_rms": float(np.sqrt(np.mean(e * e))) if len(e) else 0.0,
                   "fe_max": float(np.max(np.abs(e))) if len(e) else 0.0,
                   "lag_s": float(c[0]), "accel_lag_s2": float(c[1]), "v_max": vmax}
    return out
