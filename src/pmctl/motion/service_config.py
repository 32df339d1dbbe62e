"""The service config (config/service.toml): the loop, the NC gains and the HAL backend with its
options. Read strictly and validated whole on load: a bad value is reported with file, key and
reason, and nothing is half-applied. Each ``[hal.<backend>]`` table is validated by its backend's
``validate_options`` (pmctl.hal), whether or not that backend is the one selected."""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pmctl.core.config import CONFIG_DIR, Machine, _Section
from pmctl.core.errors import ConfigError
from pmctl.motion.nc import NCParams


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
            max_path_error_mm=self.max_path_error_mm)


@dataclass
class ServiceConfig:
    loop: LoopConfig = field(default_factory=LoopConfig)
    nc: NCConfig = field(default_factory=NCConfig)
    backend: str = "sim"
    backend_options: dict = field(default_factory=dict)   # [hal.<backend>] table, validated by the backend
    source: str = "<defaults>"
    hal_options: dict = field(default_factory=dict)       # every [hal.<name>] table (for --backend NAME)
    spindle: object = None      # [spindle]: pmctl.hal.modbus_vfd.VfdOptions, None = no spindle control
    daq: object = None          # [daq]: pmctl.hal.modbus_daq.DaqOptions, None = no strain DAQ


def _bool(s: _Section, key, default):
    if key not in s.data:
        return default
    s.used.add(key)
    v = s.data[key]
    if not isinstance(v, bool):
        raise ConfigError(s.path, s._key(key), f"must be true or false, got {v!r}")
    return v


def _int(s: _Section, key, default, minimum):
    v = s.number(key, default=default)
    if v != int(v) or v < minimum:
        raise ConfigError(s.path, s._key(key), f"must be an integer >= {minimum}, got {v:g}")
    return int(v)


def load_service_config(path: str | Path | None = None) -> ServiceConfig:
    """Read and validate config/service.toml (file, key, reason on any problem; nothing half-applied)."""
    p = Path(path) if path else CONFIG_DIR / "service.toml"
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except OSError as e:
        raise ConfigError(p, "-", f"cannot read: {e.strerror or e}") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(p, "-", f"not valid TOML: {e}") from None
    return service_from_dict(data, p)


def service_from_dict(data: dict, path="<dict>") -> ServiceConfig:
    for k in data:
        if k not in ("loop", "nc", "hal", "spindle", "daq"):
            raise ConfigError(path, k, "unknown table")
    s = _Section(path, data.get("loop", {}), "loop")
    d = LoopConfig()
    loop = LoopConfig(
        rate_hz=s.number("rate_hz", default=d.rate_hz, positive=True),
        realtime=_bool(s, "realtime", d.realtime),
        rt_priority=_int(s, "rt_priority", d.rt_priority, 1),
        lock_memory=_bool(s, "lock_memory", d.lock_memory),
        max_overruns_in_row=_int(s, "max_overruns_in_row", d.max_overruns_in_row, 1),
        stall_timeout_s=s.number("stall_timeout_ms", default=d.stall_timeout_s * 1e3, positive=True) / 1e3,
        settle_s=s.number("settle_ms", default=d.settle_s * 1e3, nonneg=True) / 1e3,
        persist_every_ticks=_int(s, "persist_every_ticks", d.persist_every_ticks, 1),
        spin_us=s.number("spin_us", default=d.spin_us, nonneg=True),
        state_file=os.path.expanduser(s.string("state_file", default="")),
    )
    if not 10 <= loop.rate_hz <= 20000:
        raise ConfigError(path, "loop.rate_hz", f"must be within 10 .. 20000 Hz, got {loop.rate_hz:g}")
    if loop.rt_priority > 99:
        raise ConfigError(path, "loop.rt_priority", "must be 1 .. 99")
    s.finish()

    s = _Section(path, data.get("nc", {}), "nc")
    d = NCConfig()
    kth = s.vector("k_theta_per_s", 3, default=None) if isinstance(s.data.get("k_theta_per_s"), list) \
        else np.full(3, s.number("k_theta_per_s", default=0.0, nonneg=True))
    if np.any(kth < 0):
        raise ConfigError(path, "nc.k_theta_per_s", "must be >= 0")
    mode = s.string("pulse_mode", default=d.pulse_mode)
    if mode not in ("multi", "single"):
        raise ConfigError(path, "nc.pulse_mode", f"must be 'multi' or 'single', got {mode!r}")
    nc = NCConfig(
        kv_per_s=s.number("kv_per_s", default=d.kv_per_s, positive=True),
        damping=s.number("damping", default=d.damping, nonneg=True),
        sv_threshold=s.number("sv_threshold", default=d.sv_threshold, positive=True),
        pulse_mode=mode, k_theta_per_s=tuple(float(x) for x in kth),
        ferror_mm=s.number("ferror_mm", default=d.ferror_mm, positive=True),
        min_ferror_mm=s.number("min_ferror_mm", default=d.min_ferror_mm, positive=True),
        max_path_error_mm=s.number("max_path_error_mm", default=d.max_path_error_mm, positive=True),
    )
    if nc.min_ferror_mm > nc.ferror_mm:
        raise ConfigError(path, "nc.min_ferror_mm", "must not exceed nc.ferror_mm")
    s.finish()

    h = data.get("hal", {})
    if not isinstance(h, dict):
        raise ConfigError(path, "hal", "must be a table")
    s = _Section(path, {k: v for k, v in h.items() if not isinstance(v, dict)}, "hal")
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
    opts = dict(h.get(backend, {}))
    spindle = None
    if "spindle" in data:
        from pmctl.hal.modbus_vfd import VfdOptions
        spindle = VfdOptions.from_dict(data["spindle"], f"{path}: spindle")
    daq = None
    if "daq" in data:
        from pmctl.hal.modbus_daq import DaqOptions
        daq = DaqOptions.from_dict(data["daq"], f"{path}: daq")
    return ServiceConfig(loop, nc, backend, opts, str(path),
                         hal_options={k: dict(v) for k, v in h.items() if isinstance(v, dict)},
                         spindle=spindle if spindle is not None and spindle.enabled else None,
                         daq=daq if daq is not None and daq.enabled else None)
