"""The sampled strain-feedback loop of one chain (K_theta, docs/vibration.md): its poles, its gain and
phase margins, and the gains designed from the chain mode -- pure math, no I/O.

**The loop as the NC runs it**, one tick of dt (seed 004 eq. 3.1 in pmctl's gains, sampled): the
motor-side chain position x_m, the chain mode's deflection y (load side minus motor side) with
y'' + 2 zeta w y' + w^2 y = -x_m'', and the offset d of the decoupled law. Each tick the NC reads
the deflection u at the tick's start (the gauges; the loop is closed by u = y) and commands the
rate

    v = -kv x_m + kv d + K_theta u,        d += dt (K_theta u - leak d)

(d = 0 in the plain law, which has no leak); the motor ramps by v dt over the tick, so y' jumps by
-(v - v_prev) at the tick's start and (y, y') then move exactly over the tick. With a leak this is
the decoupled law of pmctl.motion.nc (the pose loop no longer pulls the feedback's motion back);
without one, the seed's u = K_G (theta0 - theta_m) - K_theta (theta_m - theta_L).

**Margins** are those of this loop opened at the strain input: the gain margin is the factor on
K_theta (equally: on the strain -> deflection scale, the modal stiffness) at which a closed-loop pole
leaves the unit circle; the phase margin is the smallest extra phase lag at the frequencies where
the open loop's gain is 1, and the delay margin the same as whole ticks of extra delay.

**The design** (:func:`design_k_theta`, what ``k_theta_per_s = "auto"`` runs) takes the mode as
uncertain: the plant anywhere in the box f x (1 -+ MODE_ERROR), zeta x DAMPING_SPAN while the NC is
designed for (f, zeta), and asks every closed-loop pole, at every point of the box, for at least
DAMPING_TARGET damping, with a gain margin of MIN_GAIN_MARGIN and a phase margin of
MIN_PHASE_MARGIN_DEG everywhere.
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.linalg import expm

from pmctl.core.errors import PmctlError

DAMPING_TARGET = 0.7        # the closed loop's least damping, at the worst of the mode's errors
MODE_ERROR = 0.2            # the chain mode's frequency known to within +-this share
DAMPING_SPAN = (0.5, 2.0)   # and its damping ratio within these factors
MAX_KDT = 0.5               # K_theta dt at most this (the motor follows the load within two ticks)
KDT_STEP = 0.025            # the grid of K_theta dt the design searches
LEAK_STEPS = tuple(0.05 * i for i in range(10, 0, -1))   # leaks searched, x w (largest first)
MIN_GAIN_MARGIN = 2.0       # every design keeps these margins at every point of the box
MIN_PHASE_MARGIN_DEG = 45.0
MAX_SOFT_FDT = 0.25         # the decoupled law for modes of at least 4 ticks a period (its stretch estimate
                            # a*/w^2 takes the plan's acceleration between ticks)
STRETCH_ERROR = 0.25        # the stretch feed-forward's low-pass errs by at most this share at the mode


@lru_cache(maxsize=4096)
def _mode_transition(f, zeta, dt):
    """exp(M dt) of the free mode (y, y'), M = [[0, 1], [-w^2, -2 zeta w]]."""
    w = 2 * math.pi * f
    return expm(np.array([[0.0, 1.0], [-w * w, -2 * zeta * w]]) * dt)


def loop_matrices(f, zeta, kth, kv, dt, leak=None):
    """(A0, B0, C) of the chain's sampled loop opened at the strain input (module docstring): state
    (x_m, y, y', v_prev, d), input u (the deflection the feedback reads), output y. The closed loop
    is u = y: A = A0 + outer(B0, C)."""
    Phi = _mode_transition(float(f), float(zeta), float(dt))
    on = leak is not None
    V = np.array([-kv, 0.0, 0.0, 0.0, kv if on else 0.0])      # the rate's part from the state
    A = np.zeros((5, 5))
    A[0] = np.eye(5)[0] + dt * V
    J = np.eye(5)
    J[2] -= V
    J[2, 3] += 1.0
    A[1:3] = Phi @ J[1:3]
    A[3] = V
    if on:
        A[4, 4] = 1.0 - dt * leak
    B = np.zeros(5)
    B[0] = dt * kth
    B[1:3] = Phi @ np.array([0.0, -kth])
    B[3] = kth
    B[4] = dt * kth if on else 0.0
    return A, B, np.eye(5)[1]


def closed_loop_poles(f, zeta, kth, kv, dt, leak=None):
    """Eigenvalues z of the closed sampled loop (u = y)."""
    A, B, C = loop_matrices(f, zeta, kth, kv, dt, leak)
    return np.linalg.eigvals(A + np.outer(B, C))


def pole_damping(z, dt):
    """(natural frequency Hz, damping ratio) of discrete poles z (s = ln z / dt); poles at 0 (pure
    delays) are left out."""
    z = np.asarray(z, complex)
    z = z[np.abs(z) > 1e-12]
    s = np.log(z) / dt
    wn = np.abs(s)
    return wn / (2 * math.pi), np.where(wn > 0, -s.real / np.where(wn > 0, wn, 1.0), 1.0)


def least_damped_oscillation(z, dt):
    """(damped frequency Hz, damping ratio) of the least damped oscillating pole of ``z`` (the mode
    as a decay shows it: the frequency is the oscillation's), or (nan, 1.0) without one."""
    z = np.asarray(z, complex)
    osc = z[z.imag > 1e-12]
    if len(osc) == 0:
        return float("nan"), 1.0
    lz = np.log(osc)
    zs = -lz.real / np.abs(lz)
    i = int(np.argmin(zs))
    return abs(lz[i].imag) / (2 * math.pi * dt), float(zs[i])


@dataclass
class LoopMargins:
    gain_margin: float          # factor on K_theta (the strain scale) that makes the loop unstable (inf: none)
    phase_margin_deg: float     # extra phase lag at the gain crossover(s) before instability (inf: no crossover)
    delay_margin_ticks: float   # the least extra strain delay, in ticks, that brings a crossover to G = 1
    min_damping: float          # least damping ratio of the closed loop's poles
    mode_hz: float              # the least damped oscillating pole: damped frequency, Hz
    mode_damping: float         # ... and damping ratio


def _phase_margin(A, B, C, n):
    """(phase margin deg, delay margin ticks) of the open loop G(z) = C (zI - A)^-1 B on ``n``
    frequencies up to the Nyquist frequency (inf, inf: |G| never crosses 1)."""
    lam, V = np.linalg.eig(A)                   # G(z) = sum_i r_i / (z - lam_i)
    r = (C @ V) * np.linalg.solve(V, B)

    def G(t):
        return np.sum(r / (np.exp(1j * np.asarray(t))[..., None] - lam), -1)
    th = np.linspace(1e-4, math.pi, n)
    mag = np.abs(G(th))
    pm, dm = float("inf"), float("inf")
    for k in np.nonzero(np.diff(np.sign(mag - 1.0)) != 0)[0]:
        u = (1.0 - mag[k]) / (mag[k + 1] - mag[k])
        t = th[k] + u * (th[k + 1] - th[k])
        p = abs(math.degrees(np.angle(G(t))))
        pm, dm = min(pm, p), min(dm, math.radians(p) / t)
    return pm, dm


def loop_margins(f, zeta, kth, kv, dt, leak=None, n: int = 2048) -> LoopMargins:
    """Gain and phase margins of the loop opened at the strain input (module docstring), and its
    closed-loop poles' least damping. The gain margin is found on the poles (bisection on the factor
    on K_theta), so it needs no Nyquist bookkeeping; the phase margin is min |arg G| over the
    frequencies where |G(e^{j theta})| = 1, G the open loop (the closed loop is u = y: unstable at
    G = 1), on ``n`` frequencies up to the Nyquist frequency; the delay margin, the least of
    (phase margin / crossover angle) over the crossovers."""
    A, B, C = loop_matrices(f, zeta, kth, kv, dt, leak)
    pm, dm = _phase_margin(A, B, C, n)
    BC = np.outer(B, C)                         # B scales with K_theta, A does not

    def stable(g):
        return np.max(np.abs(np.linalg.eigvals(A + g * BC))) < 1.0
    gm = float("inf")
    if kth > 0 and not stable(1.0):
        gm = 0.0
    elif kth > 0:
        lo, hi = 1.0, 2.0
        while stable(hi) and hi < 1e3:
            lo, hi = hi, 2.0 * hi
        if hi < 1e3:
            for _ in range(40):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if stable(mid) else (lo, mid)
            gm = lo
    z = np.linalg.eigvals(A + BC)
    fm, zm = least_damped_oscillation(z, dt)
    return LoopMargins(gm, pm, dm, float(np.min(pole_damping(z, dt)[1])), fm, zm)


@dataclass(frozen=True)
class KThetaDesign:
    k_theta: float              # 1/s
    leak: float | None          # 1/s, the decoupled law's offset leak; None: the plain law
    acc_lp: float               # 1/s, the low-pass of the planned chain acceleration (the stretch feed-forward)
    worst_damping: float        # least closed-loop damping over the error box
    nominal: LoopMargins        # margins and poles at the nominal mode
    worst_gain_margin: float    # least over the error box
    worst_phase_margin_deg: float
    reached: bool               # worst_damping >= the target

    @property
    def soft(self) -> bool:
        """The decoupled (soft-chain) law."""
        return self.leak is not None


def stretch_lowpass(f, dt, error: float = STRETCH_ERROR) -> float:
    """The low-pass (1/s) of the planned chain acceleration a* whose stretch a*/w^2 the NC takes off
    the deflection and leads the motor by: the lowest cut-off of the NC's one-pole filter
    af += c (a* - af), c = 1 - exp(-w_lp dt), that reproduces a motion at the mode within ``error``
    (|1 - H(e^{j w dt})| = error). Lower, the load lags the plan (path error); higher, a one-tick
    step of the plan's velocity (a corner passed at speed) leads the motor by more of a*/w^2 in one
    tick. 3.9 w for a mode far below the tick rate."""
    x = cmath.exp(-1j * 2 * math.pi * f * dt)

    def err(c):
        return abs(1.0 - c / (1.0 - (1.0 - c) * x))
    lo, hi = 1e-9, 1.0
    if err(hi) > error:
        return math.inf
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if err(mid) <= error else (mid, hi)
    return -math.log(1.0 - hi) / dt if hi < 1.0 else math.inf


def _box(err, span):
    return [(r, zf) for r in (1.0 - err, 1.0, 1.0 + err) for zf in (span[0], 1.0, span[1])]


def _worst_damping(f, zeta, kth, kv, dt, leak, err, span):
    """Least pole damping over the error box (every pole: the mode's and the offset's slow ones;
    a slow pole ringing at 0.3 damping costs path error for its several periods); -1 when a point of
    it is unstable. (Asking 0.7 only of the poles around the mode and 0.3 of the slow ones gives
    275/s, leak 0.25 w at 40 Hz: the cone job's cut falls from 11.6x to 8.4x.)"""
    worst = 1.0
    for r, zf in _box(err, span):
        z = closed_loop_poles(f * r, zeta * zf, kth, kv, dt, leak)
        if np.max(np.abs(z)) >= 1.0:
            return -1.0
        worst = min(worst, float(np.min(pole_damping(z, dt)[1])))
    return worst


def _margins_over_box(f, zeta, kth, kv, dt, leak, err, span, n=512):
    gm, pm = float("inf"), float("inf")
    for r, zf in _box(err, span):
        m = loop_margins(f * r, zeta * zf, kth, kv, dt, leak, n=n)
        gm, pm = min(gm, m.gain_margin), min(pm, m.phase_margin_deg)
    return gm, pm


@lru_cache(maxsize=256)
def design_k_theta(f: float, zeta: float, kv: float, dt: float, k_theta: float | None = None,
                   soft: bool | None = None, target: float = DAMPING_TARGET, err: float = MODE_ERROR,
                   span: tuple = DAMPING_SPAN, max_kdt: float = MAX_KDT) -> KThetaDesign:
    """The strain feedback for a chain mode (f Hz, damping ratio zeta), the pose gain kv and the tick
    dt, robust to the mode's error (module docstring):

    * the decoupled law (``soft`` True): K_theta is the smallest gain (K_theta dt on a grid of
      KDT_STEP up to ``max_kdt``) for which some leak gives every closed-loop pole at least ``target``
      damping over the whole error box with the margins kept; the leak is the largest such (the offset d returns
      to the pose loop soonest: an error of the stretch estimate, a mode 20 % off, leaves the least
      position error). Without a gain that reaches the target: the (gain, leak) with the most
      damping at the worst point;
    * the plain law (``soft`` False, no leak): the gain with the most damping at the worst point;
    * ``soft`` None: the decoupled law when it reaches the target, else the law with more damping
      at the worst point; the plain law for a mode shorter than 1 / MAX_SOFT_FDT ticks;
    * ``k_theta`` given: that gain, and the law and leak as above for it;
    * the low-pass of the planned chain acceleration (the deflection feed-forward and the planned
      stretch taken off the deflection): :func:`stretch_lowpass` of the mode.

    PmctlError when no gain keeps the margins (a mode the tick cannot see, near its Nyquist rate)."""
    if soft is None:
        laws, why = [], None
        for law in (True, False) if f * dt <= MAX_SOFT_FDT else (False,):
            try:
                laws.append(design_k_theta(f, zeta, kv, dt, k_theta, law, target, err, span, max_kdt))
            except PmctlError as e:
                why = e
            if laws and laws[0].reached:
                return laws[0]
        if not laws:
            raise why
        return max(laws, key=lambda d: d.worst_damping)
    w = 2 * math.pi * f
    if k_theta is None:
        gains = np.arange(1, int(round(max_kdt / KDT_STEP)) + 1) * KDT_STEP / dt
    else:
        gains = [float(k_theta)]
    leaks = [x * w for x in LEAK_STEPS] if soft else [None]
    cand = [(float(k), lk, _worst_damping(f, zeta, k, kv, dt, lk, err, span)) for k in gains for lk in leaks]

    def ok(k, lk):                              # the margins at every point of the box
        for r, zf in _box(err, span):
            A, B, C = loop_matrices(f * r, zeta * zf, k, kv, dt, lk)
            if np.max(np.abs(np.linalg.eigvals(A + MIN_GAIN_MARGIN * np.outer(B, C)))) >= 1.0:
                return False
            if _phase_margin(A, B, C, 512)[0] < MIN_PHASE_MARGIN_DEG:
                return False
        return True
    pick, reached = None, False
    for k, lk, wd in cand:                          # gains ascending, leaks descending
        if wd >= target and ok(k, lk):
            pick, reached = (k, lk, wd), True
            break
    if pick is None:
        for k, lk, wd in sorted(cand, key=lambda c: -c[2]):
            if wd > 0 and ok(k, lk):
                pick = (k, lk, wd)
                break
    if pick is None and k_theta is not None:        # a gain given by hand: its best leak, margins or not
        pick = max(cand, key=lambda c: c[2])
    if pick is None:
        raise PmctlError(f"no K_theta keeps a gain margin of {MIN_GAIN_MARGIN:g} and a phase margin of "
                         f"{MIN_PHASE_MARGIN_DEG:g} deg for a {f:g} Hz chain mode at kv {kv:g}/s and "
                         f"{1 / dt:g} Hz: set k_theta_per_s by hand, or 0")
    k, lk, wd = pick
    gm, pm = _margins_over_box(f, zeta, k, kv, dt, lk, err, span, n=2048)
    return KThetaDesign(k, None if lk is None else float(lk), stretch_lowpass(f, dt), float(wd),
                        loop_margins(f, zeta, k, kv, dt, lk), gm, pm, reached)
