"""The response-surface method of the KAKENHI report "Hybrid parallel mechanism for high-precision
machining and compensation of its machining error" (ch. 5 error estimation, ch. 6 calibration),
reproduced on a simulated machine, and compared with the model-based identification.

The simulated machine (:class:`SeedMachine`) carries the report's 22 mechanism parameters, all in
the chain planes: per chain the base joint S (2: radial, height), SL and CL (offsets of the spherical
joint normal to the screw, from the plate link and the nut bracket), BL (along the screw: the
actuator zero) and RL (platform joint radius); on the platform the output point OP (2, in the
platform plane) and the spindle attitude SP (2 angles). The report gives a random subset of them
random errors within +-0.5 mm / +-0.5 deg. Its kinematics: a normal offset e = SL + CL makes the
joint distance sqrt((L + BL)^2 + e^2); the rest is pmctl's general geometry (an OP offset is a shift
of the platform frame). pmctl's 30-parameter model has no normal offset: it represents this machine
up to e^2/(2 L), under a micrometre for e <= 1 mm -- the one structural difference.

Chapter 5: for each region of Table 5.2 (Z_s 156-206 mm, theta1 0-90 / 90-180 deg, theta2 -5-0 /
0-5 deg) the tool tip error (dx, dy, dz) of the nominal commands is fitted by a 10-term quadratic in
(Z_s, theta1, theta2) on a D-optimal 20-point design (the report searched the design by a genetic
algorithm; here a Fedorov exchange on a 7x7x7 candidate grid does the same job), the terms are
t-tested (alpha = 0.05), the pruned model is refitted on a new D-optimal design for its terms, and
of the two the surface with the smaller mean error ME against the true error over the region is
kept. Z_s is the tool tip height in the base frame, theta2 the tilt of the tool axis.

Chapter 6: the tool pose actually reached (Z_se, theta1e, theta2e) is fitted by quadratics in the
chain inputs (L1, L2, L3) on 20 points of the region; the three surfaces set equal to the wanted
pose are solved for (L1, L2, L3) (Newton here, a GA in the report) and the result is commanded:
Table 6.2 for Z_s = 200 mm, theta1 = 30 deg, theta2 = 5 deg.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numpy as np
from scipy import stats

from pmctl.core import kinematics as K
from pmctl.core.config import Geometry, Machine
from pmctl.tools.calibrate import identify as I, model as Mo

SEED_PARAMS = tuple([f"{p}{i}" for i in (1, 2, 3) for p in ("S_r", "S_z", "SL", "BL", "CL", "RL")]
                    + ["OP_x", "OP_y", "SP_a", "SP_b"])            # 22
ANGLE = {"SP_a", "SP_b"}
REGIONS = {                                                          # Table 5.2
    1: ((156.0, 206.0), (0.0, 90.0), (-5.0, 0.0)),
    2: ((156.0, 206.0), (0.0, 90.0), (0.0, 5.0)),
    3: ((156.0, 206.0), (90.0, 180.0), (-5.0, 0.0)),
    4: ((156.0, 206.0), (90.0, 180.0), (0.0, 5.0)),
}
TABLE_6_2_POSE = (200.0, 30.0, 5.0)
SEED_TABLE_6_2 = {"before": (196.9629, 39.2941, 6.1886), "after": (199.9795, 29.9941, 5.0045),
                  "error_after": (-0.0205, -0.0059, 0.0045)}


# ---------------------------------------------------------------- the report's error model

@dataclass
class SeedMachine:
    """A machine built with the report's 22 parameter errors (mm / deg)."""

    nominal: Machine
    errors: dict

    @classmethod
    def random(cls, nominal: Machine, rng, *, mm=0.5, deg=0.5, fraction=0.7):
        """Errors on a random subset of the parameters, random amounts within +-mm / +-deg."""
        err = {}
        for p in SEED_PARAMS:
            if rng.random() < fraction:
                err[p] = float(rng.uniform(-1, 1) * (deg if p in ANGLE else mm))
        return cls(nominal, err)

    def e(self, p):
        return self.errors.get(p, 0.0)

    def geometry(self) -> Geometry:
        """pmctl geometry of this machine without the normal offsets (platform frame at OP)."""
        g = self.nominal.geometry
        A = np.array(g.base_joints, float)
        C = np.array(g.platform_joints, float)
        op = np.array([self.e("OP_x"), self.e("OP_y"), 0.0])
        for i in range(3):
            radial = A[i] * np.array([1.0, 1.0, 0.0])
            radial /= np.linalg.norm(radial)
            A[i] += self.e(f"S_r{i + 1}") * radial + np.array([0.0, 0.0, self.e(f"S_z{i + 1}")])
            cr = C[i] / np.linalg.norm(C[i])
            C[i] += self.e(f"RL{i + 1}") * cr
        C = C - op
        return replace(g, base_joints=A, platform_joints=C, length_offsets=np.zeros(3),
                       tool_tilt_deg=(g.tool_tilt_deg[0] + self.e("SP_a"), g.tool_tilt_deg[1] + self.e("SP_b")),
                       nominal=False)

    def effective_lengths(self, L):
        """Joint distances |C_i - A_i| of inputs L (..., 3): sqrt((L + BL)^2 + (SL + CL)^2)."""
        L = np.asarray(L, float)
        bl = np.array([self.e(f"BL{i}") for i in (1, 2, 3)])
        ee = np.array([self.e(f"SL{i}") + self.e(f"CL{i}") for i in (1, 2, 3)])
        return np.sqrt((L + bl) ** 2 + ee**2)

    def tool(self, q):
        """Tool tip in W and axis for joints q (n, 5) -- the simulator (noise-free)."""
        q = np.atleast_2d(np.asarray(q, float))
        g = self.geometry()
        sol = K.solve_platform(self.effective_lengths(q[:, :3]), g)
        if not np.all(sol.ok):
            raise RuntimeError("simulated machine: forward kinematics failed")
        return K.tool_of_platform(sol.P, sol.R, q[:, 3:5], g)


