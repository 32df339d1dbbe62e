"""Strain-gauge vibration suppression and the software V-F converter (seed 004 ch. 2-3, docs/machine.md §6).

Pure functions first, a thin CLI (``pmctl analyze vibration`` / ``pmctl analyze vf``) at the end.

**Eq. 3.1 closed loop.** The V-F input is u = K_G(θ0 − θ_m) − K_θ(θ_m − θ_L); the V-F converter is
linearised as a gain K_v (pulse/s per unit input) and the motor moves K_R rad per pulse, so
θ̇_m = K_v K_R u; the load is J θ̈_L = k(θ_m − θ_L). Eliminating θ_m:

    θ_L/θ0 = k K_G K_v K_R / (J s³ + J K_v K_R (K_G + K_θ) s² + k s + k K_G K_v K_R)    (3.1)

Hurwitz for the monic cubic s³ + a2 s² + a1 s + a0: all a_i > 0 and D2 = a2 a1 − a0 > 0; here
D2 = K_θ K_v K_R k/J (3.2). With K_θ = 0 the cubic factors exactly as (s + K_G K_v K_R)(s² + k/J):
the load mode is undamped and only strain feedback damps it.

**The paper's approximate factors (3.3).** The real root is large (a2 ≫ √(k/J)), so write
(s + p)(s² + q s + r) and match coefficients p + q = a2, p q + r = a1, p r = a0, neglecting q
beside p in the first: p = a2 = (K_G + K_θ) K_v K_R, then r = a0/p = (k/J)/(1 + K_θ/K_G) and
q = (a1 − r)/p = (k/J)(K_θ/K_G)/(1 + K_θ/K_G)² / (K_G K_v K_R). This is exactly eq. 3.3 and gives
(s + 216.4)(s² + 2·0.08·18.5 s + 18.5²) at 500 Hz and (s + 86.56)(… 0.20 …) at 200 Hz.

**Time simulation.** One sample per V-F tick at the seed's sample rate F: measure θ_m (pulse
counter × K_R) and the strain deflection θ_m − θ_L, form u, run :func:`pmctl.core.vf.vf_step` (the seed
accumulates the sampled values themselves: dt = 1 sample, threshold SD, one pulse per sample at
most), move the ideal stepping motor by K_R per pulse, then propagate the load exactly over one
sample (matrix exponential; θ_m is constant between pulses). The V-F's linear equivalent gain is
then K_v K_R = F K_R / SD: 15.7 rad/s at 500 Hz, 6.28 rad/s at 200 Hz — a factor 3 below the
2.5·6π and 6π the paper puts into eq. 3.3 (the seed does not say where the 3 comes from); the
simulation uses the seed's stated F, SD, K_R, K_G, K_θ literally and the analysis prints both.
"""

from __future__ import annotations

import math
import pathlib
from dataclasses import dataclass, field

import numpy as np
from scipy import signal
from scipy.linalg import expm
from scipy.signal import butter, sosfiltfilt

from pmctl import hal
from pmctl.core import kinematics as K, vf
from pmctl.core.config import load_machine
from pmctl.core.errors import PmctlError
from pmctl.core.shaper import corner_samples, path_error
from pmctl.motion import loop as L
from pmctl.motion.loop import ControlLoop, prepare
from pmctl.motion.nc import counts_of, initial_state
from pmctl.motion.service_config import (LoopConfig, load_service_config, nc_setup, parse_k_theta_flag,
                                         parse_shaper_flag)
from pmctl.motion.timescale import shape_trajectory
from pmctl.task.planner import home_pose, load_job, plan

# ---------------------------------------------------------------------------------------------
# Seed 004 chapter 3 parameters
# ---------------------------------------------------------------------------------------------

K_R_SEED = 0.0314            # rad per pulse (Fig. 3.2)
STEP_PULSES = 20             # 20-pulse step = 0.628 rad
K_G_SEED = 1.0 / 0.628       # so that the V-F input is 1 (= threshold) at the start of the step
K_THETA_SEED = 3.0
F_LOAD_SEED = 5.0            # Hz, spring-mass load
KVKR_PAPER = {500.0: 2.5 * 6.0 * math.pi, 200.0: 6.0 * math.pi}   # rad/s, as printed in 3.5


# ---------------------------------------------------------------------------------------------
# Eq. 3.1-3.3: characteristic polynomial, exact roots, the paper's approximate factors
# ---------------------------------------------------------------------------------------------

def eq31_char_poly(k_over_J, K_G, K_theta, KvKR):
    """Monic characteristic polynomial of eq. 3.1, [1, a2, a1, a0] (highest power first)."""
    return np.array([1.0, KvKR * (K_G + K_theta), k_over_J, k_over_J * K_G * KvKR], float)


@dataclass(frozen=True)
class CubicFactors:
    """(s + real_root_mag)(s² + 2 ζ ω_n s + ω_n²); ``roots`` holds all three roots when exact."""
    real_pole: float          # p in (s + p): the real root is −p
    wn: float                 # rad/s
    zeta: float
    roots: tuple = ()

    @property
    def wn_hz(self):
        return self.wn / (2.0 * math.pi)


def eq31_roots(k_over_J, K_G, K_theta, KvKR) -> CubicFactors:
    """Exact roots of eq. 3.1 (numpy.roots) as one real pole and a complex (or real) pair.

    The real pole reported is the one farthest from the origin when all three are real.
    """
    r = np.roots(eq31_char_poly(k_over_J, K_G, K_theta, KvKR))
    cplx = r[np.abs(r.imag) > 1e-9 * np.max(np.abs(r))]
    if len(cplx):
        real = r[np.abs(r.imag) <= 1e-9 * np.max(np.abs(r))].real
        c = cplx[0]
        wn = abs(c)
        zeta = -c.real / wn
        p = -real[0]
    else:   # three real roots: pair the two slowest into an (over-damped) quadratic
        rr = np.sort(r.real)               # most negative first
        p = -rr[0]
        a, b = rr[1], rr[2]
        wn = math.sqrt(a * b) if a * b > 0 else 0.0
        zeta = -(a + b) / (2 * wn) if wn > 0 else float("nan")
    return CubicFactors(float(p), float(wn), float(zeta), tuple(complex(x) for x in r))


def eq33_approx_factors(k_over_J, K_G, K_theta, KvKR) -> CubicFactors:
    """The paper's approximate factorisation (eq. 3.3): p = a2, r = a0/p, q = (a1 − r)/p."""
    _, a2, a1, a0 = eq31_char_poly(k_over_J, K_G, K_theta, KvKR)
    p = a2                                  # (1 + K_θ/K_G) K_G K_v K_R
    r = a0 / p                              # (k/J) / (1 + K_θ/K_G)
    q = (a1 - r) / p                        # (k/J)(K_θ/K_G)/(1+K_θ/K_G)² / (K_G K_v K_R)
    wn = math.sqrt(r)
    return CubicFactors(float(p), wn, float(q / (2.0 * wn)))


