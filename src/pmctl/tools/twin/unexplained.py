"""What the named effects leave unexplained: the report's ``unexplained`` block. Pure math.

After the selection, the residual of every channel (measured − nominal − accepted effects) is
compared with that channel's noise. A channel whose remaining residual is clearly above noise
(``excess_over_noise`` = √(rms² − σ²)/σ ≥ EXCESS_MIN, and the chi-square excess far beyond what
N noisy samples give) gets an entry with

- ``channels``, ``axis`` (the axis whose reversals, position or encoder carries it; else null),
- ``time_windows_s`` (where its moving RMS exceeds 2.5 x noise) and ``region`` (the pose tercile
  or axis position range where it is largest, when it is concentrated there),
- ``excess_over_noise``,
- ``signature``: the structure that explains most of it, measured by the fraction of the residual
  energy that a simple description of that kind removes:
  * ``delay`` — proportional to the time derivative of the channel's prediction (a time offset);
  * ``reversal-locked`` — a level that flips with an axis' direction of motion, or a transient
    or a spike after its reversals;
  * ``spectral line F Hz`` — a sinusoid at the strongest line of its spectrum;
  * ``drift`` — a slow trend (a 10-knot piecewise-linear function of time);
  * ``position-dependent`` — a smooth function of one axis' position;
  * ``step at T s`` — one level before an instant, another after (what a single level leaves:
    an offset is no step); a crash or a lost reference seen by a drive's count;
  * ``intermittent (K bursts)`` — two or more short stretches above noise, together under a
    quarter of the run, holding the excess (an encoder that miscounts now and then);
  * ``transient`` — a channel that is clean except in one stretch of the run (judged inside that
    stretch, where a line there is still reported as a spectral line);
  * ``burst`` (``burst after a reversal of AX``) — one stretch of 10 to 19 samples, too short for
    its structure to be judged, but over 3.2 x noise and 25 σ beyond it counted with the noise's
    correlation in time (a spike after the one reversal of a short run);
  a channel whose excess has none of these structures (none removes 30 %) is not reported: that
  is a noise model that is off (coloured noise, coarse quantisation), not physics; a channel
  clean but for a few short stretches is judged on those stretches together (30 % + 12/n of
  their n samples),
- ``evidence``: what was seen, the fractions, and the catalogue effects that were tried there and
  why they were refused (their own checks), so that a reader does not chase the nearest name.
"""

from __future__ import annotations

import math

import numpy as np

from pmctl.tools.twin.effects import (Context, _line_frequencies, _lstsq, axis_direction, axis_names, lstsq_rank,
                                      refine_max)

EXCESS_MIN = 1.0        # remaining rms ≥ 1.41 x noise ...
CHI_SIGMA = 8.0         # ... and Σ(y²) − N beyond 8 standard deviations of noise (√(2N))
STRUCT_MIN = 0.3        # a signature must remove this fraction of the remaining energy


def _frac(X, y):
    """Fraction of y's energy that least squares on the columns X removes."""
    if X.shape[0] < X.shape[1] + 2 or not (np.all(np.isfinite(X)) and np.all(np.isfinite(y))):
        return 0.0
    try:
        c = _lstsq(X, y)
    except np.linalg.LinAlgError:
        return 0.0
    r = y - X @ c
    e = float(y @ y)
    return max(0.0, 1.0 - float(r @ r) / e) if e > 0 else 0.0


def _hat(t, knots):
    """Piecewise-linear (hat function) basis in t with the given knots."""
    B = np.zeros((len(t), len(knots)))
    for k, c in enumerate(knots):
        lo = knots[k - 1] if k > 0 else c - 1e-12
        hi = knots[k + 1] if k + 1 < len(knots) else c + 1e-12
        up = (t - lo) / max(c - lo, 1e-12)
        dn = (hi - t) / max(hi - c, 1e-12)
        B[:, k] = np.clip(np.minimum(up if k > 0 else 1.0, dn if k + 1 < len(knots) else 1.0), 0, 1)
    return B


