"""Measurement poses for the identification: D-optimal selection from workspace candidates.

Candidates are random reachable tool poses (tilt within the limits less a margin, table within
+-55 mm). Each candidate contributes its block B_k of the whitened, column-scaled identification
Jacobian at the reference geometry, projected on the combinations that are identifiable at all
(the exact symmetries of the model are left out; they cannot be measured from any pose). The
selection maximises log det(sum B_k^T B_k) (D-optimality): greedy start, then Fedorov exchange
passes until no swap improves. The condition number of the resulting identification Jacobian is
reported next to that of random pose sets of the same size (iterative least-squares calibration of
a 6-DOF parallel mechanism with a redundant passive link chooses its measurement configurations by
the condition number; D-optimality also keeps the weakest direction up).

Output: a G-code job that visits the poses (nearest-neighbour order, G1 at a feed, ``G4`` dwell at
each) and a CSV of the poses, with the joints of the reference config.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from pmctl.core import kinematics as K
from pmctl.core.errors import PmctlError
from pmctl.core.job import home_pose
from pmctl.task.gcode import read_gcode
from pmctl.task.planner import plan as plan_job
from pmctl.tools.calibrate import identify as I, model as Mo


def candidate_blocks(machine, tip, axis, *, has_axis=True):
    """Whitened identification-Jacobian blocks (k, m, 30) of the candidate poses, at the reference."""
    q = K.ik_batch(tip, axis, machine).q
    pr = Mo.predict(q, machine.geometry)
    S = Mo.identification_jacobian(pr.P, pr.R, machine.geometry)
    B = S[:, :3, :] / I.TIP_SIGMA_MM
    if has_axis:
        B = np.concatenate([B, S[:, 3:, :] / I.AXIS_SIGMA_RAD], 1)
    return q, B


def _subspace(B):
    """Column scales and the identifiable subspace (exact symmetries removed) of all candidates."""
    J = B.reshape(-1, B.shape[-1])
    D = np.linalg.norm(J, axis=0)
    D = np.where(D > 0, D, 1.0)
    _, s, Vt = np.linalg.svd(J / D, full_matrices=False)
    keep = s / s[0] >= I.RCOND
    return D, Vt[keep]


def d_optimal(B, n, rng, *, passes=6):
    """Indices of n candidates maximising log det of the information matrix (greedy + exchange)."""
    D, V = _subspace(B)
    C = (B / D) @ V.T                                          # (k, m, r)
    Ct = np.ascontiguousarray(np.swapaxes(C, 1, 2))
    k, m, r = C.shape
    if n * m < r:
        raise PmctlError(f"{n} poses give {n * m} equations for {r} identifiable combinations: too few")
    ridge = 1e-9 * np.einsum("kmr,kmr->", C, C) / (k * r)
    Minfo = ridge * np.eye(r)
    chosen = []
    avail = np.ones(k, bool)

    def gains(Minv):
        # log det(I + C_k Minv C_k^T) for every candidate
        G = (C @ Minv) @ Ct + np.eye(m)
        return np.linalg.slogdet(G)[1]

    for _ in range(n):
        g = gains(np.linalg.inv(Minfo))
        g[~avail] = -np.inf
        j = int(np.argmax(g))
        chosen.append(j)
        avail[j] = False
        Minfo = Minfo + C[j].T @ C[j]
    for _ in range(passes):
        swapped = False
        for pos in range(n):
            i = chosen[pos]
            Mi = Minfo - C[i].T @ C[i]
            g = gains(np.linalg.inv(Mi))
            g[~avail] = -np.inf
            j = int(np.argmax(g))
            gi = np.linalg.slogdet(np.eye(m) + C[i] @ np.linalg.solve(Mi, C[i].T))[1]
            if g[j] > gi + 1e-9:
                chosen[pos] = j
                avail[j], avail[i] = False, True
                Minfo = Mi + C[j].T @ C[j]
                swapped = True
            else:
                continue
        if not swapped:
            break
    return np.array(chosen)


def tour(tip, start):
    """Nearest-neighbour visiting order from the start tip."""
    left = list(range(len(tip)))
    order = []
    cur = np.asarray(start, float)
    while left:
        d = np.linalg.norm(tip[left] - cur, axis=1)
        j = left.pop(int(np.argmin(d)))
        order.append(j)
        cur = tip[j]
    return np.array(order)


def gcode(tip, axis, *, feed, dwell_s, title):
    a, b = K.roll_pitch_from_axis(axis)
    lines = [f"( {title} )", "( measurement poses for pmctl calibrate identify: dwell, measure tip and tool axis )",
             "G21 G90 G94", f"F{feed:.1f}"]
    for k, (t, aa, bb) in enumerate(zip(tip, np.degrees(a), np.degrees(b))):
        lines.append(f"G1 X{t[0]:.6f} Y{t[1]:.6f} Z{t[2]:.6f} A{aa:.6f} B{bb:.6f} ( pose {k + 1} )")
        lines.append(f"G4 P{dwell_s:g}")
    lines.append("M2")
    return "\n".join(lines) + "\n"


def write_csv(path, tip, axis, q):
    a, b = K.roll_pitch_from_axis(axis)
    hdr = "pose,tip_x,tip_y,tip_z,tool_i,tool_j,tool_k,A_deg,B_deg,L1,L2,L3,X,Y"
    rows = [hdr]
    for k in range(len(tip)):
        vals = list(tip[k]) + list(axis[k]) + [math.degrees(a[k]), math.degrees(b[k])] + list(q[k])
        rows.append(f"{k + 1}," + ",".join(f"{v:.9f}" for v in vals))
    Path(path).write_text("\n".join(rows) + "\n", encoding="utf-8")


def plan_poses(machine, n, *, candidates=1500, has_axis=True, seed=1):
    """(tip, axis, q) of n D-optimal poses, and the candidate set's (tip, axis)."""
    rng = np.random.default_rng(seed)
    tip, axis = Mo.random_tool_poses(machine, candidates, rng)
    q, B = candidate_blocks(machine, tip, axis, has_axis=has_axis)
    idx = d_optimal(B, n, rng)
    return tip[idx], axis[idx], q[idx]