def hurwitz_D2(k_over_J, K_G, K_theta, KvKR):
    """Seed eq. 3.2: D2 = K_θ K_v K_R k/J (= a2 a1 − a0 of the monic cubic)."""
    return K_theta * KvKR * k_over_J


def hurwitz_stable(coeffs) -> bool:
    """Routh-Hurwitz for a cubic a3 s³ + a2 s² + a1 s + a0 (a3 > 0): all a_i > 0 and a2 a1 > a3 a0."""
    a3, a2, a1, a0 = (float(c) for c in coeffs)
    if a3 < 0:
        a3, a2, a1, a0 = -a3, -a2, -a1, -a0
    return a3 > 0 and a2 > 0 and a1 > 0 and a0 > 0 and a2 * a1 - a3 * a0 > 0


def seed_eq31_cases():
    """{sample rate Hz: (k/J, K_G, K_θ, K_v K_R)} with the paper's K_v K_R (section 3.5)."""
    kJ = (2.0 * math.pi * F_LOAD_SEED) ** 2
    return {F: (kJ, K_G_SEED, K_THETA_SEED, kvkr) for F, kvkr in KVKR_PAPER.items()}


# ---------------------------------------------------------------------------------------------
# Discrete-time simulation: V-F converter + pulse counter + stepping motor + flexible load
# ---------------------------------------------------------------------------------------------

@dataclass
class LoopSim:
    """Per-sample record of one simulated run (angles in rad, t in s)."""
    t: np.ndarray
    theta0: np.ndarray
    theta_m: np.ndarray        # motor = pulse counter × K_R, after this sample's pulses
    theta_L: np.ndarray        # load, at the sample instant (before this sample's pulses act)
    u: np.ndarray              # V-F input
    pulses: np.ndarray         # pulses emitted at each sample
    acc: np.ndarray            # V-F accumulator after each sample
    params: dict = field(default_factory=dict)


def load_transition(f_load_hz, dt, zeta_load=0.0):
    """Exact one-sample transition of the load state (x = θ_L − θ_m, ẋ) with θ_m held constant."""
    w = 2.0 * math.pi * f_load_hz
    A = np.array([[0.0, 1.0], [-w * w, -2.0 * zeta_load * w]])
    return expm(A * dt)


def simulate_vf_loop(theta0, F, *, K_G=K_G_SEED, K_theta=K_THETA_SEED, K_R=K_R_SEED,
                     threshold=1.0, f_load=F_LOAD_SEED, zeta_load=0.0, max_pulses_per_tick=1,
                     strain_noise=None) -> LoopSim:
    """Simulate the seed's Fig. 3.1 loop, one V-F sample per element of ``theta0`` (rate F Hz).

    u = K_G(θ0 − θ_m) − K_θ·d with d = θ_m − θ_L (+ strain_noise[i], in the same unit as d) the
    strain-gauge deflection. The load starts at rest at θ_L = θ_m = 0.
    """
    theta0 = np.asarray(theta0, float)
    n = len(theta0)
    Phi = load_transition(f_load, 1.0 / F, zeta_load)
    x = np.zeros(2)                     # θ_L − θ_m, θ̇_L
    count = 0
    acc = np.zeros(())
    out_m = np.empty(n); out_L = np.empty(n); out_u = np.empty(n); out_p = np.zeros(n, np.int64)
    out_acc = np.empty(n)
    noise = np.zeros(n) if strain_noise is None else np.asarray(strain_noise, float)
    for i in range(n):
        th_m = count * K_R
        th_L = th_m + x[0]
        d = th_m - th_L + noise[i]
        u = K_G * (theta0[i] - th_m) - K_theta * d
        p, acc = vf.vf_step(acc, u, 1.0, threshold, max_pulses_per_tick)
        p = int(p)
        count += p
        x[0] -= p * K_R                  # the motor steps; the load has not moved yet
        out_L[i] = th_L; out_u[i] = u; out_p[i] = p; out_m[i] = count * K_R; out_acc[i] = acc
        x = Phi @ x
    t = np.arange(n) / F
    return LoopSim(t, theta0, out_m, out_L, out_u, out_p, out_acc,
                   dict(F=F, K_G=K_G, K_theta=K_theta, K_R=K_R, threshold=threshold,
                        f_load=f_load, zeta_load=zeta_load))


def step_command(F, duration, n_pulses=STEP_PULSES, K_R=K_R_SEED):
    """θ0 per sample for the seed's step of n_pulses (Fig. 3.3); the command ends at t = 0."""
    return np.full(int(round(duration * F)), n_pulses * K_R), 0.0


def ramp_command(F, duration, rate_pps=F_LOAD_SEED, n_pulses=STEP_PULSES, K_R=K_R_SEED):
    """θ0 ramping at ``rate_pps`` pulses/s up to n_pulses, then held (Fig. 3.5: one pulse per load
    period puts the stepping rate on the load's resonance). Returns (θ0, time the ramp ends)."""
    t = np.arange(int(round(duration * F))) / F
    t_end = n_pulses / rate_pps
    return np.minimum(t * rate_pps, n_pulses) * K_R, t_end


@dataclass(frozen=True)
class ResponseMetrics:
    settling_time: float       # s after the command ends; inf if still outside the band at the end
    residual_pp: float         # peak-to-peak of θ_L − θ_final in the residual window, rad
    residual_rms: float        # RMS of θ_L − θ_final in the residual window, rad
    moving_rms_deflection: float   # RMS of θ_m − θ_L while the command moves (0-length: nan)
    final_offset_pulses: float  # (θ_m at end − θ_final)/K_R
    band: float


def response_metrics(sim: LoopSim, t_cmd_end, band=None, window_delay=1.0,
                     settle_guard=0.5) -> ResponseMetrics:
    """Residual vibration and settling of θ_L about the final command θ0[-1].

    Settling time: from the end of the command to the last sample with |θ_L − θ_final| > band
    (default one pulse K_R, which for the 20-pulse step is also the 5 % band); inf (not settled)
    when that last exit is within ``settle_guard`` s of the end of the run. Residual window:
    from ``window_delay`` s after the command ends to the end of the run.
    """
    K_R = sim.params["K_R"]
    band = K_R if band is None else band
    final = sim.theta0[-1]
    e = sim.theta_L - final
    out = np.nonzero(np.abs(e) > band)[0]
    if len(out) == 0:
        ts = 0.0
    elif sim.t[out[-1]] > sim.t[-1] - settle_guard:
        ts = math.inf
    else:
        ts = max(0.0, sim.t[out[-1] + 1] - t_cmd_end)
    w = sim.t >= t_cmd_end + window_delay
    if not w.any():
        raise ValueError("run too short for the residual window")
    mv = sim.t < t_cmd_end
    defl = sim.theta_m - sim.theta_L
    return ResponseMetrics(ts, float(np.ptp(e[w])), float(np.sqrt(np.mean(e[w] ** 2))),
                           float(np.sqrt(np.mean(defl[mv] ** 2))) if mv.any() else float("nan"),
                           float((sim.theta_m[-1] - final) / K_R), band)


