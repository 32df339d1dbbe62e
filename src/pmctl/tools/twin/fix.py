"""From diagnosis to fix: the compensation table of the per-axis findings
(``pmctl twin diagnose REC --write-compensation FILE``, docs/diagnosis-report.md, "From diagnosis to fix").

Only findings the diagnosis accepted (they passed their own checks) are used:

- ``backlash`` on an axis -> that axis' ``backlash_mm`` (the fitted play width; the twin's play
  operator and the controller's backlash term share the convention: moving up, the load lags the
  motor by half the play);
- ``pitch_error`` and ``periodic_error`` (a load-side error A·sin(2πx/p + φ) in the screw position
  x) -> the axis' screw table, sampled at p/16 over the axis' travel (the machine config's joint
  limits, one period beyond each end), the same values both ways;
- geometry findings are not per-axis: they go to the machine config's geometry
  (``pmctl calibrate from-twin``); the other effects have no table form (servo lag, resonance,
  thermal growth, sensor faults...) and are listed as such.

A recording made with a compensation already active is diagnosed against the compensated joints
(pmctl.core.compensation.compensated_columns), so what it finds is what is left: the new table is
the old one plus the new findings.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from pmctl.core.compensation import AXES, MAX_POINTS, AxisComp, Compensation, NO_COMPENSATION
from pmctl.tools.twin.lookalikes import compensation_safe

COMPENSABLE = ("backlash", "pitch_error", "periodic_error")
GEOMETRY = ("geometry",)
SAMPLES_PER_PERIOD = 16


def _grid(machine, a: int, periods) -> np.ndarray:
    lo, hi = float(machine.limits.joint_lower[a]), float(machine.limits.joint_upper[a])
    p = min(periods)
    lo, hi = lo - p, hi + p
    step = max(p / SAMPLES_PER_PERIOD, (hi - lo) / (MAX_POINTS - 1))
    n = int(math.ceil((hi - lo) / step)) + 1
    return lo + step * np.arange(n)


def compensation_from_findings(machine, accepted, existing: Compensation | None = None):
    """(Compensation or None, notes): the table of the accepted findings (extras["accepted"] of
    pmctl.tools.twin.diagnose.diagnose) added to ``existing``; notes say what was used and what
    was left to other tools. None when no finding is compensable."""
    base = existing or NO_COMPENSATION
    bl = [a.backlash_mm for a in base.axes]
    rate = [a.backlash_rate_mm_s for a in base.axes]
    waves = {i: [] for i in range(5)}          # axis -> [(amplitude, period, phase)]
    notes, used = [], False
    for ev in accepted:
        c, f = ev["cand"], ev["fit"]
        eff = c.effect
        alt_names = [e["cand"].effect for e, _ in ev.get("alternatives", ())]
        if alt_names and not compensation_safe(eff, alt_names):   # compensating the wrong one adds the error
            alts = ", ".join(alt_names)
            notes.append(f"{c.target}: {eff} -> not written: this recording cannot tell it from {alts}; "
                         "record a run that separates them (the report's separate_by) first")
            continue
        if eff in COMPENSABLE and getattr(c, "target_key", "axis") == "axis" and c.target in AXES:
            a = AXES.index(c.target)
            used = True
            if eff == "backlash":
                w = float(f.params["width_mm"])
                bl[a] += w
                notes.append(f"{c.target}: backlash {w * 1e3:.1f} µm -> backlash_mm = {bl[a]:.6f}")
            else:
                A, p = float(f.params["amplitude_mm"]), float(f.params["period_mm"])
                ph = float(f.internal.get("phase_rad", 0.0))
                waves[a].append((A, p, ph))
                notes.append(f"{c.target}: {eff.replace('_', ' ')} {A * 1e3:.2f} µm at period {p:.4f} mm "
                             f"(phase {ph:+.3f} rad) -> screw table")
        elif eff in GEOMETRY:
            notes.append(f"{c.target}: geometry -> not a per-axis table; write the corrected machine config with "
                         f"pmctl calibrate from-twin")
        else:
            notes.append(f"{c.target}: {eff} -> no compensation table for it (not written)")
    if not used:
        return None, notes
    axes = []
    for a in range(5):
        old = base.axes[a]
        if not waves[a]:
            axes.append(AxisComp(bl[a], rate[a], old.positions_mm, old.forward_mm, old.reverse_mm))
            continue
        x = _grid(machine, a, [p for _, p, _ in waves[a]])
        e = np.zeros_like(x)
        for A, p, ph in waves[a]:
            e += A * np.sin(2 * np.pi * x / p + ph)
        fwd, rev = base.screw_error(a, x, 1.0) + e, base.screw_error(a, x, -1.0) + e
        r = lambda v: tuple(round(float(u), 9) for u in v)     # nm: the table stays readable
        axes.append(AxisComp(bl[a], rate[a], r(x), r(fwd), r(rev)))
    return Compensation(tuple(axes), "pmctl twin diagnose"), notes


def write_compensation(path, comp: Compensation, *, recording: str, machine_source: str, notes) -> str:
    """Write the ``[compensation]`` file; returns its text."""
    head = (f"Backlash and screw compensation from `pmctl twin diagnose {recording}`\n"
            f"(machine config {machine_source}). Use it with the machine config's\n"
            f"  [compensation]\n  file = \"{Path(path).name}\"\n"
            f"or paste the tables below into it (docs/machine.md §6).\n"
            + "\n".join(notes))
    text = comp.to_toml(head)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(text, encoding="utf-8")
    return text
