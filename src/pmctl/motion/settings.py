"""A run's settings, resolved once: the machine config, the service config with the run's overrides
applied, the backend, the tick rate, the NC setup (chain modes, K_theta as resolved, the shaper) and
the NC parameters built from them.

:func:`resolve` reads the files. It runs once in the supervisor's process (pmctl run and pmctl
serve alike); the rt motion process gets the resulting :class:`Settings` as data over its spawn pipe
and never opens a config file, so both sides run the same settings whatever the files say later
(a restart after ``$X`` reuses them). This is LinuxCNC's seam between task and motion: motion never
reads the INI file."""

from __future__ import annotations

import copy
import pickle
from dataclasses import dataclass, field, replace

import numpy as np

from pmctl.core.config import Machine, load_machine
from pmctl.motion.service_config import NCSetup, ServiceConfig, load_service_config, nc_setup


@dataclass
class Settings:
    machine: Machine
    svc: ServiceConfig                 # the service config, the run's overrides applied, K_theta resolved
    backend: str                       # hal backend name
    rate_hz: float                     # the tick rate
    setup: NCSetup                     # chain modes, the shaper, and what was said about them
    params: object                     # pmctl.motion.nc.NCParams for this machine at this rate
    realtime: bool = False             # the rt process keeps real time (a paced run)
    offline: bool = False              # ticks back to back, waiting for samples (--no-realtime)
    nc_overrides: dict = field(default_factory=dict)    # what the run changed (--k-theta --shaper --pulse-mode)
    hal_overrides: dict = field(default_factory=dict)   # ... and in the backend tables (--bridge)

    @property
    def dt(self) -> float:
        return 1.0 / self.rate_hz

    def to_bytes(self) -> bytes:
        """The settings as data for the rt process's spawn pipe."""
        return pickle.dumps(self, protocol=pickle.HIGHEST_PROTOCOL)

    @staticmethod
    def from_bytes(b: bytes) -> "Settings":
        s = pickle.loads(b)
        if not isinstance(s, Settings):
            raise TypeError(f"not pmctl settings: {type(s).__name__}")
        return s


def apply_nc_overrides(svc: ServiceConfig, nc: dict | None) -> ServiceConfig:
    """A run's NC settings that differ from the service config file (``pmctl run --k-theta --shaper
    --pulse-mode``), applied to ``svc.nc``. Gains given for ``k_theta_per_s`` replace a file's
    ``"auto"`` unless ``k_theta_auto`` is given too."""
    for key, v in (nc or {}).items():
        if key == "k_theta_per_s":
            v = tuple(float(x) for x in v)
            if "k_theta_auto" not in nc:
                svc.nc.k_theta_auto = False
        setattr(svc.nc, key, v)
    return svc


def apply_hal_overrides(svc: ServiceConfig, hal: dict | None) -> ServiceConfig:
    """A run's backend options that differ from the service config file (``pmctl run --bridge``:
    ``{"stepdir": {"port": "rp2040-emu"}}``), applied to ``svc.backend_tables``."""
    for name, table in (hal or {}).items():
        svc.backend_tables[name] = {**svc.backend_tables.get(name, {}), **table}
    return svc


OFFLINE_SIM_TIMEOUT_MS = 3000.0    # a simulated VFD's or DAQ's answer in an offline run (--no-realtime)


def _relax_simulated_devices(svc: ServiceConfig):
    """An offline run (``pmctl run --no-realtime``) is a simulation in which nothing is late, and a
    loop without real-time priority (``pmctl serve --no-realtime``, ``realtime = false``: a desktop or
    a CI machine) has no timing to defend: there the simulated spindle VFD and strain DAQ
    (``simulate = true``, served on the loopback by a device-simulator process) get at least
    OFFLINE_SIM_TIMEOUT_MS to answer and for their data to count as fresh, so a loaded host (other
    processes taking the CPU) is not a lost link. Real devices keep their timeouts, and so do
    simulated ones under real-time priority (the hardware-in-the-loop setting)."""
    for dev in (svc.spindle, svc.daq):
        if dev is not None and getattr(dev, "simulate", False):
            dev.timeout_ms = max(float(dev.timeout_ms), OFFLINE_SIM_TIMEOUT_MS)
            if hasattr(dev, "max_age_ms"):
                dev.max_age_ms = max(float(dev.max_age_ms), OFFLINE_SIM_TIMEOUT_MS)