# ---------------------------------------------------------------- poses of the spatial part

def spatial_pose(machine: Machine, Zs, th1_deg, th2_deg):
    """Nominal (Z_s, theta1, theta2) -> tool tip in W at table (0, 0), tool axis, joints q (n, 5)."""
    g = machine.geometry
    Zs, t1, t2 = np.broadcast_arrays(*(np.atleast_1d(np.asarray(x, float)) for x in (Zs, th1_deg, th2_deg)))
    t1, t2 = np.radians(t1), np.radians(t2)
    Zp = Zs + g.tool_length * np.cos(t2)
    P, R = K.platform_pose(Zp, t1, t2, g.platform_radius)
    L = K.chain_lengths(P, R, g)
    tip, axis = K.tool_of_platform(P, R, np.zeros(P.shape[:-1] + (2,)), g)
    return tip, axis, np.concatenate([L, np.zeros(L.shape[:-1] + (2,))], -1)


def pose_of_tool(tip_w, axis, machine: Machine):
    """(Z_s mm in the base frame, theta1 deg, theta2 deg) of a tool pose; theta1 taken near (0, 180]."""
    t1, t2 = K.axis_to_tilt(axis)
    return tip_w[..., 2] + machine.geometry.z_table, np.degrees(t1), np.degrees(t2)


# ---------------------------------------------------------------- quadratic response surfaces

TERMS = ("1", "a", "b", "c", "ab", "ac", "bc", "aa", "bb", "cc")


def quad_design(x, mask=None):
    """Model matrix of the 10-term quadratic in 3 coded variables x (n, 3)."""
    a, b, c = x[:, 0], x[:, 1], x[:, 2]
    X = np.stack([np.ones_like(a), a, b, c, a * b, a * c, b * c, a * a, b * b, c * c], 1)
    return X if mask is None else X[:, mask]


