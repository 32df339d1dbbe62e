"""Mechanism analysis of the 3-RPS spatial part (seed 000 ch. 2.3, 2.4.1 and ch. 4; docs/machine.md §5).

Pure numpy functions, vectorised over grids (leading dimensions broadcast), plus a thin CLI
(``pmctl analyze io-ratio | drive | path-error | compliance``) that writes PNGs and prints figures.

Conventions: lengths in mm, angles in radians inside the functions (the CLI speaks degrees),
(Z, theta1, theta2) as in docs/machine.md §3 (theta1 = 0 is accepted and is the same physical tilt
as theta1 = 180 deg with theta2 negated). "J_L" is ``kinematics.jacobian_ztt`` =
d(L1, L2, L3)/d(Z, theta1, theta2); the seed's mechanism Jacobian is J = J_L^-1 (eq. 4.13).

Contents
--------
- input-output ratio (eq. 4.14-4.22): :func:`io_ratio`, :func:`io_ratio_maps`;
- drive characteristic evaluation (eq. 2.1-2.16, Table 2.1): :func:`drive_characteristics_at`,
  :func:`drive_characteristics`;
- path error of joint-space interpolation between control points (4.4, Fig. 4.4-4.6):
  :class:`ZttSegment`, :class:`ToolSegment`, :func:`interpolation_error`,
  :func:`adaptive_control_parameters`, :func:`control_points_ztt`, :func:`control_points_tool`;
- output displacement error / compliance (eq. 2.25-2.43): :func:`compliance_matrix`,
  :func:`compliance_errors`, :func:`compliance_over_box`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pmctl.core import kinematics as K
from pmctl.core.config import Geometry, Machine, load_machine
from pmctl.core.errors import PmctlError

DEG = math.pi / 180.0

# Table 2.1 of seed 000 (maxima over Z 293-458 mm, theta1 0-180 deg, theta2 +-30 deg).
TABLE_2_1 = {"G_T": 0.5599, "G_R": 0.0041, "omega_T": 1.0, "omega_R": 5.5152}
TABLE_2_1_BOX = {"Z": (293.0, 458.0), "theta1_deg": (0.0, 180.0), "theta2_deg": (-30.0, 30.0)}

_SMALL_TILT = 1e-7      # |sin theta2| below which J_L is singular (theta1 undefined at a level platform)


# ============================================================== Jacobian helpers

def _grid(Z, theta1, theta2):
    return np.broadcast_arrays(*(np.asarray(x, float) for x in (Z, theta1, theta2)))


def twist_map_ztt(Z, theta1, theta2, geom: Geometry):
    """(..., 6, 3) platform twist (dP, w) per unit chain-length change at a nominal (Z, th1, th2) pose
    (``kinematics.platform_twist_map``; chain-plane constraints held). Regular at theta2 = 0."""
    Z, t1, t2 = _grid(Z, theta1, theta2)
    P, R = K.platform_pose(Z, t1, t2, geom.platform_radius)
    return K.platform_twist_map(P, R, geom)


def output_rows(Z, theta1, theta2, geom: Geometry):
    """Rows dZ/dL and dtheta2/dL of the seed's Jacobian J = J_L^-1 (eq. 4.13), each (..., 3).

    Computed as the inverse of ``kinematics.jacobian_ztt``. At a level platform (theta2 = 0) J_L is
    singular (the theta1 column vanishes); there the rows take their limits theta2 -> 0:
    dZ/dL = the Z row of the platform twist map (Z(L) is smooth) and dtheta2/dL = w . dphi/dL, the
    rotation rate about the tilt axis w = (cos th1, sin th1, 0).
    """
    Z, t1, t2 = _grid(Z, theta1, theta2)
    JL = K.jacobian_ztt(Z, t1, t2, geom.platform_radius, geom)
    level = np.abs(np.sin(t2)) < _SMALL_TILT
    JLs = np.where(level[..., None, None], np.eye(3), JL)          # keep inv() finite, fixed below
    J = np.linalg.inv(JLs)
    dz, dt2 = J[..., 0, :], J[..., 2, :]
    if np.any(level):
        T = twist_map_ztt(Z, t1, t2, geom)
        w = np.stack([np.cos(t1), np.sin(t1), np.zeros_like(t1)], -1)
        dz = np.where(level[..., None], T[..., 2, :], dz)
        dt2 = np.where(level[..., None], np.einsum("...i,...ij->...j", w, T[..., 3:, :]), dt2)
    return dz, dt2


# ============================================================== input-output ratio (4.3)

def io_ratio(Z, theta1, theta2, geom: Geometry):
    """Input-output ratio of seed 000 eq. 4.14-4.22 at (Z, theta1, theta2) (broadcast), dimensionless.

    Definition (seed, verbatim in meaning): for the Z output, dZ = J_z^T dL with
    J_z = (dZ/dL1, dZ/dL2, dZ/dL3)^T, the Z row of J = J_L^-1 (J_L = ``jacobian_ztt``). Squaring,
    dZ^2 = dL^T (J_z J_z^T) dL; for a unit input |dL| = 1 the largest dZ^2 is the largest eigenvalue
    of the 3x3 matrix J_z J_z^T (eq. 4.22). That matrix has rank 1, so the eigenvalue is |J_z|^2
    (the seed finds it with the Jacobi method; numpy's eigvalsh gives the same number).
    Units: mm^2 of Z per mm^2 of chain length. About 1/3 at a level platform (each chain carries a
    third of a Z move), growing with |theta2| and as Z falls (Fig. 4.1-4.3).
    """
    dz, _ = output_rows(Z, theta1, theta2, geom)
    return np.einsum("...i,...i->...", dz, dz)


def io_ratio_maps(geom: Geometry, Zs=(300.0, 393.0, 500.0), theta1_deg=(0.0, 180.0),
                  theta2_deg=(-30.0, 30.0), n1=91, n2=121):
    """Maps over theta1 x theta2 at each Z of ``Zs``: returns (t1_deg (n1,), t2_deg (n2,),
    ratio (len(Zs), n1, n2))."""
    t1 = np.linspace(*theta1_deg, n1)
    t2 = np.linspace(*theta2_deg, n2)
    Zg, T1, T2 = np.meshgrid(np.asarray(Zs, float), t1 * DEG, t2 * DEG, indexing="ij")
    return t1, t2, io_ratio(Zg, T1, T2, geom)


# ============================================================== drive characteristics (2.3)

def drive_characteristics_at(Z, theta1, theta2, geom: Geometry):
    """Drive characteristics (seed 000 eq. 2.1-2.16) at each pose; dict of arrays (...).

    Seed form, with the seed's (Z, theta1, theta2) Jacobian J = J_L^-1 (generalised forces):
      - ``G_T``  = max_i |dZ/dL_i|: axial force of the most loaded chain for a unit force along Z (N/N);
      - ``G_R``  = max_i |dtheta2/dL_i|: for a unit moment (N mm) about the tilt axis (N/(N mm));
      - ``omega_T`` = max_i |dL_i/dZ|: chain speed per unit Z speed ((mm/s)/(mm/s));
      - ``omega_R`` = max_i |(dL_i/dtheta1, dL_i/dtheta2)| * pi/180: chain speed for a unit tilt
        rate (theta1', theta2') of 1 deg/s ((mm/s)/(deg/s)) (eq. 2.13-2.15, the i-th row of J^-1 = J_L).
    Physical form (6-DOF statics with the chain-plane reactions, ``kinematics.platform_twist_map`` T):
      - ``G_T_phys`` = max_i |T[0:3, i]|: unit force at P in any direction (the inclined chains
        carry part of a horizontal force);
      - ``G_R_phys`` = max_i |T[3:6, i]|: unit moment about P in any direction;
      - ``omega_R_phys``: chain speed for a unit platform angular velocity (1 deg/s, any feasible
        direction, Z held), * pi/180.
    (omega_T_phys equals omega_T: with no rotation the only feasible translation is along Z.)
    """
    Z, t1, t2 = _grid(Z, theta1, theta2)
    dz, dt2 = output_rows(Z, t1, t2, geom)
    JL = K.jacobian_ztt(Z, t1, t2, geom.platform_radius, geom)
    out = {
        "G_T": np.abs(dz).max(-1),
        "G_R": np.abs(dt2).max(-1),
        "omega_T": np.abs(JL[..., :, 0]).max(-1),
        "omega_R": np.linalg.norm(JL[..., :, 1:], axis=-1).max(-1) * DEG,
    }
    T = twist_map_ztt(Z, t1, t2, geom)
    out["G_T_phys"] = np.linalg.norm(T[..., :3, :], axis=-2).max(-1)
    out["G_R_phys"] = np.linalg.norm(T[..., 3:, :], axis=-2).max(-1)
    # Chain rates that keep Z still span a plane S (Tz . Ldot = 0); on it the angular velocity is
    # W Ldot (W = T[3:6]). max |Ldot_i| over |omega| = 1 is the norm of row i of Q (W Q)^+.
    tz = T[..., 2, :]
    _, _, vt = np.linalg.svd(tz[..., None, :])
    Q = np.swapaxes(vt[..., 1:, :], -1, -2)                       # (..., 3, 2) basis of S
    G = T[..., 3:, :] @ Q                                          # (..., 3, 2)
    M = Q @ np.linalg.pinv(G)                                      # (..., 3, 3) Ldot per omega
    out["omega_R_phys"] = np.linalg.norm(M, axis=-1).max(-1) * DEG
    return out


@dataclass
class DriveSummary:
    values: dict            # name -> maximum over the box
    where: dict             # name -> (Z, theta1_deg, theta2_deg) of the maximum
    box: dict


def maxima_over_box(fn, Z, theta1_deg, theta2_deg, steps):
    """Evaluate ``fn(Z, theta1, theta2) -> {name: grid}`` (radians) on a grid over the box and return
    ({name: max}, {name: (Z, theta1 deg, theta2 deg) where it occurs})."""
    nZ, n1, n2 = steps
    Zv = np.linspace(*Z, nZ)
    t1 = np.linspace(*theta1_deg, n1)
    t2 = np.linspace(*theta2_deg, n2)
    Zg, T1, T2 = np.meshgrid(Zv, t1 * DEG, t2 * DEG, indexing="ij")
    vals, where = {}, {}
    for k, v in fn(Zg, T1, T2).items():
        idx = np.unravel_index(int(np.argmax(v)), v.shape)
        vals[k] = float(v[idx])
        where[k] = (float(Zv[idx[0]]), float(t1[idx[1]]), float(t2[idx[2]]))
    return vals, where


def drive_characteristics(geom: Geometry, *, Z=(293.0, 458.0), theta1_deg=(0.0, 180.0),
                          theta2_deg=(-30.0, 30.0), nZ=34, n1=37, n2=61) -> DriveSummary:
    """Maxima of :func:`drive_characteristics_at` over a (Z, theta1, theta2) box (default: Table 2.1's)."""
    vals, where = maxima_over_box(lambda Zg, T1, T2: drive_characteristics_at(Zg, T1, T2, geom),
                                  Z, theta1_deg, theta2_deg, (nZ, n1, n2))
    return DriveSummary(vals, where, {"Z": Z, "theta1_deg": theta1_deg, "theta2_deg": theta2_deg,
                                      "steps": (nZ, n1, n2)})


# ============================================================== compliance (2.4.1)

def stiffness_diag(machine: Machine):
    """K = diag(axial x3, lateral x3) in N/mm: the three chains' axial springs (ball screw, nut, plate
    link) along u_i and their lateral springs (plate-link bending) normal to the chain plane at C_i,
    matching the rows of ``kinematics.constraint_jacobian``."""
    s = machine.stiffness
    return np.array([s.chain_axial] * 3 + [s.chain_lateral] * 3)


def compliance_matrix(Z, theta1, theta2, machine: Machine):
    """C = J K^-1 J^T (eq. 2.33), (..., 6, 6), for the twist (dP mm, dphi rad) of the platform at P
    under a wrench (F N, M N mm) about P.

    J = A^-1 with A = ``kinematics.constraint_jacobian`` (6 x 6: chain axes and chain-plane normals),
    i.e. the seed's 6-DOF model of 2.4.2 in which each chain also has a compliant direction normal to
    its plane; K from the config's ``[stiffness]`` table (N/mm at the chain, both directions).
    """
    geom = machine.geometry
    Z, t1, t2 = _grid(Z, theta1, theta2)
    P, R = K.platform_pose(Z, t1, t2, geom.platform_radius)
    J = np.linalg.inv(K.constraint_jacobian(P, R, geom))
    return (J / stiffness_diag(machine)) @ np.swapaxes(J, -1, -2)


def _max_sv(M):
    """sqrt(max eigenvalue of M^T M) (eq. 2.43) = largest singular value, for (..., m, n)."""
    return np.linalg.svd(M, compute_uv=False)[..., 0]


def compliance_errors(Z, theta1, theta2, machine: Machine):
    """Worst output displacement errors for a unit load in any direction (eq. 2.35-2.43), dict of (...):

    ``PF`` mm per N (translation under a force), ``RF`` rad per N (rotation under a force),
    ``PM`` mm per N mm (translation under a moment), ``RM`` rad per N mm (rotation under a moment).
    Each is sqrt(max eig(C_xy^T C_xy)) of the matching 3x3 block of C = J K^-1 J^T.
    """
    C = compliance_matrix(Z, theta1, theta2, machine)
    return {"PF": _max_sv(C[..., :3, :3]), "PM": _max_sv(C[..., :3, 3:]),
            "RF": _max_sv(C[..., 3:, :3]), "RM": _max_sv(C[..., 3:, 3:])}


def compliance_over_box(machine: Machine, *, Z=(293.0, 458.0), theta1_deg=(0.0, 180.0),
                        theta2_deg=(-20.0, 20.0), nZ=12, n1=37, n2=41):
    """Maxima of :func:`compliance_errors` over a box: (values dict, where dict (Z, th1, th2 deg))."""
    return maxima_over_box(lambda Zg, T1, T2: compliance_errors(Zg, T1, T2, machine),
                           Z, theta1_deg, theta2_deg, (nZ, n1, n2))


# ============================================================== path error of joint interpolation (4.4-4.5)
#
# A path is given as an ideal pose x(s), s in [0, 1]. The controller receives control points
# s_0 = 0 < s_1 < ... < s_n = 1, the actuator targets q(s_k) = IK(x(s_k)), and moves the actuators
# linearly between them. The path error at s is  e(s) = point(FK(q_lin(s))) - point(x(s)):
# the actual point against the ideal point of the same parameter. That is an upper bound of the
# contour error (the distance to the nearest ideal point), so a spacing that keeps |e| <= tol keeps
# the contour error <= tol too.

@dataclass(frozen=True)
class ZttSegment:
    """Straight segment in (Z mm, theta1 rad, theta2 rad) of the spatial part from ``start`` to ``end``.

    ``point_p`` is the point (platform frame, mm) whose path error is measured: the origin (the output
    point P, tool length 0, as in the seed's Fig. 4.4-4.6) or e.g. ``geom.tool_tip_p``.
    Actuators q = (L1, L2, L3).
    """

    start: np.ndarray
    end: np.ndarray
    geom: Geometry
    point_p: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def pose(self, s):
        s = np.asarray(s, float)[..., None]
        x = np.asarray(self.start, float) * (1.0 - s) + np.asarray(self.end, float) * s
        return K.platform_pose(x[..., 0], x[..., 1], x[..., 2], self.geom.platform_radius)

    def ideal(self, s):
        """(q, point, guess) of the ideal path at s (...)."""
        P, R = self.pose(s)
        q = K.chain_lengths(P, R, self.geom)
        return q, P + np.einsum("...ij,j->...i", R, self.point_p), (P, R)

    def actual(self, q, guess):
        """The measured point after FK of actuator positions q (...,3) (Newton warm-started at guess)."""
        sol = K.solve_platform(q, self.geom, guess)
        if not bool(np.all(sol.ok)):
            raise K.KinematicsError("forward kinematics failed on an interpolated path point")
        return sol.P + np.einsum("...ij,j->...i", sol.R, self.point_p)

    def point_jacobian(self, guess):
        """d(point)/dq (..., 3, 3) at the platform poses ``guess``."""
        P, R = guess
        T = K.platform_twist_map(P, R, self.geom)
        rp = np.einsum("...ij,j->...i", R, self.point_p)
        return T[..., :3, :] - K.skew(rp) @ T[..., 3:, :]


def _slerp(a0, a1, s):
    a0, a1 = np.asarray(a0, float), np.asarray(a1, float)
    s = np.asarray(s, float)[..., None]
    om = math.acos(max(-1.0, min(1.0, float(a0 @ a1))))
    if om < 1e-12:
        v = a0 * (1.0 - s) + a1 * s
    else:
        v = (np.sin((1.0 - s) * om) * a0 + np.sin(s * om) * a1) / math.sin(om)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@dataclass(frozen=True)
class ToolSegment:
    """5-axis tool-pose segment: tip moves linearly in W, the tool axis turns on the great circle
    (slerp) from ``axis0`` to ``axis1``. Actuators q = (L1, L2, L3, X, Y); the error is the tool
    tip position in W. Endpoint reachability is the caller's business (``kinematics.ik``)."""

    tip0: np.ndarray
    axis0: np.ndarray
    tip1: np.ndarray
    axis1: np.ndarray
    machine: Machine

    def ideal(self, s):
        s = np.asarray(s, float)
        tip = np.asarray(self.tip0, float) * (1.0 - s[..., None]) + np.asarray(self.tip1, float) * s[..., None]
        axis = _slerp(self.axis0, self.axis1, s)
        r = K.ik_batch(tip, axis, self.machine, check_limits=False)
        return r.q, tip, (r.P, r.R)

    def actual(self, q, guess):
        pose, ok = K.fk_batch(q, self.machine, guess)
        if not bool(np.all(ok)):
            raise K.KinematicsError("forward kinematics failed on an interpolated path point")
        return pose.tip

    def point_jacobian(self, guess):
        P, R = guess
        return K.jacobian_tool(P, R, self.machine.geometry)[..., :3, :]


def interpolation_error(seg, s_ctrl, n_sub=16):
    """Path error of joint-space linear interpolation between control points ``s_ctrl`` (sorted,
    from 0 to 1). Returns (s (M,), e (M, 3)): n_sub samples per interval plus the last point;
    e = actual point - ideal point (mm)."""
    s_ctrl = np.asarray(s_ctrl, float)
    q_ctrl = seg.ideal(s_ctrl)[0]
    f = np.arange(n_sub) / n_sub
    h = np.diff(s_ctrl)
    s = (s_ctrl[:-1, None] + f * h[:, None]).ravel()
    q_lin = (q_ctrl[:-1, None, :] + f[:, None] * (q_ctrl[1:] - q_ctrl[:-1])[:, None, :]).reshape(-1, q_ctrl.shape[-1])
    s = np.append(s, s_ctrl[-1])
    q_lin = np.vstack([q_lin, q_ctrl[-1:]])
    _, ref, guess = seg.ideal(s)
    return s, seg.actual(q_lin, guess) - ref


def _interval_max_error(seg, s_ctrl, q_ctrl, fractions):
    f = np.asarray(fractions, float)
    h = np.diff(s_ctrl)
    s = s_ctrl[:-1, None] + f * h[:, None]
    q_lin = q_ctrl[:-1, None, :] + f[:, None] * (q_ctrl[1:] - q_ctrl[:-1])[:, None, :]
    _, ref, guess = seg.ideal(s)
    e = np.linalg.norm(seg.actual(q_lin, guess) - ref, axis=-1)
    return e.max(-1)


def error_density(seg, s, ds=1e-3):
    """Local error bound of joint-space interpolation, rho(s) in mm per (unit s)^2: an interval of
    length h around s deviates by about rho h^2 (= h^2/8 |J_f q''|, J_f = d(point)/dq, the
    input-output Jacobian whose Z row gives the seed's input-output ratio |J_z|^2).
    q'' by a central difference of the closed-form IK."""
    s = np.asarray(s, float)
    q0, _, guess = seg.ideal(s)
    qm = seg.ideal(s - ds)[0]
    qp = seg.ideal(s + ds)[0]
    qdd = (qp - 2.0 * q0 + qm) / ds**2
    Jf = seg.point_jacobian(guess)
    return np.linalg.norm(np.einsum("...ij,...j->...i", Jf, qdd), axis=-1) / 8.0


@dataclass
class AdaptiveSpacing:
    s: np.ndarray              # control-point parameters, 0 ... 1
    tol: float                 # mm
    max_error: float           # largest error found by the verification samples, mm
    predicted_intervals: int   # from the local error bound alone
    refinements: int           # intervals split by the verification


def adaptive_control_parameters(seg, tol_mm=1e-3, *, n_probe=64, safety=0.8, verify_margin=0.95,
                                fractions=(0.2, 0.35, 0.5, 0.65, 0.8), max_rounds=30,
                                max_intervals=200_000) -> AdaptiveSpacing:
    """Control points for ``seg`` (a :class:`ZttSegment`, :class:`ToolSegment` or any object with
    ``ideal``/``actual``/``point_jacobian``) so that joint-space interpolation stays within ``tol_mm``.

    1. Placement from the local error bound rho(s) (:func:`error_density`): interval length
       h(s) = sqrt(safety * tol / rho(s)), points equidistributed in the integral of 1/h(s) ds
       (the optimal spacing for piecewise-linear interpolation: small steps where the
       input-output ratio and the joint curvature are large, as in seed 4.5).
    2. Verification by forward kinematics at ``fractions`` of every interval (the error of an
       interval is, to leading order, a parabola peaking at its middle); an interval over
       ``verify_margin * tol_mm`` is split into ceil(sqrt(e / (safety tol))) parts, and the check
       repeats. The margin covers the peak falling between the sampled fractions (a skewed
       interval's true maximum can exceed the sampled one by a little).
    """
    if not tol_mm > 0:
        raise PmctlError(f"path tolerance must be > 0 mm, got {tol_mm}")
    sp = np.linspace(0.0, 1.0, n_probe + 1)
    rho = error_density(seg, sp)
    dens = np.sqrt(rho / (safety * tol_mm))
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(sp))])
    n = max(1, int(math.ceil(cum[-1])))
    if n > max_intervals:
        raise PmctlError(f"tolerance {tol_mm} mm needs about {n} control points on this segment")
    s_ctrl = np.interp(np.linspace(0.0, cum[-1], n + 1), cum, sp) if cum[-1] > 0 else np.array([0.0, 1.0])
    s_ctrl[0], s_ctrl[-1] = 0.0, 1.0
    q_ctrl = seg.ideal(s_ctrl)[0]
    splits = 0
    for _ in range(max_rounds):
        emax = _interval_max_error(seg, s_ctrl, q_ctrl, fractions)
        bad = emax > verify_margin * tol_mm
        if not np.any(bad):
            return AdaptiveSpacing(s_ctrl, tol_mm, float(emax.max()), n, splits)
        parts = np.where(bad, np.maximum(2, np.ceil(np.sqrt(emax / (safety * tol_mm)))), 1).astype(int)
        if parts.sum() > max_intervals:
            raise PmctlError(f"tolerance {tol_mm} mm needs more than {max_intervals} control points")
        new = [s_ctrl[:1]]
        for k in range(len(s_ctrl) - 1):
            new.append(np.linspace(s_ctrl[k], s_ctrl[k + 1], parts[k] + 1)[1:])
        s_new = np.concatenate(new)
        splits += int(bad.sum())
        # Only the new points need IK.
        q_new = np.empty((len(s_new), q_ctrl.shape[-1]))
        old = np.isin(s_new, s_ctrl)
        q_new[old] = q_ctrl
        q_new[~old] = seg.ideal(s_new[~old])[0]
        s_ctrl, q_ctrl = s_new, q_new
    raise PmctlError(f"adaptive spacing did not meet {tol_mm} mm after {max_rounds} refinements")


