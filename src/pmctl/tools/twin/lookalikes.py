"""Look-alikes: two catalogue effects that predict the same data within noise. Pure math.

Some runs cannot tell two physical causes apart. In a run where leg 3 travels one way only, a
backlash of width w and a length offset of w/2 shift the tool by the same amount at every sample;
where a leg's force never changes, a stiffness k and a length offset F/k do; where a gauge's load
never changes, a gain g and an offset (g − 1)·S do. The fit cannot choose, so the diagnosis:

1. finds every other candidate that passes its own checks and whose full-fit prediction differs
   from the chosen one's by less than :data:`LOOK_D2` in whitened squared error (the sum of
   squared differences in units of each channel's noise: below 25 no test on this recording could
   separate them at 5 σ);
2. names the one of them whose physics needs fewer coincidences (:func:`weight`):

   - a **backlash** over an offset of the same size: the load trails the motor on the side that
     the direction of travel sets, so the backlash predicted the sign of the offset; a length
     offset would have that sign by chance (a factor of 2);
   - an **offset** (geometry, sensor offset) over a **slope** (stiffness, gain) whose driving
     quantity hardly varied: the slope then rests only on the absolute level of the modelled force
     or signal (a factor of 1/2 on the slope);
   - a magnitude outside what the effect plausibly has (:data:`PLAUSIBLE`, e.g. a play of more
     than 0.05 mm) weighs the effect down steeply;
   - with equal weights the one the selection ranked first stays (its better held-out score, or
     the screw's own temperature for a thermal growth);

3. lists the others under the finding's ``alternatives``, with their parameters and weights, and
   caps its confidence at its share of the weights (0.67 for two look-alikes at 2 : 1): the
   report says what it could not separate and which run would (``separate_by``).
"""

from __future__ import annotations

import math

import numpy as np

LOOK_D2 = 25.0          # whitened squared difference of two predictions below which they are look-alikes

# (effect, parameter) -> plausible magnitude range (absolute value, the parameter's unit)
PLAUSIBLE = {
    ("backlash", "width_mm"): (0.001, 0.05),           # a preloaded screw ... a worn one
    ("geometry", "length_offset_mm"): (0.002, 2.0),
    ("geometry", "base_joint_radial_mm"): (0.002, 2.0),
    ("geometry", "base_joint_z_mm"): (0.002, 2.0),
    ("geometry", "tool_length_mm"): (0.002, 5.0),
    ("compliance", "stiffness_N_per_mm"): (200.0, 2e5),
    ("lost_steps", "offset_mm"): (0.0004, 5.0),
}
FALLOFF_DECADES = 0.1   # outside its range a magnitude's weight falls as exp(-(decades/this)²/2)

PREFERENCE = {"backlash": 2.0, "compliance": 0.5, "sensor_gain": 0.5}

SEPARATE_BY = {
    frozenset({"backlash", "geometry"}): "a run that reverses the axis (backlash flips sign at a reversal, "
                                         "a length offset does not)",
    frozenset({"compliance", "geometry"}): "a run that changes the axial force (a calibration run with loads)",
    frozenset({"sensor_gain", "sensor_offset"}): "a run that changes the channel's signal",
    frozenset({"backlash", "lost_steps"}): "a run that reverses the axis",
    frozenset({"backlash", "friction"}): "encoders on the motor side, or a log fast enough to resolve the play's "
                                         "take-up (a friction offset flips with the velocity, a play only once the "
                                         "motor has crossed it)",
    frozenset({"backlash", "sensor_offset"}): "a run that reverses the axis (a backlash flips sign at a reversal, "
                                              "a sensor offset does not)",
    frozenset({"geometry", "sensor_offset"}): "a run over a wider range of poses",
    frozenset({"geometry", "lost_steps"}): "a longer run of the axis before and after the step",
}


# Alternatives that leave a compensation right: a backlash table flips the correction at each
# reversal, which also corrects a Coulomb friction's reversal-locked offset.
COMPENSATION_SAFE = {"backlash": {"friction"}, "pitch_error": {"periodic_error"}, "periodic_error": {"pitch_error"}}


def compensation_safe(effect: str, alternatives) -> bool:
    """Whether a compensation table of ``effect`` is right whichever of its look-alikes is the cause."""
    return set(alternatives) <= COMPENSATION_SAFE.get(effect, set())


def plausibility(effect: str, params: dict) -> float:
    """1 inside every plausible range of the effect's parameters, falling steeply outside."""
    w = 1.0
    for (eff, name), (lo, hi) in PLAUSIBLE.items():
        if eff != effect or name not in params:
            continue
        v = abs(float(params[name]))
        if v <= 0 or not math.isfinite(v):
            return 0.0
        dec = math.log10(lo / v) if v < lo else (math.log10(v / hi) if v > hi else 0.0)
        w *= math.exp(-0.5 * (dec / FALLOFF_DECADES) ** 2)
    return w


def weight(effect: str, params: dict) -> float:
    return PREFERENCE.get(effect, 1.0) * plausibility(effect, params)


def separate_by(effects) -> str | None:
    names = set(effects)
    for pair, how in SEPARATE_BY.items():
        if pair <= names:
            return how
    return None


def lookalike_d2(pred_a: np.ndarray, pred_b: np.ndarray) -> float:
    d = np.asarray(pred_a) - np.asarray(pred_b)
    return float(d @ d)


def choose(group: list[dict]) -> tuple[int, list[float]]:
    """Index of the named one among look-alikes (each {"effect", "params", "score"}; the first is
    the one the selection ranked first) and their weights: the first stays unless another weighs
    more (then the heaviest, by score among equals)."""
    ws = [weight(g["effect"], g["params"]) for g in group]
    heavier = [i for i in range(1, len(group)) if ws[i] > ws[0]]
    if not heavier:
        return 0, ws
    return max(heavier, key=lambda i: (ws[i], group[i]["score"])), ws