def d_optimal_design(cand, n, mask, rng, *, passes=20):
    """n rows of the candidate points (coded) maximising det(X^T X) (Fedorov exchange, no repeats)."""
    X = quad_design(cand, mask)
    k = X.shape[1]
    idx = list(rng.choice(len(cand), n, replace=False))
    for _ in range(50):                     # a non-singular start
        if np.linalg.matrix_rank(X[idx]) == k:
            break
        idx = list(rng.choice(len(cand), n, replace=False))

    def logdet(ii):
        return np.linalg.slogdet(X[ii].T @ X[ii])[1]
    best = logdet(idx)
    for _ in range(passes):
        improved = False
        for pos in range(n):
            Minv = np.linalg.pinv(X[idx].T @ X[idx])
            # Fedorov delta for swapping idx[pos] with every candidate
            xi = X[idx[pos]]
            dx = np.einsum("ij,jk,ik->i", X, Minv, X)
            di = xi @ Minv @ xi
            dij = X @ Minv @ xi
            delta = dx - (dx * di - dij**2) - di
            delta[idx] = -np.inf
            j = int(np.argmax(delta))
            if delta[j] > 1e-9:
                trial = idx.copy()
                trial[pos] = j
                ld = logdet(trial)
                if ld > best + 1e-12:
                    idx, best, improved = trial, ld, True
        if not improved:
            break
    return np.array(idx), best


@dataclass
class Fit:
    mask: np.ndarray
    b: np.ndarray
    t: np.ndarray
    r2: float
    r2_adj: float
    design: np.ndarray          # the coded design points it was fitted on


def fit_quadratic(x, y, mask):
    X = quad_design(x, mask)
    n, p = X.shape
    b, *_ = np.linalg.lstsq(X, y, rcond=None)
    res = y - X @ b
    sse = float(res @ res)
    syy = float(np.sum((y - y.mean()) ** 2))
    dof = n - p
    s2 = sse / dof if dof > 0 else 0.0
    XtXi = np.linalg.pinv(X.T @ X)
    se = np.sqrt(np.maximum(np.diag(XtXi) * s2, 1e-300))
    r2 = 1.0 - sse / syy if syy > 0 else 1.0
    r2a = 1.0 - (sse / dof) / (syy / (n - 1)) if dof > 0 and syy > 0 else float("nan")
    return Fit(mask, b, b / se, r2, r2a, x)


def t_prune(f: Fit, n, alpha=0.05):
    """Keep the intercept and the terms whose |t| exceeds t_{alpha/2, n-k-1} (eq. 5.15)."""
    k = int(f.mask.sum()) - 1
    tc = stats.t.ppf(1 - alpha / 2, max(n - k - 1, 1))
    keep = f.mask.copy()
    kept = np.nonzero(f.mask)[0]
    for j, tj in zip(kept, f.t):
        if j != 0 and abs(tj) < tc:
            keep[j] = False
    return keep


def predict_quad(f: Fit, x):
    return quad_design(x, f.mask) @ f.b


class Coder:
    def __init__(self, lo, hi):
        self.lo, self.hi = np.asarray(lo, float), np.asarray(hi, float)

    def __call__(self, x):
        return 2 * (np.asarray(x, float) - self.lo) / (self.hi - self.lo) - 1

    def decode(self, c):
        return self.lo + (np.asarray(c, float) + 1) * (self.hi - self.lo) / 2


def region_grid(region, n=7, eps=1e-3):
    (z0, z1), (a0, a1), (b0, b1) = region
    a0 = max(a0, eps)
    axes = [np.linspace(z0, z1, n), np.linspace(a0, a1, n), np.linspace(b0, b1, n)]
    return np.array(list(itertools.product(*axes)))


# ---------------------------------------------------------------- chapter 5: error estimation

def tip_error(sm: SeedMachine, pts):
    """True tip error (mm, base frame) of the nominal commands at (Z_s, th1, th2) points (n, 3)."""
    tip, axis, q = spatial_pose(sm.nominal, pts[:, 0], pts[:, 1], pts[:, 2])
    tip_true, _ = sm.tool(q)
    return tip_true - tip


@dataclass
class RegionResult:
    region: int
    response: str
    me_initial_um: float
    me_pruned_um: float
    r2_adj_initial: float
    r2_adj_pruned: float
    terms_pruned: int
    chosen: str
    true_range_um: float