def residual_amplitude_bound(F, f_load, K_theta, threshold=1.0):
    """Largest free load vibration the strain loop can leave behind (seed 3.4.2's design rule).

    At rest u = −K_θ·(θ_m − θ_L); a free oscillation of amplitude A at f_load feeds the V-F a sine
    of amplitude K_θ A, whose accumulator swings K_θ A/sin(π f_load/F) peak to peak over many
    cycles. Once that swing exceeds 2 SD a pulse must come whatever the residue in (−SD, SD), so the
    loop keeps acting until A ≤ 2 SD sin(π f_load/F)/K_θ (inf for K_θ = 0: nothing acts).
    """
    if K_theta <= 0:
        return math.inf
    return 2.0 * threshold * math.sin(math.pi * min(0.5, f_load / F)) / K_theta


def linear_step_response(t, k_over_J, K_G, K_theta, KvKR, amplitude):
    """θ_L(t) of the linear model eq. 3.1 for a step of ``amplitude`` (for overlay plots)."""
    num = [k_over_J * K_G * KvKR]
    sys = signal.lti(num, eq31_char_poly(k_over_J, K_G, K_theta, KvKR))
    _, y = signal.step(sys, T=t)
    return amplitude * y


# ---------------------------------------------------------------------------------------------
# V-F converter: minimum amplitude (eq. 2.2) and the three regions (Fig. 2.9), by simulation
# ---------------------------------------------------------------------------------------------

def sine_samples(f_over_F, n_samples, phase=0.0):
    """sin(2π (f/F)(i + phase)), i = 0..n−1: a sine starting at a zero crossing at t = 0, sampled
    ``phase`` samples late (phase in [0, 1)). Broadcasts f_over_F and phase against a new last axis."""
    i = np.arange(n_samples)
    r = np.asarray(f_over_F, float)[..., None]
    ph = np.asarray(phase, float)[..., None]
    return np.sin(2.0 * np.pi * r * (i + ph))


def run_vf(u, threshold=1.0, max_pulses_per_tick=1, acc0=0.0):
    """Run a bank of V-F converters over samples ``u[..., i]`` (seed: dt = 1 sample).

    Returns (pulses [..., n], acc [..., n]) — the accumulator after each sample.
    """
    u = np.asarray(u, float)
    acc = np.broadcast_to(np.asarray(acc0, float), u.shape[:-1]).copy()
    P = np.zeros(u.shape, np.int64)
    A = np.empty(u.shape)
    for i in range(u.shape[-1]):
        P[..., i], acc = vf.vf_step(acc, u[..., i], 1.0, threshold, max_pulses_per_tick)
        A[..., i] = acc
    return P, A


def vf_min_amplitude_sim(f_over_F, threshold=1.0, phase=0.0, n_periods=4, rel_tol=1e-7):
    """Smallest amplitude x for which x·sin(2π f t) (sampled as in :func:`sine_samples`, accumulator
    empty at t = 0) makes :func:`pmctl.core.vf.vf_step` emit any pulse within ``n_periods`` periods.

    Found by bisection on x to ``rel_tol``, every trial a full simulation of the bank with vf_step;
    vectorised over broadcast f_over_F and phase. inf where every sample is 0 (f/F = ½, phase 0).
    """
    r, ph = np.broadcast_arrays(np.asarray(f_over_F, float), np.asarray(phase, float))
    n = int(math.ceil(n_periods / float(np.min(r)))) + 1
    s = sine_samples(r, n, ph)
    peak = np.max(np.abs(s), axis=-1)
    dead = peak < 1e-12
    s = np.where(dead[..., None], 0.0, s)
    # Bracket: before its first pulse the accumulator is x·cumsum(s), so the answer is near
    # SD / max|cumsum(s)|. The bracket is verified by simulation (and widened if needed), then the
    # bisection below narrows it with full vf_step runs: a handful of runs instead of ~25.
    top = np.max(np.abs(np.cumsum(s, axis=-1)), axis=-1)
    guess = np.where(dead | (top <= 0), 1.0, threshold / np.where(top > 0, top, 1.0))
    hi = np.where(dead, 1.0, guess * (1 + 1e-6))
    lo = np.where(dead, 0.0, guess * (1 - 1e-6))
    P, _ = run_vf(lo[..., None] * s, threshold)
    lo = np.where(np.any(P != 0, axis=-1) & ~dead, 0.0, lo)     # lo fires after all: start from 0
    while True:                         # make sure hi fires (the largest sample alone may not)
        P, _ = run_vf(hi[..., None] * s, threshold)
        bad = ~np.any(P != 0, axis=-1) & ~dead
        if not bad.any():
            break
        lo = np.where(bad, hi, lo)
        hi = np.where(bad, 2 * hi, hi)
    while not np.all((hi - lo <= rel_tol * hi) | dead):
        mid = 0.5 * (lo + hi)
        P, _ = run_vf(mid[..., None] * s, threshold)
        fired = np.any(P != 0, axis=-1)
        hi = np.where(fired, mid, hi)
        lo = np.where(fired, lo, mid)
    return np.where(dead, np.inf, hi)


def vf_min_amplitude_exact(threshold, k, phase=0.0):
    """Closed form for integer k = F/(2f): the accumulator of x·sin(π(i + φ)/k), started empty,
    peaks at x·cos((φ − ½)π/k)/sin(π/2k), so pulses need x ≥ SD sin(π/2k)/cos((φ − ½)π/k).

    φ = ½ (samples straddling the zero crossing) gives the seed's SD sin(π/2k) (eq. 2.2, right
    side), the minimum over sampling phases; φ = 0 (the seed's sum from i = 1, eq. 2.1) gives the
    left side of eq. 2.2 at its best n = k − 1: SD tan(π/2k).
    """
    k = np.asarray(k, float)
    return threshold * np.sin(np.pi / (2 * k)) / np.cos((np.asarray(phase, float) - 0.5) * np.pi / k)


def equivalent_input(pulses, threshold=1.0):
    """The seed's "equivalent input signal generated by output pulses" (Fig. 2.4-2.8, solid line).

    Between consecutive pulses at samples n_{j−1} < n_j the equivalent level is
    sign_j · m_j · SD/(n_j − n_{j−1}) (m_j pulses at n_j): the constant input that accumulates exactly
    the emitted pulses over that interval. Samples before the first pulse and after the last are 0.
    Works on the last axis.
    """
    p = np.asarray(pulses)
    out = np.zeros(p.shape, float)
    flat_p = p.reshape(-1, p.shape[-1])
    flat_o = out.reshape(-1, p.shape[-1])
    for row, o in zip(flat_p, flat_o):
        idx = np.nonzero(row)[0]
        if len(idx) < 2:
            continue
        widths = np.diff(idx)
        lev = row[idx[1:]] * threshold / widths
        # samples idx[j-1]+1 .. idx[j] carry level j
        o[idx[0] + 1: idx[-1] + 1] = np.repeat(lev, widths)
    return out