def run(machine, args) -> str:

    n = int(args.poses)
    if n < 6 or args.candidates < 2 * n:
        raise PmctlError("need at least 6 poses and at least twice as many candidates as poses")
    if not (args.dwell_s > 0 and args.feed > 0):
        raise PmctlError("--dwell-s and --feed must be > 0")
    has_axis = not args.tip_only
    tip, axis, q = plan_poses(machine, n, candidates=args.candidates, has_axis=has_axis, seed=args.seed)
    order = tour(tip, home_pose(machine)[0])
    tip, axis, q = tip[order], axis[order], q[order]
    stem = Path(args.out)
    ngc, csv = stem.with_suffix(".ngc"), stem.with_suffix(".csv")
    text = gcode(tip, axis, feed=args.feed, dwell_s=args.dwell_s,
                 title=f"{n} calibration poses, {machine.name}, D-optimal from {args.candidates} candidates")
    try:
        ngc.write_text(text, encoding="utf-8")
        write_csv(csv, tip, axis, q)
    except OSError as e:
        raise PmctlError(f"{e.filename or stem}: cannot write: {e.strerror or e}") from None
    # The job must parse and plan like any other.
    job = read_gcode(ngc, machine)
    traj = plan_job(job, machine, 1e-2)
    c_plan, rank, ld = I.condition_number(q, machine.geometry, has_axis=has_axis, max_sigma=math.inf)
    rng = np.random.default_rng(args.seed + 1000)
    conds = []
    for _ in range(10):
        rt, ra = Mo.random_tool_poses(machine, n, rng)
        conds.append(I.condition_number(K.ik_batch(rt, ra, machine).q, machine.geometry, has_axis=has_axis,
                                        max_sigma=math.inf)[0])
    out = [f"wrote {ngc} ({n} poses, G1 F{args.feed:g}, G4 P{args.dwell_s:g} at each; planned: "
           f"{len(traj.tip) * traj.dt:.1f} s) and {csv}",
           f"identifiable combinations: {rank} of {Mo.N_PARAMS} ({'tip + tool axis' if has_axis else 'tip only'})",
           f"condition number of the scaled identification Jacobian: planned {c_plan:.1f}; "
           f"random {n} poses: median {np.median(conds):.1f} (min {min(conds):.1f}, max {max(conds):.1f}, 10 draws)"]
    return "\n".join(out)
