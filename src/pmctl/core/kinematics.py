"""Kinematics of the 3-RPS + XY-table machine (docs/machine.md §3-5; the KAKENHI report "Hybrid parallel
mechanism for high-precision machining and compensation of its machining error", ch. 3-4). Pure
functions, no I/O.

Conventions
-----------
- Angles in radians inside this module (the CLI and configs speak degrees).
- Joint vector q = (L1, L2, L3, X, Y) in mm. L_i is the actuator coordinate:
  |C_i - A_i| = L_i + length_offset_i.
- Tool pose: tip in the workpiece frame W (mm) and tool axis v (unit, tip -> spindle).
- Every function takes a single pose or a batch: leading dimensions broadcast
  (angles shape (...), vectors (..., 3), rotations (..., 3, 3), joints (..., 5)).
- Platform pose (P, R): output point P in the base frame and rotation R platform -> base.
  Newton updates use the spatial angular increment w: R <- exp(w) R.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pmctl.core.config import Geometry, Machine
from pmctl.core.errors import KinematicsError, UnreachablePose
from pmctl.core.tolerances import AXIS_TOL

FK_TOL_MM = 1e-10        # residual of the 6 loop equations at which Newton stops (criterion: < 1e-9 mm)
FK_MAX_ITER = 30
EZ = np.array([0.0, 0.0, 1.0])


# ---------------------------------------------------------------- small helpers

def skew(w):
    """[w]x for w (..., 3)."""
    w = np.asarray(w, dtype=float)
    z = np.zeros(w.shape[:-1])
    return np.stack([np.stack([z, -w[..., 2], w[..., 1]], -1),
                     np.stack([w[..., 2], z, -w[..., 0]], -1),
                     np.stack([-w[..., 1], w[..., 0], z], -1)], -2)


def expm_so3(w):
    """Rodrigues: rotation matrix of the rotation vector w (..., 3)."""
    w = np.asarray(w, dtype=float)
    th = np.linalg.norm(w, axis=-1)[..., None, None]
    K = skew(w)
    small = th < 1e-8
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th**2 / 6.0, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(ths)) / ths**2)
    return np.eye(3) + a * K + b * (K @ K)


def rot_x(a):
    a = np.asarray(a, dtype=float)
    c, s, o, z = np.cos(a), np.sin(a), np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def rot_y(b):
    b = np.asarray(b, dtype=float)
    c, s, o, z = np.cos(b), np.sin(b), np.ones_like(b), np.zeros_like(b)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def rot_z(g):
    g = np.asarray(g, dtype=float)
    c, s, o, z = np.cos(g), np.sin(g), np.ones_like(g), np.zeros_like(g)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def _mv(R, x):
    """R (...,3,3) @ x (...,3) -> (...,3)."""
    return np.einsum("...ij,...j->...i", R, x)


# ---------------------------------------------------------------- pose representations

def tilt_rotation(theta1, theta2):
    """R for tilt theta2 about the horizontal axis (cos th1, sin th1, 0) (eq. 3.1-3.3)."""
    t1, t2 = np.broadcast_arrays(np.asarray(theta1, float), np.asarray(theta2, float))
    c1, s1, c2, s2 = np.cos(t1), np.sin(t1), np.cos(t2), np.sin(t2)
    v = 1.0 - c2
    return np.stack([
        np.stack([c1 * c1 * v + c2, c1 * s1 * v, s1 * s2], -1),
        np.stack([c1 * s1 * v, s1 * s1 * v + c2, -c1 * s2], -1),
        np.stack([-s1 * s2, c1 * s2, c2], -1)], -2)


def dependent_xy(theta1, theta2, r_out):
    """Dependent platform motion X_u, Y_u of the zero-torsion 3-RPS (eq. 3.11, 3.13)."""
    t1, t2 = np.asarray(theta1, float), np.asarray(theta2, float)
    v = 1.0 - np.cos(t2)
    return r_out * np.cos(t1) * np.sin(t1) * v, 0.5 * r_out * v * np.cos(2 * t1)


def platform_pose(Z, theta1, theta2, r_out):
    """Nominal closed form: (Z, th1, th2) -> P (...,3), R (...,3,3)."""
    Z, t1, t2 = np.broadcast_arrays(*(np.asarray(x, float) for x in (Z, theta1, theta2)))
    xu, yu = dependent_xy(t1, t2, r_out)
    return np.stack([xu, yu, Z], -1), tilt_rotation(t1, t2)


def axis_to_tilt(v):
    """Tool axis v (...,3) -> (theta1, theta2), theta1 in (0, pi], theta2 signed (docs/machine.md §3).

    At theta2 = 0 the tilt axis is undefined; theta1 = pi is returned.
    """
    v = np.asarray(v, dtype=float)
    t1 = np.arctan2(v[..., 0], -v[..., 1])
    t2 = np.arctan2(np.hypot(v[..., 0], v[..., 1]), v[..., 2])
    flip = t1 <= 0.0
    t1 = np.where(flip, t1 + np.pi, t1)
    t2 = np.where(flip, -t2, t2)
    zero = t1 <= 0.0          # atan2(-0, -y) = -pi -> 0 after the flip: that is theta1 = pi unflipped
    t1 = np.where(zero, np.pi, t1)
    t2 = np.where(zero, -t2, t2)
    return t1, t2


def tilt_to_axis(theta1, theta2):
    t1, t2 = np.broadcast_arrays(np.asarray(theta1, float), np.asarray(theta2, float))
    return np.stack([np.sin(t1) * np.sin(t2), -np.cos(t1) * np.sin(t2), np.cos(t2)], -1)


def dependent_yaw(alpha, beta):
    """gamma_u of the roll-pitch representation (docs/machine.md §3, sign corrected from seed eq. 3.24)."""
    a, b = np.asarray(alpha, float), np.asarray(beta, float)
    return -np.arctan(np.sin(a) * np.sin(b) / (np.cos(a) + np.cos(b)))


def roll_pitch_pose(alpha, beta, Z, r_out):
    """Roll-pitch (alpha, beta) representation: R = Rx(a) Ry(b) Rz(gamma_u), P = (X_u, Y_u, Z)."""
    a, b, Z = np.broadcast_arrays(*(np.asarray(x, float) for x in (alpha, beta, Z)))
    g = dependent_yaw(a, b)
    R = rot_x(a) @ rot_y(b) @ rot_z(g)
    xu = -r_out * np.cos(b) * np.sin(g)
    yu = 0.5 * r_out * (np.cos(b) * np.cos(g) - np.cos(a) * np.cos(g) + np.sin(a) * np.sin(b) * np.sin(g))
    return np.stack([xu, yu, Z], -1), R


def axis_from_roll_pitch(alpha, beta):
    """Tool axis of roll alpha, pitch beta: Rx(a) Ry(b) z (yaw does not move z)."""
    a, b = np.broadcast_arrays(np.asarray(alpha, float), np.asarray(beta, float))
    return np.stack([np.sin(b), -np.sin(a) * np.cos(b), np.cos(a) * np.cos(b)], -1)


def roll_pitch_from_axis(v):
    v = np.asarray(v, dtype=float)
    beta = np.arcsin(np.clip(v[..., 0], -1.0, 1.0))
    alpha = np.arctan2(-v[..., 1], v[..., 2])
    return alpha, beta


def tilt_to_roll_pitch(theta1, theta2):
    return roll_pitch_from_axis(tilt_to_axis(theta1, theta2))


def roll_pitch_to_tilt(alpha, beta):
    return axis_to_tilt(axis_from_roll_pitch(alpha, beta))


# ---------------------------------------------------------------- loop equations

def joint_positions(P, R, geom: Geometry):
    """C_i in the base frame, (..., 3 chains, 3)."""
    return P[..., None, :] + np.einsum("...ij,kj->...ki", R, geom.platform_joints)


def chain_lengths(P, R, geom: Geometry):
    """Actuator coordinates L_i (..., 3) of a platform pose."""
    d = joint_positions(P, R, geom) - geom.base_joints
    return np.linalg.norm(d, axis=-1) - geom.length_offsets


def loop_residual(P, R, L, geom: Geometry):
    """The 6 loop equations: |C_i - A_i| - (L_i + off_i) and n_i.(C_i - A_i)."""
    d = joint_positions(P, R, geom) - geom.base_joints
    f_len = np.linalg.norm(d, axis=-1) - (np.asarray(L, float) + geom.length_offsets)
    f_pln = np.einsum("...ki,ki->...k", d, geom.revolute_axes)
    return np.concatenate([f_len, f_pln], -1)


def constraint_jacobian(P, R, geom: Geometry):
    """d(loop equations)/d(P, w), (..., 6, 6). Rows 0-2 are the unit chain directions and their
    moments (the wrench Jacobian of the chains), rows 3-5 the chain-plane constraints."""
    rc = np.einsum("...ij,kj->...ki", R, geom.platform_joints)          # R c_i
    d = P[..., None, :] + rc - geom.base_joints
    u = d / np.linalg.norm(d, axis=-1, keepdims=True)
    n = np.broadcast_to(geom.revolute_axes, u.shape)
    top = np.concatenate([u, np.cross(rc, u)], -1)
    bot = np.concatenate([n, np.cross(rc, n)], -1)
    return np.concatenate([top, bot], -2)


# ---------------------------------------------------------------- forward kinematics

@dataclass
class PlatformSolution:
    P: np.ndarray
    R: np.ndarray
    iterations: int
    residual: np.ndarray     # max |loop equation| per pose, mm
    ok: np.ndarray           # converged and on the assembly branch


def initial_guess(L, geom: Geometry):
    """Cold start: level platform at the height that fits the mean chain length."""
    L = np.asarray(L, float)
    lm = L.mean(-1) + geom.length_offsets.mean()
    dr = geom.base_radius - geom.platform_radius
    Z = np.sqrt(np.maximum(lm**2 - dr**2, 1.0))
    P = np.zeros(L.shape[:-1] + (3,))
    P[..., 2] = Z
    return P, np.broadcast_to(np.eye(3), L.shape[:-1] + (3, 3)).copy()


def _branch_ok(P, R, geom: Geometry, max_tilt_rad):
    return (P[..., 2] > 0.0) & (R[..., 2, 2] > np.cos(max_tilt_rad))


def solve_platform(L, geom: Geometry, guess=None, *, tol=FK_TOL_MM, max_iter=FK_MAX_ITER,
                   max_tilt_rad=np.radians(45.0)) -> PlatformSolution:
    """Newton on the 6-DOF platform pose for chain lengths L (..., 3). Batch-capable.

    Failure (no convergence, iteration cap, off the assembly branch) is reported in ``ok``;
    use :func:`forward_platform` for the raising single-pose form.
    """
    L = np.asarray(L, float)
    shape = L.shape[:-1]
    if guess is None:
        P, R = initial_guess(L, geom)
    else:
        P = np.broadcast_to(guess[0], shape + (3,))
        R = np.broadcast_to(guess[1], shape + (3, 3))
    # Work on flat copies and iterate only the poses that have not converged yet.
    L = L.reshape(-1, 3)
    P = np.array(P, dtype=float).reshape(-1, 3)
    R = np.array(R, dtype=float).reshape(-1, 3, 3)
    f = loop_residual(P, R, L, geom)
    res = np.abs(f).max(-1)
    act = np.nonzero(~(res < tol))[0]
    it = 0
    while it < max_iter and act.size:
        Pa, Ra, La = P[act], R[act], L[act]
        J = constraint_jacobian(Pa, Ra, geom)
        step = np.linalg.solve(J, -f[act][..., None])[..., 0]
        # Limit wild first steps from a poor guess (50 mm, 0.2 rad).
        sp = np.linalg.norm(step[:, :3], axis=-1, keepdims=True)
        sr = np.linalg.norm(step[:, 3:], axis=-1, keepdims=True)
        step = step * np.minimum(1.0, np.minimum(50.0 / np.maximum(sp, 1e-300), 0.2 / np.maximum(sr, 1e-300)))
        Pa = Pa + step[:, :3]
        Ra = expm_so3(step[:, 3:]) @ Ra
        fa = loop_residual(Pa, Ra, La, geom)
        P[act], R[act], f[act] = Pa, Ra, fa
        ra = np.abs(fa).max(-1)
        res[act] = ra
        act = act[~(ra < tol)]
        it += 1
    res = np.where(np.isfinite(res), res, np.inf)
    ok = (res < tol) & _branch_ok(P, R, geom, max_tilt_rad)
    return PlatformSolution(P.reshape(shape + (3,)), R.reshape(shape + (3, 3)), it,
                            res.reshape(shape), ok.reshape(shape))


def forward_platform(L, geom: Geometry, guess=None):
    """Single-pose FK of the spatial part; raises KinematicsError on any failure."""
    sol = solve_platform(np.asarray(L, float), geom, guess)
    if not bool(np.all(sol.ok)):
        r = float(np.max(sol.residual))
        if not r < FK_TOL_MM:
            raise KinematicsError(f"forward kinematics did not converge for L = {np.round(L, 6).tolist()} "
                                  f"(residual {r:.3g} mm after {sol.iterations} iterations)")
        raise KinematicsError(f"forward kinematics left the assembly branch for L = {np.round(L, 6).tolist()}")
    return sol.P, sol.R


# ---------------------------------------------------------------- the tool

def tool_of_platform(P, R, table_xy, geom: Geometry):
    """Tip in W and tool axis from a platform pose and the table position (..., 2)."""
    tip = P + _mv(R, geom.tool_tip_p)
    axis = _mv(R, geom.tool_axis_p)
    txy = np.asarray(table_xy, float)
    tip_w = tip - np.concatenate([txy, np.full(txy.shape[:-1] + (1,), geom.z_table)], -1)
    return tip_w, axis


@dataclass
class ToolPose:
    tip: np.ndarray          # (..., 3) tool tip in W, mm
    axis: np.ndarray         # (..., 3) unit tool axis
    P: np.ndarray
    R: np.ndarray

    @property
    def Z(self):
        return self.P[..., 2]

    @property
    def tilt(self):
        return axis_to_tilt(_mv(self.R, EZ))


def fk(q, machine: Machine, guess=None, *, check_limits=False) -> ToolPose:
    """5-axis forward kinematics q = (L1, L2, L3, X, Y) -> tool pose; raises on failure.

    With check_limits, joints outside their ranges and poses beyond the tilt or spherical-joint
    swing limits raise UnreachablePose naming the limit, as :func:`ik` does."""
    q = np.asarray(q, float)
    if check_limits:
        if not np.all(np.isfinite(q)):
            raise UnreachablePose("joint values must be finite numbers")
        # Joint ranges first: a chain far out of range may have no assembly at all.
        pre = limit_violations(q, None, None, None, machine)
        if pre[()]:
            raise UnreachablePose(f"joints out of range: {pre[()]}")
    P, R = forward_platform(q[..., :3], machine.geometry, guess)
    tip, axis = tool_of_platform(P, R, q[..., 3:5], machine.geometry)
    if check_limits:
        reason = limit_violations(q, axis_to_tilt(_mv(R, EZ))[1], P, R, machine)[()]
        if reason:
            raise UnreachablePose(f"pose out of limits: {reason}")
    return ToolPose(tip, axis, P, R)


def fk_batch(q, machine: Machine, guess=None):
    """Batch FK: returns (ToolPose, ok mask). Poses that failed have ok = False."""
    q = np.asarray(q, float)
    sol = solve_platform(q[..., :3], machine.geometry, guess)
    tip, axis = tool_of_platform(sol.P, sol.R, q[..., 3:5], machine.geometry)
    return ToolPose(tip, axis, sol.P, sol.R), sol.ok


# ---------------------------------------------------------------- inverse kinematics

def _perp_basis(v):
    """Two unit vectors orthogonal to v (..., 3), continuous away from v = -x."""
    v = np.asarray(v, float)
    a = np.where(np.abs(v[..., 0:1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    e1 = np.cross(v, a)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    return e1, np.cross(v, e1)


def _ik_platform(tip_w, axis, geom: Geometry, tol=FK_TOL_MM, max_iter=FK_MAX_ITER):
    """Platform pose realising the tool axis and tip height, satisfying the chain-plane constraints.

    Nominal geometry: the closed form of the zero-torsion mechanism (exact). General (calibrated)
    geometry: the closed form is the start guess of a Newton solve on the platform pose (P, w) with
    6 equations: the 3 chain-plane constraints n_i.(C_i - A_i) = 0, the tool axis (2 components
    normal to the target axis) and the tip height. The table X, Y then take the tip's horizontal
    position exactly. Only the poses not yet converged are iterated (batch)."""
    t1, t2 = axis_to_tilt(axis)
    Z = tip_w[..., 2] + geom.z_table + geom.tool_length * np.cos(t2)
    P, R = platform_pose(Z, t1, t2, geom.platform_radius)
    if geom.nominal:
        return P, R, np.ones(P.shape[:-1], bool)
    shape = P.shape[:-1]
    e1, e2 = _perp_basis(axis)
    e1 = np.broadcast_to(e1, shape + (3,)).reshape(-1, 3)
    e2 = np.broadcast_to(e2, shape + (3,)).reshape(-1, 3)
    z_target = np.broadcast_to(tip_w[..., 2] + geom.z_table, shape).reshape(-1)
    P = np.array(P, float).reshape(-1, 3)
    R = np.array(R, float).reshape(-1, 3, 3)
    ap, tp = geom.tool_axis_p, geom.tool_tip_p
    n_ax = geom.revolute_axes

    def residual(Pa, Ra, k):
        rc = np.einsum("...ij,kj->...ki", Ra, geom.platform_joints)
        d = Pa[:, None, :] + rc - geom.base_joints
        w = _mv(Ra, ap)
        rt = _mv(Ra, tp)
        f = np.concatenate([np.einsum("...ki,ki->...k", d, n_ax),
                            np.sum(e1[k] * w, -1, keepdims=True), np.sum(e2[k] * w, -1, keepdims=True),
                            (Pa[:, 2] + rt[:, 2] - z_target[k])[:, None]], -1)
        return f, rc, w, rt

    ok = np.zeros(len(P), bool)
    act = np.arange(len(P))
    f, rc, w, rt = residual(P, R, act)
    for it in range(max_iter + 1):
        res = np.abs(f).max(-1)
        done = res < tol
        ok[act[done]] = True
        keep = ~done & np.isfinite(res)
        act, f, rc, w, rt = act[keep], f[keep], rc[keep], w[keep], rt[keep]
        if not act.size or it == max_iter:
            break
        n = np.broadcast_to(n_ax, rc.shape)
        zeros = np.zeros(w.shape)
        rows = np.concatenate([
            np.concatenate([n, np.cross(rc, n)], -1),
            np.concatenate([zeros, np.cross(w, e1[act])], -1)[:, None, :],
            np.concatenate([zeros, np.cross(w, e2[act])], -1)[:, None, :],
            np.concatenate([np.broadcast_to(EZ, w.shape), np.cross(rt, EZ)], -1)[:, None, :]], -2)
        step = np.linalg.solve(rows, -f[..., None])[..., 0]
        # Limit wild steps (a calibrated geometry is within millimetres of the nominal one).
        sp = np.linalg.norm(step[:, :3], axis=-1, keepdims=True)
        sr = np.linalg.norm(step[:, 3:], axis=-1, keepdims=True)
        step = step * np.minimum(1.0, np.minimum(50.0 / np.maximum(sp, 1e-300), 0.2 / np.maximum(sr, 1e-300)))
        P[act] = P[act] + step[:, :3]
        R[act] = expm_so3(step[:, 3:]) @ R[act]
        f, rc, w, rt = residual(P[act], R[act], act)
    return P.reshape(shape + (3,)), R.reshape(shape + (3, 3)), ok.reshape(shape)


@dataclass
class IKResult:
    q: np.ndarray             # (..., 5) L1, L2, L3, X, Y
    P: np.ndarray
    R: np.ndarray
    theta1: np.ndarray
    theta2: np.ndarray
    ok: np.ndarray            # reachable: converged and within every limit
    reason: np.ndarray        # object array of '' or the first violated limit


def ik_batch(tip_w, axis, machine: Machine, *, check_limits=True) -> IKResult:
    """5-axis IK for a batch: tip in W (..., 3) + unit tool axis (..., 3) -> q (..., 5)."""
    geom = machine.geometry
    tip_w = np.asarray(tip_w, float)
    axis = np.asarray(axis, float)
    axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    P, R, conv = _ik_platform(tip_w, axis, geom)
    L = chain_lengths(P, R, geom)
    tip_base = P + _mv(R, geom.tool_tip_p)
    X = tip_base[..., 0] - tip_w[..., 0]
    Y = tip_base[..., 1] - tip_w[..., 1]
    q = np.concatenate([L, X[..., None], Y[..., None]], -1)
    t1, t2 = axis_to_tilt(_mv(R, EZ))
    reason = np.full(q.shape[:-1], "", dtype=object)
    if check_limits:
        reason = limit_violations(q, t2, P, R, machine)
    reason = np.where(conv, reason, "inverse kinematics did not converge (calibrated geometry)")
    return IKResult(q, P, R, t1, t2, reason == "", reason)


def limit_violations(q, theta2, P, R, machine: Machine):
    """First violated limit per pose as text ('' when within every limit).

    With ``theta2``, ``P`` and ``R`` all None only the joint ranges are checked (before FK)."""
    lim, geom = machine.limits, machine.geometry
    q = np.asarray(q, float)
    shape = q.shape[:-1]
    qf = q.reshape(-1, 5)
    if P is None:
        t2d, swing, pz = np.zeros(len(qf)), np.zeros(len(qf)), np.ones(len(qf))
    else:
        t2d = np.broadcast_to(np.degrees(np.asarray(theta2, float)), shape).reshape(-1)
        d = joint_positions(P, R, geom) - geom.base_joints
        u = d / np.linalg.norm(d, axis=-1, keepdims=True)
        cosw = np.einsum("...ki,...i->...k", u, R[..., :, 2])
        swing = np.degrees(np.arccos(np.clip(cosw, -1, 1))).max(-1).reshape(-1)
        pz = P[..., 2].reshape(-1)
    out = np.full(qf.shape[0], "", dtype=object)
    t_lo, t_hi = lim.theta2_deg
    c_lo, c_hi = lim.chain_length
    checks = [(lambda k: not t_lo - 1e-9 <= t2d[k] <= t_hi + 1e-9,
               lambda k: f"tilt theta2 = {t2d[k]:.6f} deg outside [{t_lo:g}, {t_hi:g}] deg")]
    for i in range(3):
        checks.append((lambda k, i=i: not c_lo <= qf[k, i] <= c_hi,
                       lambda k, i=i: f"chain L{i + 1} = {qf[k, i]:.6f} mm outside [{c_lo:g}, {c_hi:g}] mm"))
    for j, name, (a, b) in ((3, "X", lim.table_x), (4, "Y", lim.table_y)):
        checks.append((lambda k, j=j, a=a, b=b: not a - 1e-9 <= qf[k, j] <= b + 1e-9,
                       lambda k, j=j, a=a, b=b, name=name:
                       f"table {name} = {qf[k, j]:.6f} mm outside [{a:g}, {b:g}] mm (the table carries the "
                       f"workpiece and moves opposite to the tool: a tool tip near {name.lower()} = "
                       f"{-qf[k, j]:+.3f} mm in the workpiece frame needs table {name} = {qf[k, j]:+.3f} mm)"))
    checks.append((lambda k: swing[k] > lim.spherical_swing_deg,
                   lambda k: f"spherical joint swing {swing[k]:.2f} deg over {lim.spherical_swing_deg:g} deg"))
    checks.append((lambda k: pz[k] <= 0, lambda k: "platform below the base"))
    # Vectorised screen first; text only for the poses that fail.
    bad = ((t2d < t_lo - 1e-9) | (t2d > t_hi + 1e-9) | np.any(qf[:, :3] < c_lo, -1) | np.any(qf[:, :3] > c_hi, -1)
           | (qf[:, 3] < lim.table_x[0] - 1e-9) | (qf[:, 3] > lim.table_x[1] + 1e-9)
           | (qf[:, 4] < lim.table_y[0] - 1e-9) | (qf[:, 4] > lim.table_y[1] + 1e-9)
           | (swing > lim.spherical_swing_deg) | (pz <= 0) | ~np.all(np.isfinite(qf), -1))
    for k in np.nonzero(bad)[0]:
        for test, msg in checks:
            if test(k):
                out[k] = msg(k)
                break
        else:
            out[k] = "pose is not finite"
    return out.reshape(shape)


def ik(tip_w, axis, machine: Machine, *, axis_tol=AXIS_TOL) -> IKResult:
    """Single-pose IK; raises UnreachablePose naming the limit. ``axis`` must be unit within axis_tol."""
    tip_w = np.asarray(tip_w, float).reshape(3)
    axis = np.asarray(axis, float).reshape(3)
    if not (np.all(np.isfinite(tip_w)) and np.all(np.isfinite(axis))):
        raise UnreachablePose("tool tip and axis must be finite numbers")
    n = float(np.linalg.norm(axis))
    if abs(n - 1.0) > axis_tol:
        raise UnreachablePose(f"tool axis {axis.tolist()} is not a unit vector (|v| = {n:.6g})")
    if axis[2] <= 0:
        raise UnreachablePose(f"tool axis {axis.tolist()} has no upward component; the spindle is above the tip")
    r = ik_batch(tip_w, axis / n, machine)
    if not bool(r.ok):
        raise UnreachablePose(f"pose unreachable: {r.reason[()]}")
    return r


# ---------------------------------------------------------------- Jacobians

def jacobian_ztt(Z, theta1, theta2, r_out, geom: Geometry):
    """Analytic J_L = d(L1,L2,L3)/d(Z, theta1, theta2) (..., 3, 3) for the nominal closed form.

    Columns are per mm of Z and per radian of theta1, theta2."""
    Z, t1, t2 = np.broadcast_arrays(*(np.asarray(x, float) for x in (Z, theta1, theta2)))
    P, R = platform_pose(Z, t1, t2, r_out)
    c1, s1, c2, s2 = np.cos(t1), np.sin(t1), np.cos(t2), np.sin(t2)
    w = np.stack([c1, s1, np.zeros_like(c1)], -1)
    wp = np.stack([-s1, c1, np.zeros_like(c1)], -1)
    eye = np.eye(3)
    dR2 = (-s2[..., None, None] * eye + c2[..., None, None] * skew(w)
           + s2[..., None, None] * np.einsum("...i,...j->...ij", w, w))
    dR1 = (s2[..., None, None] * skew(wp)
           + (1 - c2)[..., None, None] * (np.einsum("...i,...j->...ij", wp, w) + np.einsum("...i,...j->...ij", w, wp)))
    dP1 = np.stack([r_out * np.cos(2 * t1) * (1 - c2), -r_out * (1 - c2) * np.sin(2 * t1), np.zeros_like(t1)], -1)
    dP2 = np.stack([0.5 * r_out * np.sin(2 * t1) * s2, 0.5 * r_out * s2 * np.cos(2 * t1), np.zeros_like(t1)], -1)
    d = joint_positions(P, R, geom) - geom.base_joints
    u = d / np.linalg.norm(d, axis=-1, keepdims=True)
    cp = geom.platform_joints
    colZ = u[..., 2]
    col1 = np.einsum("...ki,...ki->...k", u, dP1[..., None, :] + np.einsum("...ij,kj->...ki", dR1, cp))
    col2 = np.einsum("...ki,...ki->...k", u, dP2[..., None, :] + np.einsum("...ij,kj->...ki", dR2, cp))
    return np.stack([colZ, col1, col2], -1)


def platform_twist_map(P, R, geom: Geometry):
    """(..., 6, 3): platform twist (dP, w) per unit chain-length rate, chain planes held."""
    A = constraint_jacobian(P, R, geom)
    return np.linalg.inv(A)[..., :, :3]


def jacobian_tool(P, R, geom: Geometry):
    """Analytic (..., 6, 5) Jacobian d(tip_W, tool axis)/dq at a platform pose.

    Rows 0-2: tool tip in W (mm per mm); rows 3-5: tool axis vector (1 per mm). Rank 5: the axis
    stays unit, so its rate is normal to the axis."""
    T = platform_twist_map(P, R, geom)
    dP, w = T[..., :3, :], T[..., 3:, :]
    rt = _mv(R, geom.tool_tip_p)
    v = _mv(R, geom.tool_axis_p)
    d_tip = dP - skew(rt) @ w            # dP + w x rt
    d_axis = -skew(v) @ w                # w x v
    shape = P.shape[:-1]
    J = np.zeros(shape + (6, 5))
    J[..., :3, :3] = d_tip
    J[..., 0, 3] = -1.0
    J[..., 1, 4] = -1.0
    J[..., 3:, :3] = d_axis
    return J

# The control loop's single-pose FK (plain floats, predictor warm start) is pmctl.core.model_fk.ModelFK: it
# solves these same loop equations and is tested against solve_platform and jacobian_tool.
