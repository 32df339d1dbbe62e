"""What the three plate-link strain gauges say about forces at the tool (seed 004 ch. 5, position /
velocity / force modes, in the machine's own terms). Pure functions.

**Load at the tool.** The chains hold the platform: with the constraint Jacobian A (rows
[u_i, (R c_i) x u_i] and [n_i, (R c_i) x n_i], :func:`pmctl.core.kinematics.constraint_jacobian`)
equilibrium reads A^T [a; b] = -(w_g + G f), where a (3) are the axial compressions the gauges measure
(strain = -k_eps a, :func:`pmctl.core.statics.strain_of_axial`), b (3) the lateral forces the revolute
joints carry along their axes (no gauge), w_g the gravity wrench and G = [I; [R p_tip]x] maps a force
f at the tool tip to a wrench about P. Unknown are b and f: six unknowns, six equations, so

    [A^T[:, 3:]  G] [b; f] = -w_g - A^T[:, :3] a

is solved exactly wherever that 6x6 matrix is regular (:func:`tip_load`). Not observable from three
gauges: a moment at the tool (the spindle's cutting torque about the tool axis, or any couple), a
force applied anywhere but the tip (it is attributed to the tip), and the split between a tip force
and platform inertia (subtract m a_platform first when accelerating): three gauges give three numbers,
so at most three load components can be estimated, and only under the "pure tip force" assumption.

**Touch-off.** Moving toward a surface, the tip force is zero until contact, then grows with the
contact stiffness. :func:`detect_contact` flags the first tick where a chain's axial force departs
from the model (gravity statics) by more than a threshold for ``debounce`` ticks in a row;
:func:`contact_point` back-extrapolates the force ramp to zero to report where contact began, and
:func:`overtravel_bound` bounds how far the tool goes past the contact before it is stopped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pmctl.core import kinematics as K, statics
from pmctl.core.config import Machine
from pmctl.core.kinematics import _mv, constraint_jacobian


# ---------------------------------------------------------------------------------------------
# Load at the tool
# ---------------------------------------------------------------------------------------------

def _load_system(P, R, machine: Machine):
    """6x6 matrix [A^T[:, 3:] | G] of (b, f) and the map A^T[:, :3] of the axial forces."""
    A = constraint_jacobian(np.asarray(P, float), np.asarray(R, float), machine.geometry)
    At = np.swapaxes(A, -1, -2)
    r = _mv(np.asarray(R, float), machine.geometry.tool_tip_p)
    G = np.zeros(r.shape[:-1] + (6, 3))
    G[..., 0, 0] = G[..., 1, 1] = G[..., 2, 2] = 1.0
    # rows 3..5: r x f
    G[..., 3, 1], G[..., 3, 2] = -r[..., 2], r[..., 1]
    G[..., 4, 0], G[..., 4, 2] = r[..., 2], -r[..., 0]
    G[..., 5, 0], G[..., 5, 1] = -r[..., 1], r[..., 0]
    M = np.concatenate([At[..., 3:], G], -1)
    return M, At[..., :3]


def tip_load_condition(P, R, machine: Machine):
    """Condition number of the load estimate's 6x6 system at the pose (inf where it is singular)."""
    M, _ = _load_system(P, R, machine)
    return np.linalg.cond(M)


def tip_load(strain, P, R, machine: Machine, *, gravity=True):
    """Force at the tool tip (fx, fy, fz) in N, base axes, from the three plate-link strains (µε,
    tension positive) at platform pose (P, R). ``gravity``: the strains include the platform's weight
    (as the gauges read it) and it is taken off with the statics model. Batch over leading axes."""
    strain = np.asarray(strain, float)
    axial = -strain / machine.strain_gain
    M, Aa = _load_system(P, R, machine)
    w = statics.external_wrench(P, R, machine) if gravity else np.zeros(np.shape(P)[:-1] + (6,))
    rhs = -w - np.einsum("...ij,...j->...i", Aa, axial)
    x = np.linalg.solve(M, rhs[..., None])[..., 0]
    return x[..., 3:]


# ---------------------------------------------------------------------------------------------
# Touch-off
# ---------------------------------------------------------------------------------------------

def force_departure(strain, model_strain, machine: Machine):
    """Axial force departure per chain (N, compression positive) of measured vs model strain."""
    return -(np.asarray(strain, float) - np.asarray(model_strain, float)) / machine.strain_gain