def control_points_ztt(start, end, machine: Machine, tol_mm=1e-3, *, point="P") -> np.ndarray:
    """Parameters s in [0, 1] of the control points of the straight (Z mm, theta1 rad, theta2 rad)
    segment ``start`` -> ``end`` that keep the joint-interpolation path error of ``point`` ("P": the
    output point; "tip": the tool tip) within ``tol_mm``."""
    p = np.zeros(3) if point == "P" else machine.geometry.tool_tip_p
    seg = ZttSegment(np.asarray(start, float), np.asarray(end, float), machine.geometry, p)
    return adaptive_control_parameters(seg, tol_mm).s


def control_points_tool(tip0, axis0, tip1, axis1, machine: Machine, tol_mm=1e-3) -> np.ndarray:
    """Parameters s in [0, 1] of the control points of a tool-pose segment (tip linear in W, axis
    slerp) that keep the tool-tip error of joint-space interpolation of q = (L1, L2, L3, X, Y)
    within ``tol_mm``. For a planner: pose(s) is the ideal pose at each returned s."""
    a0 = np.asarray(axis0, float) / np.linalg.norm(axis0)
    a1 = np.asarray(axis1, float) / np.linalg.norm(axis1)
    seg = ToolSegment(np.asarray(tip0, float), a0, np.asarray(tip1, float), a1, machine)
    return adaptive_control_parameters(seg, tol_mm).s


