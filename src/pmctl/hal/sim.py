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
  load of the true (load-side) platform pose (pmctl.core.statics, docs/diagnosis-report.md §1) plus the spring
  force k * y of the flexible mode (microstrain, tension positive);
- **measurement noise**: Gaussian on encoders (mm) and strain (microstrain), seeded RNG.

The true tool tip is FK(load-side joints) (:meth:`truth` gives them). The per-tick step is C
(simplant.c, built at install with the compiled NC core, whose FK it uses for the gravity strain). Fault injection for tests:
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
    motor_offset_mm: tuple | None = None  # per axis: at open the motors stand this far from where the counters
                                          # say (a position lost in a power cut); encoders and device counters
                                          # count from the counters, only the truth and the switches see it

    @classmethod
    def from_dict(cls, d: dict, machine: Machine | None = None, where="sim"):
        """Strictly validated options (the ``[hal.sim]`` table): every key known, every value of its
        exact type (no string or bool for a number, no string for a bool) and within range; a vector
        option takes one number for all axes or one per axis. ConfigError(where, key, reason)."""
        import difflib

        from pmctl.core.strict_toml import Table
        if isinstance(d, SimOptions):
            d = {f.name: getattr(d, f.name) for f in fields(cls)}
        base = cls()
        if machine is not None:
            base.mode_stiffness_N_per_mm = (machine.stiffness.chain_axial,) * 3
            base.mode_mass_kg = (machine.mass.platform_kg / 3,) * 3
        t = Table(where, d, "")
        names = [f.name for f in fields(cls)]
        for k in d:
            if k not in names:
                near = difflib.get_close_matches(str(k), names, n=1)
                raise ConfigError(where, k, "unknown sim option" + (f" (did you mean '{near[0]}'?)" if near else ""))
        big = 2**62
        o = cls(
            drive_tau_s=t.vector("drive_tau_s", 5, default=base.drive_tau_s, nonneg=True, hi=1e3, scalar_ok=True),
            flex=t.boolean("flex", default=base.flex),
            mode_stiffness_N_per_mm=t.vector("mode_stiffness_N_per_mm", 3, default=base.mode_stiffness_N_per_mm,
                                             positive=True, hi=1e10, scalar_ok=True),
            mode_mass_kg=t.vector("mode_mass_kg", 3, default=base.mode_mass_kg, positive=True, hi=1e5,
                                  scalar_ok=True),
            mode_damping_ratio=t.vector("mode_damping_ratio", 3, default=base.mode_damping_ratio, nonneg=True,
                                        hi=100.0, scalar_ok=True),
            enc_noise_mm=t.number("enc_noise_mm", default=base.enc_noise_mm, nonneg=True, hi=1e3),
            strain_noise_ue=t.number("strain_noise_ue", default=base.strain_noise_ue, nonneg=True, hi=1e6),
            seed=t.integer("seed", default=base.seed, lo=0, hi=2**63 - 1),
            gravity_update_ticks=t.integer("gravity_update_ticks", default=base.gravity_update_ticks, lo=1, hi=10**6),
            read_timeout_s=t.number("read_timeout_s", default=base.read_timeout_s, positive=True, hi=1.0),
            stall_at_tick=t.integer("stall_at_tick", default=base.stall_at_tick, lo=-1, hi=big),
            lost_steps_at_tick=t.integer("lost_steps_at_tick", default=base.lost_steps_at_tick, lo=-1, hi=big),
            lost_steps_axis=t.integer("lost_steps_axis", default=base.lost_steps_axis, lo=0, hi=4),
            lost_steps_mm=t.number("lost_steps_mm", default=base.lost_steps_mm, lo=-1e3, hi=1e3),
            estop_from_tick=t.integer("estop_from_tick", default=base.estop_from_tick, lo=-1, hi=big),
            estop_to_tick=t.integer("estop_to_tick", default=base.estop_to_tick, lo=-1, hi=big),
            home_switch_mm=(t.vector("home_switch_mm", 5, default=[0.0] * 5, lo=-1e4, hi=1e4, scalar_ok=True)
                            if "home_switch_mm" in d else None),
            motor_offset_mm=(t.vector("motor_offset_mm", 5, default=[0.0] * 5, lo=-1e3, hi=1e3, scalar_ok=True)
                             if "motor_offset_mm" in d else None),
        )
        t.finish()
        return o


