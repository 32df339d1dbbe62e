"""The identification model: geometry parameters <-> Geometry, predicted tool poses, and the
analytic identification Jacobian d(tip_W, tool axis)/d(parameters) at fixed actuator positions.

Parameters (30, all as small changes of a reference geometry, in mm and degrees):

- per chain i = 1..3: base joint A_i (x, y, z mm, base frame), platform joint C_i^p (x, y, z mm,
  platform frame), revolute axis n_i (2 tilts in degrees: ``up`` toward +Z, ``yaw`` about Z in the
  horizontal plane), actuator zero offset (mm);
- tool: length (mm), tilt (2, degrees, about x_p then y_p, as the config's ``tool_tilt_deg``).

The table height ``z_table`` is not a parameter: it and a common vertical shift of the three base
joints move the tool identically (kept fixed, as are base/platform radius, which only name the
nominal joints).

Pure math, no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from pmctl.core import kinematics as K
from pmctl.core.config import Geometry
from pmctl.core.errors import KinematicsError

DEG = math.pi / 180.0
EZ = np.array([0.0, 0.0, 1.0])


def _names():
    out = []
    for i in range(1, 4):
        out += [f"chain{i}.base_joint.{c}_mm" for c in "xyz"]
        out += [f"chain{i}.platform_joint.{c}_mm" for c in "xyz"]
        out += [f"chain{i}.revolute_axis.up_deg", f"chain{i}.revolute_axis.yaw_deg"]
        out += [f"chain{i}.length_offset_mm"]
    return out + ["tool.length_mm", "tool.tilt_a_deg", "tool.tilt_b_deg"]


PARAM_NAMES = tuple(_names())
N_PARAMS = len(PARAM_NAMES)           # 30
PER_CHAIN = 9
IS_ANGLE = np.array([n.endswith("_deg") for n in PARAM_NAMES])


def axis_tangents(n):
    """Two unit tangents of each revolute axis n (3, 3): 'up' (toward +Z) and 'yaw' (horizontal)."""
    n = np.asarray(n, float)
    up = EZ - n * n[:, 2:3]
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    return up, np.cross(n, up)


def perturb(geom: Geometry, dp) -> Geometry:
    """The geometry moved by the parameter change dp (30,): exact for positions, lengths and tool
    tilt; the revolute axes turn by the two small angles (normalised)."""
    dp = np.asarray(dp, float)
    A = np.array(geom.base_joints, float)
    C = np.array(geom.platform_joints, float)
    N = np.array(geom.revolute_axes, float)
    off = np.array(geom.length_offsets, float)
    up, yaw = axis_tangents(N)
    for i in range(3):
        b = PER_CHAIN * i
        A[i] += dp[b:b + 3]
        C[i] += dp[b + 3:b + 6]
        N[i] = N[i] + math.tan(dp[b + 6] * DEG) * up[i] + math.tan(dp[b + 7] * DEG) * yaw[i]
        N[i] /= np.linalg.norm(N[i])
        off[i] += dp[b + 8]
    tilt = (geom.tool_tilt_deg[0] + dp[28], geom.tool_tilt_deg[1] + dp[29])
    return replace(geom, base_joints=A, platform_joints=C, revolute_axes=N, length_offsets=off,
                   tool_length=geom.tool_length + dp[27], tool_tilt_deg=(float(tilt[0]), float(tilt[1])),
                   nominal=False)


def difference(geom: Geometry, ref: Geometry) -> np.ndarray:
    """Parameter vector dp with perturb(ref, dp) == geom (axis angles measured in ref's tangents)."""
    dp = np.zeros(N_PARAMS)
    up, yaw = axis_tangents(ref.revolute_axes)
    for i in range(3):
        b = PER_CHAIN * i
        dp[b:b + 3] = geom.base_joints[i] - ref.base_joints[i]
        dp[b + 3:b + 6] = geom.platform_joints[i] - ref.platform_joints[i]
        n = geom.revolute_axes[i] / (geom.revolute_axes[i] @ ref.revolute_axes[i])
        dp[b + 6] = math.atan(n @ up[i]) / DEG
        dp[b + 7] = math.atan(n @ yaw[i]) / DEG
        dp[b + 8] = geom.length_offsets[i] - ref.length_offsets[i]
    dp[27] = geom.tool_length - ref.tool_length
    dp[28] = geom.tool_tilt_deg[0] - ref.tool_tilt_deg[0]
    dp[29] = geom.tool_tilt_deg[1] - ref.tool_tilt_deg[1]
    return dp


@dataclass
class Prediction:
    tip: np.ndarray       # (n, 3) tool tip in W, mm
    axis: np.ndarray      # (n, 3) unit tool axis
    P: np.ndarray
    R: np.ndarray


def predict(q, geom: Geometry, guess=None) -> Prediction:
    """Tool poses of the actuator positions q (n, 5) on this geometry; raises if any FK fails."""
    q = np.asarray(q, float)
    sol = K.solve_platform(q[:, :3], geom, guess)
    if not np.all(sol.ok):
        sol2 = K.solve_platform(q[:, :3], geom)          # cold start for the ones a warm start lost
        P = np.where(sol.ok[:, None], sol.P, sol2.P)
        R = np.where(sol.ok[:, None, None], sol.R, sol2.R)
        ok = sol.ok | sol2.ok
        if not np.all(ok):
            k = int(np.nonzero(~ok)[0][0])
            raise KinematicsError(f"forward kinematics failed at measured pose {k + 1} "
                                  f"(L = {np.round(q[k, :3], 4).tolist()}) on the trial geometry")
    else:
        P, R = sol.P, sol.R
    tip, axis = K.tool_of_platform(P, R, q[:, 3:5], geom)
    return Prediction(tip, axis, P, R)


def identification_jacobian(P, R, geom: Geometry) -> np.ndarray:
    """d(tip_W, tool axis)/d(parameters) (n, 6, 30) at the platform poses (P, R) solving the loop
    equations of ``geom`` at fixed actuator positions (implicit function theorem:
    dX = -A^-1 df/dp with A the constraint Jacobian, X = (P, w))."""
    n = P.shape[0]
    A = K.constraint_jacobian(P, R, geom)                              # (n, 6, 6)
    rc = np.einsum("nij,kj->nki", R, geom.platform_joints)
    d = P[:, None, :] + rc - geom.base_joints
    u = d / np.linalg.norm(d, axis=-1, keepdims=True)
    N = np.broadcast_to(geom.revolute_axes, u.shape)
    up, yaw = axis_tangents(geom.revolute_axes)
    F = np.zeros((n, 6, N_PARAMS))                                     # df/dp
    for i in range(3):
        b = PER_CHAIN * i
        F[:, i, b:b + 3] = -u[:, i, :]
        F[:, 3 + i, b:b + 3] = -N[:, i, :]
        F[:, i, b + 3:b + 6] = np.einsum("nj,njk->nk", u[:, i, :], R)
        F[:, 3 + i, b + 3:b + 6] = np.einsum("nj,njk->nk", N[:, i, :], R)
        F[:, 3 + i, b + 6] = d[:, i, :] @ up[i] * DEG
        F[:, 3 + i, b + 7] = d[:, i, :] @ yaw[i] * DEG
        F[:, i, b + 8] = -1.0
    dX = -np.linalg.solve(A, F)                                        # (n, 6, 30)
    dP, w = dX[:, :3, :], dX[:, 3:, :]
    rt = np.einsum("nij,j->ni", R, geom.tool_tip_p)
    v = np.einsum("nij,j->ni", R, geom.tool_axis_p)
    S = np.zeros((n, 6, N_PARAMS))
    S[:, :3] = dP + np.cross(w, rt[:, :, None], axisa=1, axisb=1, axisc=1)
    S[:, 3:] = np.cross(w, v[:, :, None], axisa=1, axisb=1, axisc=1)
    # tool parameters act directly
    a, bt = np.radians(geom.tool_tilt_deg)
    ap = geom.tool_axis_p
    da = np.array([0.0, -math.cos(a) * math.cos(bt), -math.sin(a) * math.cos(bt)]) * DEG
    db = np.array([math.cos(bt), math.sin(a) * math.sin(bt), -math.cos(a) * math.sin(bt)]) * DEG
    S[:, :3, 27] = -np.einsum("nij,j->ni", R, ap)
    for k, dd in ((28, da), (29, db)):
        Rd = np.einsum("nij,j->ni", R, dd)
        S[:, :3, k] = -geom.tool_length * Rd
        S[:, 3:, k] = Rd
    return S


# ---------------------------------------------------------------- simulated machines and poses

def random_geometry(ref: Geometry, rng, *, mm=0.5, deg=0.5) -> Geometry:
    """A built machine: every parameter uniformly within +-mm / +-deg of the reference."""
    lim = np.where(IS_ANGLE, deg, mm)
    return perturb(ref, rng.uniform(-1.0, 1.0, N_PARAMS) * lim)


def random_tool_poses(machine, n, rng, *, z=(290.0, 470.0), theta2_deg=None, table=55.0, margin_deg=2.0):
    """n reachable tool poses (tip in W, axis) spread over the workspace of ``machine``:
    platform height Z, tilt direction theta1 in (0, 180], tilt theta2 within the limits less a
    margin, table within +-table mm."""
    lo, hi = theta2_deg or machine.limits.theta2_deg
    lo, hi = lo + margin_deg, hi - margin_deg
    g = machine.geometry
    tips, axes = [], []
    have = 0
    while have < n:
        m = 2 * (n - have) + 8
        P, R = K.platform_pose(rng.uniform(*z, m), rng.uniform(1e-3, math.pi, m),
                               np.radians(rng.uniform(lo, hi, m)), g.platform_radius)
        tip, axis = K.tool_of_platform(P, R, rng.uniform(-table, table, (m, 2)), g)
        ok = K.ik_batch(tip, axis, machine).ok
        tips.append(tip[ok])
        axes.append(axis[ok])
        have += int(ok.sum())
    return np.concatenate(tips)[:n], np.concatenate(axes)[:n]


def simulate_measurement(q, true_geom: Geometry, rng, *, tip_sigma_mm=2e-3, axis_sigma_rad=1e-5):
    """What a measuring instrument sees at actuator positions q on the true machine: tool tip
    (noise tip_sigma per coordinate) and unit tool axis (angular noise axis_sigma per direction)."""
    pr = predict(q, true_geom)
    tip = pr.tip + rng.normal(0.0, tip_sigma_mm, pr.tip.shape)
    e = rng.normal(0.0, axis_sigma_rad, pr.axis.shape)
    e -= np.sum(e * pr.axis, -1, keepdims=True) * pr.axis           # angular noise only
    ax = pr.axis + e
    ax /= np.linalg.norm(ax, axis=-1, keepdims=True)
    return tip, ax


def angle_between(a, b):
    """Angle (rad) between unit vectors, accurate for tiny angles."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, -1))


def tool_errors(tip_target, axis_target, q, true_geom: Geometry):
    """Where the tool really goes when q is commanded: tip error |dtip| (mm) and axis error (rad)."""
    pr = predict(q, true_geom)
    e_tip = np.linalg.norm(pr.tip - tip_target, axis=-1)
    e_ax = angle_between(pr.axis, axis_target)
    return e_tip, e_ax