REGION_CORRECT, REGION_NOISY, REGION_NONE, REGION_SATURATED = 0, 1, 2, 3
REGION_NAMES = {REGION_CORRECT: "I correct", REGION_NOISY: "II noisy",
                REGION_NONE: "III no output", REGION_SATURATED: "saturated"}


def vf_conversion_error(level, f_over_F, threshold=1.0, n_periods=6, phase=0.0,
                        max_pulses_per_tick=1):
    """Simulate x·sin(2π f t) through vf_step for every (level, f/F) pair (broadcast).

    Returns (error, n_pulses, saturated):
    - error: |E1 − X1|/|X1|, the complex relative error (amplitude and phase) of the fundamental
      E1 of the seed's equivalent input (:func:`equivalent_input`) against the input's X1, both
      taken as the DFT at f over the whole periods after the first (the first period is the
      converter's start-up) — the seed's Fourier evaluation of Fig. 2.4(b)-2.8(b); 1 if no pulse;
    - n_pulses: total |pulses|;
    - saturated: the converter clipped (pulses·SD + final residue ≠ integral of the input).
    """
    level, r = np.broadcast_arrays(np.asarray(level, float), np.asarray(f_over_F, float))
    n = int(math.ceil((n_periods + 1) / float(np.min(r)))) + 1
    u = level[..., None] * sine_samples(r, n, phase)
    P, A = run_vf(u, threshold, max_pulses_per_tick)
    integral = u.sum(-1)
    saturated = np.abs(P.sum(-1) * threshold + A[..., -1] - integral) > 1e-9 * (1 + np.abs(u).sum(-1))
    eq = equivalent_input(P, threshold)
    i = np.arange(n)
    r0 = float(r.reshape(-1)[0]) if r.size else 0.0
    if r.size and np.all(r == r0):
        # one f/F for the whole bank (the region map's columns): one DFT kernel, a matrix product
        per = 1.0 / r0
        w = (i >= per) & (i < np.floor((n - 1) / per) * per)
        ph = np.exp(-2j * np.pi * r0 * i) * w
        E1 = eq @ ph
        X1 = u @ ph
    else:
        per = 1.0 / r[..., None]
        n_whole = np.floor((n - 1) / per)
        w = (i >= per) & (i < n_whole * per)          # periods 2 .. last whole one
        ph = np.exp(-2j * np.pi * r[..., None] * i) * w
        E1 = (eq * ph).sum(-1)
        X1 = (u * ph).sum(-1)
    err = np.abs(E1 - X1) / np.maximum(np.abs(X1), 1e-300)
    return err, np.abs(P).sum(-1), saturated


def vf_region_map(levels, ratios, threshold=1.0, correct_tol=0.25, n_phases=4, **kw):
    """Fig. 2.9 by simulation: region code per (level, f/F) on the grid levels × ratios.

    Definitions (following seed 004 2.3.3-2.3.4; levels relative to the threshold SD; every cell is
    simulated with vf_step for ``n_phases`` sampling phases φ = 0, 1/n, ...):
    - III, no output: no pulse at all in any of the runs (the accumulator never reaches ±SD);
    - saturated: the converter clipped at one pulse per sample in some run (level above SD; the
      seed's "above level 1 the conversion saturates");
    - I, correct: pulses, not saturated, and the fundamental of the seed's equivalent input
      (:func:`equivalent_input`) matches the input's within ``correct_tol`` (complex relative error
      of :func:`vf_conversion_error`, averaged over the phases) in steady state;
    - II, noisy: pulses, not saturated, larger error.
    With 0.25 the seed's 4 Hz / 500 Hz example (2.3.4: "good from level 1 down to about 0.2, large
    errors from 0.2 to 0.02, nothing below 0.02") gets I from level ≈ 0.13 and III below 0.025, and
    its 50 Hz / 500 Hz example ("large distortion") is II at every level up to 1.
    Returns (codes [len(levels), len(ratios)], mean error array).
    """
    levels = np.asarray(levels, float)
    ratios = np.asarray(ratios, float)
    err = np.zeros((len(levels), len(ratios)))
    fired = np.zeros(err.shape, bool)
    sat = np.zeros(err.shape, bool)
    phases = np.arange(n_phases) / n_phases
    # one f/F at a time, all levels and phases together: each column simulates just the periods it
    # needs (a high f/F needs few samples), so time and memory follow the grid, not its lowest f/F
    for j, r in enumerate(ratios):
        e, npulse, s = vf_conversion_error(levels[:, None] * threshold, np.full((1, n_phases), r),
                                           threshold, phase=phases[None, :], **kw)
        err[:, j] = e.mean(axis=1)
        fired[:, j] = (npulse > 0).any(axis=1)
        sat[:, j] = s.any(axis=1)
    codes = np.where(~fired, REGION_NONE,
                     np.where(sat, REGION_SATURATED,
                              np.where(err <= correct_tol, REGION_CORRECT, REGION_NOISY)))
    return codes, err


def vf_noise_pulses(noise, gain=1.0, threshold=1.0, max_pulses_per_tick=1):
    """Pulses a V-F converter (empty accumulator) emits for the input gain·noise[..., i].

    Returns total |pulses| per row. Used for seed 004 3.6: strain noise through K_θ."""
    P, _ = run_vf(gain * np.asarray(noise, float), threshold, max_pulses_per_tick)
    return np.abs(P).sum(-1)


def seed36_noise_check(F=200.0, threshold=10.0, K_theta=25.0, amplitude=0.03,
                       freqs=None, n_phases=8, duration=10.0, seed=0):
    """Seed 004 3.6: strain noise ≤ 0.03 V above 100 Hz, sampled at 200 Hz, through K_θ = 25 into a
    V-F with threshold 10 V, should produce no pulses.

    Sine noise at each frequency (n_phases sampling phases each) and a random multi-sine noise
    (200 components in 100-195 Hz, random phases, scaled to peak ``amplitude``) are run for
    ``duration`` s. Returns dict(freqs, pulses_per_freq (max over phases), random_pulses,
    alias_limit_hz): frequencies whose alias |f − mF| is below alias_limit_hz = F/π·asin(K_θ x/SD)
    can reach the threshold (the alias is then a near-DC input the accumulator integrates).
    """
    freqs = np.arange(100.0, 300.0 + 1e-9, 0.5) if freqs is None else np.asarray(freqs, float)
    n = int(round(duration * F))
    t = np.arange(n) / F
    pulses = np.zeros(len(freqs), np.int64)
    for ph in np.arange(n_phases) / n_phases:       # one phase at a time: memory of one bank
        x = amplitude * np.sin(2 * np.pi * (freqs[:, None] * t + ph))
        pulses = np.maximum(pulses, vf_noise_pulses(x, K_theta, threshold))
    rng = np.random.default_rng(seed)
    fr = rng.uniform(100.0, 195.0, 200)
    noise = np.sin(2 * np.pi * (fr[:, None] * t + rng.uniform(0, 1, 200)[:, None])).sum(0)
    noise *= amplitude / np.max(np.abs(noise))
    rnd = int(vf_noise_pulses(noise, K_theta, threshold))
    lim = F / math.pi * math.asin(min(1.0, K_theta * amplitude / threshold))
    return dict(freqs=freqs, pulses_per_freq=pulses, random_pulses=rnd, alias_limit_hz=lim,
                vf_input_amplitude=K_theta * amplitude)