def _step(tt, yy, edge=0.05):
    """(fraction of the energy that a level, a linear trend and a step at one instant remove, that
    instant) — the best instant with at least ``edge`` of the samples on each side; 0 when the step
    removes less than STRUCT_MIN of what the level and the trend leave (an offset or a steady
    drift is no step; a step left over by a fitted offset and drift still is)."""
    n = len(yy)
    e = float(yy @ yy)
    lo = max(int(edge * n), 3)
    if n < 2 * lo + 2 or e <= 0 or np.ptp(tt) <= 0:
        return (0.0, None)
    Q, _ = np.linalg.qr(np.stack([np.ones(n), (tt - tt.mean()) / np.ptp(tt)], 1))
    r = yy - Q @ (Q.T @ yy)
    rr = float(r @ r)
    if rr <= 0:
        return (0.0, None)
    # H_i = 1 from sample i on; h_i = H_i minus its projection on the level and trend:
    # h_i·r = Σ_{j≥i} r_j (r is orthogonal to both), h_i·h_i = (n − i) − |Qᵀ H_i|²
    tail = lambda x: np.cumsum(x[::-1])[::-1]            # noqa: E731  (Σ_{j≥i} x_j)
    sr, q1, q2 = tail(r), tail(Q[:, 0]), tail(Q[:, 1])
    i = np.arange(lo, n - lo)
    hh = (n - i) - q1[i] ** 2 - q2[i] ** 2
    gain = np.where(hh > 1e-9, sr[i] ** 2 / np.maximum(hh, 1e-9), 0.0)
    k = int(np.argmax(gain))
    if gain[k] / rr < STRUCT_MIN:
        return (0.0, None)
    j = i[k]
    return (float((e - rr + gain[k]) / e), 0.5 * float(tt[j - 1] + tt[j]))


def _bursts(tt, yy, wins, duration):
    """(fraction of the energy inside the windows, their number) when the channel's excess lives in
    two or more short stretches that together last less than a quarter of the run; else (0, None)."""
    if len(wins) < 2 or sum(b - a for a, b in wins) > 0.25 * duration:
        return (0.0, None)
    pad = 0.01 * duration
    inside = np.zeros(len(tt), bool)
    for a, b in wins:
        inside |= (tt >= a - pad) & (tt <= b + pad)
    e = float(yy @ yy)
    if e <= 0:
        return (0.0, None)
    # the noise inside the windows is not structure: count only the excess there
    ex = float(yy[inside] @ yy[inside]) - inside.sum()
    return (max(ex, 0.0) / e, len(wins))


def _refined_line(tt, yy, f0, n=61):
    """(fraction of the energy, frequency) of the best line near a spectral peak f0. The Welch
    spectrum's bins are coarse (a few tenths of a hertz on a record, about 1 Hz on a one-second
    stretch), and a line fitted half a bin off takes far less than it should: a 14.4 Hz burst in a
    one-second stretch, fitted at its peak's 14.9 Hz, took 38 % of the stretch's energy instead of
    about 90 %. So the fit scans ±max(2/span, 3 %) around the peak, then refines the best step."""
    def frac(f):
        return _frac(np.stack([np.sin(2 * np.pi * f * tt), np.cos(2 * np.pi * f * tt)], 1), yy)
    half = max(2.0 / max(float(np.ptp(tt)), 1e-9), 0.03 * f0)
    grid = np.linspace(max(f0 - half, 1e-3), f0 + half, n)
    i = int(np.argmax([frac(f) for f in grid]))
    step = grid[1] - grid[0]
    f, best = refine_max(frac, float(grid[i]), step, xatol=1e-4 * step)
    return float(best), float(f)


