"""Calibration on simulated machines: held-out tool errors before calibration, after the
response-surface method and after the model-based identification, at 20 / 40 / 60 measured poses,
planned (D-optimal) vs random.

    .venv/bin/python benchmarks/eval_calibration.py [--machines 3] [--heldout 300]

The machines are the report's 22-parameter error model (pmctl.tools.calibrate.rsm.SeedMachine,
+-0.5 mm / +-0.5 deg on a random subset of the parameters): an independent model, with a normal
joint offset pmctl's 30-parameter model does not have. Measurements carry 2 um tip noise per
coordinate and 10 urad tool-axis noise per direction. A held-out pose is commanded through the
calibrated model (IK for identification, the inverted surfaces for RSM) and the true machine's tool
pose is compared with the wanted one. Figures are the mean over the machines of the worst (and RMS)
error over the held-out poses.

"RSM (report)" fits the report's responses (Z_se, theta1e, theta2e); "RSM, axis responses" fits
the tool axis components instead (theta1 is singular at theta2 = 0 and no quadratic follows it).
Table 1 is inside a region where the response-surface method applies (Z_s 175-225 mm, theta1
15-45 deg, theta2 2.5-7.5 deg, table +-50 mm); Table 2 is the whole workspace (identification only:
the response surfaces are regional).
"""

import argparse
import math
import time
from dataclasses import replace

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default, pmctl/__init__.py)
import numpy as np

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.tools.calibrate import identify as I, model as Mo, plan as Pl, rsm

TIP_SIGMA = 2e-3
AXIS_SIGMA = 1e-5


def measure(sm, q, rng):
    tip, axis = sm.tool(q)
    tip = tip + rng.normal(0, TIP_SIGMA, tip.shape)
    e = rng.normal(0, AXIS_SIGMA, axis.shape)
    e -= np.sum(e * axis, -1, keepdims=True) * axis
    axis = axis + e
    return tip, axis / np.linalg.norm(axis, axis=-1, keepdims=True)


def errors(sm, tip, axis, q):
    t, a = sm.tool(q)
    return np.linalg.norm(t - tip, axis=-1) * 1e3, np.degrees(Mo.angle_between(a, axis))


def region_poses(m, region, n, rng, table=50.0):
    lo = [r[0] for r in region]
    hi = [r[1] for r in region]
    pts = np.stack([rng.uniform(lo[j], hi[j], n) for j in range(3)], 1)
    tip, axis, q = rsm.spatial_pose(m, pts[:, 0], pts[:, 1], pts[:, 2])
    xy = rng.uniform(-table, table, (n, 2))
    tip = tip.copy()
    tip[:, :2] -= xy
    return tip, axis, K.ik_batch(tip, axis, m).q


def planned_region_ident(m, region, n, rng, cands=800):
    tip, axis, q = region_poses(m, region, cands, rng)
    _, B = Pl.candidate_blocks(m, tip, axis)
    idx = Pl.d_optimal(B, n, rng)
    return tip[idx], axis[idx], q[idx]


def summary(e_tip, e_ax):
    return float(e_tip.max()), float(np.sqrt(np.mean(e_tip**2))), float(e_ax.max())