# ---------------------------------------------------------------------------------------------
# CLI: pmctl analyze vibration | vf
# ---------------------------------------------------------------------------------------------

STEP_CASES = [  # (label, F, K_θ, f_load) — seed Fig. 3.3 (a)-(d), plus K_θ=0 references for (c), (d)
    ("(a) K_θ=0, 500 Hz, 5 Hz load", 500.0, 0.0, 5.0),
    ("(b) K_θ=3, 500 Hz, 5 Hz load", 500.0, 3.0, 5.0),
    ("(c0) K_θ=0, 200 Hz, 5 Hz load", 200.0, 0.0, 5.0),
    ("(c) K_θ=3, 200 Hz, 5 Hz load", 200.0, 3.0, 5.0),
    ("(d0) K_θ=0, 500 Hz, 50 Hz load", 500.0, 0.0, 50.0),
    ("(d) K_θ=3, 500 Hz, 50 Hz load", 500.0, 3.0, 50.0),
]
RAMP_CASES = [  # seed Fig. 3.5 (a), (b)
    ("(a) K_θ=0, 500 Hz, ramp 5 pulse/s", 500.0, 0.0, 5.0),
    ("(b) K_θ=3, 500 Hz, ramp 5 pulse/s", 500.0, 3.0, 5.0),
]


def run_step_cases(duration=3.0, window_delay=1.0):
    out = []
    for label, F, Kt, fl in STEP_CASES:
        th, te = step_command(F, duration)
        sim = simulate_vf_loop(th, F, K_theta=Kt, f_load=fl)
        out.append((label, sim, response_metrics(sim, te, window_delay=window_delay)))
    return out


def run_ramp_cases(duration=7.0, window_delay=1.0):
    out = []
    for label, F, Kt, fl in RAMP_CASES:
        th, te = ramp_command(F, duration)
        sim = simulate_vf_loop(th, F, K_theta=Kt, f_load=fl)
        out.append((label, sim, response_metrics(sim, te, window_delay=window_delay), te))
    return out


# ---------------------------------------------------------------------------------------------
# Chain vibration of a run, band-passed around the chain mode (docs/vibration.md §5)
# ---------------------------------------------------------------------------------------------

BAND = (0.5, 2.0)    # the band around the chain mode: 20-80 Hz at 40 Hz


def band_pass(x, dt: float, mode_hz: float, band=BAND):
    """``x`` (along axis 0) through a zero-phase 2nd-order Butterworth band-pass over band x mode_hz:
    the quasi-static stretch m a / k of a planned acceleration lies below it, the pulses' steps
    above it."""
    sos = butter(2, [band[0] * mode_hz, band[1] * mode_hz], "bandpass", fs=1.0 / dt, output="sos")
    return sosfiltfilt(sos, np.asarray(x, float), axis=0)


def chain_vibration_um(load, motor, dt: float, mode_hz: float, band=BAND) -> float:
    """RMS over the ticks and chains (µm) of the chain deflection, load side against motor side
    ((N, C) chain positions, mm), band-passed around the mode."""
    y = band_pass(np.asarray(load, float) - np.asarray(motor, float), dt, mode_hz, band)
    return 1e3 * float(np.sqrt(np.mean(y ** 2)))