def seed_path_error(machine: Machine, theta2_points_deg, *, Z=393.0, theta1_deg=0.0, n_sub=40):
    """Seed 000 4.4 experiment: control points at theta2_points_deg (theta1, Z fixed), tool length 0.
    Returns (theta2_deg (M,), Z error (M,) mm, per-interval max |Z error| (n,))."""
    t2 = np.radians(np.asarray(theta2_points_deg, float))
    start = np.array([Z, theta1_deg * DEG, t2[0]])
    end = np.array([Z, theta1_deg * DEG, t2[-1]])
    seg = ZttSegment(start, end, machine.geometry)
    s_ctrl = (t2 - t2[0]) / (t2[-1] - t2[0])
    s, e = interpolation_error(seg, s_ctrl, n_sub)
    ez = e[:, 2]
    per = np.abs(ez[:-1]).reshape(len(t2) - 1, n_sub).max(-1)
    return np.degrees(t2[0] + s * (t2[-1] - t2[0])), ez, per


# ============================================================== CLI (thin: compute, print, plot)

def _setup(args):
    machine = load_machine(args.config)
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise PmctlError(f"{out}: cannot create output directory: {e.strerror or e}") from None
    import matplotlib  # lazy: matplotlib (heavy) loads only when a figure is drawn
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: matplotlib (heavy) loads only when a figure is drawn
    return machine, out, plt


