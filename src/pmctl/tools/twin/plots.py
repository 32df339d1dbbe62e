"""PNG plots of a diagnosis (matplotlib, Agg): residual before/after, direction split, spectra."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pmctl.tools.twin.effects import axis_names, welch_runs
from pmctl.tools.twin.locate import axis_projection, channel_series, spectrum_position


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _top_channels(extras, k=4):
    """The channels worth a panel: most excess over noise, or most changed by the findings (a fast
    mode can hide inside the noise estimate and still be what the findings remove). Channels with
    nothing in them (rms 0) come last."""
    loc = extras["locate"]["channels"]
    after = extras.get("locate_after", {}).get("channels", {})

    def score(c):
        v = loc[c]
        gain = (v["rms"] - after.get(c, {}).get("rms", v["rms"])) / v["noise"] if v["noise"] > 0 else 0.0
        return (v["rms"] > 0, max(v["excess"], gain))
    return sorted(loc, key=score, reverse=True)[:k]


def write_plots(report, extras, out_dir) -> list[Path]:
    plt = _plt()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ctx, yf = extras["ctx"], extras["y_final"]
    paths = []
    name = report["recording"]

    # 1. residual before / after, top channels
    chans = _top_channels(extras)
    fig, axs = plt.subplots(len(chans), 1, figsize=(10, 2.2 * len(chans) + 0.6), sharex=True, squeeze=False)
    for ax, c in zip(axs[:, 0], chans):
        t, r0 = channel_series(ctx, c)
        _, r1 = channel_series(ctx, c, yf)
        unit = (report.get("units") or {}).get(c, "")
        ax.plot(t, r0, ".", ms=1.5, color="0.6", label="nominal twin")
        ax.plot(t, r1, ".", ms=1.5, color="C3", label="with the findings")
        ax.set_ylabel(f"{c} {unit}")
        ax.axhline(0, color="k", lw=0.5)
    axs[0, 0].legend(loc="upper right", markerscale=6, fontsize=8)
    axs[-1, 0].set_xlabel("t (s)")
    fig.suptitle(f"recording {name}: residual (measured − predicted) before and after — {report['verdict']}")
    fig.tight_layout()
    p = out / "residual_before_after.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)

    # 2. direction split: tool-equivalent error along each axis, moving + vs −
    names = axis_names(ctx)
    fig, axs = plt.subplots(1, len(names), figsize=(max(2.6 * len(names), 5), 3.4), squeeze=False)
    for a, ax in enumerate(axs[0]):
        ax.set_title(names[a])
        for y, lab, col in ((None, "nominal", "0.5"), (yf, "after", "C3")):
            _, e, rows = axis_projection(ctx, a, y)
            if not len(e):
                continue
            v = np.gradient(ctx.q_cmd[:, a], ctx.t)[rows]
            mv = np.abs(v) > 1e-3 * max(np.abs(v).max(), 1e-12)
            data = [1000 * e[mv & (v > 0)], 1000 * e[mv & (v < 0)]]
            if min(len(d) for d in data) < 3:
                continue
            pos = [0, 1] if lab == "nominal" else [0.3, 1.3]
            bp = ax.boxplot(data, positions=pos, widths=0.25, showfliers=False, patch_artist=True)
            for b in bp["boxes"]:
                b.set_facecolor(col)
        ax.set_xticks([0.15, 1.15], ["+ motion", "− motion"])
        ax.axhline(0, color="k", lw=0.5)
    axs[0, 0].set_ylabel("load-side error along the axis (µm)" if "axes" in ctx.extra else "tool error along the axis (µm)")
    fig.suptitle("direction split (grey: nominal twin, red: with the findings)")
    fig.tight_layout()
    p = out / "direction_split.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)

    # 3. spectra: against time (top channel) and against screw position (every axis)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4))
    c = chans[0] if chans else None
    if c:
        spectrum_panel(a1, report, extras, c)
    for a in range(len(names)):
        _, e, rows = axis_projection(ctx, a)
        if not len(e):
            continue
        x = ctx.q_cmd[rows, a]
        v = np.gradient(ctx.q_cmd[:, a], ctx.t)[rows]
        sp = spectrum_position(x, e, np.abs(v) > 1e-3 * max(np.abs(v).max(), 1e-12))
        if sp is not None:
            f, amp = sp
            m = f > 0
            a2.plot(f[m], 1000 * amp[m], lw=0.8, label=names[a])
    a2.set_xlim(0, 1.0)
    a2.set_xlabel("spatial frequency along the screw (1/mm)  — a 5 mm pitch is a line at 0.2")
    a2.set_ylabel("amplitude of the load-side error (µm)")
    if a2.get_legend_handles_labels()[0]:
        a2.legend(fontsize=8)
    else:
        a2.text(0.5, 0.5, "no load-side channel: no error against position", ha="center", va="center",
                transform=a2.transAxes, fontsize=9, color="0.4")
    fig.suptitle("spectrum of the residual against time and against screw position")
    fig.tight_layout()
    p = out / "spectrum.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)
    return paths


def full_rate_residual(report, extras, c):
    """(t, residual) of channel ``c`` at every row where it was sampled (not only the analysis
    samples the cap kept): the nominal twin recomputed there."""
    cols, machine, ctx = extras.get("columns"), extras.get("machine"), extras["ctx"]
    if cols is None or c not in cols:
        return None
    x = np.asarray(cols[c], float)
    rows = np.flatnonzero(np.isfinite(x))
    if len(rows) < 64:
        return None
    if "axes" in ctx.extra:
        from pmctl.tools.twin.axes import predict_columns
        b = ctx.extra.get("bounds")
        pred = predict_columns(dict(cols, t=ctx.t), machine, [c], rows, b)[c]
    else:
        from pmctl.tools.twin import nominal
        sub = {k: np.asarray(v, float)[rows] for k, v in cols.items()}
        pred = nominal.predict_columns(sub, machine, [c])[c]
    r = x[rows] - pred
    ok = np.isfinite(r)
    return ctx.t[rows][ok], r[ok]


def spectrum_panel(ax, report, extras, c):
    """PSD of channel ``c``'s residual, in its unit²/Hz: the nominal twin's at every sample of the
    channel as recorded, up to its own Nyquist frequency (the analysis samples, thinned to the cap,
    would alias a 246.6 Hz mode of a 1 kHz log below their 166 Hz); after the findings, at the
    analysis samples, up to their Nyquist frequency (the findings are fitted there)."""
    ctx, yf = extras["ctx"], extras["y_final"]
    unit = (report.get("units") or {}).get(c, "")
    cuts = ctx.extra.get("cuts")
    full = full_rate_residual(report, extras, c)
    t0, r0 = full if full is not None else channel_series(ctx, c)
    sp = welch_runs(t0, r0, cuts)
    if sp is not None:
        ax.semilogy(sp[0][1:], sp[1][1:], color="0.5",
                    label=f"nominal twin, all {len(r0)} samples (to {0.5 / np.median(np.diff(t0)):.0f} Hz)")
    t1, r1 = channel_series(ctx, c, yf)
    if len(r1) >= 64:
        nyq = 0.5 / float(np.median(np.diff(t1)))
        if full is not None and len(r1) < len(r0):       # thinned: before and after at the same samples too
            tb, rb = channel_series(ctx, c)
            spb = welch_runs(tb, rb, cuts)
            if spb is not None:
                ax.semilogy(spb[0][1:], spb[1][1:], color="0.75", lw=0.8,
                            label=f"nominal twin, {len(rb)} analysis samples (to {nyq:.0f} Hz)")
        sp1 = welch_runs(t1, r1, cuts)
        if sp1 is not None:
            ax.semilogy(sp1[0][1:], sp1[1][1:], color="C3",
                        label=f"with the findings, {len(r1)} analysis samples (to {nyq:.0f} Hz)")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel(f"PSD of the {c} residual ({unit}²/Hz)" if unit and unit != "1" else f"PSD of the {c} residual (1/Hz)")
    ax.legend(fontsize=7)
