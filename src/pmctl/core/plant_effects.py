"""Forward physics of the effect catalogue, written once: per tick and in batch.

One place for the physics that the simulated machine (:mod:`pmctl.hal.sim`, per control tick), the
concealed-effect recordings (:mod:`pmctl.tools.twin.synth`, whole runs at once) and the diagnosis
models (:mod:`pmctl.tools.twin.effects`) share. Every effect with memory has a *batch* function
(arrays over time, vectorised where the physics allows) and a *per-tick* class (its state, one
value per axis: ``step`` takes the new input and returns the new output); both give the same
numbers (tests/core/test_plant_effects.py checks them against each other on random inputs). Memoryless
effects are one function that takes scalars, per-axis vectors or whole arrays alike.

Positions in mm, times in s. ``s`` is the screw (motor-side) position of an axis.

- backlash, the play operator (:func:`play_load`, :func:`play_error`, :class:`Play`): the load stays within ±w/2 of
  the motor and moves only when the motor drags it at an edge of the deadband;
- periodic screw error, pitch error at the lead or any other period (:func:`periodic_error`):
  A·sin(2π·s/P + φ);
- thermal growth (:func:`thermal_growth`): α·ΔT·(s − s_fixed), zero at the screw's fixed bearing;
- Coulomb/Stribeck friction as the position loop's following error (:func:`friction_offset`,
  :class:`Friction`): −d·(c + c_s·exp(−(v/v_s)²)), d the direction of the last motion (held
  through stops, 0 before the first move);
- servo lag (:func:`first_order_lag`, :class:`FirstOrderLag`): τ·y' + y = u, exact for an input
  linear between samples (a ramp at speed v is trailed by exactly τ·v);
- a flexible mode on an axis (:func:`mode_response`, :class:`Mode`): y'' + 2ζωy' + ω²y = −x'',
  the base-excited relative displacement, exact for x linear between samples (each sample a
  velocity jump, then free motion through the transition matrix :func:`mode_transition`);
- lost steps (:func:`step_offset`): a position offset from t_s on;
- the force a drive needs to move its axis (:func:`drive_force`): moving mass, viscous and
  Coulomb friction (the viscous part may differ by direction), Stribeck, a constant load.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal
from scipy.linalg import expm

# Where each screw of the prototype (L1 L2 L3 X Y) has its fixed bearing, mm of screw position:
# thermal growth is zero there and grows with the distance from it.
SCREW_FIXED_END_MM = (150.0, 150.0, 150.0, -75.0, -75.0)


# ---------------------------------------------------------------- backlash

def play_load(x, width, start=0.0):
    """Backlash as a play operator, batch: the load positions behind the motor positions ``x``.
    The load stays within ±width/2 of the motor and only moves when dragged; ``start`` in [-1, 1]
    is where in the deadband it rests at the first sample (y[0] = x[0] + start·width/2). Exact,
    segment-wise: on a monotone stretch y = clip(y0, x − w/2, x + w/2)."""
    h = 0.5 * abs(width)
    x = np.asarray(x, float)
    if len(x) == 0:
        return x.copy()
    y0 = x[0] + float(np.clip(start, -1, 1)) * h
    y = np.full_like(x, y0)
    dx = np.diff(x)
    nz = np.nonzero(dx)[0]
    if len(nz) == 0:
        return y
    s = np.sign(dx[nz])
    rev = nz[1:][s[1:] != s[:-1]]          # the increment index where direction changes
    starts = np.concatenate([[0], rev])    # segment k starts at sample starts[k]
    ends = np.concatenate([rev, [len(x) - 1]])
    for a, b in zip(starts, ends):
        xs = x[a:b + 1]
        seg = np.minimum(np.maximum(y0, xs - h), xs + h)
        y[a:b + 1] = seg
        y0 = seg[-1]
    return y


def play_error(x, width, start=0.0):
    """:func:`play_load` as e = x_load − x_motor (e[0] = start·width/2)."""
    x = np.asarray(x, float)
    return play_load(x, width, start) - x


def first_direction(x) -> float:
    """+1/−1: the direction of the first motion of ``x`` (0 if it never moves)."""
    x = np.asarray(x, float)
    moved = np.flatnonzero(x != x[0]) if len(x) else []
    return float(np.sign(x[moved[0]] - x[0])) if len(moved) else 0.0


def play(x, width):
    """Load-side positions behind the play operator when the load starts on the side that the
    first motion pushes (it follows at once, width/2 behind)."""
    return play_load(x, width, -first_direction(x))


class Play:
    """Play operator per tick, one deadband per axis: ``step(x)`` → e = x_load − x_motor."""

    def __init__(self, width, x0, start=0.0):
        x0 = np.asarray(x0, float)
        self.h = 0.5 * np.abs(np.broadcast_to(np.asarray(width, float), x0.shape))
        self.y = x0 + np.clip(np.asarray(start, float), -1, 1) * self.h     # load position
        self.x = x0.copy()

    @property
    def error(self):
        return self.y - self.x

    def step(self, x):
        self.x = np.array(x, float)          # a copy: the caller may reuse its buffer
        self.y = np.minimum(np.maximum(self.y, self.x - self.h), self.x + self.h)
        return self.y - self.x


# ---------------------------------------------------------------- memoryless screw errors

def periodic_error(s, amplitude, period, phase=0.0):
    """Periodic error of the screw position s (pitch error at the lead, or a bearing/gear/coupling
    period): A·sin(2π/P·s + φ). Scalars, per-axis vectors or arrays (broadcast); P > 0 where A ≠ 0;
    an axis with P = 0 (and A = 0) gives 0."""
    period = np.asarray(period, float)
    k = np.where(period > 0, 2 * np.pi / np.where(period > 0, period, 1.0), 0.0)
    return amplitude * np.sin(k * np.asarray(s, float) + phase)


class PeriodicError:
    """:func:`periodic_error` per tick with its constants prepared (the same arithmetic)."""

    def __init__(self, amplitude, period, phase=0.0):
        period = np.asarray(period, float)
        self.k = np.where(period > 0, 2 * np.pi / np.where(period > 0, period, 1.0), 0.0)
        self.a, self.phase = np.asarray(amplitude, float), np.asarray(phase, float)

    def __call__(self, s):
        return self.a * np.sin(self.k * s + self.phase)


def thermal_growth(s, alpha_per_K, delta_K, fixed_end_mm):
    """Thermal growth of a screw with its fixed bearing at ``fixed_end_mm``: the nut position s
    reads α·ΔT·(s − s_fixed) too short of the true one (the load moves by that much)."""
    return alpha_per_K * delta_K * (np.asarray(s, float) - fixed_end_mm)


def step_offset(t, t_s, offset):
    """Lost steps: ``offset`` from time ``t_s`` on, 0 before."""
    return np.where(np.asarray(t, float) >= t_s, offset, 0.0)


# ---------------------------------------------------------------- friction

def direction(x, dead=0.0):
    """+1/−1 for the direction of the last motion (held through stops), 0 before the first move.
    Batch over the first axis of ``x``; a step of at most ``dead`` is no motion."""
    x = np.asarray(x, float)
    if len(x) == 0:
        return np.zeros_like(x)
    dx = np.diff(x, axis=0, prepend=x[:1])
    s = np.where(dx > dead, 1.0, np.where(dx < -dead, -1.0, 0.0))
    idx = np.where(s != 0, np.arange(len(s)).reshape((-1,) + (1,) * (s.ndim - 1)), 0)
    np.maximum.accumulate(idx, axis=0, out=idx)
    return np.take_along_axis(s, idx, axis=0)        # s[0] = 0: no move yet


class Direction:
    """:func:`direction` per tick, one per axis."""

    def __init__(self, x0, dead=0.0):
        self.x = np.asarray(x0, float).copy()
        self.d = np.zeros_like(self.x)
        self.dead = dead

    def step(self, x):
        x = np.array(x, float)               # a copy: the caller may reuse its buffer
        dx = x - self.x
        self.d = np.where(dx > self.dead, 1.0, np.where(dx < -self.dead, -1.0, self.d))
        self.x = x
        return self.d


def velocity(x, dt):
    """Backward difference (x_k − x_{k−1})/dt along the first axis, 0 at the first sample (what a
    tick sees; causal)."""
    x = np.asarray(x, float)
    return np.diff(x, axis=0, prepend=x[:1]) / dt


def friction_force_offset(d, v, coulomb_mm, stribeck_mm, stribeck_speed_mm_s):
    """The following error of a position loop against Coulomb + Stribeck friction, for direction d
    and speed v: −d·(c + c_s·exp(−(v/v_s)²)) (mm; the motor trails the command)."""
    vs = np.where(np.asarray(stribeck_speed_mm_s, float) > 0, stribeck_speed_mm_s, 1.0)
    return -d * (coulomb_mm + stribeck_mm * np.exp(-(np.asarray(v, float) / vs) ** 2))


def friction_offset(x, dt, coulomb_mm, stribeck_mm=0.0, stribeck_speed_mm_s=1.0, v=None):
    """Friction following error over a run of commanded positions ``x`` (batch): direction of the
    last motion of x, speed ``v`` (default the backward difference of x)."""
    v = velocity(x, dt) if v is None else v
    return friction_force_offset(direction(x), v, coulomb_mm, stribeck_mm, stribeck_speed_mm_s)


class Friction:
    """:func:`friction_offset` per tick: ``step(x)`` with the new commanded position(s)."""

    def __init__(self, x0, dt, coulomb_mm, stribeck_mm=0.0, stribeck_speed_mm_s=1.0):
        self.dir = Direction(x0)
        self.dt = dt
        self.c, self.cs = np.asarray(coulomb_mm, float), np.asarray(stribeck_mm, float)
        self.vs = np.where(np.asarray(stribeck_speed_mm_s, float) > 0, stribeck_speed_mm_s, 1.0)
        self.stribeck = bool(np.any(self.cs != 0))

    def step(self, x):
        x = np.array(x, float)
        v = (x - self.dir.x) / self.dt
        d = self.dir.step(x)
        if not self.stribeck:
            return -d * self.c
        return -d * (self.c + self.cs * np.exp(-(v / self.vs) ** 2))


# ---------------------------------------------------------------- servo lag

def lag_coefficients(tau, h):
    """(a, b0, b1) of y_k = a·y_{k−1} + b0·u_k + b1·u_{k−1}: τ·y' + y = u exact for u linear over
    a step h (first-order hold)."""
    a = math.exp(-h / tau)
    c = (1 - a) * tau / h - a
    return a, 1 - a - c, c


def first_order_lag(t, u, tau):
    """Response of a first-order lag τ·y' + y = u to u at times t, starting settled at u[0].
    Exact for an input that is linear between samples, so a ramp at speed v is trailed by exactly
    τ·v whatever the sample rate. τ ≤ 0: y = u."""
    u = np.asarray(u, float)
    if tau <= 0:
        return u.copy()
    t = np.asarray(t, float)
    dt = np.diff(t)
    if len(dt) and np.ptp(dt) <= 1e-6 * np.mean(dt):
        a, b0, b1 = lag_coefficients(tau, float(np.mean(dt)))
        y, _ = signal.lfilter([b0, b1], [1, -a], u - u[0], zi=[0.0])
        return y + u[0]
    y = np.empty_like(u)
    if len(u) == 0:
        return y
    y[0] = u[0]
    aa = np.exp(-dt / tau)
    cc = (1 - aa) * tau / dt - aa
    for k in range(1, len(u)):
        y[k] = aa[k - 1] * y[k - 1] + (1 - aa[k - 1] - cc[k - 1]) * u[k] + cc[k - 1] * u[k - 1]
    return y


class FirstOrderLag:
    """:func:`first_order_lag` per tick at a fixed step dt, one lag per axis (τ = 0: y = u)."""

    def __init__(self, tau, dt, u0):
        self.u0 = np.asarray(u0, float).copy()
        self.u = self.u0.copy()
        self.y = self.u0.copy()
        tau = np.broadcast_to(np.asarray(tau, float), self.u.shape)
        on = tau > 0
        with np.errstate(over="ignore"):           # a tiny τ: a = 0, y = u
            self.a = np.where(on, np.exp(-dt / np.where(on, tau, 1.0)), 0.0)
        c = np.where(on, (1 - self.a) * np.where(on, tau, 0.0) / dt - self.a, 0.0)
        self.b0, self.b1 = 1 - self.a - c, c

    def step(self, u):
        u = np.array(u, float)
        u0 = self.u0           # the same arithmetic as the batch filter, which runs on u − u0
        y = self.a * (self.y - u0) + self.b0 * (u - u0) + self.b1 * (self.u - u0) + u0
        self.y, self.u = y, u
        return y


# ---------------------------------------------------------------- flexible mode

def mode_transition(freq_hz, zeta, dt):
    """Transition matrix over dt of the free mode (y, y'): x' = [[0, 1], [−ω², −2ζω]]·x."""
    w = 2 * math.pi * freq_hz
    return expm(np.array([[0.0, 1.0], [-w * w, -2 * zeta * w]]) * dt)


def mode_response(x, dt, freq_hz, zeta):
    """Relative displacement y of a base-excited oscillator y'' + 2ζωy' + ω²y = −x'' (uniform dt,
    at rest at x[0]), exact for x linear between samples: at sample k the base velocity jumps by
    Δv_k, y' by −Δv_k, then the mode moves freely for dt (what :class:`Mode` does per tick)."""
    x = np.asarray(x, float)
    if len(x) == 0:
        return x.copy()
    v = velocity(x, dt)
    u = np.diff(v, prepend=0.0)                     # velocity jump at each sample
    ph = mode_transition(freq_hz, zeta, dt)
    # state s_k = Φ(s_{k−1} − e2·u_k), y_k = e1·s_k: in the standard form with z_k = s_{k−1}
    B = -ph[:, 1:2]
    C = ph[0:1, :]
    D = B[0:1, :]
    num, den = signal.ss2tf(ph, B, C, D)
    return signal.lfilter(num[0], den, u)


