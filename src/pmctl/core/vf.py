"""Software V-F (voltage-to-frequency) converter with pulse counting (seed 004 2.2, 4.3.4).

Pure functions of state. The converter integrates its input u (in pulses per second once
scaled) over one sample; whenever the accumulated sum passes the threshold it emits a pulse and
subtracts the threshold, so rounding never accumulates: the pulses emitted plus the residue in
the accumulator always equal the integral of the input.

Two modes:
- ``max_pulses_per_tick=1``: the seed's converter, at most one pulse per sample (max rate = F);
- ``max_pulses_per_tick=n``: the integer number of pulses per tick, up to n, for real servo rates
  (200 kpulse/s at 1 kHz is n = 200); a bridge spreads them evenly inside the tick.

Ties: an accumulator within ``TIE`` (1e-9 of the threshold) short of a whole number of thresholds
has reached it. A target exactly half a pulse from the counters gives rates whose sums land on a
whole pulse exactly; computed two ways (the Python NC's LAPACK pseudo-inverse, the compiled core's
Jacobi SVD) they end a few units in the last place above or below it, and a plain truncation would
send the pulse in one and not in the other. With the margin both send it. The margin is far below
anything physical (a nanopulse) and far above the rounding of a sum of rates (1e-13 over 10^8 ticks).
"""

from __future__ import annotations

import math

import numpy as np

TIE = 1e-9          # of a threshold: an accumulator this close below a whole pulse has reached it


def vf_step(acc, u, dt, threshold=1.0, max_pulses_per_tick=1):
    """One sample of a bank of V-F converters.

    acc: accumulator per axis (same unit as u*dt); u: input per axis; threshold: the input
    integral worth one pulse (SD). Returns (pulses: int64 array, new acc). Pulses are signed.
    Input beyond max_pulses_per_tick saturates; the excess is dropped, as in the hardware
    (the accumulator is clamped to one threshold beyond the emitted pulses), so a saturated
    converter does not wind up.
    """
    a = np.asarray(acc, float) + np.asarray(u, float) * dt
    x = a / threshold
    n = np.trunc(np.where(x >= 0, x + TIE, x - TIE))
    n = np.clip(n, -max_pulses_per_tick, max_pulses_per_tick)
    a = a - n * threshold
    a = np.clip(a, -threshold, threshold)
    return n.astype(np.int64), a


def vf_min_amplitude(threshold, f_over_F):
    """Smallest sine amplitude that produces any pulse (seed 004 eq. 2.2): x >= SD sin(pi/2k), f/F = 1/2k."""
    k = 1.0 / (2.0 * np.asarray(f_over_F, float))
    return threshold * np.sin(np.pi / (2.0 * k))


def vf_tick(acc, u, dt, threshold=1.0, max_pulses_per_tick=1):
    """:func:`vf_step` for one tick of a small bank on plain lists (the control loop's hot path,
    where numpy's per-call cost is larger than the work). Same arithmetic, same results; tested
    equal to vf_step. Returns (pulses: list of int, new acc: list of float)."""
    pulses, out = [], []
    for a, x in zip(acc, u):
        a = a + x * dt
        y = a / threshold
        n = math.trunc(y + TIE if y >= 0 else y - TIE)
        if n > max_pulses_per_tick:
            n = max_pulses_per_tick
        elif n < -max_pulses_per_tick:
            n = -max_pulses_per_tick
        a = a - n * threshold
        if a > threshold:
            a = threshold
        elif a < -threshold:
            a = -threshold
        pulses.append(n)
        out.append(a)
    return pulses, out
