"""Static forces in the three chains (docs/diagnosis-report.md §1, docs/machine.md §2). Pure functions, batch-capable.

The platform (mass m_p at its centre of mass P + R·com_offset) under gravity, plus a known force
on the tool tip, is held by the three chains. Chain i pushes on the platform at C_i with

    f_i = a_i·u_i + b_i·n_i,     u_i = (C_i − A_i)/|C_i − A_i|,   n_i = revolute axis of chain i

(the in-plane force perpendicular to u_i is zero: the revolute joint at A_i cannot hold it).
a_i > 0 is compression. Equilibrium of forces and of moments about P:

    Σ f_i + F_ext = 0,   Σ (R c_i) × f_i + M_ext = 0

whose matrix is the transpose of :func:`pmctl.core.kinematics.constraint_jacobian` (rows
[u_i, (R c_i)×u_i] and [n_i, (R c_i)×n_i]). Units: mm, N, N·mm.

API
---
``external_wrench(P, R, machine, tip_force=None) -> (..., 6)``  [F (N); M about P (N·mm)] of
    gravity on the platform and ``tip_force`` (..., 3) N applied at the tool tip (base axes).
``chain_forces(P, R, machine, tip_force=None) -> ChainForces(axial, lateral)``: a_i (compression
    positive) and b_i, each (..., 3) N.
``strain_of_axial(axial, machine) -> (..., 3)`` plate-link strain µε = −k_ε·a_i (tension positive).
``static_strain(P, R, machine, tip_force=None)`` = the two above composed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pmctl.core.config import Machine
from pmctl.core.kinematics import _mv, constraint_jacobian


@dataclass
class ChainForces:
    axial: np.ndarray     # (..., 3) a_i, N, compression positive
    lateral: np.ndarray   # (..., 3) b_i, N, along the revolute axis n_i


def external_wrench(P, R, machine: Machine, tip_force=None):
    """Wrench on the platform about P from gravity and a tool-tip force: (..., 6) [N, N·mm]."""
    P = np.asarray(P, float)
    R = np.asarray(R, float)
    m = machine.mass
    shape = P.shape[:-1]
    fg = np.zeros(shape + (3,))
    fg[..., 2] = -m.platform_kg * m.gravity
    r_com = _mv(R, m.com_offset)
    F = fg
    M = np.cross(r_com, fg)
    if tip_force is not None:
        fl = np.broadcast_to(np.asarray(tip_force, float), shape + (3,))
        r_tip = _mv(R, machine.geometry.tool_tip_p)
        F = F + fl
        M = M + np.cross(r_tip, fl)
    return np.concatenate([F, M], -1)


def chain_forces(P, R, machine: Machine, tip_force=None) -> ChainForces:
    """Solve the six equilibrium equations for (a_i, b_i)."""
    A = constraint_jacobian(np.asarray(P, float), np.asarray(R, float), machine.geometry)
    w = external_wrench(P, R, machine, tip_force)
    x = np.linalg.solve(np.swapaxes(A, -1, -2), -w[..., None])[..., 0]
    return ChainForces(x[..., :3], x[..., 3:])


def strain_of_axial(axial, machine: Machine):
    """Plate-link strain (µε, tension positive) of compression forces a_i (N)."""
    return -machine.strain_gain * np.asarray(axial, float)


def static_strain(P, R, machine: Machine, tip_force=None):
    return strain_of_axial(chain_forces(P, R, machine, tip_force).axial, machine)
