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
    k_theta_auto: bool = False         # k_theta_per_s = "auto": per chain from the chain mode (ChainModes)
    # the chain modes (docs/vibration.md): measured (pmctl analyze resonance --write) or declared;
    # None = not given here (then the sim's declared plant, else the machine config's stiffness)
    mode_hz: tuple | None = None
    mode_damping_ratio: tuple | None = None
    modal_stiffness_N_per_mm: tuple | None = None
    deflection_feedforward: bool = True   # soft chains: the motor leads by the planned stretch a*/w^2
    shaper: str = "none"               # time-law input shaper: none, a type (pmctl.core.shaper.SHAPERS) or auto
    shaper_hz: tuple | None = None     # per chain; None = the chain modes
    shaper_damping_ratio: float | None = None   # None = the chain modes' damping
    # the chain-length offset input (slow compensation): bound and slew rate, from [daq] comp_max_mm / comp_rate_mm_s
    chain_offset_max_mm: float = 0.2
    chain_offset_rate_mm_s: float = 0.05

    def params(self, machine: Machine, dt: float, where="service config", modes: "ChainModes | None" = None) -> NCParams:
        """NC parameters. ``modes``: the chain modes (:func:`chain_modes`); they set the strain ->
        deflection scale (modal stiffness), turn on the soft-chain K_theta for modes below
        SOFT_MODE_FACTOR x kv (where the pose loop would undo the feedback), and size
        ``k_theta_per_s = "auto"``."""
        if self.kv_per_s * dt >= 1.0:
            raise ConfigError(where, "nc.kv_per_s",
                              f"{self.kv_per_s:g}/s at {1 / dt:g} Hz gives kv*dt = {self.kv_per_s * dt:.2f}; "
                              f"must be < 1 for a stable loop (lower the gain or raise the rate)")
        kw = {}
        if modes is not None:
            kw["modal_stiffness_N_per_mm"] = np.asarray(modes.stiffness_N_per_mm, float)
            soft = modes.soft(self.kv_per_s)
            if np.any(soft):
                kw["mode_hz"] = np.where(soft, modes.hz, 0.0)
                kw["deflection_ff"] = self.deflection_feedforward
        if self.k_theta_auto:
            if modes is None:
                raise ConfigError(where, "nc.k_theta_per_s",
                                  '"auto" needs the chain modes: nc.mode_hz, a [hal.sim] plant with flex = true, '
                                  "or pmctl analyze resonance --write")
            kth = np.array(auto_k_theta(modes, self.kv_per_s, dt))
        else:
            kth = np.asarray(self.k_theta_per_s, float)
        if np.any(kth * dt >= 1.0):
            raise ConfigError(where, "nc.k_theta_per_s", "k_theta*dt must be < 1")
        return NCParams.from_machine(
            machine, dt, max_pulses_per_tick=1 if self.pulse_mode == "single" else None,
            k_theta=kth, kv=self.kv_per_s, damping=self.damping, sv_threshold=self.sv_threshold,
            ferror_mm=self.ferror_mm, min_ferror_mm=self.min_ferror_mm,
            max_path_error_mm=self.max_path_error_mm, implementation=self.implementation,
            chain_offset_max_mm=self.chain_offset_max_mm, chain_offset_rate_mm_s=self.chain_offset_rate_mm_s, **kw)


SOFT_MODE_FACTOR = 2.0      # the soft-chain K_theta below w = 2 kv (docs/vibration.md, eq. 3.1 table)


@dataclass
class ChainModes:
    """The chain mode per chain (L1-L3) and where it comes from (said when a run starts)."""

    hz: np.ndarray                    # (3,)
    damping_ratio: np.ndarray         # (3,)
    stiffness_N_per_mm: np.ndarray    # (3,) chain stiffness at the gauge (strain -> deflection scale)
    source: str

    def soft(self, kv: float) -> np.ndarray:
        """Chains whose mode lies below SOFT_MODE_FACTOR x kv: the pose loop, closed on the motor side,
        would pull back the feedback's own motion there (docs/vibration.md §1.4)."""
        return 2 * np.pi * self.hz < SOFT_MODE_FACTOR * kv

    def describe(self) -> str:
        f = ", ".join(f"{x:.1f}" for x in self.hz)
        z = ", ".join(f"{x:.3f}" for x in self.damping_ratio)
        k = ", ".join(f"{x:g}" for x in self.stiffness_N_per_mm)
        return f"chain modes [{f}] Hz, damping [{z}], stiffness [{k}] N/mm (from {self.source})"