def _cap_to_backend(params, svc: ServiceConfig, backend: str, notes: list):
    """The joint speeds capped to the step rate a step/dir bridge holds ([hal.stepdir] max_step_rate_hz;
    the emulated RP2040's own rate): the planner and the NC then stay within what it can emit, and
    the job takes longer instead of the bridge falling behind its step schedule mid-job."""
    if backend != "stepdir":
        return params
    from pmctl.hal.stepdir import StepDirOptions  # lazy: a backend's module loads when it is the backend
    o = StepDirOptions.from_dict(dict(svc.backend_tables.get("stepdir", {})), f"{svc.source}: [hal.stepdir]")
    rate = o.step_rate_cap()
    if not rate:
        return params
    cap = rate / np.asarray(params.pulses_per_mm, float)
    if not np.any(params.vmax > cap + 1e-12):
        return params
    vmax = np.minimum(params.vmax, cap)
    notes.append(f"step/dir bridge {o.port}: {rate / 1e3:g} kstep/s per axis: joint speeds capped at "
                 f"{vmax[:3].min():.3g} mm/s (chains) and {vmax[3:].min():.3g} mm/s (table)")
    return replace(params, vmax=vmax)


def resolve(config="prototype", service=None, *, backend=None, rate_hz=None, realtime=None, offline=None,
            nc=None, hal=None, machine=None, svc=None) -> Settings:
    """Read the machine config ``config`` and the service config ``service`` (None: the shipped one),
    apply the run's overrides and resolve the NC setup: every check of a setting against the machine
    and the backend happens here, before any device opens or anything moves. ``realtime`` None: the
    service config's ``[loop] realtime``; ``offline`` None: not ``realtime``. ``machine`` and ``svc``:
    already loaded ones (not read again; ``svc`` is copied, the overrides go to the copy)."""
    machine = machine if machine is not None else load_machine(config)
    svc = copy.deepcopy(svc) if svc is not None else load_service_config(service)
    svc = apply_hal_overrides(apply_nc_overrides(svc, nc), hal)
    backend = backend or svc.backend
    rate_hz = float(rate_hz or svc.loop.rate_hz)
    svc.loop.rate_hz = rate_hz
    realtime = bool(svc.loop.realtime if realtime is None else realtime)
    offline = (not realtime) if offline is None else bool(offline)
    svc.loop.realtime = realtime
    if offline or not realtime:
        _relax_simulated_devices(svc)
    dt = 1.0 / rate_hz
    # chain modes, K_theta auto (off on a backend without strain), the shaper; [daq] k_theta_source
    setup = nc_setup(svc, machine, dt, backend)
    params = svc.nc.params(machine, dt, where=svc.source, modes=setup.modes)
    if np.any(params.vmax < machine.limits.joint_speed - 1e-9):
        setup.notes.append(f"V-F converters limit the joints to {params.vmax.min():.3g} mm/s at {rate_hz:g} Hz: "
                           f"planning with that")
    params = _cap_to_backend(params, svc, backend, setup.notes)
    svc.homing.check(params, svc.source)             # [homing] against this machine's joints
    return Settings(machine=machine, svc=svc, backend=backend, rate_hz=rate_hz, setup=setup, params=params,
                    realtime=bool(realtime), offline=bool(offline), nc_overrides=dict(nc or {}),
                    hal_overrides=dict(hal or {}))