def fmt(s):
    return f"{s[0]:9.2f} {s[1]:7.2f} {s[2]:9.5f}"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--machines", type=int, default=3, help="simulated machines (default 3)")
    ap.add_argument("--heldout", type=int, default=300, help="held-out poses per machine (default 300)")
    ap.add_argument("--seed", type=int, default=11)
    args = ap.parse_args()
    m = load_machine()
    region = rsm.LOCAL_REGION
    t0 = time.time()
    rows1, rows2 = {}, {}
    for s in range(args.machines):
        rng = np.random.default_rng(args.seed + s)
        sm = rsm.SeedMachine.random(m, rng)
        # ---- table 1: inside the RSM region
        ht, ha, hq = region_poses(m, region, args.heldout, rng)
        before = summary(*errors(sm, ht, ha, hq))
        for n in (20, 40, 60):
            for how in ("planned", "random"):
                if how == "planned":
                    _, _, q_rsm = rsm.design_poses(m, region, n, rng, planned=True)
                    _, _, q_id = planned_region_ident(m, region, n, rng)
                else:
                    _, _, q_rsm = region_poses(m, region, n, rng)
                    q_id = q_rsm
                tm, am = measure(sm, q_rsm, rng)
                cal = rsm.RSMCalibration.build(q_rsm, tm, am, m)
                r_rsm = summary(*errors(sm, ht, ha, cal.command(ht, ha, m)))
                cal = rsm.RSMCalibration.build(q_rsm, tm, am, m, responses="axis")
                r_rsm2 = summary(*errors(sm, ht, ha, cal.command(ht, ha, m)))
                tm, am = measure(sm, q_id, rng)
                res = I.identify(q_id, tm, am, m.geometry)
                mi = replace(m, geometry=res.geometry)
                r_id = summary(*errors(sm, ht, ha, K.ik_batch(ht, ha, mi, check_limits=False).q))
                rows1.setdefault((n, how), []).append((before, r_rsm, r_rsm2, r_id))
        # ---- table 2: the whole workspace, identification only
        wt, wa = Mo.random_tool_poses(m, args.heldout, rng)
        wq = K.ik_batch(wt, wa, m).q
        before_w = summary(*errors(sm, wt, wa, wq))
        for n in (20, 40, 60):
            for how in ("planned", "random"):
                if how == "planned":
                    _, _, q = Pl.plan_poses(m, n, candidates=1000, seed=int(rng.integers(1 << 30)))
                else:
                    t_, a_ = Mo.random_tool_poses(m, n, rng)
                    q = K.ik_batch(t_, a_, m).q
                tm, am = measure(sm, q, rng)
                res = I.identify(q, tm, am, m.geometry)
                mi = replace(m, geometry=res.geometry)
                r_id = summary(*errors(sm, wt, wa, K.ik_batch(wt, wa, mi, check_limits=False).q))
                cond = I.condition_number(q, m.geometry, max_sigma=math.inf)[0]
                rows2.setdefault((n, how), []).append((before_w, r_id, cond))

    def mean(vals):
        return tuple(float(np.mean([v[k] for v in vals])) for k in range(3))

    print(f"{args.machines} simulated machines (report's 22-parameter model, +-0.5 mm / +-0.5 deg), "
          f"noise 2 um tip / 10 urad axis, {args.heldout} held-out poses each; mean over machines of "
          "the worst tip error, the RMS tip error (um) and the worst axis error (deg)")
    print()
    print(f"Table 1: inside Z_s {region[0][0]:g}-{region[0][1]:g} mm, theta1 {region[1][0]:g}-{region[1][1]:g} deg, "
          f"theta2 {region[2][0]:g}-{region[2][1]:g} deg, table +-50 mm")
    hdr = f"{'worst um':>9} {'RMS um':>7} {'worst deg':>9}"
    print(f"{'poses':>5} {'choice':>8} | {'before calibration':^27} | {'after RSM (report)':^27} | "
          f"{'after RSM, axis responses':^27} | {'after identification':^27}")
    print(f"{'':>5} {'':>8} | {hdr} | {hdr} | {hdr} | {hdr}")
    for (n, how), vals in rows1.items():
        b, r, r2, i = (mean([v[k] for v in vals]) for k in range(4))
        print(f"{n:>5} {how:>8} | {fmt(b)} | {fmt(r)} | {fmt(r2)} | {fmt(i)}")
    print()
    print("Table 2: the whole workspace (Z 290-470 mm, theta1 0-180 deg, |theta2| <= 18 deg, table +-55 mm), "
          "identification")
    print(f"{'poses':>5} {'choice':>8} | {'before calibration':^27} | {'after identification':^27} | cond (scaled)")
    print(f"{'':>5} {'':>8} | {hdr} | {hdr} |")
    for (n, how), vals in rows2.items():
        b, i = mean([v[0] for v in vals]), mean([v[1] for v in vals])
        c = float(np.median([v[2] for v in vals]))
        print(f"{n:>5} {how:>8} | {fmt(b)} | {fmt(i)} | {c:10.0f}")
    print(f"\n({time.time() - t0:.0f} s)")


if __name__ == "__main__":
    main()
