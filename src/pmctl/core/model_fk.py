"""The control loop's single-pose forward kinematics (:class:`ModelFK`): the model pose of the tick,
in plain floats, with a predictor warm start.

The batch functions of :mod:`pmctl.core.kinematics` cost ~0.3 ms per call in numpy overhead alone;
this solves the same 6 loop equations with the same Newton scheme as ``kinematics.solve_platform``
and builds the same Jacobian as ``kinematics.jacobian_tool`` (tests check both against
kinematics.py). The NC step (pmctl.motion.nc) and its compiled twin (pmctl.motion.ncore, whose C
does the same arithmetic in the same order) use it for the model pose; the sim plant
(pmctl.hal.sim) uses the compiled FK for the load-side pose and the gravity strain, with the
constant block of :func:`fk_constants`. The one 6x6 solve is therefore plain floats in a fixed
order (:func:`_solve6`), not LAPACK, so that both compute the model pose to the last bit.
"""

from __future__ import annotations

import math

import numpy as np

from pmctl.core.config import Machine
from pmctl.core.errors import KinematicsError
from pmctl.core.kinematics import FK_MAX_ITER, FK_TOL_MM

FK_SINGULAR_TEXT = "forward kinematics: singular constraint Jacobian (a chain aligned with its plane normal)"
FK_CONST_LEN = 45           # the model's part of the compiled core's constant block (ncore.h)
NC_CONST_LEN = 66           # the NC limits' part after it (ncore.h; zeros where only FK runs)


def _solve6(M, B):
    """Solve M X = B in place (M: 6 lists of 6, B: 6 lists of nr floats) by Gaussian elimination
    with partial pivoting (LAPACK dgesv's scheme), in plain floats and in the compiled core's
    operation order, so that both NCs compute the same model pose to the last bit (the pose is
    warm-started from tick to tick: differences would otherwise accumulate within the Newton
    tolerance). Raises KinematicsError on an exactly zero pivot (dgesv's info > 0)."""
    nr = len(B[0])
    for k in range(6):
        p, mx = k, abs(M[k][k])
        for i in range(k + 1, 6):
            if abs(M[i][k]) > mx:
                p, mx = i, abs(M[i][k])
        if M[p][k] == 0.0:
            raise KinematicsError(FK_SINGULAR_TEXT)
        if p != k:
            M[k], M[p] = M[p], M[k]
            B[k], B[p] = B[p], B[k]
        Mk, Bk, piv = M[k], B[k], M[k][k]
        for i in range(k + 1, 6):
            Mi = M[i]
            lf = Mi[k] / piv
            if lf == 0.0:
                continue
            for j in range(k + 1, 6):
                Mi[j] -= lf * Mk[j]
            Bi = B[i]
            for j in range(nr):
                Bi[j] -= lf * Bk[j]
    for k in range(5, -1, -1):
        Mk, Bk = M[k], B[k]
        for j in range(nr):
            sm = Bk[j]
            for i in range(k + 1, 6):
                sm -= Mk[i] * B[i][j]
            Bk[j] = sm / Mk[k]
    return B


def _rodrigues_l(wx, wy, wz):
    """Rotation matrix (nested lists) of the rotation vector (wx, wy, wz), as kinematics.expm_so3."""
    th2 = wx * wx + wy * wy + wz * wz
    if th2 < 1e-16:
        a, b = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0
    else:
        th = math.sqrt(th2)
        a, b = math.sin(th) / th, (1.0 - math.cos(th)) / th2
    return [[1.0 - b * (wy * wy + wz * wz), -a * wz + b * wx * wy, a * wy + b * wx * wz],
            [a * wz + b * wx * wy, 1.0 - b * (wx * wx + wz * wz), -a * wx + b * wy * wz],
            [-a * wy + b * wx * wz, a * wx + b * wy * wz, 1.0 - b * (wx * wx + wy * wy)]]


def fk_noconv_text(L, res, it):
    return (f"forward kinematics did not converge for L = {[round(x, 6) for x in L]} "
            f"(residual {res:.3g} mm after {int(it)} iterations)")


def fk_branch_text(L):
    return f"forward kinematics left the assembly branch for L = {[round(x, 6) for x in L]}"