def detect_contact(departure, threshold_N: float, debounce: int = 2):
    """First tick index at which any chain's |force departure| (N, (n, 3)) has exceeded the threshold
    for ``debounce`` consecutive ticks (the index of the last of them: when the stop is decided),
    or None."""
    if threshold_N <= 0 or debounce < 1:
        raise ValueError("threshold must be > 0 N and debounce >= 1 tick")
    over = np.any(np.abs(np.asarray(departure, float)) > threshold_N, axis=-1)
    run = 0
    for k, o in enumerate(over):
        run = run + 1 if o else 0
        if run >= debounce:
            return k
    return None


def contact_point(positions, departure, k_detect: int, noise_N: float, window: int = 20):
    """Where the contact began: the force norm after contact grows linearly with the travel; fit the
    unbroken run of samples above 3x the noise (3-channel norm) that ends at the detection tick (at
    most ``window`` of them) and extrapolate to zero force. Returns (position (3,), fractional tick
    index of the contact)."""
    pos = np.asarray(positions, float)
    f = np.linalg.norm(np.asarray(departure, float), axis=-1)
    lo = max(0, k_detect - window)
    floor = 3.0 * math.sqrt(3.0) * noise_N
    j = k_detect
    while j > lo and f[j - 1] > floor:
        j -= 1
    sel = np.arange(j, k_detect + 1)
    if len(sel) < 2:
        kc = float(k_detect)
    else:
        c1, c0 = np.polyfit(sel.astype(float), f[sel], 1)
        kc = float(np.clip(-c0 / c1, lo, k_detect)) if c1 > 0 else float(k_detect)
    i = int(math.floor(kc))
    u = kc - i
    j = min(i + 1, len(pos) - 1)
    return pos[i] * (1.0 - u) + pos[j] * u, kc


def contact_onset(filtered, window: int, resolution: float = 0.05) -> float:
    """Where a force ramp began, from departures seen through a ``window``-tick moving average.

    After contact at (fractional) tick c the raw force of each chain grows as a_i (k - c) (constant
    speed into a linear surface); its moving average is that ramp convolved with the box, quadratic
    for ``window`` ticks, then linear. ``filtered`` (n, 3) holds the averaged departures of the last
    n ticks; the onset c (index into them, may be < 0) and the slopes a_i are fitted by least
    squares: a coarse search over whole ticks (from 4 ticks before the first raw tick the averages
    cover), then a fine one at ``resolution`` around the best.
    Robust against the ringing a straight-line extrapolation picks up when the ramp is short."""
    y = np.asarray(filtered, float)
    n = len(y)
    j = (np.arange(n)[:, None] - np.arange(window)[None, :]).astype(float)     # raw ticks under each average
    yy = float((y * y).sum())

    def best(cands):
        B = np.maximum(0.0, j[None] - cands[:, None, None]).mean(-1)            # (C, n)
        bb = (B * B).sum(-1)
        by = B @ y                                                              # (C, 3)
        with np.errstate(divide="ignore", invalid="ignore"):
            resid = np.where(bb > 0, yy - (by * by).sum(-1) / bb, np.inf)
        return float(cands[int(np.argmin(resid))])

    c = best(np.arange(-float(window) - 4.0, n - 1.0))   # an onset up to 4 ticks before the first one held
    return best(np.arange(c - 1.0, c + 1.0 + 1e-9, resolution))


def overtravel_bound(speed_mm_s: float, decel_mm_s2: float, dt: float, threshold_N: float,
                     contact_stiffness_N_per_mm: float, debounce: int = 2, latency_ticks: int = 1,
                     noise_N: float = 0.0, noise_sigmas: float = 5.0, share: float = 1.0) -> float:
    """Upper bound on the travel past the contact point before the tool is at rest (mm).

    After contact the tip force grows as k_c x (x: travel past contact) and the most loaded chain
    carries ``share`` of it (max |:func:`chain_share`|, N per N). Travel until that chain force, minus
    noise (``noise_sigmas`` x ``noise_N``), passes the chain threshold: (threshold + n sigma)/(share
    k_c); then the sampling (one tick), the debounce (debounce - 1 ticks), the latency to the first
    braking tick, the braking distance v^2 / (2 a) and one tick for its discretisation."""
    v = abs(speed_mm_s)
    x_force = (threshold_N + noise_sigmas * noise_N) / (share * contact_stiffness_N_per_mm)
    ticks = 1 + (debounce - 1) + latency_ticks + 1
    return x_force + v * ticks * dt + v * v / (2.0 * decel_mm_s2)