def estimate_region(sm: SeedMachine, region_id, rng, *, n_points=20, alpha=0.05, noise_mm=0.0):
    region = REGIONS[region_id]
    lo = [r[0] for r in region]
    hi = [r[1] for r in region]
    code = Coder(lo, hi)
    cand = region_grid(region)
    dense = region_grid(region, 11)
    true_dense = tip_error(sm, dense)
    full = np.ones(10, bool)
    idx, _ = d_optimal_design(code(cand), n_points, full, rng)
    y1 = tip_error(sm, cand[idx]) + rng.normal(0, noise_mm, (len(idx), 3)) if noise_mm else tip_error(sm, cand[idx])
    out = []
    for k, name in enumerate(("dx", "dy", "dz")):
        f1 = fit_quadratic(code(cand[idx]), y1[:, k], full)
        keep = t_prune(f1, n_points, alpha)
        # next generation: a new D-optimal design for the kept terms, new "experiments", refit
        idx2, _ = d_optimal_design(code(cand), n_points, keep, rng)
        y2 = tip_error(sm, cand[idx2])[:, k]
        if noise_mm:
            y2 = y2 + rng.normal(0, noise_mm, len(idx2))
        f2 = fit_quadratic(code(cand[idx2]), y2, keep)
        me1 = float(np.mean(np.abs(predict_quad(f1, code(dense)) - true_dense[:, k]))) * 1e3
        me2 = float(np.mean(np.abs(predict_quad(f2, code(dense)) - true_dense[:, k]))) * 1e3
        out.append(RegionResult(region_id, name, me1, me2, f1.r2_adj, f2.r2_adj, int(keep.sum()),
                                "pruned" if me2 < me1 else "initial", float(np.ptp(true_dense[:, k])) * 1e3))
    return out


# ---------------------------------------------------------------- chapter 6: calibration

@dataclass
class RSMCalibration:
    """Quadratic surfaces of the reached pose in the chain inputs (and, for the table, of the
    reached tip x, y) for one region; solve() gives the inputs for a wanted pose."""

    code: Coder
    fits: dict          # "Z", "t1", "t2", "x", "y" -> Fit in coded L
    region: tuple

    responses: str = "tilt"

    @classmethod
    def build(cls, q, tip_meas, axis_meas, machine, *, alpha=0.05, region=None, responses="tilt"):
        """responses "tilt": the report's (Z_se, theta1e, theta2e); "axis": (Z_se, v_x, v_y), the
        tool axis components, smooth in L where theta1 is not (it is undefined at theta2 = 0)."""
        L = q[:, :3]
        code = Coder(L.min(0), L.max(0))
        Zs, t1, t2 = pose_of_tool(tip_meas, axis_meas, machine)
        if responses == "axis":
            t1, t2 = axis_meas[:, 0], axis_meas[:, 1]
        # tip in the base frame with the table at the commanded position
        xb = tip_meas[:, 0] + q[:, 3]
        yb = tip_meas[:, 1] + q[:, 4]
        fits = {}
        full = np.ones(10, bool)
        for name, y in (("Z", Zs), ("t1", t1), ("t2", t2), ("x", xb), ("y", yb)):
            f = fit_quadratic(code(L), y, full)
            keep = t_prune(f, len(L), alpha)
            f2 = fit_quadratic(code(L), y, keep)
            # keep the pruned surface unless it fits the data worse (adjusted R^2)
            fits[name] = f2 if (np.isnan(f.r2_adj) or f2.r2_adj >= f.r2_adj) else f
        return cls(code, fits, region, responses)

    def predict(self, L):
        c = self.code(np.atleast_2d(L))
        return {k: predict_quad(f, c) for k, f in self.fits.items()}

    def solve(self, Zs, r1, r2, L0, *, tol=1e-10, max_iter=50):
        """Inputs L (3,) whose predicted pose is (Zs, r1, r2) -- (Z_s, theta1, theta2) in degrees, or
        (Z_s, v_x, v_y) with axis responses: Newton on the three surfaces."""
        L = np.array(L0, float)
        target = np.array([Zs, r1, r2])
        for _ in range(max_iter):
            p = self.predict(L)
            f = np.array([p["Z"][0], p["t1"][0], p["t2"][0]]) - target
            if np.max(np.abs(f)) < tol:
                break
            J = np.zeros((3, 3))
            h = 1e-4
            for j in range(3):
                d = np.zeros(3)
                d[j] = h
                pp, pm = self.predict(L + d), self.predict(L - d)
                J[:, j] = [(pp[k][0] - pm[k][0]) / (2 * h) for k in ("Z", "t1", "t2")]
            L = L - np.linalg.solve(J, f)
        return L

    def command(self, tip_w, axis, machine):
        """Joints for a wanted tool pose (tip in W, axis): chains from the surfaces, table from the
        predicted horizontal tip position at those chain inputs."""
        Zs, t1, t2 = pose_of_tool(tip_w, axis, machine)
        if self.responses == "axis":
            t1, t2 = axis[:, 0], axis[:, 1]
        q0 = K.ik_batch(tip_w, axis, machine, check_limits=False).q
        out = np.array(q0, float)
        for k in range(len(out)):
            L = self.solve(Zs[k], t1[k], t2[k], q0[k, :3])
            p = self.predict(L)
            out[k, :3] = L
            out[k, 3] = p["x"][0] - tip_w[k, 0]
            out[k, 4] = p["y"][0] - tip_w[k, 1]
        return out