class SimBackend(Backend):
    name = "sim"
    accepts = "pulses"
    can_rereference = True

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
        # The per-tick step runs in C (simplant.c, built at install with the NC core): drive, flexible
        # modes, gravity strain (the core's FK, exact every gravity_update_ticks ticks, extrapolated
        # between) and the feedback sample, on the buffers below.
        from pmctl.hal import _simplant
        from pmctl.motion.ncore import constants
        self._fk_consts = constants(machine, None)
        k = np.zeros(_simplant.K_LEN)
        k[0:5] = self.ppm
        k[5] = self.dt
        k[6] = float(np.any(tau > 0))
        k[7:12] = tau
        k[12:17] = self._lag
        k[17:29] = phi.reshape(3, 4).ravel()
        k[29] = float(bool(o.flex))
        k[30:33] = self._strain_per_mm
        k[33] = float(o.lost_steps_at_tick)
        k[34] = float(o.lost_steps_axis)
        k[35] = float(o.lost_steps_mm)
        k[36] = float(o.enc_noise_mm)
        k[37] = float(o.strain_noise_ue)
        k[38] = float(o.gravity_update_ticks)
        k[39] = 5.0 if o.enc_noise_mm > 0 else 0.0
        self._k = k
        self._lib = _simplant
        self._n_noise = (5 if o.enc_noise_mm > 0 else 0) + (3 if o.strain_noise_ue > 0 else 0)
        self._noise, self._noise_i = None, 0
        self._fb = Feedback()
        self._fb.counts = np.zeros(5, np.int64)
        self._off = None            # plant counters - controller counters (motor_offset_mm, homing), or None
        self._open = False

    # ---------------------------------------------------------------- Backend API
    def open(self, counts):
        from pmctl.core.errors import KinematicsError
        from pmctl.core.kinematics import forward_platform
        L = self._lib
        self.counts = np.array(counts, dtype=np.int64)
        if self.opt.motor_offset_mm is not None:
            self._off = np.rint(np.asarray(self.opt.motor_offset_mm) * self.ppm).astype(np.int64)
            self.counts += self._off
        d = np.zeros(L.D_LEN)
        d[L.D_CMD:L.D_CMD + 5] = self.counts / self.ppm          # commanded position, mm
        d[L.D_MOTOR:L.D_MOTOR + 5] = d[L.D_CMD:L.D_CMD + 5]     # motor side = command at rest
        P, R = forward_platform(d[L.D_MOTOR:L.D_MOTOR + 3], self.machine.geometry)
        d[L.D_P:L.D_P + 3] = P
        d[L.D_R:L.D_R + 9] = R.ravel()
        self._d = d
        self._q = d[L.D_Q:L.D_Q + 5]
        self._plant = L.Plant(self._fk_consts, self._k, d, self.counts, self._fb.enc, self._fb.strain,
                              self._fb.counts)
        self._KinematicsError = KinematicsError
        self.tick = 0
        self._fb.seq = 1
        self._open = True
        r = self._plant.sample(self._draw(), 0)
        self._relative()
        self._check(r)

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
        nz = self._draw() if self._n_noise else None
        try:
            r = self._plant.step(pulses, nz, self.tick)
        except (TypeError, ValueError):          # not a contiguous int64 array: convert (checked before any change)
            r = self._plant.step(np.ascontiguousarray(pulses, np.int64), nz, self.tick)
        self.tick += 1
        self._fb.seq += 1
        if self._off is not None:
            self._relative()
        if r:
            self._check(r)

    def inputs(self):
        o = self.opt
        est = 0 <= o.estop_from_tick <= self.tick and (o.estop_to_tick < 0 or self.tick < o.estop_to_tick)
        home = None
        if o.home_switch_mm is not None:
            m = self._d[self._lib.D_MOTOR:self._lib.D_MOTOR + 5]
            home = tuple(bool(m[i] >= o.home_switch_mm[i]) for i in range(5))
        return Inputs(home, est)

    def rereference(self, counts):
        """The device counters and encoders read from ``counts`` on (the motors stay where they are)."""
        self._off = self.counts - np.asarray(counts, np.int64)
        self._fb.counts[:] = self.counts
        self._fb.enc[:] = self._d[self._lib.D_MOTOR:self._lib.D_MOTOR + 5]
        self._relative()

    def truth(self):
        """Load-side joints (mm): motor side plus the chains' deflection."""
        return self._q.copy()

    def status(self):
        return Status(True, "")

    def close(self):
        self._open = False

    # ---------------------------------------------------------------- internals
    def _relative(self):
        """Device counters and encoders as the controller knows them (plant counters minus the offset)."""
        if self._off is not None:
            self._fb.counts -= self._off
            self._fb.enc -= self._off / self.ppm

    def _check(self, r):
        if r:
            raise self._KinematicsError(f"sim backend: the load-side pose is lost (forward kinematics, event {r})")

    def _draw(self):
        """Next row of Gaussian noise (encoders, then gauges) from the seeded RNG, drawn in blocks."""
        if not self._n_noise:
            return None
        if self._noise is None or self._noise_i >= len(self._noise):
            self._noise = np.zeros((512, 8))
            self._noise[:, :self._n_noise] = self._rng.standard_normal((512, self._n_noise))
            self._noise_i = 0
        r = self._noise[self._noise_i]
        self._noise_i += 1
        return r