def auto_k_theta(modes: ChainModes, kv: float, dt: float) -> list[float]:
    """K_theta per chain for ``k_theta = auto``: the sampled eq. 3.1 model's smallest gain that damps
    the chain's mode to 0.3 (pmctl.tools.analysis.resonance.k_theta_for_mode), with the feedback the
    NC will run (decoupled for a soft chain)."""
    from pmctl.tools.analysis.resonance import k_theta_for_mode
    soft = modes.soft(kv)
    out = []
    for i in range(3):
        f, z = float(modes.hz[i]), float(modes.damping_ratio[i])
        leak = 0.1 * 2 * np.pi * f if soft[i] else None
        out.append(k_theta_for_mode(f, kv, dt, z, leak=leak)[0])
    return out


def shaper_design(f_hz: float, zeta: float, k_theta: float, kv: float, dt: float, soft: bool):
    """(frequency Hz, damping ratio) a shaper should be designed for, for a chain mode (f_hz, zeta):
    the mode itself without feedback; with K_theta on, the closed-loop mode that the feedback leaves
    (the sampled eq. 3.1 model, pmctl.tools.analysis.resonance.predict_sampled, with the feedback the
    NC runs). A shaper tuned to the open-loop mode misses the damped, shifted closed-loop one and
    only adds its own impulses' excitation (docs/vibration.md §5)."""
    if k_theta <= 0:
        return f_hz, zeta
    from pmctl.tools.analysis.resonance import predict_sampled
    fc, zc = predict_sampled(f_hz, k_theta, kv, dt, zeta, leak=0.1 * 2 * np.pi * f_hz if soft else None)
    if not (np.isfinite(fc) and 0.0 <= zc < 0.95):
        return f_hz, zeta
    return float(fc), float(zc)


def choose_shaper(nc: NCConfig, modes: "ChainModes | None", k_theta, dt: float, where: str = "service config"):
    """The time-law shaper of a run (None = off) and a sentence saying what it is and why.
    ``nc.shaper``: none, a type, or auto (the type the resonance analysis recommends: the shortest
    whose remaining vibration stays within 5 % over +-10 % of the mode). Frequencies: nc.shaper_hz
    (per chain) else the chain modes; each chain's design point is :func:`shaper_design` with that
    chain's K_theta; distinct design points (more than 3 % apart) are convolved."""
    name = nc.shaper
    if name == "none":
        return None, "shaper: none"
    from pmctl.core import shaper as S
    if nc.shaper_hz is not None:
        hz = np.broadcast_to(np.asarray(nc.shaper_hz, float), (3,))
        zs = np.broadcast_to(np.asarray(modes.damping_ratio if modes is not None else 0.02, float), (3,))
        src = f"{where}: [nc] shaper_hz"
    elif modes is not None:
        hz, zs, src = modes.hz, modes.damping_ratio, modes.source
    else:
        raise ConfigError(where, "nc.shaper", f'"{name}" needs a frequency: nc.shaper_hz, nc.mode_hz '
                                              "(pmctl analyze resonance --write), or a [hal.sim] plant with flex = true")
    if nc.shaper_damping_ratio is not None:
        zs = np.full(3, nc.shaper_damping_ratio)
    kth = np.broadcast_to(np.asarray(k_theta, float), (3,))
    soft = (2 * np.pi * np.asarray(hz) < SOFT_MODE_FACTOR * nc.kv_per_s)
    points = []
    for i in range(3):
        fz = shaper_design(float(hz[i]), float(zs[i]), float(kth[i]), nc.kv_per_s, dt, bool(soft[i]))
        if not any(abs(fz[0] - p[0]) <= 0.03 * p[0] for p in points):
            points.append(fz)
    if name == "auto":
        from pmctl.tools.analysis.resonance import shaper_advice
        name = shaper_advice(points[0][0], points[0][1])[1].name
    sh = S.convolve([S.make_shaper(name, f, min(z, 0.9)) for f, z in points]) if len(points) > 1 \
        else S.make_shaper(name, *points[0])
    pts = ", ".join(f"{f:.1f} Hz / {z:.3f}" for f, z in points)
    why = " (closed-loop mode with K_theta)" if np.any(kth > 0) else ""
    return sh, (f"shaper: {sh.name}{' (auto)' if nc.shaper == 'auto' else ''} at {pts}{why}, "
                f"{1e3 * sh.duration:.1f} ms per stop, time law along the path; modes from {src}")


