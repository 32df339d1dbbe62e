"""Signal measures the twin's analyses share (pure math, no I/O): the robust white-noise level of a
residual and its spectrum against a screw's position."""

from __future__ import annotations

import math

import numpy as np
from scipy import signal

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
