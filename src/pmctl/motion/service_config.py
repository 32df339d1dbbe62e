"""The service config (config/service.toml): the loop, the NC gains and the HAL backend with its
options. Read strictly (pmctl.core.strict_toml: UTF-8, unknown tables and keys refused, no
coercion, integers are TOML integers, every number finite and within its range) and validated
whole on load: a bad value is reported with file, key and reason, and nothing is half-applied.
Each ``[hal.<backend>]`` table is validated by its backend's ``validate_options`` (pmctl.hal),
whether or not that backend is the one selected."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pmctl.core.config import CONFIG_DIR, Machine
from pmctl.core.errors import ConfigError
from pmctl.core.strict_toml import Table, check_tables, read_toml
from pmctl.hal.base import AXES as HOMING_AXES

from pmctl.motion.nc import IMPLEMENTATIONS, NCParams


@dataclass
class LoopConfig:
    rate_hz: float = 1000.0
    realtime: bool = True
    rt_priority: int = 50
    lock_memory: bool = True
    max_overruns_in_row: int = 10
    stall_timeout_s: float = 0.05
    settle_s: float = 0.05
    persist_every_ticks: int = 100
    state_file: str = ""            # "" = no persistence
    spin_us: float = 0.0            # busy-wait this long before each deadline (keeps a VM's CPU awake)

    @property
    def dt(self):
        return 1.0 / self.rate_hz


@dataclass
class NCConfig:
    kv_per_s: float = 400.0
    damping: float = 0.05
    sv_threshold: float = 0.05
    pulse_mode: str = "multi"       # "multi": integer pulses per tick up to the speed limit; "single": seed's 1/tick
    k_theta_per_s: tuple = (0.0, 0.0, 0.0)
    ferror_mm: float = 1.0
    min_ferror_mm: float = 0.01
    max_path_error_mm: float = 0.5
    implementation: str = "compiled"   # the loop's NC: "compiled" (C core) or "python" (the reference, nc.nc_step)

    def params(self, machine: Machine, dt: float, where="service config") -> NCParams:
        if self.kv_per_s * dt >= 1.0:
            raise ConfigError(where, "nc.kv_per_s",
                              f"{self.kv_per_s:g}/s at {1 / dt:g} Hz gives kv*dt = {self.kv_per_s * dt:.2f}; "
                              f"must be < 1 for a stable loop (lower the gain or raise the rate)")
        kth = np.asarray(self.k_theta_per_s, float)
        if np.any(kth * dt >= 1.0):
            raise ConfigError(where, "nc.k_theta_per_s", "k_theta*dt must be < 1")
        return NCParams.from_machine(
            machine, dt, max_pulses_per_tick=1 if self.pulse_mode == "single" else None,
            k_theta=kth, kv=self.kv_per_s, damping=self.damping, sv_threshold=self.sv_threshold,
            ferror_mm=self.ferror_mm, min_ferror_mm=self.min_ferror_mm,
            max_path_error_mm=self.max_path_error_mm, implementation=self.implementation)



@dataclass
class HomingConfig:
    """[homing]: the per-axis sequence of ``$H`` (pmctl.task.homing). Every home switch closes when its
    joint moves in + past the switch (a cam switch: closed on the + side of its edge)."""
    order: tuple = HOMING_AXES                            # axes homed one after another (one joint moves)
    reference_mm: tuple = (400.0, 400.0, 400.0, 5.0, 5.0)  # joint position of each switch's closing edge
    seek_mm_s: float = 5.0                                # toward the switch (grbl $25)
    latch_mm_s: float = 0.5                               # the slow approach whose edge is taken (grbl $24)
    pull_off_mm: float = 1.0                              # past the opening edge, before and after the latch (grbl $27)
    search_mm: float = 15.0                               # farthest seek; no switch within it: ALARM 9

    def check(self, params, where="[homing]"):
        """Against the machine's joint limits (ConfigError naming the key)."""
        for i, a in enumerate(HOMING_AXES):
            r = self.reference_mm[i]
            if not params.lower[i] + self.pull_off_mm <= r <= params.upper[i] - self.pull_off_mm:
                raise ConfigError(where, "homing.reference_mm", f"{a} = {r:g} mm must lie inside the joint range "
                                  f"[{params.lower[i]:g}, {params.upper[i]:g}] mm with room for the pull-off")
            for key, v in (("seek_mm_s", self.seek_mm_s), ("latch_mm_s", self.latch_mm_s)):
                if v > 0.5 * params.vmax[i]:
                    raise ConfigError(where, f"homing.{key}", f"{v:g} mm/s exceeds half the {a} speed limit "
                                                              f"({params.vmax[i]:g} mm/s)")


