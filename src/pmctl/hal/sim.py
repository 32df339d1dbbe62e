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
- **measurement noise**: Gaussian on encoders (mm) and strain (microstrain), seeded RNG;
- **contact and applied load** (off by default): a plane z = ``contact_z_mm`` in W that pushes back on
  the tool tip with ``contact_stiffness_N_per_mm`` times the depth the tip has entered it, and a
  constant force ``tip_force_N`` (base axes) on the tip. Their sum goes through the statics
  (pmctl.core.statics, the tip force at the load-side pose) into the three strains, per tick, in
  Python after the C step (about 0.1-0.3 ms a tick while on). It does not deflect the chains' modes
  nor stop the tip: a surface stiff against the probing feed, read by the gauges.
- **the effect catalogue** (a misbehaving machine; pmctl.core.plant_effects, docs/service.md):
  friction adds the position loop's following error to the motor side (the encoders see it);
  backlash (play operator), periodic screw error (pitch) and thermal growth of the screw position
  sit between motor and load (only the load side, so the true tip and the gauges, see them).
  With all of them zero the tick is the C step alone; else the C step moves drive and modes, the
  effects follow the new motor position in Python, and the C sample reads the feedback.

The true tool tip is FK(load-side joints) (:meth:`truth` gives them). The per-tick step is C
(simplant.c, built at install with the compiled NC core, whose FK it uses for the gravity strain). Fault injection for tests:
a stall (``read`` blocks, then times out) and lost steps (the motor slips by a given amount).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, fields

import numpy as np

from pmctl.core import plant_effects as PE
from pmctl.core import statics
from pmctl.core.config import Machine
from pmctl.core.kinematics import forward_platform, tool_of_platform
from pmctl.core.plant_effects import SCREW_FIXED_END_MM
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
    # ---- contact and applied load (a surface to probe, a known force at the tool tip)
    contact_z_mm: float | None = None   # a plane z = this (tool tip in W, mm) resisting the tip below it
    contact_stiffness_N_per_mm: float = 2000.0
    tip_force_N: tuple = (0.0, 0.0, 0.0)   # constant force on the tool tip, N, base axes
    # ---- the effect catalogue (pmctl.core.plant_effects), per axis L1 L2 L3 X Y; all 0 = off
    backlash_mm: tuple = (0.0,) * 5                     # play (deadband) width between motor and load
    backlash_start: tuple = (0.0,) * 5                  # where the load rests in the play at open, -1..1
    pitch_error_amp_mm: tuple = (0.0,) * 5              # periodic screw error A·sin(2π·s/P + φ)
    pitch_error_period_mm: tuple = (5.0,) * 5          # default: the machine's screw leads
    pitch_error_phase_rad: tuple = (0.0,) * 5
    thermal_delta_K: tuple = (0.0,) * 5                 # screw temperature over the calibration's
    thermal_alpha_per_K: tuple = (11.5e-6,) * 5         # expansion coefficient (steel)
    thermal_fixed_end_mm: tuple = tuple(SCREW_FIXED_END_MM)   # the screw's fixed bearing (growth 0 there)
    friction_coulomb_mm: tuple = (0.0,) * 5             # following error against Coulomb friction
    friction_stribeck_mm: tuple = (0.0,) * 5            # ... plus the Stribeck term at low speed
    friction_stribeck_speed_mm_s: tuple = (2.0,) * 5

    @property
    def effects_on(self) -> bool:
        """Any catalogue effect set (else the plant's tick is the C step alone)."""
        return bool(np.any(np.asarray(self.backlash_mm) != 0) or np.any(np.asarray(self.pitch_error_amp_mm) != 0)
                    or np.any(np.asarray(self.thermal_delta_K) != 0) or np.any(np.asarray(self.friction_coulomb_mm) != 0)
                    or np.any(np.asarray(self.friction_stribeck_mm) != 0))
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
            r = machine.resolution
            base.pitch_error_period_mm = (r.screw_lead,) * 3 + (r.table_screw_lead,) * 2
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
            **cls._effect_options(t, base),
            motor_offset_mm=(t.vector("motor_offset_mm", 5, default=[0.0] * 5, lo=-1e3, hi=1e3, scalar_ok=True)
                             if "motor_offset_mm" in d else None),
        )
        # ---- contact and applied load
        if d.get("contact_z_mm") is not None:
            o.contact_z_mm = t.number("contact_z_mm", lo=-1e4, hi=1e4)
        o.contact_stiffness_N_per_mm = t.number("contact_stiffness_N_per_mm", default=base.contact_stiffness_N_per_mm,
                                                positive=True, hi=1e9)
        o.tip_force_N = tuple(float(x) for x in t.vector("tip_force_N", 3, default=base.tip_force_N, lo=-1e6, hi=1e6))
        t.finish()
        return o

    @staticmethod
    def _effect_options(t, base) -> dict:
        """The effect catalogue's options, each one number for all axes or one per axis."""
        def v(name, **rng):
            return t.vector(name, 5, default=getattr(base, name), scalar_ok=True, **rng)
        return dict(
            backlash_mm=v("backlash_mm", nonneg=True, hi=10.0),
            backlash_start=v("backlash_start", lo=-1.0, hi=1.0),
            pitch_error_amp_mm=v("pitch_error_amp_mm", lo=-10.0, hi=10.0),
            pitch_error_period_mm=v("pitch_error_period_mm", positive=True, hi=1e4),
            pitch_error_phase_rad=v("pitch_error_phase_rad", lo=-1e3, hi=1e3),
            thermal_delta_K=v("thermal_delta_K", lo=-200.0, hi=500.0),
            thermal_alpha_per_K=v("thermal_alpha_per_K", lo=-1e-3, hi=1e-3),
            thermal_fixed_end_mm=v("thermal_fixed_end_mm", lo=-1e4, hi=1e4),
            friction_coulomb_mm=v("friction_coulomb_mm", nonneg=True, hi=10.0),
            friction_stribeck_mm=v("friction_stribeck_mm", nonneg=True, hi=10.0),
            friction_stribeck_speed_mm_s=v("friction_stribeck_speed_mm_s", positive=True, hi=1e4),
        )