class Mode:
    """:func:`mode_response` per tick, one mode per axis: ``step(x)`` → y."""

    def __init__(self, freq_hz, zeta, dt, x0):
        self.x = np.asarray(x0, float).copy()
        n = self.x.shape
        f = np.broadcast_to(np.asarray(freq_hz, float), n)
        z = np.broadcast_to(np.asarray(zeta, float), n)
        self.ph = np.array([mode_transition(fi, zi, dt) for fi, zi in zip(f.ravel(), z.ravel())]).reshape(n + (2, 2))
        self.dt = dt
        self.v = np.zeros(n)
        self.y = np.zeros(n)
        self.yd = np.zeros(n)

    def step(self, x):
        x = np.array(x, float)
        v = (x - self.x) / self.dt
        yd = self.yd - (v - self.v)
        p = self.ph
        self.y, self.yd = p[..., 0, 0] * self.y + p[..., 0, 1] * yd, p[..., 1, 0] * self.y + p[..., 1, 1] * yd
        self.x, self.v = x, v
        return self.y


# ---------------------------------------------------------------- the drive's force

def moving_sign(v, v_dead=0.0):
    """The direction friction opposes: sign(v) beyond ±v_dead, v/v_dead within it (0 standing still:
    friction then holds whatever it must; a ramp, not a step, through the pre-sliding band, so that
    a speed known to a fraction of v_dead gives the force to that fraction of the Coulomb level)."""
    v = np.asarray(v, float)
    if not v_dead > 0:
        return np.sign(v)
    return np.clip(v / v_dead, -1.0, 1.0)


def drive_force(v, a, *, mass, viscous, coulomb, offset=0.0, stribeck=0.0, stribeck_speed=1.0,
                viscous_neg=None, v_dead=0.0):
    """The force (or torque) a drive applies to move its axis at speed ``v`` and acceleration ``a``:
    mass·a + viscous·v + sign(v)·(coulomb + stribeck·exp(−(v/stribeck_speed)²)) + offset, where the
    viscous coefficient is ``viscous_neg`` while moving in −, when given. Coefficients per unit of
    ``v`` and ``a`` as given (a mass of m kg against a in mm/s² is m/1000 N per mm/s²); the sign
    is 0 at standstill (|v| <= v_dead). The offset is a constant load: gravity on a vertical axis,
    a counterweight, a cable chain's pull, a current sensor's zero."""
    v = np.asarray(v, float)
    d = moving_sign(v, v_dead)
    vs = stribeck_speed if stribeck_speed > 0 else 1.0
    visc = viscous if viscous_neg is None else np.where(v < 0, viscous_neg, viscous)
    return mass * np.asarray(a, float) + visc * v + d * (coulomb + stribeck * np.exp(-(v / vs) ** 2)) + offset