def homing_from_dict(data, path) -> HomingConfig:
    s = Table(path, data, "homing")
    d = HomingConfig()
    present, order = s._get("order", list(d.order), False)
    if not isinstance(order, list) or not order or not all(isinstance(a, str) for a in order):
        raise ConfigError(path, "homing.order", "must be a non-empty list of axis names (L1 L2 L3 X Y)")
    for a in order:
        if a not in HOMING_AXES:
            raise ConfigError(path, "homing.order", f"unknown axis {a!r}; known: {', '.join(HOMING_AXES)}")
    if len(set(order)) != len(order):
        raise ConfigError(path, "homing.order", "an axis is listed twice")
    h = HomingConfig(
        order=tuple(order),
        reference_mm=tuple(float(x) for x in s.vector("reference_mm", 5, default=d.reference_mm, lo=-1e4, hi=1e4)),
        seek_mm_s=s.number("seek_mm_s", default=d.seek_mm_s, positive=True, hi=1e3),
        latch_mm_s=s.number("latch_mm_s", default=d.latch_mm_s, positive=True, hi=1e3),
        pull_off_mm=s.number("pull_off_mm", default=d.pull_off_mm, positive=True, hi=100.0),
        search_mm=s.number("search_mm", default=d.search_mm, positive=True, hi=1e4),
    )
    s.finish()
    if h.latch_mm_s > h.seek_mm_s:
        raise ConfigError(path, "homing.latch_mm_s", "must not exceed homing.seek_mm_s (the latch is the slow approach)")
    return h


@dataclass
class ServiceConfig:
    loop: LoopConfig = field(default_factory=LoopConfig)
    nc: NCConfig = field(default_factory=NCConfig)
    backend: str = "sim"
    source: str = "<defaults>"
    backend_tables: dict = field(default_factory=dict)    # every [hal.<name>] table (for --backend NAME)
    spindle: object = None      # [spindle]: pmctl.hal.modbus_vfd.VfdOptions, None = no spindle control
    daq: object = None          # [daq]: pmctl.hal.modbus_daq.DaqOptions, None = no strain DAQ
    homing: HomingConfig = field(default_factory=HomingConfig)   # [homing]

    @property
    def backend_options(self) -> dict:
        """The selected backend's [hal.<backend>] table (validated at load by the backend)."""
        return self.backend_tables.get(self.backend, {})


def _bool(s: Table, key, default):
    return s.boolean(key, default=default)


def _int(s: Table, key, default, minimum, maximum=10**9):
    return s.integer(key, default=default, lo=minimum, hi=maximum)


def load_service_config(path: str | Path | None = None) -> ServiceConfig:
    """Read and validate config/service.toml (file, key, reason on any problem; nothing half-applied)."""
    p = Path(path) if path else CONFIG_DIR / "service.toml"
    return service_from_dict(read_toml(p), p)