def _save(fig, path, plt):
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"wrote {path}")


def _cmd_io_ratio(args):
    machine, out, plt = _setup(args)
    Zs = (300.0, 393.0, 500.0)
    t1, t2, r = io_ratio_maps(machine.geometry, Zs)
    print("input-output ratio dZ^2 = max eig(J_z J_z^T) per unit |dL| (Tachiya et al. 2006, eq. 4.22), theta1 0-180, theta2 +-30 deg")
    i0 = int(np.argmin(np.abs(t2)))
    for k, Z in enumerate(Zs):
        m = r[k]
        band = np.abs(t2) <= 20.0
        print(f"  Z = {Z:5.0f} mm: level {m[:, i0].mean():.4f}, max over |theta2|<=20: {m[:, band].max():.4f}, "
              f"max over |theta2|<=30: {m.max():.4f} at theta1 = {t1[np.argmax(m) // len(t2)]:.0f} deg, "
              f"theta2 = {t2[np.argmax(m) % len(t2)]:+.0f} deg")
    fig, axs = plt.subplots(1, 3, figsize=(16, 4.6), constrained_layout=True)
    for k, ax in enumerate(axs):
        m = r[k].T
        im = ax.pcolormesh(t1, t2, m, shading="auto", cmap="viridis")
        ax.contour(t1, t2, m, levels=np.linspace(m.min(), m.max(), 10)[1:-1], colors="w", linewidths=0.5)
        ax.set_title(f"input-output ratio ΔZ²,  Z = {Zs[k]:.0f} mm\n(own colour scale: {m.min():.4f} ... {m.max():.4f})")
        ax.set_xlabel("θ1 [deg]")
        ax.set_ylabel("θ2 [deg]")
        fig.colorbar(im, ax=ax, label="ΔZ² per unit |ΔL|² [-]")
    _save(fig, out / "io_ratio.png", plt)
    return 0