def chain_share(P, R, machine: Machine, direction):
    """Axial force per chain (N) for 1 N at the tip along ``direction`` (the probing direction)."""
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    return statics.chain_forces(P, R, machine, tip_force=d).axial - statics.chain_forces(P, R, machine).axial


@dataclass
class ProbeResult:
    detected: bool
    k_detect: int
    contact: np.ndarray       # reported contact point (3,)
    stop: np.ndarray          # where the tool came to rest (3,)
    overtravel_mm: float      # travel past the true contact point, along the approach


def simulate_probe(P, R, machine: Machine, *, start, direction, surface_mm: float, speed_mm_s: float,
                   decel_mm_s2: float, dt: float, contact_stiffness_N_per_mm: float, threshold_N: float,
                   debounce: int = 2, latency_ticks: int = 1, noise_ue: float = 0.0, rng=None,
                   max_ticks: int = 100000) -> ProbeResult:
    """A synthetic strain stream of a probing move: the tip moves from ``start`` along ``direction``
    at ``speed_mm_s``; contact at travel ``surface_mm``; the tip force is -k_c x direction beyond it.
    Gauges read the gravity strain plus the contact strain plus Gaussian noise. On detection the move
    brakes at ``decel_mm_s2`` after ``latency_ticks``. The pose (P, R) is held for the statics (the
    small travel changes the chain forces negligibly)."""
    rng = rng or np.random.default_rng(0)
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    start = np.asarray(start, float)
    s0 = statics.static_strain(P, R, machine)
    per_N = statics.strain_of_axial(chain_share(P, R, machine, d), machine)     # µε per N of contact force
    x, v = 0.0, abs(speed_mm_s)
    pos, dep = [], []
    k_detect, braking_from = None, None
    for k in range(max_ticks):
        pen = max(0.0, x - surface_mm)
        strain = s0 + per_N * (contact_stiffness_N_per_mm * pen) + noise_ue * rng.standard_normal(3)
        pos.append(start + x * d)
        dep.append(force_departure(strain, s0, machine))
        if k_detect is None:
            kd = detect_contact(np.array(dep[-debounce:]), threshold_N, debounce) if len(dep) >= debounce else None
            if kd is not None:
                k_detect = k
                braking_from = k + latency_ticks
        if braking_from is not None and k >= braking_from:
            v = max(0.0, v - decel_mm_s2 * dt)
            if v == 0.0:
                break
        x += v * dt
    noise_N = noise_ue / machine.strain_gain
    if k_detect is None:
        return ProbeResult(False, -1, np.full(3, np.nan), start + x * d, max(0.0, x - surface_mm))
    cp, _ = contact_point(np.array(pos), np.array(dep), k_detect, noise_N)
    return ProbeResult(True, k_detect, cp, start + x * d, x - surface_mm)


def tip_load_of_joints(strain, q, machine: Machine):
    """:func:`tip_load` in batch at the poses of joint positions ``q`` (..., 5) (the model's: the
    commanded joints), gravity taken off; NaN where the forward kinematics fails. (..., 3) N."""
    q = np.asarray(q, float)
    strain = np.asarray(strain, float)
    out = np.full(q.shape[:-1] + (3,), np.nan)
    fin = np.all(np.isfinite(q), -1) & np.all(np.isfinite(strain), -1)
    if not fin.any():
        return out
    pose, ok = K.fk_batch(q[fin], machine)
    f = np.full((int(fin.sum()), 3), np.nan)
    if ok.any():
        f[ok] = tip_load(strain[fin][ok], pose.P[ok], pose.R[ok], machine)
    out[fin] = f
    return out


# ---------------------------------------------------------------------------------------------
# The recordings' load channels (pmctl run and pmctl serve --record)
# ---------------------------------------------------------------------------------------------

LOAD_CHANNELS = ("load_fx", "load_fy", "load_fz")
LOAD_NOTE = ("estimate: force at the tool tip from the three strains and the statics at the commanded pose, "
             "the platform's weight taken off (pmctl.core.strain_sensing.tip_load; a moment at the tool is not "
             "observable, platform inertia reads as load while accelerating)")


def load_columns(strain, q_cmd, machine: Machine) -> dict:
    """The load_fx/fy/fz channels of a chunk of drained records (strain (n, 3) µε, commanded joints
    (n, 5) mm), vectorised."""
    f = tip_load_of_joints(strain, q_cmd, machine)
    return {c: f[:, i] for i, c in enumerate(LOAD_CHANNELS)}