def chain_modes(svc: "ServiceConfig", machine: Machine, backend: str | None = None) -> ChainModes | None:
    """The chain modes for the NC and the shaper, first found of: ``[nc] mode_hz`` (measured: pmctl
    analyze resonance --write, or declared); the sim backend's declared plant when its flexible mode
    is on (``[hal.sim]`` flex, mode_stiffness_N_per_mm, mode_mass_kg, mode_damping_ratio); else None
    (the NC then scales the strain with the machine config's chain stiffness)."""
    nc = svc.nc
    backend = backend or svc.backend
    if nc.mode_hz is not None:
        k = nc.modal_stiffness_N_per_mm
        src = f"{svc.source}: [nc] mode_hz"
        if k is None:
            k = (machine.stiffness.chain_axial,) * 3
            src += " (stiffness: the machine config's chain_axial)"
        z = nc.mode_damping_ratio if nc.mode_damping_ratio is not None else (0.02,) * 3
        return ChainModes(np.array(nc.mode_hz, float), np.array(z, float), np.array(k, float), src)
    if backend == "sim":
        from pmctl.hal.sim import SimOptions
        o = SimOptions.from_dict(svc.backend_tables.get("sim", {}), machine, where=f"{svc.source}: hal.sim")
        if o.flex:
            k = np.asarray(o.mode_stiffness_N_per_mm, float)
            m = np.asarray(o.mode_mass_kg, float)
            hz = np.sqrt(k * 1e3 / m) / (2 * np.pi)
            if nc.modal_stiffness_N_per_mm is not None:
                k = np.array(nc.modal_stiffness_N_per_mm, float)
            return ChainModes(hz, np.asarray(o.mode_damping_ratio, float), k,
                              f"{svc.source}: [hal.sim] declared plant")
    if nc.modal_stiffness_N_per_mm is not None:
        raise ConfigError(svc.source, "nc.modal_stiffness_N_per_mm", "needs nc.mode_hz (the chain mode) with it")
    return None



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


@dataclass(frozen=True)
class InterpreterConfig:
    """[interpreter]: what the RS-274 interpreter (pmctl.task.rs274, docs/gcode.md) takes from the service
    config. Paths are absolute here (relative ones in the file are relative to the file's folder)."""
    tool_table: str = str(CONFIG_DIR / "tools.tbl")   # LinuxCNC .tbl: T P Z (length offset) D (diameter);
                                                      # absent from the file: the bundled config/tools.tbl
    subroutine_path: tuple = ()            # folders searched for o<name> call files (name.ngc)
    user_m_codes: tuple = ()               # M100-M199 a program may use (EVENT user_m; else refused)
    optional_stop: bool = True             # M1 pauses like M0 (false: M1 is skipped)
    block_delete: bool = False             # lines starting with '/' are skipped
    digital_outputs: int = 4               # M62-M65 P0 .. P(n-1)
    analog_outputs: int = 4                # M67/M68 E0 .. E(n-1)


def interpreter_from_dict(data, path) -> InterpreterConfig:
    s = Table(path, data, "interpreter")
    d = InterpreterConfig()
    here = Path(path).parent if Path(str(path)).is_file() else CONFIG_DIR

    def resolve(p: str) -> str:
        q = Path(os.path.expanduser(p))
        return str(q if q.is_absolute() else here / q)

    table = s.string("tool_table", default=d.tool_table)      # absent: the bundled table
    if not table:
        raise ConfigError(path, "interpreter.tool_table", "must name a tool table file (LinuxCNC .tbl)")
    present, folders = s._get("subroutine_path", [], False)
    if not isinstance(folders, list) or not all(isinstance(f, str) and f and "\0" not in f for f in folders):
        raise ConfigError(path, "interpreter.subroutine_path", "must be a list of folder names (strings)")
    present, codes = s._get("user_m_codes", [], False)
    if not isinstance(codes, list) or not all(isinstance(c, int) and not isinstance(c, bool) for c in codes):
        raise ConfigError(path, "interpreter.user_m_codes", "must be a list of integers (M100-M199)")
    for c in codes:
        if not 100 <= c <= 199:
            raise ConfigError(path, "interpreter.user_m_codes", f"{c} is not a user M-code (100 .. 199)")
    cfg = InterpreterConfig(
        tool_table=resolve(table),
        subroutine_path=tuple(resolve(f) for f in folders),
        user_m_codes=tuple(sorted(set(codes))),
        optional_stop=s.boolean("optional_stop", default=d.optional_stop),
        block_delete=s.boolean("block_delete", default=d.block_delete),
        digital_outputs=s.integer("digital_outputs", default=d.digital_outputs, lo=0, hi=64),
        analog_outputs=s.integer("analog_outputs", default=d.analog_outputs, lo=0, hi=64),
    )
    s.finish()
    return cfg