def _cmd_drive(args):
    machine, out, plt = _setup(args)
    geom = machine.geometry
    full = drive_characteristics(geom)
    seedgrid = drive_characteristics(geom, Z=(298.0, 458.0), nZ=9, n1=37, n2=61)
    print("drive characteristics (Tachiya et al. 2006, sec. 2.3.1), maxima over Z 293-458 mm, theta1 0-180 deg, theta2 +-30 deg")
    print(f"  {'':10s} {'Table 2.1':>10s} {'ours':>10s}  {'Z from 298 step 20':>18s}   at (Z, theta1, theta2)")
    units = {"G_T": "N/N", "G_R": "N/(N mm)", "omega_T": "(mm/s)/(mm/s)", "omega_R": "(mm/s)/(deg/s)"}
    for k in ("G_T", "G_R", "omega_T", "omega_R"):
        w = full.where[k]
        print(f"  {k:10s} {TABLE_2_1[k]:10.4f} {full.values[k]:10.4f}  {seedgrid.values[k]:18.4f}   "
              f"({w[0]:.0f}, {w[1]:.0f}, {w[2]:+.0f})  {units[k]}")
    print("  physical 6-DOF forms (unit load / angular velocity in any direction):")
    for k in ("G_T_phys", "G_R_phys", "omega_R_phys"):
        print(f"  {k:12s} {full.values[k]:10.4f}")
    print("  R_out*pi/180 = %.4f (mm/s)/(deg/s)" % (geom.platform_radius * DEG))
    print("  notes: G_T, G_R rise steeply as Z falls, so their maxima sit at the lowest Z of the box.\n"
          "  Over Z 293-458 our model gives G_T 0.575, G_R 0.0042; evaluated on Z = 298, 318, ..., 458\n"
          "  (the 20 mm grid of the report's 2.4.2 study) it gives Table 2.1's 0.5599 / 0.0041: the report's\n"
          "  table was evidently computed from Z = 298 mm. omega_T = max dL_i/dZ = 1 (chains nearly vertical);\n"
          "  omega_R = 5.52 ~ R_out pi/180. G_T/G_R use generalised forces (Z force, theta2 moment) as the\n"
          "  report's J = J_L^-1 does; a horizontal force also loads the inclined chains (G_T_phys).")
    # Plot: maxima over theta1 vs theta2 for a few heights.
    t1 = np.linspace(0.0, 180.0, 91) * DEG
    t2 = np.linspace(-30.0, 30.0, 121)
    fig, axs = plt.subplots(2, 2, figsize=(11, 7.5), constrained_layout=True)
    for Z in (293.0, 343.0, 393.0, 458.0):
        Zg, T1, T2 = np.meshgrid([Z], t1, t2 * DEG, indexing="ij")
        res = drive_characteristics_at(Zg, T1, T2, geom)
        for ax, k in zip(axs.ravel(), ("G_T", "G_R", "omega_T", "omega_R")):
            ax.plot(t2, res[k][0].max(0), label=f"Z = {Z:.0f} mm")
    for ax, k in zip(axs.ravel(), ("G_T", "G_R", "omega_T", "omega_R")):
        ax.axhline(TABLE_2_1[k], color="k", ls="--", lw=0.8, label="Table 2.1")
        ax.set_xlabel("θ2 [deg]")
        ax.set_ylabel(f"{k} [{units[k]}]")
        ax.set_title(f"{k}: max over θ1")
        ax.grid(alpha=0.3)
    axs[0, 0].legend(fontsize=8)
    _save(fig, out / "drive.png", plt)
    return 0