def _signatures(ctx: Context, name: str, m: np.ndarray, y: np.ndarray, wins=()) -> dict:
    """Fraction of the channel's remaining (whitened) energy each kind of structure removes, with
    its detail (delay, axis, frequency, instant, number of bursts); ``wins``: the channel's windows
    above noise (locate), for the intermittent signature."""
    o = ctx.obs
    idx = np.flatnonzero(m)
    idx = idx[np.argsort(o.row[idx], kind="stable")]
    yy = y[idx]
    rows = o.row[idx]
    tt = ctx.t[rows]
    w = o.w[idx]
    out = {}
    # delay: residual ∝ d(prediction)/dt
    pr = o.pred[idx]
    if len(tt) > 3 and np.ptp(tt) > 0:
        dp = np.gradient(pr, tt) * w
        out["delay"] = (_frac(dp[:, None], yy), float(_lstsq(-dp[:, None], yy)[0]) if np.any(dp) else 0.0)
    # reversal-locked, per axis: a level flipping with the direction, and a decaying transient
    best = (0.0, None)
    for a, ax in enumerate(axis_names(ctx)):
        x = ctx.q_cmd[:, a]
        if np.ptp(x) <= 0:
            continue
        d = axis_direction(ctx, a)
        if not np.any(d):
            continue
        flips = np.flatnonzero(np.diff(d) != 0) + 1
        since = np.full(len(x), np.inf)
        if len(flips):
            mark = np.zeros(len(x), int)
            mark[flips] = flips
            last = np.maximum.accumulate(mark)
            since = np.where(last > 0, ctx.t - ctx.t[last], np.inf)
        s = np.minimum(since[rows], 1e3)          # (before the first reversal: long ago)
        dd = d[rows]
        X = np.stack([dd, dd * np.exp(-s / 0.05), dd * np.exp(-s / 0.3),       # a level, decaying transients
                      dd * (s / 0.02) * np.exp(-s / 0.02), dd * (s / 0.06) * np.exp(-s / 0.06),   # a spike
                      np.ones(len(rows))], 1)
        f = _frac(X, yy) - _frac(X[:, 5:], yy)
        if f > best[0]:
            best = (f, ax)
    out["reversal-locked"] = best
    # spectral line
    fl = _line_frequencies(tt, yy, fmin=0.5, k=1, ratio_min=10.0, cuts=ctx.extra.get("cuts"))
    if fl:
        out["spectral line"] = _refined_line(tt, yy, fl[0])
    # drift: slow trend in time
    if np.ptp(tt) > 0:
        knots = np.linspace(tt[0], tt[-1], 10)
        out["drift"] = (_frac(_hat(tt, knots), yy), None)
    # step: one level before an instant, another after (what a level alone leaves)
    out["step"] = _step(tt, yy)
    out["intermittent"] = _bursts(tt, yy, wins, ctx.duration)
    # position-dependent: a smooth function of one axis' position (10 knots over its range)
    bestp = (0.0, None)
    for a, ax in enumerate(axis_names(ctx)):
        x = ctx.q_cmd[rows, a]
        if np.ptp(x) <= 0:
            continue
        knots = np.linspace(x.min(), x.max(), 10)
        f = _frac(_hat(x, knots), yy)
        if f > bestp[0]:
            bestp = (f, ax)
    out["position-dependent"] = bestp
    return out


def flexible_gain(ctx: Context, y: np.ndarray, channel_mask: np.ndarray, *, with_dof=False):
    """SSE that a flexible, physics-free description removes from y in the given channels (one
    fit per channel): 10-knot piecewise-linear functions of time and of each moving axis'
    position, plus a level per direction of motion of each axis. A named effect that removes only
    a small share of this is a partial description of something else. ``with_dof``: (gain, dof),
    dof the directions the fit uses summed over the channels fitted (:func:`lstsq_rank`: the hats of
    one variable sum to one, and hats of axes that move together are nearly dependent, so it is less
    than the columns), which is what it removes on average from white noise of unit variance (y is
    whitened)."""
    o = ctx.obs
    key = ("flex_basis",)
    if key not in ctx.extra:
        rows = ctx.rows
        tt = ctx.t[rows]
        cols = [_hat(tt, np.linspace(tt[0], tt[-1], 10))] if len(tt) and np.ptp(tt) > 0 else []
        for a in range(ctx.q_cmd.shape[1]):
            x = ctx.q_cmd[rows, a]
            if np.ptp(x) <= 0:
                continue
            cols.append(_hat(x, np.linspace(x.min(), x.max(), 8)))
            cols.append(axis_direction(ctx, a)[rows][:, None])
        ctx.extra[key] = np.concatenate(cols, 1) if cols else np.ones((len(rows), 1))
    B = ctx.extra[key]
    gain, dof = 0.0, 0
    for ci in np.flatnonzero(channel_mask):
        m = o.ch == ci
        if m.sum() <= B.shape[1] + 2:
            continue
        X = B[o.pos[m]]
        yy = y[m]
        c = _lstsq(X, yy)
        r = yy - X @ c
        gain += float(yy @ yy - r @ r)
        if with_dof:
            rk = ("flex_rank", int(ci))
            if rk not in ctx.extra:
                ctx.extra[rk] = lstsq_rank(X)
            dof += ctx.extra[rk]
    return (gain, dof) if with_dof else gain


def left_structure(ctx: Context, y: np.ndarray, channel_mask: np.ndarray) -> float:
    """log10(1 + g/n): g the energy the flexible description (:func:`flexible_gain`) still removes
    from the final residual y of the given channels, n their number of samples. About 0.01-0.05 when
    what is left is noise; large when a finding leaves its own channels clearly structured (a
    partial description of something else)."""
    n = int(channel_mask[ctx.obs.ch].sum())
    return math.log10(1.0 + flexible_gain(ctx, y, channel_mask) / n) if n else 0.0


def _region(ctx, loc_regions, name):
    best = None
    for k, regs in loc_regions.items():
        if len(regs) < 3:
            continue
        v = [r["rms_over_noise"] for r in regs]
        ratio = max(v) / max(min(v), 1e-12)
        if ratio > 2.0 and (best is None or ratio > best[0]):
            r = regs[int(np.argmax(v))]
            best = (ratio, f"{k[:-3] if k.endswith('_mm') or k.endswith('_deg') else k} in "
                           f"[{r['range'][0]:.1f}, {r['range'][1]:.1f}] {k.split('_')[-1]}")
    return best[1] if best else None