@dataclass
class ServiceConfig:
    loop: LoopConfig = field(default_factory=LoopConfig)
    nc: NCConfig = field(default_factory=NCConfig)
    backend: str = "sim"
    source: str = "<defaults>"
    backend_tables: dict = field(default_factory=dict)    # every [hal.<name>] table (for --backend NAME)
    spindle: object = None      # [spindle]: pmctl.hal.modbus_vfd.VfdOptions, None = no spindle control
    daq: object = None          # [daq]: pmctl.hal.modbus_daq.DaqOptions, None = no strain DAQ
    probe: object = None        # [probe]: pmctl.motion.probe.ProbeConfig (stop on contact, G38.2/G38.3)
    homing: HomingConfig = field(default_factory=HomingConfig)   # [homing]
    interpreter: InterpreterConfig = field(default_factory=InterpreterConfig)   # [interpreter]

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
    check_tables(path, data, (), ("loop", "nc", "hal", "spindle", "daq", "probe", "homing", "interpreter"))
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
    kth_auto = data.get("nc", {}).get("k_theta_per_s") == "auto"
    kth = [0.0] * 3 if kth_auto else s.vector("k_theta_per_s", 3, default=[0.0] * 3, nonneg=True, hi=1e5,
                                              scalar_ok=True)
    if kth_auto:
        s.string("k_theta_per_s", choices=("auto",))
    opt_vec = lambda key, **kw: (tuple(float(x) for x in s.vector(key, 3, scalar_ok=True, **kw))   # noqa: E731
                                 if key in data.get("nc", {}) else None)
    mode_hz = opt_vec("mode_hz", positive=True, hi=1e4)
    mode_z = opt_vec("mode_damping_ratio", nonneg=True, hi=1.0)
    modal_k = opt_vec("modal_stiffness_N_per_mm", positive=True, hi=1e10)
    shaper_hz = opt_vec("shaper_hz", positive=True, hi=1e4)
    from pmctl.core.shaper import SHAPERS
    shaper = s.string("shaper", default="none", choices=("none", "auto") + tuple(SHAPERS))
    shaper_z = s.number("shaper_damping_ratio", nonneg=True, hi=0.9) if "shaper_damping_ratio" in data.get("nc", {}) \
        else None
    if mode_z is not None and mode_hz is None:
        raise ConfigError(path, "nc.mode_damping_ratio", "needs nc.mode_hz (the chain mode) with it")
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
        implementation=impl, k_theta_auto=kth_auto, mode_hz=mode_hz, mode_damping_ratio=mode_z,
        modal_stiffness_N_per_mm=modal_k,
        deflection_feedforward=_bool(s, "deflection_feedforward", True),
        shaper=shaper, shaper_hz=shaper_hz, shaper_damping_ratio=shaper_z,
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
        nc.chain_offset_max_mm, nc.chain_offset_rate_mm_s = daq.comp_max_mm, daq.comp_rate_mm_s
    from pmctl.motion.probe import ProbeConfig
    probe = ProbeConfig.from_dict(data.get("probe", {}), path)
    homing = homing_from_dict(data.get("homing", {}), path)
    interp = interpreter_from_dict(data.get("interpreter", {}), path)
    return ServiceConfig(loop, nc, backend, source=str(path), backend_tables=tables,
                         spindle=spindle if spindle is not None and spindle.enabled else None,
                         daq=daq if daq is not None and daq.enabled else None, probe=probe,
                         homing=homing, interpreter=interp)


