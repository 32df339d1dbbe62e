"""From a twin diagnosis to a calibrated config.

The twin's ``geometry`` findings (``pmctl twin diagnose``; one per parameter group) carry parameter
changes of the nominal geometry:

- ``{"effect": "geometry", "chain": i, "parameters": {"length_offset_mm": d}}``
- ``... "chain": i, "parameters": {"base_joint_radial_mm": r, "base_joint_z_mm": z}}`` (A_i moved in
  its chain plane: r along the horizontal direction of A_i, z vertically)
- ``... "chain": i, "parameters": {"platform_joint_mm": [dx, dy, dz]}}`` (C_i^p, platform frame)
- ``... "chain": "tool", "parameters": {"tool_length_mm": d}`` or ``{"tool_tilt_deg": [da, db]}``

:func:`geometry_dp` turns them into the identification's parameter vector, :func:`apply_findings`
into a geometry (the same :func:`pmctl.tools.calibrate.model.perturb` the identification uses), and
:func:`write_calibrated` into a machine config any command accepts with ``--config``. Findings of
other effects are ignored; an unknown geometry parameter is an error (nothing is half-applied).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from pmctl.core.config import Machine
from pmctl.core.errors import InputError
from pmctl.tools.calibrate import configio, model as Mo


def _geometry(report):
    if isinstance(report, dict):
        report = report.get("findings", [report] if "effect" in report else [])
    return [f for f in report if isinstance(f, dict) and f.get("effect") == "geometry"]


def _findings(report):
    """The geometry findings to apply: not those with look-alikes (``alternatives``: the recording
    could not tell them from another effect, docs/diagnosis-report.md "Look-alikes")."""
    return [f for f in _geometry(report) if not f.get("alternatives")]


def lookalike_findings(report):
    """Geometry findings left out because the recording could not tell them from another effect."""
    return [f for f in _geometry(report) if f.get("alternatives")]


def _vec(v, n, where):
    arr = np.atleast_1d(np.asarray(v, dtype=float))
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise InputError(where, None, f"expected {n} finite number(s), got {v!r}")
    return arr


def geometry_dp(machine: Machine, report, *, source="<twin report>") -> np.ndarray:
    """Parameter vector (30,) of the geometry findings of a twin report (or a list of findings)."""
    g = machine.geometry
    dp = np.zeros(Mo.N_PARAMS)
    for f in _findings(report):
        chain = f.get("chain")
        params = f.get("parameters", {})
        where = f"{source}: geometry finding for chain {chain!r}"
        if chain == "tool":
            for k, v in params.items():
                if k == "tool_length_mm":
                    dp[27] += _vec(v, 1, where)[0]
                elif k == "tool_tilt_deg":
                    dp[28:30] += _vec(v, 2, where)
                else:
                    raise InputError(where, None, f"unknown tool parameter {k!r}")
            continue
        if isinstance(chain, bool) or not isinstance(chain, int) or not 1 <= chain <= 3:
            raise InputError(where, None, "chain must be 1, 2, 3 or \"tool\"")
        b = Mo.PER_CHAIN * (chain - 1)
        a = g.base_joints[chain - 1]
        radial = np.array([a[0], a[1], 0.0]) / max(math.hypot(a[0], a[1]), 1e-12)
        for k, v in params.items():
            if k == "length_offset_mm":
                dp[b + 8] += _vec(v, 1, where)[0]
            elif k == "base_joint_radial_mm":
                dp[b:b + 3] += _vec(v, 1, where)[0] * radial
            elif k == "base_joint_z_mm":
                dp[b + 2] += _vec(v, 1, where)[0]
            elif k == "platform_joint_mm":
                dp[b + 3:b + 6] += _vec(v, 3, where)
            else:
                raise InputError(where, None, f"unknown chain parameter {k!r}")
    return dp


def apply_findings(machine: Machine, report, **kw) -> Machine:
    """The machine with the twin's geometry findings applied."""
    dp = geometry_dp(machine, report, **kw)
    if not np.any(dp):
        return machine
    return replace(machine, geometry=Mo.perturb(machine.geometry, dp))


def write_calibrated(machine: Machine, report, out, *, name=None, source="<twin report>") -> Machine:
    """Write the calibrated config of a twin report; returns the machine loaded back from it."""
    dp = geometry_dp(machine, report, source=source)
    geom = Mo.perturb(machine.geometry, dp)
    lines = [f"Calibrated from the geometry findings of a twin diagnosis ({source})",
             f"reference config: {machine.source}"]
    lines += [f"  {n} {v:+.6g}" for n, v in zip(Mo.PARAM_NAMES, dp) if v]
    return configio.write_machine(out, configio.calibrated_dict(machine, geom, name=name), "\n".join(lines))