def _axis_of_channel(name):
    if name.startswith(("load_", "effort_", "acc_")):       # a machine of independent axes
        return name.split("_", 1)[1]
    if name.startswith("enc_"):
        return name[4:]
    if name.startswith("strain_"):
        return f"L{name[-1]}"
    return None


SHORT_N = 10            # a lone stretch of 10 to 19 samples ...
SHORT_EXCESS = 3.0      # ... is reported as a burst when its rms is over 3.2 x noise
SHORT_Z = 25.0          # ... and its chi-square excess is 25 σ with the noise's correlation in time


def _short_burst(ctx, y, m, mw):
    """(excess, {"burst": (fraction, axis reversed just before or None)}) of a lone stretch too short
    for its structure to be judged, when it stands far above noise; else None.

    The noise of a tracker is coloured (its samples correlate), so a short excursion of white-noise
    size is common; the chi-square excess of the stretch is judged against the effective number of
    independent samples n(1 − ρ)/(1 + ρ), ρ the lag-1 correlation of the channel's residual in time."""
    o = ctx.obs
    nw = int(mw.sum())
    ssw = float(y[mw] @ y[mw])
    exw = math.sqrt(max(ssw / nw - 1.0, 0.0))
    if exw < SHORT_EXCESS:
        return None
    tt = ctx.t[o.row]
    yy = y[m][np.argsort(tt[m], kind="stable")]
    rho = float(np.corrcoef(yy[:-1], yy[1:])[0, 1]) if len(yy) > 3 and np.std(yy) > 0 else 0.0
    rho = min(max(rho, 0.0), 0.95)
    neff = nw * (1 - rho) / (1 + rho)
    if (ssw / nw - 1.0) * neff < SHORT_Z * math.sqrt(2 * neff):
        return None
    a, b = float(tt[mw].min()), float(tt[mw].max())
    rev = None
    for j, ax in enumerate(axis_names(ctx)):          # an axis that reversed within 0.2 s before it, or in it
        d = axis_direction(ctx, j)
        sel = (ctx.t >= a - 0.2) & (ctx.t <= b)
        dd = d[sel][d[sel] != 0]
        if len(dd) > 1 and np.any(dd[1:] != dd[:-1]):
            rev = ax
            break
    return exw, {"burst": (1.0 - 1.0 / (ssw / nw), rev)}