@dataclass
class NCSetup:
    """What a run's NC and shaping stage use, resolved from the service config (and the flags that
    changed it): the chain modes, K_theta per chain (auto resolved), the shaper, and the sentences
    that say so."""

    modes: ChainModes | None
    shaper: object                # pmctl.core.shaper.Shaper or None
    notes: list


def strain_in_loop(backend: str) -> bool:
    """Whether ``backend`` carries the strain gauges in its cyclic data (the per-tick strain K_theta
    damps with and the recording's strain_* and load_* channels); the canopen drives carry none."""
    from pmctl import hal
    return bool(getattr(hal.backend_class(backend), "strain_in_loop", True))


def nc_setup(svc: ServiceConfig, machine: Machine, dt: float, backend: str | None = None) -> NCSetup:
    """Resolve the chain modes, ``k_theta_per_s = "auto"`` (written back into svc.nc as numbers; 0 on a
    ``backend`` (default: the service's) without strain in its cyclic data, after the K_theta source
    check) and the shaper. Then ``svc.nc.params(machine, dt, modes=setup.modes)`` builds the NC
    parameters and pmctl.motion.timescale.shape_trajectory applies ``setup.shaper`` to the plan."""
    nc = svc.nc
    backend = backend or svc.backend
    modes = chain_modes(svc, machine, backend)
    notes = []
    if modes is not None:
        notes.append(modes.describe())
    if nc.k_theta_auto:
        if modes is None:
            raise ConfigError(svc.source, "nc.k_theta_per_s",
                              '"auto" needs the chain modes: nc.mode_hz (pmctl analyze resonance --write) '
                              "or a [hal.sim] plant with flex = true")
        nc.k_theta_per_s = tuple(auto_k_theta(modes, nc.kv_per_s, dt))
        nc.k_theta_auto = False
        notes.append("K_theta auto: [" + ", ".join(f"{k:.0f}" for k in nc.k_theta_per_s)
                     + "]/s per chain (sampled eq. 3.1 model: the smallest gain damping the chain mode to 0.3)")
    # [daq] k_theta_source = "daq": refused when the DAQ samples slower than twice the chain mode. It
    # sees the K_theta the config asks for (auto resolved), before a backend without strain switches it
    # off below, so every backend refuses the same configs (pmctl run, pmctl serve, the rt process).
    from pmctl.hal.modbus_daq import check_k_theta_source
    check_k_theta_source(svc.daq, nc.k_theta_per_s, machine, f"{svc.source}: daq")
    if backend is not None and any(nc.k_theta_per_s) and not strain_in_loop(backend):
        nc.k_theta_per_s = (0.0,) * 3
        notes.append(f"K_theta off: backend {backend} carries no strain gauges in its cyclic data")
    if modes is not None and any(nc.k_theta_per_s):
        soft = modes.soft(nc.kv_per_s)
        if np.any(soft):
            notes.append("K_theta on soft chains (mode below 2 kv): planned stretch off, decoupled from the pose "
                         "loop" + (", deflection feed-forward" if nc.deflection_feedforward else ""))
    shaper, text = choose_shaper(nc, modes, nc.k_theta_per_s, dt, svc.source)
    if shaper is not None:
        notes.append(text)
    return NCSetup(modes, shaper, notes)


def parse_k_theta_flag(v):
    """``--k-theta``: None, "auto", or a gain >= 0 (1/s). PmctlError naming the flag otherwise."""
    from pmctl.core.errors import PmctlError
    if v is None or v == "auto":
        return v
    try:
        k = float(v)
    except (TypeError, ValueError):
        raise PmctlError(f"--k-theta must be a gain in 1/s (>= 0) or auto, got {v!r}") from None
    if not (np.isfinite(k) and k >= 0):
        raise PmctlError(f"--k-theta must be >= 0 1/s, got {v}")
    return k


def parse_shaper_flag(v):
    """``--shaper``: None, none, auto or a shaper type (case-insensitive) -> the canonical name."""
    if v is None:
        return None
    from pmctl.core.errors import PmctlError
    from pmctl.core.shaper import SHAPERS
    key = str(v).strip()
    if key.lower() in ("none", "auto"):
        return key.lower()
    if key.upper() in SHAPERS:
        return key.upper()
    raise PmctlError(f"--shaper must be one of none, auto, {', '.join(SHAPERS)}; got {v!r}")