class SimBackend(Backend):
    stall_hold = True          # the plant advances with the ticks: a stall moves nothing (base.Backend)
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
        phi = np.array([PE.mode_transition(self.mode_hz[i], o.mode_damping_ratio[i], self.dt) for i in range(3)])
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
        self._effects = o.effects_on
        self._off = None            # plant counters - controller counters (motor_offset_mm, homing), or None
        self._open = False
        # ---- contact and applied load
        self._load_on = o.contact_z_mm is not None or any(o.tip_force_N)
        self._per_N, self._per_N_tick = None, -1

    # ---------------------------------------------------------------- Backend API
    def open(self, counts):
        from pmctl.core.errors import KinematicsError
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
        if self._effects:
            self._start_effects(d)
        r = self._plant.sample(self._draw(), 0)
        self._relative()
        self._check(r)
        if self._load_on:
            self._add_load()

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
        if self._effects:
            self._step_effects(pulses, nz)
            if self._load_on:
                self._add_load()
            return
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
        if self._load_on:
            self._add_load()

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

    # ---------------------------------------------------------------- contact and applied load
    def tip_force(self):
        """The force on the tool tip this tick (N, base axes): the applied one plus the contact's."""
        return self._tip_force_now.copy() if self._load_on else np.zeros(3)

    def _add_load(self):
        """Add the strain of this tick's tip force (contact + applied) at the load-side pose."""
        o, g = self.opt, self.machine.geometry
        q = self._q
        P, R = forward_platform(q[:3], g)
        f = np.array(o.tip_force_N, float)
        if o.contact_z_mm is not None:
            tip_w, _ = tool_of_platform(P, R, q[3:5], g)
            depth = o.contact_z_mm - float(tip_w[2])
            if depth > 0.0:
                f[2] += o.contact_stiffness_N_per_mm * depth
        self._tip_force_now = f
        if not f.any():
            return
        if self._per_N is None or self.tick - self._per_N_tick >= o.gravity_update_ticks:
            # strain per N of tip force (3 x 3), refreshed with the gravity strain's period
            s0 = statics.static_strain(P, R, self.machine)
            Pb, Rb = np.broadcast_to(P, (3, 3)), np.broadcast_to(R, (3, 3, 3))
            self._per_N = (statics.static_strain(Pb, Rb, self.machine, tip_force=np.eye(3)) - s0).T
            self._per_N_tick = self.tick
        self._fb.strain += self._per_N @ f

    # ---------------------------------------------------------------- internals
    def _start_effects(self, d):
        """The effects' state at the opening position (pmctl.core.plant_effects, per tick); only the
        effects that are set take time in the tick."""
        o, L = self.opt, self._lib
        self._moff = d[L.D_MOFF:L.D_MOFF + 5]
        self._loff = d[L.D_LOFF:L.D_LOFF + 5]
        self._cmd = d[L.D_CMD:L.D_CMD + 5]
        self._mot = d[L.D_MOTOR:L.D_MOTOR + 5]
        self._play = PE.Play(o.backlash_mm, self._mot, o.backlash_start) if np.any(o.backlash_mm) else None
        self._friction = (PE.Friction(self._cmd, self.dt, o.friction_coulomb_mm, o.friction_stribeck_mm,
                                      o.friction_stribeck_speed_mm_s)
                          if np.any(o.friction_coulomb_mm) or np.any(o.friction_stribeck_mm) else None)
        self._pitch = (PE.PeriodicError(o.pitch_error_amp_mm, o.pitch_error_period_mm, o.pitch_error_phase_rad)
                       if np.any(o.pitch_error_amp_mm) else None)
        self._thermal = np.any(o.thermal_delta_K) and np.any(o.thermal_alpha_per_K)
        self._zero5 = np.zeros(5)
        self._set_offsets(self._play.error if self._play is not None else 0.0, self._zero5)

    def _set_offsets(self, play_err, moff):
        """Motor side = drive + friction (the encoders see it); load side = that + play + screw
        errors (pitch/periodic, thermal growth) of the screw position."""
        o = self.opt
        s = self._mot + moff
        self._moff[:] = moff
        loff = play_err
        if self._pitch is not None:
            loff = loff + self._pitch(s)
        if self._thermal:
            loff = loff + PE.thermal_growth(s, o.thermal_alpha_per_K, o.thermal_delta_K, o.thermal_fixed_end_mm)
        self._loff[:] = loff

    def _step_effects(self, pulses, nz):
        """One tick with the effects: the C step moves drive and modes, the effects follow the new
        motor position here, then the C sample reads encoders, load-side pose and strain."""
        try:
            self._plant.step(pulses, None, self.tick, True)
        except (TypeError, ValueError):
            self._plant.step(np.ascontiguousarray(pulses, np.int64), None, self.tick, True)
        moff = self._friction.step(self._cmd) if self._friction is not None else self._zero5
        self._set_offsets(self._play.step(self._mot + moff) if self._play is not None else 0.0, moff)
        self.tick += 1
        self._fb.seq += 1
        r = self._plant.sample(nz, self.tick)
        if self._off is not None:
            self._relative()
        self._check(r)

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