def service_from_dict(data: dict, path="<dict>") -> ServiceConfig:
    check_tables(path, data, (), ("loop", "nc", "hal", "spindle", "daq", "homing"))
    s = Table(path, data.get("loop", {}), "loop")
    d = LoopConfig()
    loop = LoopConfig(
        rate_hz=s.number("rate_hz", default=d.rate_hz, lo=10.0, hi=20000.0),
        realtime=_bool(s, "realtime", d.realtime),
        rt_priority=_int(s, "rt_priority", d.rt_priority, 1, 99),
        lock_memory=_bool(s, "lock_memory", d.lock_memory),
        max_overruns_in_row=_int(s, "max_overruns_in_row", d.max_overruns_in_row, 1, 10**6),
        stall_timeout_s=s.number("stall_timeout_ms", default=d.stall_timeout_s * 1e3, positive=True, hi=60e3) / 1e3,
        settle_s=s.number("settle_ms", default=d.settle_s * 1e3, nonneg=True, hi=60e3) / 1e3,
        persist_every_ticks=_int(s, "persist_every_ticks", d.persist_every_ticks, 1, 10**9),
        spin_us=s.number("spin_us", default=d.spin_us, nonneg=True, hi=1e5),
        state_file=os.path.expanduser(s.string("state_file", default="")),
    )
    if loop.spin_us * 1e-6 >= loop.dt:
        raise ConfigError(path, "loop.spin_us", f"must be shorter than the tick period ({loop.dt * 1e6:g} us), "
                                                f"got {loop.spin_us:g}")
    s.finish()

    s = Table(path, data.get("nc", {}), "nc")
    d = NCConfig()
    kth = s.vector("k_theta_per_s", 3, default=[0.0] * 3, nonneg=True, hi=1e5, scalar_ok=True)
    mode = s.string("pulse_mode", default=d.pulse_mode, choices=("multi", "single"))
    impl = s.string("implementation", default=d.implementation, choices=IMPLEMENTATIONS)
    nc = NCConfig(
        kv_per_s=s.number("kv_per_s", default=d.kv_per_s, positive=True, hi=1e5),
        damping=s.number("damping", default=d.damping, nonneg=True, hi=10.0),
        sv_threshold=s.number("sv_threshold", default=d.sv_threshold, positive=True, hi=10.0),
        pulse_mode=mode, k_theta_per_s=tuple(float(x) for x in kth),
        ferror_mm=s.number("ferror_mm", default=d.ferror_mm, positive=True, hi=1e3),
        min_ferror_mm=s.number("min_ferror_mm", default=d.min_ferror_mm, positive=True, hi=1e3),
        max_path_error_mm=s.number("max_path_error_mm", default=d.max_path_error_mm, positive=True, hi=1e3),
        implementation=impl,
    )
    if nc.min_ferror_mm > nc.ferror_mm:
        raise ConfigError(path, "nc.min_ferror_mm", "must not exceed nc.ferror_mm")
    for key, k in (("kv_per_s", nc.kv_per_s), ("k_theta_per_s", max(nc.k_theta_per_s))):
        if k * loop.dt >= 1.0:        # checked again by NCConfig.params for the rate a run uses
            raise ConfigError(path, f"nc.{key}", f"{k:g}/s at {loop.rate_hz:g} Hz gives {k * loop.dt:.2f} per tick; "
                                                 "must be < 1 for a stable loop (lower the gain or raise the rate)")
    s.finish()

    h = data.get("hal", {})
    if not isinstance(h, dict):
        raise ConfigError(path, "hal", "must be a table")
    s = Table(path, {k: v for k, v in h.items() if not isinstance(v, dict)}, "hal")
    backend = s.string("backend", default="sim")
    s.finish()
    from pmctl.hal import BACKENDS, validate_options
    for k, v in h.items():
        if isinstance(v, dict) and k not in BACKENDS:
            raise ConfigError(path, f"hal.{k}", f"options for an unknown backend; known: {', '.join(BACKENDS)}")
    if backend not in BACKENDS:
        raise ConfigError(path, "hal.backend", f"unknown backend {backend!r}; known: {', '.join(sorted(BACKENDS))}")
    for k, v in h.items():           # validate every backend's options now, not at the first tick
        if isinstance(v, dict):
            validate_options(k, v, f"{path}: hal.{k}")
    tables = {k: dict(v) for k, v in h.items() if isinstance(v, dict)}
    spindle = None
    if "spindle" in data:
        from pmctl.hal.modbus_vfd import VfdOptions
        spindle = VfdOptions.from_dict(data["spindle"], f"{path}: spindle")
    daq = None
    if "daq" in data:
        from pmctl.hal.modbus_daq import DaqOptions
        daq = DaqOptions.from_dict(data["daq"], f"{path}: daq")
    homing = homing_from_dict(data.get("homing", {}), path)
    return ServiceConfig(loop, nc, backend, source=str(path), backend_tables=tables,
                         spindle=spindle if spindle is not None and spindle.enabled else None,
                         daq=daq if daq is not None and daq.enabled else None, homing=homing)
