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
from pmctl.hal.base import Backend, Feedback, HalError, HalTimeout, Inputs, Status


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
    estop_from_tick: int = -1           # >= 0: the E-stop input reads pressed from this tick ...
    estop_to_tick: int = -1             # ... until this tick (-1: for ever)
    home_switch_mm: tuple | None = None  # per axis: the home switch closes at motor position >= this

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
        if o.home_switch_mm is not None:
            o.home_switch_mm = _vec(o.home_switch_mm, 5, where, "home_switch_mm")
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
        from pmctl.motion.nc import ModelFK
        self._fk = ModelFK(machine)          # the load-side pose, for the gravity strain
        self._fb = Feedback()
        self._fb.counts = np.zeros(5, np.int64)
        self._open = False

    # ---------------------------------------------------------------- Backend API
    def open(self, counts):
        self.counts = np.array(counts, dtype=np.int64)
        self.cmd = self.counts / self.ppm          # commanded position, mm
        self.motor = self.cmd.copy()               # motor-side position
        self.vmotor = np.zeros(5)                  # motor velocity over the last tick
        self.y = np.zeros(3)                       # load - motor deflection, chains
        self.ydot = np.zeros(3)
        self.tick = 0
        self._fb.seq = 0
        self._open = True
        from pmctl.core.kinematics import forward_platform
        q = self.truth()
        P, R = forward_platform(q[:3], self.machine.geometry)
        self._pose = (P.tolist(), R.tolist(), None, q)
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
        p = np.asarray(pulses)
        self.counts += p
        c_old = self.cmd
        c_new = self.counts / self.ppm
        v = (c_new - c_old) / self.dt
        if self._tau.any():
            tv = self._tau * v
            m_new = c_new - tv + (self.motor - c_old + tv) * self._lag
        else:
            m_new = c_new
        if self.tick == self.opt.lost_steps_at_tick:
            m_new = m_new.copy()
            m_new[self.opt.lost_steps_axis] += self.opt.lost_steps_mm
        vm = (m_new - self.motor) / self.dt
        if self.opt.flex:
            yd = self.ydot - (vm[:3] - self.vmotor[:3])        # velocity jump of the motor frame
            ph = self._phi
            y = ph[:, 0, 0] * self.y + ph[:, 0, 1] * yd
            self.ydot = ph[:, 1, 0] * self.y + ph[:, 1, 1] * yd
            self.y = y
        self.cmd, self.motor, self.vmotor = c_new, m_new, vm
        self.tick += 1
        self._sample()

    def inputs(self):
        o = self.opt
        est = 0 <= o.estop_from_tick <= self.tick and (o.estop_to_tick < 0 or self.tick < o.estop_to_tick)
        home = None
        if o.home_switch_mm is not None:
            home = tuple(bool(self.motor[i] >= o.home_switch_mm[i]) for i in range(5))
        return Inputs(home, est)

    def truth(self):
        q = self.motor.copy()
        q[:3] += self.y
        return q

    def status(self):
        return Status(True, "")

    def close(self):
        self._open = False

    # ---------------------------------------------------------------- internals
    def _gravity_strain(self):
        """Static strain of the platform's weight at the true (load-side) pose. Exact (FK warm-started,
        one Newton step) every ``gravity_update_ticks`` ticks; in between extrapolated along the
        motion from the last two exact values (the strain changes by ~0.1 microstrain per mm)."""
        q = self.truth()
        a, b = self._g_a, self._g_b
        n = self.opt.gravity_update_ticks
        if a is not None and n > 1 and self.tick % n:
            if b is None:
                return a[1]
            d = a[0] - b[0]
            dd = float(d @ d)
            if dd <= 0.0:
                return a[1]
            return a[1] + (a[1] - b[1]) * (float((q - a[0]) @ d) / dd)
        P, R, T, q0 = self._pose
        pred = None if T is None else ((q - q0)[:3], T)
        P, R, _, _, _ = self._fk.solve_l(q, P, R, pred)
        T = self._fk.last_T
        self._pose = (P, R, T, q)
        g = np.array(self._fk.static_strain(R, T))
        self._g_b, self._g_a = self._g_a, (q, g)
        return g

    def _sample(self):
        fb, o = self._fb, self.opt
        fb.seq += 1
        fb.counts[:] = self.counts
        if o.enc_noise_mm > 0:
            fb.enc[:] = self.motor + o.enc_noise_mm * self._rng.standard_normal(5)
        else:
            fb.enc[:] = self.motor
        s = self._strain_per_mm * self.y + self._gravity_strain()
        if o.strain_noise_ue > 0:
            s = s + o.strain_noise_ue * self._rng.standard_normal(3)
        fb.strain[:] = s
