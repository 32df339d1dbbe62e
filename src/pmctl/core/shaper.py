"""Input shapers as pure math: impulse trains that cancel a mode's residual vibration, their analytic
residual-vibration curves, and two ways to apply them to a sampled tool path.

A shaper is a train of impulses (A_i, t_i), sum A_i = 1, t_0 = 0. Convolving a motion with it leaves a
single lightly damped mode (frequency f, damping ratio zeta) with the fraction

    V(f) = exp(-zeta w t_n) * |sum_i A_i exp(zeta w t_i) exp(j w_d t_i)|,  w = 2 pi f, w_d = w sqrt(1 - zeta^2)

of the residual vibration the unshaped motion leaves (exact for any motion, by linearity: the free
oscillation after the last impulse is the unshaped one summed with those weights and delays).

Shapers (Singhose's closed forms; K = exp(-zeta pi / sqrt(1 - zeta^2)), T_d = 1 / (f sqrt(1 - zeta^2))):

=========  ================================================  ==================================
name       amplitudes (before normalising to sum 1)           times (x T_d)
=========  ================================================  ==================================
ZV         1, K                                               0, 1/2
MZV        a, (sqrt2 - 1) K', a K'^2; a = 1 - 1/sqrt2,         0, 3/8, 3/4
           K' = exp(-0.75 zeta pi / sqrt(1 - zeta^2))
ZVD        1, 2K, K^2                                         0, 1/2, 1
EI         (1+V)/4, (1-V)/2 K, (1+V)/4 K^2                     0, 1/2, 1
2HUMP_EI   a1, (1/2 - a1) K, (1/2 - a1) K^2, a1 K^3           0, 1/2, 1, 3/2
3HUMP_EI   a1, (1-V)/4 K, ((1+V)/2 - 2 a1) K^2, (1-V)/4 K^3,   0, 1/2, 1, 3/2, 2
           a1 K^4
MA         K_i = exp(-zeta w t_i), i = 0 .. MA_TAPS - 1            i / MA_TAPS (one damped period)
=========  ================================================  ==================================

(V = the EI shapers' tolerated vibration, 5 %.)

**MA, the moving average over one period.** Its taps are a damped period's MA_TAPS roots of unity:
the mode at the design frequency, and its first MA_TAPS - 1 harmonics, are left with no vibration
at all, and between them its curve is a sinc (V = 0.24 at 0.8 f, 0.16 at 1.2 f). Unlike the
impulse shapers, whose curves repeat every 2 f (ZV, ZVD, EI and the humps leave the whole motion at
2 f, 4 f, ...), it also smooths: a velocity step (a corner the planner passes at its corner speed,
a piece of the path starting or ending at speed) becomes a ramp over one period, so the motion
keeps little content anywhere in the band around the mode. Combined with an impulse shaper
(``"ZV*MA"``: a name joining types with ``*`` is their convolution) the curve is the product.

**Applying a shaper without leaving the path.** Shaping the Cartesian targets (as 3-D printers do)
averages points of different path segments, so a corner is cut: :func:`shape_cartesian`.
Shaping the *time law* instead -- the arc length along the path s(t) convolved with the impulses,
s~(t) = sum_i A_i s(t - t_i), and the pose looked up on the path at s~(t) -- only changes *when* the
tool is where; every sample stays on the programmed path: :func:`shape_time_law`. It is done piece
by piece between corners, so the tool still stops where the planner stopped it.
Both take a trajectory sampled at a fixed period dt (tip (N, 3) mm, axis (N, 3) unit) whose
consecutive samples are joined by straight lines (the planner's G1 samples; corners are samples).
:func:`path_error` measures the distance of shaped samples from that polyline.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SHAPERS = ("ZV", "MZV", "ZVD", "EI", "2HUMP_EI", "3HUMP_EI", "MA")
EI_TOLERANCE = 0.05
MA_TAPS = 32              # taps of the moving average over one period (zero vibration at f .. 31 f)
# Time-law shaping splits the path at corners turning more than this. At a split the shaped clock
# comes to rest at the corner and leaves from rest: with the planner's corner speed v_c that costs
# velocity steps adding up to 2 v_c. Not splitting costs a step |u2 - u1| v~ at the corner (v~ the
# shaped speed there, a little above v_c): less for a shallow turn (the comb job's 6 deg G0/G1
# junction at 4.5 mm/s: 0.5 mm/s instead of 9 mm/s), more for a sharp one.
SPLIT_DEG = 20.0


@dataclass(frozen=True)
class Shaper:
    name: str
    freq_hz: float
    damping: float
    A: np.ndarray        # (n,) amplitudes, sum 1
    T: np.ndarray        # (n,) times, s, T[0] = 0

    @property
    def duration(self) -> float:
        return float(self.T[-1])

    @property
    def delay(self) -> float:
        """Mean delay sum A_i t_i: how much later the shaped motion arrives, on average (s)."""
        return float(self.A @ self.T)


def shaper_name(name: str) -> str:
    """The canonical name of a shaper type or of a combination of types joined by ``*`` (``"zv*ma"``
    -> ``"ZV*MA"``); ValueError naming the choices for an unknown one."""
    parts = [p.strip().upper() for p in str(name).split("*")]
    for p in parts:
        if p not in SHAPERS:
            raise ValueError(f"unknown shaper {name!r}: choose one of {', '.join(SHAPERS)}, or types joined "
                             f"by '*' (their convolution, e.g. ZV*MA)")
    return "*".join(parts)


def make_shaper(name: str, freq_hz: float, damping: float = 0.1, tolerance: float = EI_TOLERANCE) -> Shaper:
    """The shaper ``name`` (one of SHAPERS, case-insensitive, or types joined by ``*``: their
    convolution, each designed for the same mode) designed for ``freq_hz`` and ``damping``."""
    key = shaper_name(name)
    if "*" in key:
        sh = convolve([make_shaper(p, freq_hz, damping, tolerance) for p in key.split("*")])
        return Shaper(key, float(freq_hz), float(damping), sh.A, sh.T)
    if not (math.isfinite(freq_hz) and freq_hz > 0):
        raise ValueError(f"shaper frequency must be > 0 Hz, got {freq_hz!r}")
    if not (0.0 <= damping < 1.0):
        raise ValueError(f"shaper damping ratio must be within [0, 1), got {damping!r}")
    z, v = float(damping), float(tolerance)
    sq = math.sqrt(1.0 - z * z)
    K = math.exp(-z * math.pi / sq)
    td = 1.0 / (freq_hz * sq)
    if key == "ZV":
        A, T = [1.0, K], [0.0, 0.5]
    elif key == "ZVD":
        A, T = [1.0, 2.0 * K, K * K], [0.0, 0.5, 1.0]
    elif key == "MZV":
        k = math.exp(-0.75 * z * math.pi / sq)
        a1 = 1.0 - 1.0 / math.sqrt(2.0)
        A, T = [a1, (math.sqrt(2.0) - 1.0) * k, a1 * k * k], [0.0, 0.375, 0.75]
    elif key == "MA":
        T = np.arange(MA_TAPS) / MA_TAPS * td
        A = np.exp(-z * 2.0 * math.pi * freq_hz * T)
        return Shaper(key, float(freq_hz), z, A / A.sum(), T)
    elif key == "EI":
        a1 = 0.25 * (1.0 + v)
        A, T = [a1, 0.5 * (1.0 - v) * K, a1 * K * K], [0.0, 0.5, 1.0]
    elif key == "2HUMP_EI":
        v2 = v * v
        x = (v2 * (math.sqrt(1.0 - v2) + 1.0)) ** (1.0 / 3.0)
        a1 = (3.0 * x * x + 2.0 * x + 3.0 * v2) / (16.0 * x)
        a2 = (0.5 - a1) * K
        A, T = [a1, a2, a2 * K, a1 * K ** 3], [0.0, 0.5, 1.0, 1.5]
    else:  # 3HUMP_EI
        k2 = K * K
        a1 = 0.0625 * (1.0 + 3.0 * v + 2.0 * math.sqrt(2.0 * (v + 1.0) * v))
        a2 = 0.25 * (1.0 - v) * K
        a3 = (0.5 * (1.0 + v) - 2.0 * a1) * k2
        A, T = [a1, a2, a3, a2 * k2, a1 * k2 * k2], [0.0, 0.5, 1.0, 1.5, 2.0]
    A = np.array(A, float)
    return Shaper(key, float(freq_hz), z, A / A.sum(), np.array(T, float) * td)


def convolve(shapers, merge: float = 1e-9) -> Shaper:
    """One shaper that is the convolution of ``shapers`` (impulse trains): it cancels each of their
    modes; its duration is the sum of theirs. Impulses closer than ``merge`` s are merged. The
    result's name joins the names; freq_hz and damping are the first shaper's."""
    shapers = list(shapers)
    if not shapers:
        raise ValueError("no shaper to convolve")
    A, T = np.array([1.0]), np.array([0.0])
    for sh in shapers:
        A = (A[:, None] * sh.A[None]).ravel()
        T = (T[:, None] + sh.T[None]).ravel()
    o = np.argsort(T, kind="stable")
    A, T = A[o], T[o]
    keep = np.r_[True, np.diff(T) > merge]
    grp = np.cumsum(keep) - 1
    A2 = np.bincount(grp, weights=A)
    T2 = T[keep]
    s0 = shapers[0]
    return Shaper("*".join(sh.name for sh in shapers), s0.freq_hz, s0.damping, A2 / A2.sum(), T2 - T2[0])


AUTO_DRIFT = 0.10         # recommend(): the mode may be this far (relative) from its design point
AUTO_REMAINING = 0.05     # ... and leave at most this residual vibration anywhere within it


def candidates() -> list[str]:
    """The shapers :func:`recommend` chooses from, shortest first: the moving average over one period
    (MA) alone and convolved with each impulse shaper. The MA always takes part: the time law's
    steps (a piece of the path starting or ending at the planner's corner speed) carry motion
    across the whole band around the mode, which an impulse shaper alone leaves (its curve repeats
    every 2 f); the MA spreads them over a period."""
    names = ["MA"] + [f"{n}*MA" for n in SHAPERS if n != "MA"]
    return sorted(names, key=lambda n: make_shaper(n, 1.0, 0.0).duration)


def recommend(freq_hz: float, damping: float, drift: float = AUTO_DRIFT, max_remaining: float = AUTO_REMAINING) -> str:
    """The shaper ``auto`` takes for a mode (freq_hz, damping): the shortest of :func:`candidates`
    whose residual vibration stays at most ``max_remaining`` over freq_hz x (1 -+ drift), else the one
    with the least there."""
    band = np.linspace(1.0 - drift, 1.0 + drift, 81) * freq_hz
    worst = []
    for n in candidates():
        v = float(np.max(residual_vibration(make_shaper(n, freq_hz, damping), band, damping)))
        if v <= max_remaining:
            return n
        worst.append((v, n))
    return min(worst)[1]


def residual_vibration(shaper: Shaper, freq_hz, damping: float | None = None):
    """Analytic residual vibration V (fraction of the unshaped motion's) of a mode at ``freq_hz``
    (scalar or array) with damping ratio ``damping`` (default: the shaper's design damping)."""
    z = shaper.damping if damping is None else float(damping)
    f = np.asarray(freq_hz, float)
    w = 2.0 * np.pi * f[..., None]
    wd = w * math.sqrt(1.0 - z * z)
    e = shaper.A * np.exp(z * w * shaper.T)
    c = np.sum(e * np.cos(wd * shaper.T), -1)
    s = np.sum(e * np.sin(wd * shaper.T), -1)
    return np.exp(-z * w[..., 0] * shaper.duration) * np.hypot(c, s)


# ---------------------------------------------------------------------------------------------
# Applying a shaper to a sampled path
# ---------------------------------------------------------------------------------------------

def path_at_index(tip, axis, sigma):
    """Pose on the sampled polyline at fractional sample index sigma (linear between samples; the
    axis by normalised linear interpolation, i.e. on the great circle between the two samples)."""
    n = len(tip)
    sigma = np.clip(sigma, 0.0, n - 1.0)
    k = np.minimum(np.floor(sigma).astype(int), n - 2) if n > 1 else np.zeros(len(sigma), int)
    u = (sigma - k)[:, None]
    if n == 1:
        return np.repeat(tip, len(sigma), 0), np.repeat(axis, len(sigma), 0)
    p = tip[k] * (1.0 - u) + tip[k + 1] * u
    a = axis[k] * (1.0 - u) + axis[k + 1] * u
    return p, a / np.linalg.norm(a, axis=-1, keepdims=True)


def shaped_clock(tip, axis, dt: float, shaper: Shaper, axis_weight_mm: float = 100.0):
    """The shaped time law as fractional sample indices of the input trajectory.

    s_k = arc length along the sampled path up to sample k (tip mm, plus ``axis_weight_mm`` per unit
    of tool-axis change, so a pure reorientation has a length too); s(t) is linear between samples
    and held at both ends; the shaped law s~(t_k) = sum_i A_i s(t_k - t_i) for
    k = 0 .. n - 1 + ceil(t_n/dt) (the motion ends later); each s~ is mapped back to the point of the
    polyline at that arc length, as a fractional sample index."""
    x = np.concatenate([np.asarray(tip, float), axis_weight_mm * np.asarray(axis, float)], 1)
    n = len(x)
    seg = np.linalg.norm(np.diff(x, axis=0), axis=1)
    S = np.r_[0.0, np.cumsum(seg)]
    extra = int(math.ceil(shaper.duration / dt - 1e-9))
    k = np.arange(n + extra, dtype=float)
    s_sh = np.zeros(len(k))
    idx = np.arange(n, dtype=float)
    for Ai, ti in zip(shaper.A, shaper.T):
        s_sh += Ai * np.interp(np.clip(k - ti / dt, 0.0, n - 1.0), idx, S)
    s_sh = np.minimum(s_sh, S[-1])
    j = np.clip(np.searchsorted(S, s_sh, side="right") - 1, 0, max(n - 2, 0))
    if n < 2:
        return np.zeros(len(k))
    L = seg[j]
    u = np.where(L > 0, (s_sh - S[j]) / np.where(L > 0, L, 1.0), 0.0)
    sigma = j + np.clip(u, 0.0, 1.0)
    sigma[s_sh >= S[-1]] = n - 1.0
    return sigma


def corner_samples(tip, axis, corner_deg: float = SPLIT_DEG, axis_weight_mm: float = 100.0):
    """Indices of the samples where the motion turns by more than ``corner_deg`` (a corner: the
    planner stops there, or slows to a junction speed) -- the tool-axis motion counted as
    ``axis_weight_mm`` per unit of axis change."""
    x = np.concatenate([np.asarray(tip, float), axis_weight_mm * np.asarray(axis, float)], 1)
    d = np.diff(x, axis=0)
    nrm = np.linalg.norm(d, axis=1)
    moving = np.nonzero(nrm > 1e-12)[0]
    out = []
    c = math.cos(math.radians(corner_deg))
    for i, j in zip(moving[:-1], moving[1:]):
        # displacement i (samples i -> i+1) and the next moving one j: they meet at sample i+1 .. j
        if float(d[i] @ d[j]) < c * nrm[i] * nrm[j]:
            out.append(int(j))          # the sample where the new direction starts
    return out


def _pieces_index(tip, axis, dt: float, cuts, shaper_of):
    """Fractional sample indices of the time law shaped piece by piece: ``cuts`` (sorted sample
    indices, first 0, last n - 1) bound the pieces; ``shaper_of(a, b)`` is the Shaper of piece a..b,
    or None to leave its clock as planned."""
    out = []
    for k, (a, b) in enumerate(zip(cuts[:-1], cuts[1:])):
        sh = shaper_of(a, b)
        if sh is None:
            sg = np.arange(a, b + 1, dtype=float)
        else:
            sg = a + shaped_clock(tip[a:b + 1], axis[a:b + 1], dt, sh)
        out.append(sg[1:] if k else sg)        # the corner sample ends the previous piece
    return np.concatenate(out)


def shaped_index(tip, axis, dt: float, shaper: Shaper, *, split_at_corners: bool = True, corner_deg: float = SPLIT_DEG):
    """The time-law shaping of :func:`shape_time_law` as fractional sample indices of the input
    (non-decreasing; first 0, last n - 1): output sample k is the input path at index sigma_k, so
    per-sample data (job line, spindle speed) follows as the input's at floor(sigma_k)."""
    tip = np.asarray(tip, float)
    axis = np.asarray(axis, float)
    n = len(tip)
    if not split_at_corners or n < 3:
        return shaped_clock(tip, axis, dt, shaper)
    cuts = [0] + [c for c in corner_samples(tip, axis, corner_deg) if 0 < c < n - 1] + [n - 1]
    return _pieces_index(tip, axis, dt, cuts, lambda a, b: shaper)


CHAIN_SPLIT_DEG = 10.0   # a turn of the chains' velocity vector that splits the path (ChainShaping)
PIECE_SHARE = 0.1        # a chain whose planned acceleration in a piece is under this share of the
                         # piece's largest does not choose the piece's shaper (ChainShaping)
MERGE_REL = 0.03         # design points this close (relative frequency) share one shaper


@dataclass(frozen=True)
class ChainShaping:
    """Time-law shaping with a shaper per chain: each piece of the path (between corners) is shaped
    for the chains it moves, so the path is kept (one clock along it) while a piece that moves
    only chains with the same mode pays for one shaper, and a piece that moves no chain (a table
    move) pays nothing.

    ``shapers``: one Shaper per chain, designed for that chain's mode. ``joints``: a pure function
    (tip (N, 3), axis (N, 3)) -> the planned chain lengths (N, 3), mm (the inverse kinematics).
    ``jump_mm_s``: per chain, the velocity change within one tick that counts as a kink (it leaves
    the chain's mode ringing by about jump / w); ``still_mm_s2``: per chain, the planned acceleration
    below which the chain counts as still in a piece.

    Pieces: the path is split at the corners of :func:`corner_samples` (the tip and axis turning
    more than SPLIT_DEG) and where the chains' velocity vector turns by more than CHAIN_SPLIT_DEG
    with a jump of some chain's velocity above its ``jump_mm_s`` (a junction of the plan that is
    a corner for the chains: a G0 ending in a plunge, a tilt that stops). A chain chooses the shaper
    of a piece when its largest planned acceleration there (its first and last rates count as a
    step from rest in one tick) reaches both its ``still_mm_s2`` and PIECE_SHARE of the largest
    chain's; the piece is
    shaped with the convolution of the chosen chains' shapers (one per distinct design point,
    within MERGE_REL), or not at all when no chain is chosen."""

    shapers: tuple
    joints: object
    jump_mm_s: tuple = (0.0, 0.0, 0.0)
    still_mm_s2: tuple = (0.0, 0.0, 0.0)

    @property
    def name(self) -> str:
        return self.combined(range(len(self.shapers))).name

    @property
    def duration(self) -> float:
        """The longest a piece can be delayed (all chains' shapers convolved)."""
        return self.combined(range(len(self.shapers))).duration

    def combined(self, chains) -> Shaper:
        """The shaper of a piece moving ``chains``: their shapers, one per distinct design point."""
        pts = []
        for i in sorted(set(chains)):
            sh = self.shapers[i]
            if not any(p.name == sh.name and abs(p.freq_hz - sh.freq_hz) <= MERGE_REL * p.freq_hz for p in pts):
                pts.append(sh)
        return pts[0] if len(pts) == 1 else convolve(pts)

    def plan(self, tip, axis, dt: float):
        """(cuts, chosen, kinks): the sample indices bounding the pieces (first 0, last n - 1), per
        piece the tuple of chains that choose its shaper (empty: not shaped), and the set of cuts
        that are kinks of the chains rather than corners of the path."""
        tip = np.asarray(tip, float)
        axis = np.asarray(axis, float)
        n = len(tip)
        if n < 3:
            return [0, max(n - 1, 0)], [()] if n > 1 else [], set()
        q = np.asarray(self.joints(tip, axis), float)[:, :len(self.shapers)]
        v = np.diff(q, axis=0) / dt                       # (n - 1, C): rate of sample k -> k + 1
        jump = np.abs(np.diff(v, axis=0))                 # (n - 2, C): at samples 1 .. n - 2
        corners = set(c for c in corner_samples(tip, axis) if 0 < c < n - 1)
        big = np.any(jump > np.asarray(self.jump_mm_s, float), axis=1)
        vi, vo = v[:-1], v[1:]
        ni, no = np.linalg.norm(vi, axis=1), np.linalg.norm(vo, axis=1)
        cosang = np.einsum("ij,ij->i", vi, vo) / np.maximum(ni * no, 1e-300)
        turn = (ni > 0) & (no > 0) & (cosang < math.cos(math.radians(CHAIN_SPLIT_DEG)))
        kinks = set(int(k) + 1 for k in np.nonzero(big & turn)[0]) - corners
        cuts = [0] + sorted(c for c in corners | kinks if 0 < c < n - 1) + [n - 1]
        acc = np.zeros_like(q)
        acc[1:-1] = jump / dt
        floor = np.asarray(self.still_mm_s2, float)
        chosen = []
        for a, b in zip(cuts[:-1], cuts[1:]):
            # the piece's own motion: its inner samples' accelerations and its first and last rates
            # (the shaped clock starts and ends at rest), not the jumps at its ends, which belong to
            # the clock of the piece on the other side
            peak = np.maximum(np.abs(v[a]), np.abs(v[b - 1])) / dt
            if b - a > 1:
                peak = np.maximum(peak, np.abs(acc[a + 1:b]).max(axis=0))
            top = float(peak.max())
            chosen.append(tuple(int(i) for i in np.nonzero((peak >= floor) & (peak >= PIECE_SHARE * top)
                                                            & (peak > 0))[0]))
        return cuts, chosen, kinks

    def index(self, tip, axis, dt: float):
        """Fractional sample indices of the shaped time law (as :func:`shaped_index`)."""
        tip = np.asarray(tip, float)
        axis = np.asarray(axis, float)
        if len(tip) < 3:
            return np.arange(len(tip), dtype=float)
        cuts, chosen, kinks = self.plan(tip, axis, dt)
        of = dict(zip(zip(cuts[:-1], cuts[1:]), chosen))
        cache = {}

        def shaper_of(a, b):
            ch = of[(a, b)]
            if not ch:
                return None
            key = (ch, a in kinks or b in kinks)
            if key not in cache:
                sh = self.combined(ch)
                if key[1]:          # a stop the planner did not make: brought to rest over two periods
                    lo = min(self.shapers[i].freq_hz for i in ch)
                    sh = convolve([sh, make_shaper("MA", 0.5 * lo, 0.0)])
                cache[key] = sh
            return cache[key]
        return _pieces_index(tip, axis, dt, cuts, shaper_of)


def shape_time_law(tip, axis, dt: float, shaper: Shaper, *, split_at_corners: bool = True,
                   corner_deg: float = SPLIT_DEG):
    """Time-law shaping of a trajectory sampled every ``dt``: every output sample lies on the
    polyline of the input samples (the path is kept, only the timing along it changes); the first
    and last samples are the input's first and last.

    ``split_at_corners`` (default): the clock of each piece between corners (:func:`corner_samples`)
    is shaped on its own, so the tool still comes to the corner point with the speed the planner gave
    it and leaves from there -- one clock shaped across a corner would carry the tool through the
    corner at speed, a jump of velocity. Each piece ends ceil(t_n/dt) samples later (the time cost).
    Returns (tip, axis)."""
    tip = np.asarray(tip, float)
    axis = np.asarray(axis, float)
    return path_at_index(tip, axis, shaped_index(tip, axis, dt, shaper, split_at_corners=split_at_corners,
                                           corner_deg=corner_deg))


def shape_cartesian(tip, axis, dt: float, shaper: Shaper):
    """Cartesian (target) shaping, as printers do: each output sample is sum_i A_i pose(t - t_i)
    (the axis renormalised). Cuts corners: compare with :func:`shape_time_law`."""
    tip = np.asarray(tip, float)
    axis = np.asarray(axis, float)
    n = len(tip)
    extra = int(math.ceil(shaper.duration / dt - 1e-9))
    k = np.arange(n + extra, dtype=float)
    p = np.zeros((len(k), 3))
    a = np.zeros((len(k), 3))
    for Ai, ti in zip(shaper.A, shaper.T):
        pi, ai = path_at_index(tip, axis, np.clip(k - ti / dt, 0.0, n - 1.0))
        p += Ai * pi
        a += Ai * ai
    return p, a / np.linalg.norm(a, axis=-1, keepdims=True)


def path_error(points, path_tip):
    """Distance (mm) of each of ``points`` (M, 3) from the polyline through ``path_tip`` (N, 3)."""
    P = np.asarray(points, float)
    Q = np.asarray(path_tip, float)
    a, b = Q[:-1], Q[1:]
    d = b - a
    L2 = np.einsum("ij,ij->i", d, d)
    keep = L2 > 0
    a, d, L2 = a[keep], d[keep], L2[keep]
    if len(a) == 0:
        return np.linalg.norm(P - Q[0], axis=-1)
    best = np.full(len(P), np.inf)
    for s in range(0, len(a), 256):          # blocks: memory stays bounded on long paths
        aa, dd, ll = a[s:s + 256], d[s:s + 256], L2[s:s + 256]
        u = np.clip(np.einsum("mij,ij->mi", P[:, None, :] - aa[None], dd) / ll, 0.0, 1.0)
        r = np.linalg.norm(P[:, None, :] - (aa[None] + u[..., None] * dd[None]), axis=-1)
        best = np.minimum(best, r.min(1))
    return best


def corner_trajectory(v_mm_s: float, accel_mm_s2: float, leg_mm: float, dt: float, stop: bool = True):
    """A 90 degree corner (along +X into the origin, then along +Y) sampled every dt: trapezoidal speed
    with an exact stop at the corner (``stop``) or at constant speed v through it. Returns (tip, axis)."""
    def leg(stop_end, stop_start):
        # distance as a function of time along one leg, trapezoid v/accel
        ta = v_mm_s / accel_mm_s2
        da = 0.5 * v_mm_s * ta
        acc_in, acc_out = stop_start, stop_end
        d_acc = da * acc_in + da * acc_out
        cruise = max(leg_mm - d_acc, 0.0) / v_mm_s
        T = ta * acc_in + cruise + ta * acc_out
        t = np.arange(0.0, T, dt)
        s = np.empty_like(t)
        for i, ti in enumerate(t):
            if acc_in and ti < ta:
                s[i] = 0.5 * accel_mm_s2 * ti * ti
            elif ti < ta * acc_in + cruise:
                s[i] = da * acc_in + v_mm_s * (ti - ta * acc_in)
            else:
                r = T - ti
                s[i] = leg_mm - 0.5 * accel_mm_s2 * r * r if acc_out else leg_mm - v_mm_s * r
        return s
    s1 = leg(stop, True)
    s2 = leg(True, stop)
    tip = np.concatenate([np.c_[s1 - leg_mm, 0 * s1, 0 * s1], [[0.0, 0.0, 0.0]], np.c_[0 * s2, s2, 0 * s2][1:],
                          [[0.0, leg_mm, 0.0]]])
    axis = np.tile([0.0, 0.0, 1.0], (len(tip), 1))
    return tip, axis


def smoothing_mm(shaper: Shaper, v_mm_s: float = 50.0, accel_mm_s2: float = 2000.0, dt: float = 1e-4) -> float:
    """Smoothing of a shaper as the corner it cuts when applied to the Cartesian targets: the largest
    distance from the programmed path on a 90 degree corner taken at constant speed ``v_mm_s`` (mm).
    Time-law shaping cuts nothing (0 by construction); this is the cost it avoids."""
    leg = max(5.0, 2.0 * v_mm_s * shaper.duration + v_mm_s ** 2 / accel_mm_s2)
    tip, axis = corner_trajectory(v_mm_s, accel_mm_s2, leg, dt, stop=False)
    p, _ = shape_cartesian(tip, axis, dt, shaper)
    return float(path_error(p, np.array([[-leg, 0, 0], [0, 0, 0], [0, leg, 0]])).max())