def unexplained(ctx: Context, y: np.ndarray, loc_after: dict, rejected=()) -> list[dict]:
    """Entries for the channels the accepted effects leave clearly above noise (see module doc).

    ``rejected``: evaluations of catalogue effects refused by their own checks, with
    ``problems`` (list of reasons); named in the evidence of the channels they touched."""
    o = ctx.obs
    out = []
    for ci, name in enumerate(o.channels):
        m = o.ch == ci
        n = int(m.sum())
        if n < 20:
            continue
        ss = float(y[m] @ y[m])
        ms = ss / n
        excess = math.sqrt(max(ms - 1.0, 0.0))
        local = local_ws = None
        glob = excess >= EXCESS_MIN and ss - n >= CHI_SIGMA * math.sqrt(2 * n)
        wins = loc_after["channels"][name]["windows_s"]      # (locate describes every observed channel)
        sig = _signatures(ctx, name, m, y, wins) if glob else {}
        # (_signatures always scores the reversal-locked, step, intermittent and position kinds)
        if not glob or max(v[0] for v in sig.values()) < STRUCT_MIN:
            # not over the whole record: a stretch of it? (the longest window above 2.5 x noise),
            # or, short as each one may be, all of them together (a spike after each reversal,
            # an encoder's bursts)
            tt_all = ctx.t[o.row]
            tries = [[w] for w in sorted(wins, key=lambda w: w[0] - w[1])]
            if len(wins) >= 2 and sum(b - a for a, b in wins) < 0.25 * ctx.duration:
                tries.insert(0, sorted(wins))
            for ws in tries:
                mw = np.zeros_like(m)
                for a, b in ws:
                    mw |= m & (tt_all >= a) & (tt_all <= b)
                nw = int(mw.sum())
                if nw < max(20, 5 * len(ws)):
                    if len(ws) == 1 and nw >= SHORT_N:
                        b = _short_burst(ctx, y, m, mw)
                        if b is not None:
                            local, local_ws, m, excess, sig = (ws[0][0], ws[0][1]), ws, mw, b[0], b[1]
                            break
                    continue
                ssw = float(y[mw] @ y[mw])
                exw = math.sqrt(max(ssw / nw - 1.0, 0.0))
                span = sum(b - a for a, b in ws)
                if exw >= 1.5 and ssw - nw > CHI_SIGMA * math.sqrt(2 * nw) and span < 0.7 * ctx.duration:
                    sw = _signatures(ctx, name, mw, y)
                    # a few dozen samples: a signature must beat what its columns take from noise
                    if max(v[0] for v in sw.values()) >= STRUCT_MIN + 12.0 / nw:
                        local = (ws[0][0], ws[-1][1]) if len(ws) == 1 else None
                        local_ws = ws
                        m, excess, sig = mw, exw, sw
                        break
            else:
                continue
        kind, frac, detail = "broadband", 0.0, None
        for k, (f, d) in sig.items():
            if f > frac:
                kind, frac, detail = k, f, d
        if frac < STRUCT_MIN:
            # excess without any structure is a noise model that is off (coloured noise, a
            # channel quantised coarser than its noise), not physics: not reported
            continue
        axis = _axis_of_channel(name)
        if kind == "spectral line":
            label = f"spectral line {detail:.2f} Hz"
        elif kind == "delay":
            label = f"delay {1000 * detail:.2f} ms"
        elif kind in ("reversal-locked", "position-dependent"):
            label = kind
            axis = detail or axis
        elif kind == "step":
            label = f"step at {detail:.2f} s"
        elif kind == "intermittent":
            label = f"intermittent ({detail} bursts)"
        elif kind == "burst":
            label = f"burst after a reversal of {detail}" if detail else "burst"
            axis = detail or axis
        else:
            label = kind
        tw = [list(local)] if local else wins
        if kind == "step":
            tw = [[detail, detail]]
        region = _region(ctx, loc_after.get("regions", {}), name)
        if kind == "step":
            region = f"from t = {detail:.2f} s on"
        elif kind == "intermittent":
            region = None                 # the bursts' windows say where
        elif kind == "reversal-locked" and axis:
            region = f"{axis} reversals"
        elif kind == "position-dependent" and axis:
            region = f"{axis} position"
        tried = []
        for ev in rejected:
            if ev["affected"][ci]:
                c = ev["cand"]
                tried.append(f"{c.effect} on {c.target_key} {c.target} ({'; '.join(ev['problems'])})")
        fr = ", ".join(f"{k} {100 * v[0]:.0f} %" for k, v in sorted(sig.items(), key=lambda kv: -kv[1][0]))
        where = f" between {local[0]:.1f} and {local[1]:.1f} s only" if local else ""
        if local and kind == "drift":
            label = "transient"
        if local_ws and len(local_ws) > 1:          # short stretches together
            where = f" in {len(local_ws)} short stretches only"
            if kind in ("drift", "step", "intermittent"):
                label, region = f"intermittent ({len(local_ws)} bursts)", None
        ev_text = (f"{name} keeps {excess:.1f} x its noise{where} after the named effects; its structure: {fr} of "
                   f"the remaining energy.")
        if kind == "burst":
            ev_text = (f"{name} has one burst of {int(m.sum())} samples at {excess:.1f} x its noise between "
                       f"{local[0]:.2f} and {local[1]:.2f} s, far beyond its noise even counted with the noise's "
                       f"correlation in time, and too short for its structure to be judged"
                       + (f"; {detail} reversed just before it." if detail else "."))
        if tried:
            ev_text += " Refused by their own checks: " + "; ".join(dict.fromkeys(tried)) + "."
        else:
            ev_text += " No catalogued effect improved the held-out fit of this channel beyond noise."
        out.append({"channels": [name], "axis": axis,
                    "time_windows_s": [[round(a, 3), round(b, 3)] for a, b in tw],
                    "region": region,
                    "excess_over_noise": round(excess, 2),
                    "signature": label,
                    "structure_fraction": round(frac, 3),
                    "evidence": ev_text})
    # merge channels of one sensor with one signature (e.g. tip_x, tip_y with the same line)
    merged = []
    for e in sorted(out, key=lambda e: -e["excess_over_noise"]):
        for g in merged:
            same = g["signature"].split(" ")[0] == e["signature"].split(" ")[0] and g["axis"] == e["axis"]
            if same and g["channels"][0][:4] == e["channels"][0][:4]:
                g["channels"].append(e["channels"][0])
                g["time_windows_s"] = sorted(g["time_windows_s"] + e["time_windows_s"])[:6]
                break
        else:
            merged.append(e)
    return merged