class ModelFK:
    """Single-pose forward kinematics + tool Jacobian for the tick (same equations as kinematics.py).

    ``solve(q, P, R)`` -> (P, R, tip_w, axis, J): Newton on the 6 loop equations
    |C_i - A_i| = L_i + off_i, n_i.(C_i - A_i) = 0 from the warm start (P, R); J is the 6x5
    d(tip_W, axis)/dq, evaluated at the last Newton linearisation point (the previous model pose
    when the counters moved: relative error ~ step/length, below 1e-3 at 200 pulses per tick; J
    only shapes rates, positions always come from the converged FK).
    Raises KinematicsError on non-convergence or a step off the assembly branch.
    """

    def __init__(self, machine: Machine, *, tol=FK_TOL_MM, max_iter=FK_MAX_ITER, max_tilt_rad=math.radians(45.0)):
        g = machine.geometry
        self.A = np.array(g.base_joints, float)
        self.Cp = np.array(g.platform_joints, float)
        self.N = np.array(g.revolute_axes, float)
        self.off = np.array(g.length_offsets, float)
        self.tip_p = np.array(g.tool_tip_p, float)
        self.axis_p = np.array(g.tool_axis_p, float)
        self.z_table = float(g.z_table)
        self.tol, self.max_iter = tol, max_iter
        ms = machine.mass
        self._fz = -ms.platform_kg * ms.gravity                # N, gravity on the platform (base -Z)
        self._com = [float(x) for x in ms.com_offset]
        self._keps = float(machine.strain_gain)
        self.cos_max_tilt = math.cos(max_tilt_rad)
        self._tip_p = self.tip_p.tolist()
        self._axis_p = self.axis_p.tolist()
        self._A = self.A.tolist()
        self._Cp = self.Cp.tolist()
        self._N = self.N.tolist()
        self._off = self.off.tolist()

    def _residual(self, P, R, L):
        """Loop equations at (P, R) in plain floats (one pose: cheaper than numpy calls).
        Returns (f (6 floats), rc rows, d rows, lengths)."""
        Rl = R
        px, py, pz = P
        f = [0.0] * 6
        rcs, ds, lns = [], [], []
        for i in range(3):
            cx, cy, cz = self._Cp[i]
            rx = Rl[0][0] * cx + Rl[0][1] * cy + Rl[0][2] * cz
            ry = Rl[1][0] * cx + Rl[1][1] * cy + Rl[1][2] * cz
            rz = Rl[2][0] * cx + Rl[2][1] * cy + Rl[2][2] * cz
            ax, ay, az = self._A[i]
            dx, dy, dz = rx + px - ax, ry + py - ay, rz + pz - az
            ln = math.sqrt(dx * dx + dy * dy + dz * dz)
            nx, ny, nz = self._N[i]
            f[i] = ln - L[i] - self._off[i]
            f[3 + i] = dx * nx + dy * ny + dz * nz
            rcs.append((rx, ry, rz))
            ds.append((dx, dy, dz))
            lns.append(ln)
        return f, rcs, ds, lns

    def _linearise(self, rcs, ds, lns):
        """Constraint Jacobian d(loop equations)/d(P, w) (6 lists of 6), as kinematics.constraint_jacobian."""
        rows = [None] * 6
        for i in range(3):
            rx, ry, rz = rcs[i]
            dx, dy, dz = ds[i]
            ln = lns[i]
            ux, uy, uz = dx / ln, dy / ln, dz / ln
            nx, ny, nz = self._N[i]
            rows[i] = [ux, uy, uz, ry * uz - rz * uy, rz * ux - rx * uz, rx * uy - ry * ux]
            rows[3 + i] = [nx, ny, nz, ry * nz - rz * ny, rz * nx - rx * nz, rx * ny - ry * nx]
        return rows

    def solve_l(self, q, P, R, pred=None):
        """:meth:`solve` on plain lists (the per-tick path): P, R, tip, axis and J as lists."""
        ql = q.tolist()
        L = ql[:3]
        if not isinstance(P, list):
            P = P.tolist()
            R = R.tolist()
        if pred is not None:
            dL, Tp = pred
            if dL[0] or dL[1] or dL[2]:
                d0, d1, d2 = float(dL[0]), float(dL[1]), float(dL[2])
                st = [r[0] * d0 + r[1] * d1 + r[2] * d2 for r in Tp.tolist()]    # Tp @ dL
                P = [P[0] + st[0], P[1] + st[1], P[2] + st[2]]
                E = _rodrigues_l(st[3], st[4], st[5])
                R = [[E[r][0] * R[0][c] + E[r][1] * R[1][c] + E[r][2] * R[2][c] for c in range(3)] for r in range(3)]
        f, rcs, ds, lns = self._residual(P, R, L)
        res = max(abs(x) for x in f)
        T = None
        it = 0
        while not res < self.tol:
            if it >= self.max_iter or not math.isfinite(res):
                raise KinematicsError(fk_noconv_text(L, res, it))
            M = self._linearise(rcs, ds, lns)
            sol = _solve6(M, [[f[0], 1.0, 0.0, 0.0], [f[1], 0.0, 1.0, 0.0], [f[2], 0.0, 0.0, 1.0],
                              [f[3], 0.0, 0.0, 0.0], [f[4], 0.0, 0.0, 0.0], [f[5], 0.0, 0.0, 0.0]])
            if T is None:
                T = [row[1:] for row in sol]
            step = [-row[0] for row in sol]
            sp = math.sqrt(step[0] * step[0] + step[1] * step[1] + step[2] * step[2])
            sr = math.sqrt(step[3] * step[3] + step[4] * step[4] + step[5] * step[5])
            sc = min(1.0, 50.0 / max(sp, 1e-300), 0.2 / max(sr, 1e-300))
            P = [P[0] + sc * step[0], P[1] + sc * step[1], P[2] + sc * step[2]]
            E = _rodrigues_l(sc * step[3], sc * step[4], sc * step[5])
            R = [[E[r][0] * R[0][c] + E[r][1] * R[1][c] + E[r][2] * R[2][c] for c in range(3)] for r in range(3)]
            f, rcs, ds, lns = self._residual(P, R, L)
            res = max(abs(x) for x in f)
            it += 1
        if not (P[2] > 0.0 and R[2][2] > self.cos_max_tilt):
            raise KinematicsError(fk_branch_text(L))
        if T is None:           # already converged: linearise at the pose
            T = _solve6(self._linearise(rcs, ds, lns), [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0],
                                                         [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
        self.last_T = np.array(T)
        # Tool pose and the 6x5 tool Jacobian (as kinematics.tool_of_platform / jacobian_tool), floats.
        tp, ap = self._tip_p, self._axis_p
        rt = [R[r][0] * tp[0] + R[r][1] * tp[1] + R[r][2] * tp[2] for r in range(3)]
        ax = [R[r][0] * ap[0] + R[r][1] * ap[1] + R[r][2] * ap[2] for r in range(3)]
        tip_w = [P[0] + rt[0] - ql[3], P[1] + rt[1] - ql[4], P[2] + rt[2] - self.z_table]
        Tl = T
        J = [[0.0] * 5 for _ in range(6)]
        for j in range(3):
            wx, wy, wz = Tl[3][j], Tl[4][j], Tl[5][j]
            # d tip = dP + w x rt ; d axis = w x axis
            J[0][j] = Tl[0][j] + wy * rt[2] - wz * rt[1]
            J[1][j] = Tl[1][j] + wz * rt[0] - wx * rt[2]
            J[2][j] = Tl[2][j] + wx * rt[1] - wy * rt[0]
            J[3][j] = wy * ax[2] - wz * ax[1]
            J[4][j] = wz * ax[0] - wx * ax[2]
            J[5][j] = wx * ax[1] - wy * ax[0]
        J[0][3] = -1.0
        J[1][4] = -1.0
        return P, R, tip_w, ax, J

    def static_strain(self, R, T):
        """Plate-link strain (microstrain, tension positive) of the platform's weight at rotation R,
        from the twist map T = (constraint Jacobian)^-1[:, :3] of the same pose: the chains'
        compressions are a = -T^T w with w = (F, M about P) the gravity wrench (as
        pmctl.core.statics.static_strain, one pose, plain floats), and strain = -k_eps a."""
        c = self._com
        rc = [R[r][0] * c[0] + R[r][1] * c[1] + R[r][2] * c[2] for r in range(3)]
        fz = self._fz
        w = (0.0, 0.0, fz, rc[1] * fz, -rc[0] * fz, 0.0)        # F; M = rc x F
        Tl = T.tolist() if not isinstance(T, list) else T
        k = self._keps
        return [k * sum(Tl[r][i] * w[r] for r in range(6)) for i in range(3)]

    def solve(self, q, P, R, pred=None):
        """Model pose at joints q (5,) from the warm start (P, R): returns arrays
        (P, R, tip_w, axis, J (6, 5)). ``pred`` = (dL, T): chain-length change since (P, R) and
        the twist map d(P, w)/dL there (``self.last_T`` of the previous solve); the first-order
        predicted pose then starts Newton, which usually converges in one iteration, not two."""
        P, R, tip, ax, J = self.solve_l(q, P, R, pred)
        return np.array(P), np.array(R), np.array(tip), np.array(ax), np.array(J)


def fk_constants(model: ModelFK) -> list:
    """The model's part of the compiled core's constant block (ncore.h, nc_setup's order): the
    plain-float copies ModelFK solves with, so both FKs use the same numbers."""
    m = model
    c = []
    c += [x for row in m._A for x in row]
    c += [x for row in m._Cp for x in row]
    c += [x for row in m._N for x in row]
    c += m._off + m._tip_p + m._axis_p
    c += [m.z_table, m.tol, float(m.max_iter), m.cos_max_tilt, m._fz] + m._com + [m._keps]
    assert len(c) == FK_CONST_LEN, len(c)
    return c


def fk_only_constants(machine: Machine) -> np.ndarray:
    """The whole constant block for FK alone (the sim plant's gravity strain): the model of
    ``machine``, no NC limits (zeros)."""
    return np.array(fk_constants(ModelFK(machine)) + [0.0] * NC_CONST_LEN, float)
