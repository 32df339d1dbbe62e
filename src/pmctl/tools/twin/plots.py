"""PNG plots of a diagnosis (matplotlib, Agg): residual before/after, direction split, spectra."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pmctl.tools.twin.effects import AXES
from pmctl.tools.twin.locate import axis_projection, channel_series, spectrum_position, spectrum_time


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
        unit = "µε" if c.startswith("strain") else ("" if c.startswith("tool") else "mm")
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
    fig, axs = plt.subplots(1, 5, figsize=(13, 3.4), squeeze=False)
    for a, ax in enumerate(axs[0]):
        ax.set_title(AXES[a])
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
    axs[0, 0].set_ylabel("tool error along the axis (µm)")
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
        for y, lab, col in ((None, "nominal", "0.5"), (yf, "after", "C3")):
            t, r = channel_series(ctx, c, y)
            sp = spectrum_time(t, r)
            if sp is not None:
                a1.semilogy(sp[0][1:], sp[1][1:], color=col, label=lab)
        a1.set_xlabel("frequency (Hz)")
        a1.set_ylabel(f"PSD of {c} residual")
        a1.legend(fontsize=8)
    for a in range(5):
        _, e, rows = axis_projection(ctx, a)
        if not len(e):
            continue
        x = ctx.q_cmd[rows, a]
        v = np.gradient(ctx.q_cmd[:, a], ctx.t)[rows]
        sp = spectrum_position(x, e, np.abs(v) > 1e-3 * max(np.abs(v).max(), 1e-12))
        if sp is not None:
            f, amp = sp
            m = f > 0
            a2.plot(f[m], 1000 * amp[m], lw=0.8, label=AXES[a])
    a2.set_xlim(0, 1.0)
    a2.set_xlabel("spatial frequency along the screw (1/mm)  — a 5 mm pitch is a line at 0.2")
    a2.set_ylabel("amplitude (µm)")
    a2.legend(fontsize=8)
    fig.suptitle("spectrum of the residual against time and against screw position")
    fig.tight_layout()
    p = out / "spectrum.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)
    return paths