def path_error_vectors(points, path, along=None, window: int = 64):
    """From the closest point of the polyline through ``path`` (N, 3) to each of ``points`` (M, 3),
    which follow the path in order (a tool tip near a target moving along it): the vectors (M, 3), mm.
    Each point is searched over the ``window`` segments either side of where the running arc length
    of ``along`` (M, 3: the targets on the path the points follow; default the points) falls on the
    path's."""
    P = np.asarray(points, float)
    Q = np.asarray(path, float)
    if len(Q) < 2:
        return P - Q[:1]
    G = P if along is None else np.asarray(along, float)
    s_path = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(Q, axis=0), axis=1))]
    s_pts = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(G, axis=0), axis=1))]
    k0 = np.clip(np.searchsorted(s_path, s_pts) - 1, 0, len(Q) - 2)
    out = np.empty_like(P)
    best = np.full(len(P), np.inf)
    for off in range(-window, window + 1):
        k = np.clip(k0 + off, 0, len(Q) - 2)
        a, d = Q[k], Q[k + 1] - Q[k]
        L2 = np.einsum("ij,ij->i", d, d)
        u = np.clip(np.einsum("ij,ij->i", P - a, d) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
        v = P - (a + u[:, None] * d)
        r = np.einsum("ij,ij->i", v, v)
        upd = r < best
        best[upd] = r[upd]
        out[upd] = v[upd]
    return out


def tip_band_error_um(tip, path, dt: float, mode_hz: float, along=None, band=BAND, window: int = 64) -> float:
    """RMS (µm) of the tool tip's error from the path (:func:`path_error_vectors`), band-passed
    around the mode: the vibration the part sees, without the stretch's slow lag."""
    e = band_pass(path_error_vectors(tip, path, along, window), dt, mode_hz, band)
    return 1e3 * float(np.sqrt(np.mean(np.sum(e ** 2, -1))))


def run_on_sim(service, job: str, *, k_theta=None, shaper=None, mode_hz=None, modal_stiffness=None,
               start_tip=None, tip_metric: bool = True, implementation: str | None = None) -> dict:
    """One job as ``pmctl run --service SERVICE --job JOB [--k-theta K] [--shaper S] --no-realtime
    --state ''`` runs it against the sim backend (the same calls: the service config, nc_setup, the
    NC parameters, the planner, the shaping stage, the loop), in this process, so the sim's load-side
    truth is at hand; returns the figures of docs/vibration.md §5: ``chain_um``
    (:func:`chain_vibration_um` around the plant's mode), ``tip_um`` (:func:`tip_band_error_um`),
    ``p99_um`` (the load-side tip's distance from the programmed path), ``job_s``, the K_theta per
    chain and the shaper's note. ``k_theta`` / ``shaper``: the flags (None: the service file's);
    ``mode_hz`` (+ ``modal_stiffness``): [nc] mode_hz as if measured; ``start_tip``: the tool stands
    there, vertical, when the job starts (default: the home pose)."""
    m = load_machine("prototype")
    svc = load_service_config(service)
    cfg = svc.loop
    cfg.realtime, cfg.settle_s, cfg.state_file = False, 0.0, ""
    if k_theta is not None:
        k = parse_k_theta_flag(k_theta)
        svc.nc.k_theta_auto = k == "auto"
        svc.nc.k_theta_per_s = (0.0,) * 3 if k == "auto" else (float(k),) * 3
    if shaper is not None:
        svc.nc.shaper = parse_shaper_flag(shaper)
    if mode_hz is not None:
        svc.nc.mode_hz = (float(mode_hz),) * 3
        if modal_stiffness is not None:
            svc.nc.modal_stiffness_N_per_mm = (float(modal_stiffness),) * 3
    if implementation:
        svc.nc.implementation = implementation
    dt = cfg.dt
    setup = nc_setup(svc, m, dt, "sim")
    params = svc.nc.params(m, dt, where=svc.source, modes=setup.modes)
    h_tip, h_axis = home_pose(m)
    if start_tip is not None:
        h_tip = np.asarray(start_tip, float)
    c0 = counts_of(K.ik(h_tip, h_axis, m).q, params)
    st = initial_state(m, c0)
    planned = plan(load_job(job, m, start=(st.tip, st.axis)), m, dt, start=(st.tip, st.axis))
    traj = shape_trajectory(planned, setup.shaper)
    tg = prepare(m, params, traj, dt, c0)
    be = hal.create("sim", m, dt, svc.backend_tables.get("sim", {}))
    be.open(c0)
    try:
        res = ControlLoop(m, be, params, tg, cfg, st, log=lambda s: None).run()
    finally:
        be.close()
    i0 = res.job_start
    f0 = float(np.mean(be.omega)) / (2 * math.pi)          # the plant's mode: the band's centre
    pl, _ = K.fk_batch(res.truth[i0:], m)
    keep = sorted(set([0] + corner_samples(planned.tip, planned.axis, corner_deg=1e-3) + [len(planned) - 1]))
    e = path_error(pl.tip, planned.tip[keep])               # the same polyline, straight runs merged
    shtxt = [t for t in setup.notes if t.startswith("shaper")]
    return dict(status=res.status, reason=res.reason,
                chain_um=chain_vibration_um(res.truth[i0:, :3], res.enc[i0:, :3], dt, f0),
                tip_um=(tip_band_error_um(pl.tip, planned.tip, dt, f0, along=res.target[i0:, :3])
                        if tip_metric else float("nan")),
                p99_um=1e3 * float(np.percentile(e, 99)), job_s=(res.ticks - i0) * dt,
                kth=params.k_theta.tolist(), shaper=shtxt[0].split(" at ")[0] if shtxt else "shaper: none",
                notes=list(setup.notes))


def _plt():
    import matplotlib  # lazy: matplotlib (heavy) loads only when a figure is drawn
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: matplotlib (heavy) loads only when a figure is drawn
    return plt


def _fmt_ts(ts):
    """A settling time for a table cell: '0.123 s', or 'never' (still outside the band at the end)."""
    return "never" if math.isinf(ts) else f"{ts:.3f} s"


def _settles(ts):
    """A settling time in a sentence."""
    return "does not settle within the run" if math.isinf(ts) else f"settles in {ts:.3f} s"


def _outdir(path):
    d = pathlib.Path(path)
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise PmctlError(f"cannot create output directory {d}: {e.strerror}") from None
    return d


def _print_eq31():
    print("Eq. 3.1 closed loop (Kamiya et al. 2005, sec. 3.5): k/J = (2π·5)², K_G = 1/0.628, K_θ = 3")
    print(f"  {'F':>6} {'K_vK_R':>8}  {'exact: real root':>16} {'ω_n':>7} {'ζ':>6}   "
          f"{'eq.3.3 approx: (s+p)':>20} {'ω_n':>6} {'ζ':>5}   {'D2=K_θK_vK_R k/J':>16}  Hurwitz")
    rows = []
    for F, case in seed_eq31_cases().items():
        ex = eq31_roots(*case)
        ap = eq33_approx_factors(*case)
        d2 = hurwitz_D2(*case)
        stab = hurwitz_stable(eq31_char_poly(*case))
        print(f"  {F:4.0f}Hz {case[3]:8.3f}  {-ex.real_pole:16.1f} {ex.wn:7.2f} {ex.zeta:6.3f}   "
              f"{ap.real_pole:20.2f} {ap.wn:6.1f} {ap.zeta:5.2f}   {d2:16.0f}  {'stable' if stab else 'UNSTABLE'}")
        rows.append((F, ex, ap))
    print("  paper (3.4)/(3.5): (s+216.4)(s²+2·0.08·18.5s+18.5²), (s+86.56)(…0.20…18.5…)")
    print("  Literal V-F gain of the simulation, K_vK_R = F·K_R/SD (SD = 1, K_R = 0.0314 rad/pulse):")
    kJ = (2 * math.pi * F_LOAD_SEED) ** 2
    for F in (500.0, 200.0):
        kvkr = F * K_R_SEED
        ex = eq31_roots(kJ, K_G_SEED, K_THETA_SEED, kvkr)
        print(f"  {F:4.0f}Hz {kvkr:8.3f}  {-ex.real_pole:16.1f} {ex.wn:7.2f} {ex.zeta:6.3f}   "
              f"(paper's K_vK_R is {KVKR_PAPER[F] / kvkr:.2f}× this)")
    return rows


def cmd_vibration(args):
    d = _outdir(args.out)
    _print_eq31()
    steps = run_step_cases()
    ramps = run_ramp_cases()
    kJ = lambda fl: (2 * math.pi * fl) ** 2
    print("\nStep responses (20 pulses = 0.628 rad; V-F threshold 1, one pulse per sample; undamped load)")
    print("  settling: last exit from ±1 pulse (= ±5 %) of the command; residual: θ_L − θ0 over "
          "t ≥ 1 s after the command ends, to the end of the run (3 s)")
    print("  dead-region bound on the residual p-p: 2·(2 SD sin(π f_load/F)/K_θ) (residual_amplitude_bound)")
    print(f"  {'case':34} {'settling time':>13} {'resid p-p':>10} {'resid RMS':>10} {'p-p bound':>10} "
          f"{'pulses':>6} {'end offset':>10}")
    for (label, sim, m), (_, F, Kt, fl) in zip(steps, STEP_CASES):
        bound = 2 * residual_amplitude_bound(F, fl, Kt)
        print(f"  {label:34} {_fmt_ts(m.settling_time):>13} {m.residual_pp:10.4f} {m.residual_rms:10.4f} "
              f"{bound:10.4f} {int(np.abs(sim.pulses).sum()):6d} {m.final_offset_pulses:+8.0f} p")
    for (la, _, a), (lb, _, b) in zip(steps[0::2], steps[1::2]):
        print(f"  {la.split(',', 1)[1].strip()}: K_θ=0 → K_θ=3 residual p-p {a.residual_pp / b.residual_pp:.1f}× "
              f"smaller, RMS {a.residual_rms / b.residual_rms:.1f}× smaller, settling time "
              f"{_fmt_ts(a.settling_time)} → {_fmt_ts(b.settling_time)}")
    print("\nRamp responses (5 pulse/s = one pulse per load period, 20 pulses, then hold)")
    print(f"  {'case':34} {'RMS defl. moving':>16} {'settling time':>13} {'resid p-p':>10} {'resid RMS':>10}")
    for label, sim, m, te in ramps:
        print(f"  {label:34} {m.moving_rms_deflection:16.4f} {_fmt_ts(m.settling_time):>13} "
              f"{m.residual_pp:10.4f} {m.residual_rms:10.4f}")
    a, b = ramps[0][2], ramps[1][2]
    print(f"  K_θ=3 vs K_θ=0: deflection while moving {a.moving_rms_deflection / b.moving_rms_deflection:.1f}× "
          f"smaller, residual p-p {a.residual_pp / b.residual_pp:.1f}× smaller")

    plt = _plt()
    fig, axs = plt.subplots(3, 2, figsize=(11, 10), sharey=True)
    for ax, (label, sim, m), (_, F, Kt, fl) in zip(axs.flat, steps, STEP_CASES):
        ax.plot(sim.t, sim.theta0, "k:", lw=1, label="θ0 command")
        ax.step(sim.t, sim.theta_m, where="post", lw=1, label="θ_m motor (pulse counter)")
        ax.plot(sim.t, sim.theta_L, lw=1.3, label="θ_L load")
        lin = linear_step_response(sim.t, kJ(fl), K_G_SEED, Kt, F * K_R_SEED, sim.theta0[-1])
        ax.plot(sim.t, lin, "--", lw=0.8, color="gray", label="linear eq. 3.1, K_vK_R=F·K_R")
        ax.set_title(f"{label}\n{_settles(m.settling_time)}, residual p-p {m.residual_pp:.3f} rad",
                     fontsize=9)
        ax.set_xlim(0, 2.0)
        ax.grid(alpha=0.3)
    for ax in axs[-1]:
        ax.set_xlabel("t [s]")
    for ax in axs[:, 0]:
        ax.set_ylabel("angle [rad]")
    axs[0, 0].legend(fontsize=7, loc="lower right")
    fig.suptitle("Kamiya et al. 2005, Fig. 3.3: 20-pulse step, simulated with the software V-F converter", fontsize=10)
    fig.tight_layout()
    p1 = d / "vibration_step.png"
    fig.savefig(p1, dpi=110)
    plt.close(fig)

    fig, axs = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True, sharey=True)
    for ax, (label, sim, m, te) in zip(axs, ramps):
        ax.plot(sim.t, sim.theta0, "k:", lw=1, label="θ0 command")
        ax.step(sim.t, sim.theta_m, where="post", lw=1, label="θ_m motor")
        ax.plot(sim.t, sim.theta_L, lw=1.2, label="θ_L load")
        ax.plot(sim.t, 5 * (sim.theta_m - sim.theta_L), lw=0.8, label="5 × (θ_m − θ_L) strain")
        ax.axvline(te, color="gray", lw=0.6)
        ax.set_title(f"{label}: RMS deflection while moving {m.moving_rms_deflection:.4f} rad, "
                     f"residual p-p {m.residual_pp:.3f} rad", fontsize=9)
        ax.set_ylabel("angle [rad]")
        ax.grid(alpha=0.3)
    axs[-1].set_xlabel("t [s]")
    axs[0].legend(fontsize=7, loc="upper left")
    fig.suptitle("Kamiya et al. 2005, Fig. 3.5: ramp at the load's resonance, simulated", fontsize=10)
    fig.tight_layout()
    p2 = d / "vibration_ramp.png"
    fig.savefig(p2, dpi=110)
    plt.close(fig)
    print(f"\nwrote {p1}\nwrote {p2}")
    return 0