def design_poses(machine, region, n, rng, *, planned=True):
    """n poses (tip in W at table 0, axis, q) in a region: D-optimal for the quadratic or random."""
    lo = [r[0] for r in region]
    hi = [r[1] for r in region]
    code = Coder(lo, hi)
    cand = region_grid(region)
    if planned:
        idx, _ = d_optimal_design(code(cand), n, np.ones(10, bool), rng)
        pts = cand[idx]
    else:
        pts = np.stack([rng.uniform(lo[j], hi[j], n) for j in range(3)], 1)
        pts[:, 1] = np.maximum(pts[:, 1], 1e-3)
    return spatial_pose(machine, pts[:, 0], pts[:, 1], pts[:, 2])


LOCAL_REGION = ((175.0, 225.0), (15.0, 45.0), (2.5, 7.5))     # around the Table 6.2 pose
SMALL_REGION = ((190.0, 210.0), (25.0, 35.0), (4.0, 6.0))


def table_6_2(sm: SeedMachine, rng, *, n_points=20, region=REGIONS[2], tip_sigma_mm=0.0, axis_sigma_rad=0.0):
    """Calibrate the Table 6.2 pose with RSM and with identification from the same poses."""

    m = sm.nominal
    tip, axis, q = design_poses(m, region, n_points, rng)
    tip_m, axis_m = sm.tool(q)
    if tip_sigma_mm or axis_sigma_rad:
        tip_m = tip_m + rng.normal(0, tip_sigma_mm, tip_m.shape)
        e = rng.normal(0, axis_sigma_rad, axis_m.shape)
        e -= np.sum(e * axis_m, -1, keepdims=True) * axis_m
        axis_m = axis_m + e
        axis_m /= np.linalg.norm(axis_m, axis=-1, keepdims=True)
    target_tip, target_axis, q_nom = spatial_pose(m, *TABLE_6_2_POSE)
    tt, ta = sm.tool(q_nom)
    before = np.array(pose_of_tool(tt, ta, m)).ravel()
    cal = RSMCalibration.build(q, tip_m, axis_m, m)
    L = cal.solve(*TABLE_6_2_POSE, q_nom[0, :3])
    ra = sm.tool(np.concatenate([L, [0.0, 0.0]])[None])
    after = np.array(pose_of_tool(*ra, m)).ravel()
    # identification from the same measurements (tip + axis), then IK of the wanted pose
    res = I.identify(q, tip_m, axis_m, m.geometry, tip_sigma_mm=tip_sigma_mm or I.TIP_SIGMA_MM,
                     axis_sigma_rad=axis_sigma_rad or I.AXIS_SIGMA_RAD)
    mi = replace(m, geometry=res.geometry)
    qi = K.ik_batch(target_tip, target_axis, mi, check_limits=False).q
    ri = sm.tool(qi)
    ident = np.array(pose_of_tool(*ri, m)).ravel()
    return {"target": np.array(TABLE_6_2_POSE), "before": before, "rsm": after, "identification": ident,
            "rsm_axis_deg": float(np.degrees(Mo.angle_between(ra[1][0], target_axis[0]))),
            "identification_tip_um": float(np.linalg.norm(ri[0][0] - target_tip[0])) * 1e3,
            "identification_axis_deg": float(np.degrees(Mo.angle_between(ri[1][0], target_axis[0]))),
            "rank": res.rank, "region": region}


