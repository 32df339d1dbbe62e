"""Geometry identification by iterative least squares (Levenberg-Marquardt on Gauss-Newton steps).

Given measured poses -- actuator positions q (n, 5), measured tool tip (n, 3) and, where measured,
tool axis (n, 3) -- find the geometry parameters (see :mod:`pmctl.tools.calibrate.model`) that
make the forward kinematics reproduce the measurements, each residual weighted by its noise level.

Identifiability: the whitened identification Jacobian is column-scaled (each parameter column to
unit norm) and decomposed by SVD. A direction is *not identifiable* when its singular value is
below ``rcond`` times the largest (an exact symmetry of the model, e.g. turning the platform frame
together with its joints and the tool) or when the data would fix it no better than
``max_sigma`` (mm or degrees, 1 sigma): such a direction is never stepped along (truncated SVD,
the minimum-norm solution), so it stays at the reference value instead of being fitted to noise.
Every such direction is reported with the parameters that dominate it.

The report holds the residuals (RMS and worst, tip in um and axis in urad), the 1-sigma parameter
uncertainties (covariance scaled by the a-posteriori noise factor when the fit is worse than the
stated noise), and the predicted accuracy of the calibrated model over the measured poses and
over a sample of the workspace.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pmctl.core.config import Geometry
from pmctl.core.errors import PmctlError
from pmctl.tools.calibrate import model as Mo

TIP_SIGMA_MM = 2e-3        # default measurement noise: 2 um per tip coordinate
AXIS_SIGMA_RAD = 1e-5      # 10 urad per axis direction
RCOND = 1e-6
MAX_SIGMA = 0.5            # a direction known no better than 0.5 mm / 0.5 deg (1 sigma) is fixed


class IdentificationError(PmctlError):
    pass


@dataclass
class Direction:
    singular_value: float       # relative to the largest
    sigma: float                # 1-sigma uncertainty along it, mm/deg (inf for exact symmetries)
    terms: list                 # [(parameter name, weight)] dominating the direction


@dataclass
class Result:
    geometry: Geometry
    dp: np.ndarray                  # identified change from the reference (30,)
    sigma: np.ndarray               # 1-sigma uncertainty per parameter (0 for fixed combinations)
    rank: int
    fixed: list                     # [Direction] not identified (held at the reference)
    weak: list                      # [Direction] identified but the least well determined
    iterations: int
    n_poses: int
    has_axis: bool
    chi2_red: float                 # weighted SSE / degrees of freedom (1 = exactly the stated noise)
    tip_rms_um: float
    tip_max_um: float
    axis_rms_urad: float
    axis_max_urad: float
    before_tip_rms_um: float
    before_tip_max_um: float
    predicted_tip_um: float = float("nan")     # 1-sigma model uncertainty of the tip, RMS over the sample
    predicted_tip_max_um: float = float("nan")
    predicted_axis_urad: float = float("nan")
    cond: float = float("nan")                 # condition number of the scaled Jacobian, identified part
    tip_sigma_mm: float = TIP_SIGMA_MM
    axis_sigma_rad: float = AXIS_SIGMA_RAD
    history: list = field(default_factory=list)


def _residual(q, tip, axis, geom, guess, ws, has_axis=None):
    pr = Mo.predict(q, geom, guess)
    r_tip = (pr.tip - tip) / ws[0]
    parts = [r_tip.reshape(-1)]
    if axis is not None:
        sel = slice(None) if has_axis is None or has_axis is True else has_axis
        parts.append(((pr.axis[sel] - axis[sel]) / ws[1]).reshape(-1))
    return np.concatenate(parts), pr


def _jac(pr, geom, has_axis, ws):
    """Whitened identification Jacobian; has_axis True / False or a mask of poses with an axis."""
    S = Mo.identification_jacobian(pr.P, pr.R, geom)
    rows = [(S[:, :3, :] / ws[0]).reshape(-1, Mo.N_PARAMS)]
    if has_axis is not False:
        sel = slice(None) if has_axis is True else has_axis
        rows.append((S[sel, 3:, :] / ws[1]).reshape(-1, Mo.N_PARAMS))
    return np.concatenate(rows, 0)


def _terms(v_phys, k=4):
    a = np.abs(v_phys)
    idx = np.argsort(a)[::-1][:k]
    tot = np.linalg.norm(v_phys)
    return [(Mo.PARAM_NAMES[j], round(float(v_phys[j] / tot), 3)) for j in idx if a[j] > 0.1 * tot]


def analyse(J, *, rcond=RCOND, max_sigma=MAX_SIGMA, noise_factor=1.0):
    """SVD of the column-scaled whitened Jacobian J (m, 30).

    Returns (D, U, s, Vt, keep, dirs): column scales D, SVD factors, the mask of identified
    directions and a Direction per singular vector."""
    D = np.linalg.norm(J, axis=0)
    D = np.where(D > 0, D, 1.0)
    U, s, Vt = np.linalg.svd(J / D, full_matrices=False)
    rel = s / s[0]
    dirs = []
    keep = np.zeros(len(s), bool)
    for k in range(len(s)):
        v_phys = Vt[k] / D                        # unit change of the scaled coordinate -> physical
        sig = noise_factor * np.linalg.norm(v_phys) / s[k] if s[k] > 0 else math.inf
        if rel[k] < rcond:
            sig = math.inf
        keep[k] = rel[k] >= rcond and sig <= max_sigma
        dirs.append(Direction(float(rel[k]), float(sig), _terms(v_phys)))
    return D, U, s, Vt, keep, dirs


def identify(q, tip, axis, ref: Geometry, *, tip_sigma_mm=TIP_SIGMA_MM, axis_sigma_rad=AXIS_SIGMA_RAD,
             rcond=RCOND, max_sigma=MAX_SIGMA, max_iter=40, workspace_q=None) -> Result:
    """Identify the geometry from measured poses. ``axis`` may be None (tip-only measurement) or
    have NaN rows where the axis was not measured. ``workspace_q`` (k, 5): actuator positions where
    the predicted accuracy is evaluated (default: the measured poses)."""
    q = np.asarray(q, float)
    tip = np.asarray(tip, float)
    amask = True
    if axis is not None:
        axis = np.asarray(axis, float)
        amask = np.all(np.isfinite(axis), -1)
        if not amask.any():
            axis = None
        else:
            axis = np.where(amask[:, None], axis, np.array([0.0, 0.0, 1.0]))
            axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
            amask = True if amask.all() else amask
    if axis is None:
        amask = False
    has_axis = axis is not None
    n = len(q)
    if n < 3:
        raise IdentificationError(f"{n} measured poses: too few to identify anything")
    ws = (tip_sigma_mm, axis_sigma_rad)
    geom = ref
    r, pr = _residual(q, tip, axis, geom, None, ws, amask)
    cost = float(r @ r)
    r0 = r
    lam = 1e-3
    it = 0
    history = [cost]
    rank = 0
    for it in range(1, max_iter + 1):
        J = _jac(pr, geom, amask, ws)
        D, U, s, Vt, keep, _ = analyse(J, rcond=rcond, max_sigma=max_sigma)
        rank = int(keep.sum())
        Ur, sr, Vr = U[:, keep], s[keep], Vt[keep]
        g = Ur.T @ r
        improved = False
        for _ in range(12):
            z = -(sr / (sr**2 + lam * sr[0] ** 2)) * g       # LM in the identified subspace
            dp = (Vr.T @ z) / D
            try:
                g_new = Mo.perturb(geom, dp)
                r_new, pr_new = _residual(q, tip, axis, g_new, (pr.P, pr.R), ws, amask)
            except PmctlError:
                lam *= 10
                continue
            c_new = float(r_new @ r_new)
            if c_new < cost:
                improved = True
                break
            lam *= 10
        if not improved:
            break
        step_small = np.max(np.abs(dp)) < 1e-10
        rel_drop = (cost - c_new) / max(cost, 1e-300)
        geom, r, pr, cost = g_new, r_new, pr_new, c_new
        history.append(cost)
        lam = max(lam / 10, 1e-12)
        if step_small or rel_drop < 1e-12:
            break
    # Final analysis at the solution.
    J = _jac(pr, geom, amask, ws)
    # degrees of freedom of the residuals: 3 per measured tip, 2 per measured tool axis (a direction:
    # its residual's 3 components are noise in 2, the one along the axis is second order)
    n_ax = 0 if axis is None else (n if amask is True else int(np.sum(amask)))
    m = 3 * n + 2 * n_ax
    dof = max(m - rank, 1)
    chi2 = cost / dof
    nf = math.sqrt(max(chi2, 1.0))
    D, U, s, Vt, keep, dirs = analyse(J, rcond=rcond, max_sigma=max_sigma, noise_factor=nf)
    rank = int(keep.sum())
    Vr = Vt[keep] / D                                     # (rank, 30) physical directions
    cov = (Vr.T / s[keep] ** 2) @ Vr * chi2 if chi2 > 1 else (Vr.T / s[keep] ** 2) @ Vr
    sigma = np.sqrt(np.maximum(np.diag(cov), 0.0))
    order = np.argsort([d.singular_value for d in dirs])
    fixed = [dirs[k] for k in order if not keep[k]]
    weak = [dirs[k] for k in order if keep[k]][:3]
    res_tip = (pr.tip - tip)
    e_tip = np.linalg.norm(res_tip, axis=-1) * 1e3
    e0 = np.linalg.norm(r0[:3 * n].reshape(n, 3), axis=-1) * tip_sigma_mm * 1e3
    if has_axis:
        e_ax = Mo.angle_between(pr.axis, axis) * 1e6
        if amask is not True:
            e_ax = e_ax[amask]
        ax_rms, ax_max = float(np.sqrt(np.mean(e_ax**2))), float(e_ax.max())
    else:
        ax_rms = ax_max = float("nan")
    res = Result(geometry=geom, dp=Mo.difference(geom, ref), sigma=sigma, rank=rank, fixed=fixed, weak=weak,
                 iterations=it, n_poses=n, has_axis=has_axis, chi2_red=chi2,
                 tip_rms_um=float(np.sqrt(np.mean(e_tip**2))), tip_max_um=float(e_tip.max()),
                 axis_rms_urad=ax_rms, axis_max_urad=ax_max,
                 before_tip_rms_um=float(np.sqrt(np.mean(e0**2))), before_tip_max_um=float(e0.max()),
                 cond=float(s[keep][0] / s[keep][-1]) if rank else math.inf,
                 tip_sigma_mm=tip_sigma_mm, axis_sigma_rad=axis_sigma_rad, history=history)
    # Predicted accuracy: 1-sigma of the predicted tool pose from the parameter covariance.
    wq = q if workspace_q is None else np.asarray(workspace_q, float)
    pw = Mo.predict(wq, geom)
    Sw = Mo.identification_jacobian(pw.P, pw.R, geom)
    var = np.einsum("nip,pr,nir->ni", Sw, cov, Sw)
    st = np.sqrt(np.maximum(var[:, :3].sum(-1), 0.0)) * 1e3
    sa = np.sqrt(np.maximum(var[:, 3:].sum(-1), 0.0)) * 1e6
    res.predicted_tip_um = float(np.sqrt(np.mean(st**2)))
    res.predicted_tip_max_um = float(st.max())
    res.predicted_axis_urad = float(np.sqrt(np.mean(sa**2)))
    return res


def condition_number(q, geom: Geometry, *, has_axis=True, tip_sigma_mm=TIP_SIGMA_MM, axis_sigma_rad=AXIS_SIGMA_RAD,
                     rcond=RCOND, max_sigma=MAX_SIGMA):
    """Condition number (largest / smallest kept singular value) of the scaled identification
    Jacobian at these poses, its rank and the log-determinant of the kept part (D-optimality)."""
    pr = Mo.predict(np.asarray(q, float), geom)
    J = _jac(pr, geom, has_axis, (tip_sigma_mm, axis_sigma_rad))
    D, U, s, Vt, keep, _ = analyse(J, rcond=rcond, max_sigma=max_sigma)
    sk = s[keep]
    return float(sk[0] / sk[-1]), int(keep.sum()), float(2 * np.sum(np.log(sk)))


def format_report(res: Result, *, ref_name="reference") -> str:
    """Human-readable identification report."""
    L = []
    L.append(f"poses: {res.n_poses}  measured: tip{' + tool axis' if res.has_axis else ' only'}  "
             f"(noise assumed {res.tip_sigma_mm * 1e3:g} um tip"
             + (f", {res.axis_sigma_rad * 1e6:g} urad axis)" if res.has_axis else ")"))
    L.append(f"iterations: {res.iterations}  identified combinations: {res.rank} of {Mo.N_PARAMS}  "
             f"condition number of the identified part (scaled): {res.cond:.1f}")
    L.append(f"residual before: tip distance RMS {res.before_tip_rms_um:.2f} um, worst {res.before_tip_max_um:.2f} um")
    L.append(f"residual after:  tip distance RMS {res.tip_rms_um:.3f} um, worst {res.tip_max_um:.3f} um"
             + (f"; axis RMS {res.axis_rms_urad:.2f} urad, worst {res.axis_max_urad:.2f} urad" if res.has_axis else ""))
    L.append(f"chi2 per degree of freedom: {res.chi2_red:.3f} (1 = residuals match the assumed noise)")
    L.append(f"predicted accuracy of the calibrated model (1 sigma, over the evaluation poses): tip RMS "
             f"{res.predicted_tip_um:.3f} um, worst {res.predicted_tip_max_um:.3f} um"
             + (f"; axis RMS {res.predicted_axis_urad:.2f} urad" if res.has_axis else ""))
    L.append("")
    L.append(f"not identifiable from these data ({len(res.fixed)} combinations, held at the {ref_name} value):")
    for d in res.fixed:
        why = "exact symmetry" if not math.isfinite(d.sigma) else f"1 sigma {d.sigma:.3g}"
        L.append(f"  s = {d.singular_value:.2e} ({why}): " + ", ".join(f"{w:+.3f} {n}" for n, w in d.terms))
    if res.weak:
        L.append("least well determined identified combinations:")
        for d in res.weak:
            L.append(f"  s = {d.singular_value:.2e} (1 sigma {d.sigma:.3g}): "
                     + ", ".join(f"{w:+.3f} {n}" for n, w in d.terms))
    L.append("")
    L.append(f"{'parameter':36s} {'change':>12s} {'1 sigma':>10s}")
    for name, v, s in zip(Mo.PARAM_NAMES, res.dp, res.sigma):
        L.append(f"{name:36s} {v:12.5f} {s:10.5f}")
    return "\n".join(L)