def _cmd_path_error(args):
    machine, out, plt = _setup(args)
    tol = args.tol_um * 1e-3
    if not (math.isfinite(tol) and tol > 0):
        raise PmctlError(f"--tol-um must be a positive number, got {args.tol_um}")
    geom = machine.geometry
    fig44 = np.arange(-20.0, 20.1, 5.0)
    fig46 = np.array([-20.0, -15.0, -10.0, -5.0, 0.0, 5.0, 10.0, 13.5, 17.0, 20.0])
    print("path error of joint-space interpolation, Z = 393 mm, theta1 = 0 deg, tool length 0 (Tachiya et al. 2006, sec. 4.4)")
    res = {}
    for name, pts in (("Fig. 4.4 (5 deg spacing)", fig44), ("Fig. 4.6 (3.5/3.5/3 deg above +10)", fig46)):
        th, ez, per = seed_path_error(machine, pts)
        res[name] = (th, ez, pts)
        print(f"  {name}: max |Z error| per interval [mm]:")
        print("    " + "  ".join(f"{a:+.1f}..{b:+.1f}: {e:.4f}" for a, b, e in zip(pts[:-1], pts[1:], per)))
    seg = ZttSegment(np.array([393.0, 0.0, -20.0 * DEG]), np.array([393.0, 0.0, 20.0 * DEG]), geom)
    ad = adaptive_control_parameters(seg, tol)
    s_d, e_d = interpolation_error(seg, ad.s, 32)
    h = np.diff(ad.s) * 40.0
    print(f"  adaptive spacing for {args.tol_um:g} um on the same sweep: {len(ad.s) - 1} intervals, spacing "
          f"{h.min():.2f}-{h.max():.2f} deg (finest near theta2 = {(-20 + 40 * ad.s[np.argmin(h)]):+.1f}), "
          f"max |error| {np.linalg.norm(e_d, axis=1).max() * 1e3:.3f} um (32 samples/interval)")
    print(f"  adaptive spacing, other segments (tol {args.tol_um:g} um, error of P and of the tool tip):")
    cases = [("theta1 = 60, theta2 -20 -> +20, Z 393", (393, 60, -20), (393, 60, 20)),
             ("Z 300 -> 458, theta1 = 120, theta2 = 15", (300, 120, 15), (458, 120, 15)),
             ("theta1 10 -> 170, theta2 = 20, Z 300", (300, 10, 20), (300, 170, 20)),
             ("(300, 0, -20) -> (458, 180, 20)", (300, 0, -20), (458, 180, 20))]
    for text, a, b in cases:
        a = np.array([a[0], a[1] * DEG, a[2] * DEG])
        b = np.array([b[0], b[1] * DEG, b[2] * DEG])
        row = []
        for label, p in (("P", np.zeros(3)), ("tip", geom.tool_tip_p)):
            sg = ZttSegment(a, b, geom, p)
            r = adaptive_control_parameters(sg, tol)
            _, e = interpolation_error(sg, r.s, 16)
            row.append(f"{label}: {len(r.s) - 1:4d} intervals, max {np.linalg.norm(e, axis=1).max() * 1e3:.3f} um")
        print(f"    {text:42s} " + "; ".join(row))
    fig, axs = plt.subplots(2, 2, figsize=(14, 9), constrained_layout=True)
    axs = axs.ravel()
    for ax, (name, (th, ez, pts)) in zip(axs[:2], res.items()):
        ax.plot(th, ez * 1e3, lw=1.2)
        ax.plot(pts, np.zeros_like(pts), "k|", ms=12, label="control points")
        ax.axhline(20, color="r", ls=":", lw=0.8, label="20 µm")
        ax.axhline(50, color="r", ls="--", lw=0.8, label="50 µm")
        ax.set_title(f"Z path error, θ1 = 0°, Z = 393 mm\n{name}")
        ax.set_xlabel("θ2 [deg]")
        ax.set_ylabel("Z error [µm]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    th_d = -20.0 + 40.0 * s_d
    axs[2].plot(th_d, e_d[:, 2] * 1e3, lw=1.0, label="Z error")
    axs[2].plot(th_d, np.linalg.norm(e_d, axis=1) * 1e3, lw=1.0, label="|error of P|")
    axs[2].plot(-20.0 + 40.0 * ad.s, np.zeros_like(ad.s), "k|", ms=10, label=f"{len(ad.s)} control points")
    axs[2].axhline(args.tol_um, color="r", ls="--", lw=0.8, label="tolerance")
    axs[2].set_title(f"adaptive spacing, tolerance {args.tol_um:g} µm")
    axs[2].set_xlabel("θ2 [deg]")
    axs[2].set_ylabel("error [µm]")
    axs[2].grid(alpha=0.3)
    axs[2].legend(fontsize=8)
    # Spacing chosen vs the input-output ratio along the sweep.
    mid = -20.0 + 40.0 * 0.5 * (ad.s[1:] + ad.s[:-1])
    axs[3].step(mid, h, where="mid", color="C0", label="adaptive spacing")
    axs[3].set_xlabel("θ2 [deg]")
    axs[3].set_ylabel("control-point spacing [deg]", color="C0")
    ax2 = axs[3].twinx()
    th_r = np.linspace(-20.0, 20.0, 161)
    ax2.plot(th_r, io_ratio(393.0, 0.0, th_r * DEG, geom), color="C3", label="ΔZ² (io ratio)")
    ax2.set_ylabel("input-output ratio ΔZ² [-]", color="C3")
    axs[3].set_title(f"spacing for {args.tol_um:g} µm vs input-output ratio (θ1 = 0°, Z = 393 mm)")
    axs[3].grid(alpha=0.3)
    _save(fig, out / "path_error.png", plt)
    return 0


def _cmd_compliance(args):
    machine, out, plt = _setup(args)
    s = machine.stiffness
    vals, where = compliance_over_box(machine)
    print(f"output displacement error (Tachiya et al. 2006, sec. 2.4.1), C = J K^-1 J^T at P, chain axial "
          f"{s.chain_axial:g} N/mm, lateral {s.chain_lateral:g} N/mm;\n"
          f"  maxima over Z 293-458 mm, theta1 0-180 deg, theta2 +-20 deg. Names as in eq. 2.34: C_<error><load>,\n"
          f"  P = translation error, R = rotation error, F = force load, M = moment load:")
    # Table 2.4/2.5 of the report name the same four maxima by load first (P_F, P_M: under a
    # force; R_F, R_M: under a moment), so its P_M is our RF and its R_F our PM (docs/machine.md).
    lines = [("PF", "translation per unit force", vals["PF"] * 1e3, "um/N", "Table 2.5 column P_F"),
             ("RF", "rotation per unit force", vals["RF"] / DEG * 1e3, "mdeg/N", "Table 2.5 column P_M"),
             ("PM", "translation per unit moment", vals["PM"] * 1e6, "um/(N m)", "Table 2.5 column R_F"),
             ("RM", "rotation per unit moment", vals["RM"] / DEG * 1e6, "mdeg/(N m)", "Table 2.5 column R_M")]
    for k, text, v, u, seed in lines:
        w = where[k]
        print(f"  C_{k} {text:28s} {v:10.4f} {u:11s} at ({w[0]:.0f}, {w[1]:.0f}, {w[2]:+.0f})  [{seed}]")
    print("  (Table 2.5 names the maxima load first: its P_M is the rotation under a force (our C_RF), its R_F\n"
          "  the translation under a moment (our C_PM). Its values for the 134 mm plate link, P_F 0.133,\n"
          "  P_M 0.058, R_F 0.166, R_M 0.078, come from its own stiffness model, whose stiffness values the\n"
          "  report does not give: not directly comparable)")
    t1 = np.linspace(0.0, 180.0, 91)
    t2 = np.linspace(-20.0, 20.0, 81)
    Zs = (300.0, 393.0, 458.0)
    Zg, T1, T2 = np.meshgrid(Zs, t1 * DEG, t2 * DEG, indexing="ij")
    res = compliance_errors(Zg, T1, T2, machine)
    fig, axs = plt.subplots(2, 3, figsize=(15, 8), constrained_layout=True)
    for row, (k, scale, unit) in enumerate((("PF", 1e3, "µm/N"), ("RM", 1e6 / DEG, "mdeg/(N·m)"))):
        m = res[k] * scale
        for c, ax in enumerate(axs[row]):
            im = ax.pcolormesh(t1, t2, m[c].T, shading="auto", cmap="magma", vmin=m.min(), vmax=m.max())
            ax.set_title(f"C_{k} ({'translation per unit force' if k == 'PF' else 'rotation per unit moment'}): "
                         f"worst error, Z = {Zs[c]:.0f} mm", fontsize=10)
            ax.set_xlabel("θ1 [deg]")
            ax.set_ylabel("θ2 [deg]")
        fig.colorbar(im, ax=axs[row], label=f"{k} [{unit}]")
    _save(fig, out / "compliance.png", plt)
    return 0