def run(machine: Machine, *, seed=3) -> str:
    rng = np.random.default_rng(seed)
    sm = SeedMachine.random(machine, rng)
    L = []
    L.append(f"simulated machine (seed {seed}): {len(sm.errors)} of 22 parameters with errors "
             "(+-0.5 mm / +-0.5 deg): " + ", ".join(f"{k} {v:+.3f}" for k, v in sm.errors.items()))
    L.append("")
    L.append("Table 5.2 regions: tool tip error surfaces, quadratic in (Z_s, theta1, theta2), D-optimal 20 points,")
    L.append("t-test pruning (alpha 0.05) and a new 20-point design for the pruned model; ME = mean |surface - true|")
    L.append("over an 11x11x11 grid of the region (the report: 'a few micrometres or less').")
    L.append(f"{'region':>6} {'Z_s mm':>9} {'th1 deg':>8} {'th2 deg':>7} {'resp':>4} {'true range um':>13} "
             f"{'ME init um':>10} {'ME pruned um':>12} {'R2adj init':>10} {'R2adj pr':>9} {'terms':>5} kept")
    for rid, reg in REGIONS.items():
        for r in estimate_region(sm, rid, rng):
            L.append(f"{rid:>6} {reg[0][0]:>4.0f}-{reg[0][1]:<4.0f} {reg[1][0]:>3.0f}-{reg[1][1]:<4.0f} "
                     f"{reg[2][0]:>3.0f}-{reg[2][1]:<3.0f} {r.response:>4} {r.true_range_um:13.1f} "
                     f"{r.me_initial_um:10.3f} {r.me_pruned_um:12.3f} {r.r2_adj_initial:10.6f} "
                     f"{r.r2_adj_pruned:9.6f} {r.terms_pruned:5d} {r.chosen}")

    def row(name, v):
        L.append(f"{name:34s} {v[0]:10.4f} {v[1]:11.4f} {v[2]:11.4f}")
    cases = [("region 2 as printed, noise-free", REGIONS[2], 0.0, 0.0),
             ("around the pose, noise-free", LOCAL_REGION, 0.0, 0.0),
             ("small region around the pose, noise-free", SMALL_REGION, 0.0, 0.0),
             ("small region around the pose, 2 um / 10 urad noise", SMALL_REGION, 2e-3, 1e-5)]
    for title, reg, ts, as_ in cases:
        t = table_6_2(sm, rng, region=reg, tip_sigma_mm=ts, axis_sigma_rad=as_)
        L.append("")
        L.append(f"Table 6.2: the pose Z_s = 200 mm, theta1 = 30 deg, theta2 = 5 deg; 20 D-optimal points in "
                 f"Z_s {reg[0][0]:g}-{reg[0][1]:g} mm, theta1 {reg[1][0]:g}-{reg[1][1]:g} deg, "
                 f"theta2 {reg[2][0]:g}-{reg[2][1]:g} deg ({title})")
        L.append(f"{'':34s} {'Z_s mm':>10} {'theta1 deg':>11} {'theta2 deg':>11}")
        row("wanted", t["target"])
        row("before (nominal IK)", t["before"])
        row("  error", t["before"] - t["target"])
        row("after RSM (surfaces in L1-L3)", t["rsm"])
        row("  error", t["rsm"] - t["target"])
        row("after identification (same poses)", t["identification"])
        row("  error", t["identification"] - t["target"])
        L.append(f"  tool axis error: RSM {t['rsm_axis_deg']:.5f} deg, identification {t['identification_axis_deg']:.6f} deg; "
                 f"identification whole tip error {t['identification_tip_um']:.3f} um ({t['rank']} combinations)")
    s = SEED_TABLE_6_2
    L.append("")
    L.append(f"{'the report (Table 6.2)':34s} {'Z_s mm':>10} {'theta1 deg':>11} {'theta2 deg':>11}")
    row("before", s["before"])
    row("after", s["after"])
    row("error after", s["error_after"])
    return "\n".join(L)