def cmd_vf(args):
    d = _outdir(args.out)
    SD = 1.0
    print("V-F minimum amplitude (Kamiya et al. 2005, eq. 2.2), by simulation with vf_step (bisection to 1e-7):")
    print("  sine starting at a zero crossing, accumulator empty, sampled φ samples late")
    print(f"  {'k':>4} {'f/F':>7} {'sim φ=½':>10} {'SD sin(π/2k)':>12} {'sim φ=0':>10} {'SD tan(π/2k)':>12} "
          f"{'sim min φ':>10}")
    ks = np.array([1, 2, 3, 5, 10, 25, 50, 125])
    phases = np.linspace(0, 1, 16, endpoint=False)
    sim_half = vf_min_amplitude_sim(1 / (2 * ks), SD, 0.5)
    sim_zero = vf_min_amplitude_sim(1 / (2 * ks), SD, 0.0)
    sim_ph = vf_min_amplitude_sim((1 / (2 * ks))[:, None], SD, phases[None, :]).min(axis=1)
    for k, a, b, c in zip(ks, sim_half, sim_zero, sim_ph):
        print(f"  {k:4d} {1 / (2 * k):7.4f} {a:10.6f} {vf.vf_min_amplitude(SD, 1 / (2 * k)):12.6f} "
              f"{b:10.6f} {(SD * math.tan(math.pi / (2 * k)) if k > 1 else math.inf):12.6f} {c:10.6f}")
    # seed checks: 50 Hz at 500 Hz, 4 Hz at 500 Hz, level 1 cut-off near f/F = 0.3
    print("  report sec. 2.3.4: 50 Hz @ 500 Hz, SD 1 → no output below "
          f"{vf_min_amplitude_sim(0.1, SD, 0.0):.3f} (report: ≈0.2 and below gives none); "
          f"4 Hz → {vf_min_amplitude_sim(0.008, SD, 0.0):.4f} (report: ≈0.02)")
    R = np.linspace(0.2, 0.35, 151)
    fires = vf_min_amplitude_sim(R, SD, 0.0, n_periods=40) <= 1.0
    print(f"  report sec. 2.3.3: level 1 stops producing pulses above f/F = {R[fires][-1]:.3f} "
          f"(report: 150 Hz @ 500 Hz and 300 Hz @ 1000 Hz, f/F = 0.3)")

    levels = 10.0 ** np.round(np.linspace(-3.0, 0.3, 67), 6)     # 0.05-decade steps, 1.0 exact
    ratios = np.logspace(np.log10(0.002), np.log10(0.5), 56)
    codes, err = vf_region_map(levels, ratios, SD)
    print("\nThree regions (Fig. 2.9), SD = 1, 4 sampling phases, 6 periods after a 1-period start-up:")
    for lev in (1.0, 0.5, 0.2, 0.05, 0.02):
        i = int(np.argmin(np.abs(levels - lev)))
        row = codes[i]
        first = lambda code: next((ratios[j] for j in range(len(ratios)) if row[j] == code), None)
        notI = next((ratios[j] for j in range(len(ratios)) if row[j] != REGION_CORRECT), None)
        parts = [f"I for f/F ≤ {ratios[max(0, np.searchsorted(ratios, notI) - 1)]:.3g}"
                 if row[0] == REGION_CORRECT else "not I at the lowest f/F"]
        if first(REGION_NOISY) is not None:
            parts.append(f"II from {first(REGION_NOISY):.3g}")
        if first(REGION_NONE) is not None:
            parts.append(f"III from {first(REGION_NONE):.3g} (eq. 2.2: {np.arcsin(min(1, levels[i])) / np.pi:.3g})")
        print(f"  level {levels[i]:.3g}: " + ", ".join(parts) + f"; {int(np.sum(np.diff(row) != 0))} changes along f/F")

    chk = seed36_noise_check()
    bad = chk["freqs"][chk["pulses_per_freq"] > 0]
    print("\nReport sec. 3.6 noise claim: 0.03 V strain noise × K_θ 25 = "
          f"{chk['vf_input_amplitude']:.2f} V into SD 10 V at 200 Hz, 10 s runs, 8 sampling phases:")
    print(f"  sine noise 100-300 Hz (0.5 Hz steps): pulses at {len(bad)} of {len(chk['freqs'])} frequencies"
          + (f", all within {np.max(np.abs(bad - 200.0)):.1f} Hz of 200 Hz (alias near DC; bound "
             f"F/π·asin(K_θx/SD) = {chk['alias_limit_hz']:.2f} Hz)" if len(bad) else ""))
    print(f"  random multi-sine noise 100-195 Hz, peak 0.03 V: {chk['random_pulses']} pulses")

    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.5, 5))
    Rf = np.logspace(np.log10(0.002), np.log10(0.5), 80)
    ks_c = np.unique(np.round(1 / (2 * Rf)).astype(int))
    Rk = 1 / (2 * ks_c)
    ax.loglog(Rf, vf.vf_min_amplitude(SD, Rf), "k-", lw=1, label="eq. 2.2: SD·sin(π/2k)")
    ax.loglog(Rk[ks_c > 1], SD * np.tan(np.pi / (2 * ks_c[ks_c > 1])), "k--", lw=1,
              label="eq. 2.2 exact form, best n: SD·tan(π/2k)")
    ax.loglog(Rk, vf_min_amplitude_sim(Rk, SD, 0.5), "o", ms=4, mfc="none", label="simulated, φ = ½")
    z = vf_min_amplitude_sim(Rk, SD, 0.0)
    ax.loglog(Rk[np.isfinite(z)], z[np.isfinite(z)], "x", ms=4, label="simulated, φ = 0")
    ax.set_xlabel("f/F = 1/(2k)")
    ax.set_ylabel("smallest amplitude that gives a pulse (× SD)")
    ax.set_title("V-F minimum amplitude: eq. 2.2 vs simulation with vf_step", fontsize=10)
    ax.grid(which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    p1 = d / "vf_min_amplitude.png"
    fig.savefig(p1, dpi=110)
    plt.close(fig)

    from matplotlib.colors import ListedColormap  # lazy: matplotlib (heavy) loads only when a figure is drawn
    fig, ax = plt.subplots(figsize=(7.5, 5.5))
    cmap = ListedColormap(["#8fd18f", "#f2d16b", "#d9d9d9", "#e88d8d"])
    ax.pcolormesh(ratios, levels, codes, cmap=cmap, vmin=-0.5, vmax=3.5, shading="nearest")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.plot(Rf, vf.vf_min_amplitude(SD, Rf), "k-", lw=1, label="eq. 2.2 SD·sin(π f/F)")
    import matplotlib.patches as mpatches  # lazy: matplotlib (heavy) loads only when a figure is drawn
    handles = [mpatches.Patch(color=cmap(i), label=REGION_NAMES[i]) for i in range(4)]
    handles.append(ax.get_lines()[0])
    ax.legend(handles=handles, fontsize=8, loc="lower right")
    ax.set_xlabel("R = f/F (input frequency / sampling frequency)")
    ax.set_ylabel("input level (× threshold SD)")
    ax.set_title("Kamiya et al. 2005, Fig. 2.9 by simulation: I correct (fundamental of the\n"
                 "equivalent input within 25 %), II noisy, III no output", fontsize=10)
    fig.tight_layout()
    p2 = d / "vf_regions.png"
    fig.savefig(p2, dpi=110)
    plt.close(fig)
    print(f"\nwrote {p1}\nwrote {p2}")
    return 0


def ringdown_on_sim(machine, params, k_N_per_mm: float, mass_kg: float, zeta: float, y0_mm: float,
                    duration_s: float, tip=None, axis=None, sim: dict | None = None):
    """The real loop (NC ``params``, ControlLoop, the sim with its flexible chain mode and gauges, the
    V-F converters) holding the pose (tip, axis) -- default 100 mm below home -- while the three
    chains start from a deflection ``y0_mm``: (the load-side deflection y of chain 1, mm, one sample
    a tick; the loop's result). The plant: modal stiffness ``k_N_per_mm`` and mass ``mass_kg`` per
    chain, damping ratio ``zeta``; ``sim``: more [hal.sim] options (e.g. strain_noise_ue)."""
    if tip is None:
        tip, axis = home_pose(machine)
        tip = np.asarray(tip, float) + [0.0, 0.0, -100.0]
    c0 = counts_of(K.ik(tip, axis, machine).q, params)
    st = initial_state(machine, c0)
    dt = params.dt
    n = int(duration_s / dt)
    tg = L.build_targets(np.repeat(st.tip[None], n, 0), np.repeat(st.axis[None], n, 0), np.zeros(n, int), dt,
                         machine, params)
    be = hal.create("sim", machine, dt, dict(flex=True, mode_stiffness_N_per_mm=[k_N_per_mm] * 3,
                                             mode_mass_kg=[mass_kg] * 3, mode_damping_ratio=[zeta] * 3, **(sim or {})))
    be.open(c0)
    Ly = be._lib.D_Y                                   # the plant's deflection state (simplant.c)
    be._d[Ly:Ly + 3] = y0_mm
    be._check(be._plant.sample(be._draw(), 0))         # the gauges read the initial deflection
    ys = []
    wp = be.write_pulses

    def write(pl):
        wp(pl)
        ys.append(be._d[Ly])
    be.write_pulses = write
    try:
        res = L.ControlLoop(machine, be, params, tg, LoopConfig(realtime=False, state_file="", settle_s=0.0,
                                                                stall_timeout_s=60.0), st, log=lambda s: None).run()
    finally:
        be.close()
    return np.array(ys), res
