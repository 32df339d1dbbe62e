"""Loopback simulation backend: a plant that takes the pulses and answers like the machine would.

Per axis (L1, L2, L3, X, Y):
- **drive**: the commanded position c = pulse counter x resolution moves as a ramp inside each
  tick (the bridge spreads the pulses evenly); the motor follows with a first-order lag tau
  (tau = 0: ideal drive, motor = command). Solved exactly for a ramp input.
- **flexible mode** per chain (L1-L3): the load side (what moves the platform) hangs on the motor
  side through a spring k (N/mm), modal mass m (kg) and damping ratio zeta. In the motor frame the
  deflection y = x_L - x_m obeys  y'' + 2 zeta w y' + w^2 y = -x_m''  (w^2 = k/m); the motor moves
  piecewise-linearly, so each tick is a velocity jump followed by free motion, integrated exactly
  with a precomputed transition matrix (stable at any tick rate).
- **strain gauge** on each plate link: strain = k_eps * tension, tension = the static gravity
  load of the true (load-side) platform pose (pmctl.core.statics, RECORDING.md §2) plus the spring
  force k * y of the flexible mode (microstrain, tension positive);
- **measurement noise**: Gaussian on encoders (mm) and strain (microstrain), seeded RNG.

The true tool tip is FK(load-side joints) (:meth:`truth` gives them). Fault injection for tests:
a stall (``read`` blocks, then times out) and lost steps (the motor slips by a given amount).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, fields

import numpy as np
from scipy.linalg import expm

from pmctl.core.config import Machine
from pmctl.core.errors import ConfigError
from pmctl.hal.base import Backend, Feedback, HalError, HalTimeout, Status


@dataclass
class SimOptions:
    drive_tau_s: tuple = (0.0, 0.0, 0.0, 0.0, 0.0)     # first-order lag per axis, 0 = ideal
    flex: bool = False                                  # flexible mode per chain on/off
    mode_stiffness_N_per_mm: tuple = (20000.0,) * 3     # default from the machine config
    mode_mass_kg: tuple = (25.0 / 3,) * 3               # default: platform mass / 3
    mode_damping_ratio: tuple = (0.02,) * 3
    enc_noise_mm: float = 0.0
    strain_noise_ue: float = 0.0
    seed: int = 0
    gravity_update_ticks: int = 10      # exact gravity strain every N ticks, secant-extrapolated between
    read_timeout_s: float = 0.005
    stall_at_tick: int = -1             # >= 0: from this tick on, read() blocks and times out
    lost_steps_at_tick: int = -1        # >= 0: at this tick the motor of lost_steps_axis slips
    lost_steps_axis: int = 0
    lost_steps_mm: float = 0.0

    @classmethod
    def from_dict(cls, d: dict, machine: Machine | None = None, where="sim"):
        kw = {}
        if machine is not None:
            kw["mode_stiffness_N_per_mm"] = (machine.stiffness.chain_axial,) * 3
            kw["mode_mass_kg"] = (machine.mass.platform_kg / 3,) * 3
        names = {f.name for f in fields(cls)}
        for k, v in d.items():
            if k not in names:
                raise ConfigError(where, k, "unknown sim option")
            kw[k] = v
        o = cls(**kw)
        if isinstance(o.gravity_update_ticks, bool) or not isinstance(o.gravity_update_ticks, int) \
                or o.gravity_update_ticks < 1:
            raise ConfigError(where, "gravity_update_ticks", "must be an integer >= 1")
        o.drive_tau_s = _vec(o.drive_tau_s, 5, where, "drive_tau_s", nonneg=True)
        o.mode_stiffness_N_per_mm = _vec(o.mode_stiffness_N_per_mm, 3, where, "mode_stiffness_N_per_mm", pos=True)
        o.mode_mass_kg = _vec(o.mode_mass_kg, 3, where, "mode_mass_kg", pos=True)
        o.mode_damping_ratio = _vec(o.mode_damping_ratio, 3, where, "mode_damping_ratio", nonneg=True)
        return o


def _vec(v, n, where, key, pos=False, nonneg=False):
    a = np.broadcast_to(np.asarray(v, float), (n,)).copy() if np.ndim(v) == 0 or len(v) == n else None
    if a is None or not np.all(np.isfinite(a)):
        raise ConfigError(where, key, f"must be a number or a list of {n} numbers, got {v!r}")
    if pos and np.any(a <= 0):
        raise ConfigError(where, key, "must be > 0")
    if nonneg and np.any(a < 0):
        raise ConfigError(where, key, "must be >= 0")
    return a


class SimBackend(Backend):
    name = "sim"
    accepts = "pulses"

    @classmethod
    def validate_options(cls, table: dict, where: str) -> SimOptions:
        try:
            return SimOptions.from_dict(table, None, where=where)
        except TypeError as e:
            raise ConfigError(where, "-", str(e)) from None

    def __init__(self, machine: Machine, dt: float, options: dict | SimOptions | None = None):
        self.machine, self.dt = machine, float(dt)
        o = options if isinstance(options, SimOptions) else SimOptions.from_dict(options or {}, machine)
        self.opt = o
        self.ppm = machine.resolution.pulses_per_mm
        tau = o.drive_tau_s
        self._lag = np.where(tau > 0, np.exp(-self.dt / np.where(tau > 0, tau, 1.0)), 0.0)
        self._tau = tau
        # Flexible mode transition matrices: x = (y, y'), x' = [[0, 1], [-w^2, -2 zeta w]] x.
        k_N_per_m = o.mode_stiffness_N_per_mm * 1e3
        self.omega = np.sqrt(k_N_per_m / o.mode_mass_kg)          # rad/s
        self.mode_hz = self.omega / (2 * math.pi)
        phi = np.empty((3, 2, 2))
        for i in range(3):
            w, z = self.omega[i], o.mode_damping_ratio[i]
            phi[i] = expm(np.array([[0.0, 1.0], [-w * w, -2 * z * w]]) * self.dt)
        self._phi = phi
        self._strain_per_mm = machine.strain_gain * o.mode_stiffness_N_per_mm   # microstrain per mm of y
        self._rng = np.random.default_rng(o.seed)
        # The per-tick path works on plain floats (5 axes: cheaper than numpy calls) and the
        # compiled core's FK for the gravity strain (pmctl.motion.ncore).
        self._ppm_l = [float(x) for x in self.ppm]
        self._tau_on = bool(np.any(tau > 0))
        self._tau_l = [float(x) for x in tau]
        self._lag_l = [float(x) for x in self._lag]
        self._ph = [[float(x) for x in (ph[0, 0], ph[0, 1], ph[1, 0], ph[1, 1])] for ph in phi]
        self._spm_l = [float(x) for x in self._strain_per_mm]
        self._n_enc = 5 if o.enc_noise_mm > 0 else 0
        self._n_noise = self._n_enc + (3 if o.strain_noise_ue > 0 else 0)
        self._noise, self._noise_i = [], 0
        self._fb = Feedback()
        self._fb.counts = np.zeros(5, np.int64)
        self._open = False

    # ---------------------------------------------------------------- Backend API
    def open(self, counts):
        self.counts = np.array(counts, dtype=np.int64)
        ppm = self._ppm_l
        cl = self.counts.tolist()
        self._cmd = [cl[i] / ppm[i] for i in range(5)]      # commanded position, mm
        self._motor = list(self._cmd)                       # motor-side position
        self._vm = [0.0] * 5                                # motor velocity over the last tick
        self._y = [0.0] * 3                                 # load - motor deflection, chains
        self._yd = [0.0] * 3
        self.tick = 0
        self._fb.seq = 0
        self._open = True
        from pmctl.core.kinematics import forward_platform
        from pmctl.motion.ncore import CompiledFK
        q = self.truth()
        P, R = forward_platform(q[:3], self.machine.geometry)
        self._fk = CompiledFK(self.machine, P, R, q)         # the load-side pose, for the gravity strain
        self._g_a = self._g_b = None            # last two exact (q, gravity strain) evaluations
        self._sample()

    def read(self):
        if not self._open:
            raise HalError("sim backend: read before open")
        o = self.opt
        if 0 <= o.stall_at_tick <= self.tick:
            time.sleep(o.read_timeout_s)
            raise HalTimeout(f"sim backend: no answer within {o.read_timeout_s * 1e3:.1f} ms "
                             f"(injected stall at tick {o.stall_at_tick})")
        return self._fb

    def write_pulses(self, pulses):
        self.counts += pulses
        cl = self.counts.tolist()
        ppm, dt = self._ppm_l, self.dt
        c_old, motor = self._cmd, self._motor
        c_new = [cl[i] / ppm[i] for i in range(5)]
        if self._tau_on:
            # first-order lag, exact for the ramp the command makes inside the tick
            m_new = [0.0] * 5
            for i in range(5):
                tv = self._tau_l[i] * ((c_new[i] - c_old[i]) / dt)
                m_new[i] = c_new[i] - tv + (motor[i] - c_old[i] + tv) * self._lag_l[i]
        else:
            m_new = list(c_new)
        if self.tick == self.opt.lost_steps_at_tick:
            m_new[self.opt.lost_steps_axis] += self.opt.lost_steps_mm
        vm = [(m_new[i] - motor[i]) / dt for i in range(5)]
        if self.opt.flex:
            y, yd0, vm0 = self._y, self._yd, self._vm
            for i in range(3):
                a, b, c, d = self._ph[i]
                yd = yd0[i] - (vm[i] - vm0[i])          # velocity jump of the motor frame
                y[i], yd0[i] = a * y[i] + b * yd, c * y[i] + d * yd
        self._cmd, self._motor, self._vm = c_new, m_new, vm
        self.tick += 1
        self._sample()

    def truth(self):
        """Load-side joints (mm): motor side plus the chains' deflection."""
        m, y = self._motor, self._y
        return np.array([m[0] + y[0], m[1] + y[1], m[2] + y[2], m[3], m[4]])

    def status(self):
        return Status(True, "")

    def close(self):
        self._open = False

    # ---------------------------------------------------------------- internals
    def _gravity_strain(self):
        """Static strain of the platform's weight at the true (load-side) pose (list of 3). Exact (FK
        warm-started with the predictor) every ``gravity_update_ticks`` ticks; in between
        extrapolated along the motion from the last two exact values (the strain changes by ~0.1
        microstrain per mm)."""
        m, y = self._motor, self._y
        q = [m[0] + y[0], m[1] + y[1], m[2] + y[2], m[3], m[4]]
        a, b = self._g_a, self._g_b
        n = self.opt.gravity_update_ticks
        if a is not None and n > 1 and self.tick % n:
            if b is None:
                return a[1]
            qa, ga = a
            qb, gb = b
            d = [qa[i] - qb[i] for i in range(5)]
            dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2] + d[3] * d[3] + d[4] * d[4]
            if dd <= 0.0:
                return ga
            f = sum((q[i] - qa[i]) * d[i] for i in range(5)) / dd
            return [ga[i] + (ga[i] - gb[i]) * f for i in range(3)]
        fk = self._fk
        fk.solve(np.array(q))
        g = fk.static_strain().tolist()
        self._g_b, self._g_a = self._g_a, (q, g)
        return g

    def _draw(self):
        """Next row of Gaussian noise (encoders, then gauges), drawn from the seeded RNG in blocks."""
        if self._noise_i >= len(self._noise):
            self._noise = self._rng.standard_normal((512, self._n_noise)).tolist()
            self._noise_i = 0
        r = self._noise[self._noise_i]
        self._noise_i += 1
        return r

    def _sample(self):
        fb, o = self._fb, self.opt
        fb.seq += 1
        fb.counts[:] = self.counts
        nz = self._draw() if self._n_noise else None
        if self._n_enc:
            e, m = o.enc_noise_mm, self._motor
            fb.enc[:] = [m[i] + e * nz[i] for i in range(5)]
        else:
            fb.enc[:] = self._motor
        g = self._gravity_strain()
        spm, y = self._spm_l, self._y
        s = [spm[i] * y[i] + g[i] for i in range(3)]
        if o.strain_noise_ue > 0:
            k, e = self._n_enc, o.strain_noise_ue
            s = [s[i] + e * nz[k + i] for i in range(3)]
        fb.strain[:] = s
