"""Machine configuration: TOML file -> typed, validated, immutable objects.

Every value is checked on load (pmctl.core.strict_toml: UTF-8, no unknown tables or keys, no
coercion, every number finite and within the range its key allows). A bad file is rejected whole
with the file, key and reason; nothing is half-applied. Units are part of the key names (``_mm``,
``_deg``, ...): a key with the wrong unit suffix is reported with the key that was expected.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pmctl.core.compensation import parse_compensation
from pmctl.core.errors import ConfigError
from pmctl.core.strict_toml import Table, check_tables, read_toml

_SRC_CONFIG = Path(__file__).resolve().parents[3] / "config"      # a source checkout (editable install)
_PKG_CONFIG = Path(__file__).resolve().parents[1] / "config"      # shipped as package data
CONFIG_DIR = _SRC_CONFIG if (_SRC_CONFIG / "prototype.toml").is_file() else _PKG_CONFIG

# Unit directions of the three chain planes (docs/machine.md §2).
E_DIRS = np.array([[0.0, -1.0, 0.0],
                   [math.sqrt(3) / 2, 0.5, 0.0],
                   [-math.sqrt(3) / 2, 0.5, 0.0]])


@dataclass(frozen=True)
class Geometry:
    """General (calibratable) geometry. Arrays are 3x3, one row per chain, base frame / platform frame."""

    base_radius: float
    platform_radius: float
    tool_length: float
    tool_tilt_deg: tuple[float, float]
    z_home: float
    z_table: float
    base_joints: np.ndarray          # A_i in the base frame
    platform_joints: np.ndarray      # C_i^p in the platform frame
    revolute_axes: np.ndarray        # n_i, unit; chain-plane constraint n_i . (C_i - A_i) = 0
    length_offsets: np.ndarray       # |C_i - A_i| = L_i + offset_i
    nominal: bool                    # True when the joints are the ideal ones (closed forms apply)

    @property
    def tool_axis_p(self) -> np.ndarray:
        """Tool axis (tip -> spindle) in the platform frame."""
        a, b = np.radians(self.tool_tilt_deg)
        # Rx(a) . Ry(b) . z
        return np.array([math.sin(b), -math.sin(a) * math.cos(b), math.cos(a) * math.cos(b)])

    @property
    def tool_tip_p(self) -> np.ndarray:
        """Tool tip in the platform frame."""
        return -self.tool_length * self.tool_axis_p


@dataclass(frozen=True)
class Limits:
    chain_length: tuple[float, float]
    table_x: tuple[float, float]
    table_y: tuple[float, float]
    theta2_deg: tuple[float, float]
    spherical_swing_deg: float
    chain_speed: float
    chain_accel: float
    table_speed: float
    table_accel: float

    @property
    def joint_lower(self) -> np.ndarray:
        return np.array([self.chain_length[0]] * 3 + [self.table_x[0], self.table_y[0]])

    @property
    def joint_upper(self) -> np.ndarray:
        return np.array([self.chain_length[1]] * 3 + [self.table_x[1], self.table_y[1]])

    @property
    def joint_speed(self) -> np.ndarray:
        return np.array([self.chain_speed] * 3 + [self.table_speed] * 2)

    @property
    def joint_accel(self) -> np.ndarray:
        return np.array([self.chain_accel] * 3 + [self.table_accel] * 2)


@dataclass(frozen=True)
class Resolution:
    chain_pulses_per_mm: float
    table_pulses_per_mm: float
    screw_lead: float
    table_screw_lead: float

    @property
    def pulses_per_mm(self) -> np.ndarray:
        """Per actuator q = (L1, L2, L3, X, Y)."""
        return np.array([self.chain_pulses_per_mm] * 3 + [self.table_pulses_per_mm] * 2)


@dataclass(frozen=True)
class Mass:
    platform_kg: float
    com_offset: np.ndarray
    gravity: float


@dataclass(frozen=True)
class Stiffness:
    chain_axial: float     # N/mm
    chain_lateral: float   # N/mm


@dataclass(frozen=True)
class Machine:
    name: str
    description: str
    source: str
    geometry: Geometry
    limits: Limits
    resolution: Resolution
    mass: Mass
    strain_gain: float     # microstrain per N of chain tension
    stiffness: Stiffness
    extra: dict = field(default_factory=dict)   # kept for compatibility: unknown tables are refused now
    compensation: object = None    # [compensation]: pmctl.core.compensation.Compensation, None = none




MM = 1e4            # bound of any length or position in the machine config, mm (10 m)


def _geometry(path, s: Table) -> Geometry:
    r_in = s.number("base_radius_mm", positive=True, hi=MM)
    r_out = s.number("platform_radius_mm", positive=True, hi=MM)
    l_t = s.number("tool_length_mm", positive=True, hi=MM)
    tilt = s.vector("tool_tilt_deg", 2, default=[0.0, 0.0], lo=-10.0, hi=10.0)
    z_home = s.number("z_home_mm", positive=True, hi=MM)
    z_table = s.number("z_table_mm", lo=-MM, hi=MM)
    ideal_a = r_in * E_DIRS
    ideal_c = r_out * E_DIRS
    ideal_n = np.cross([0.0, 0.0, 1.0], E_DIRS)
    a = s.matrix3("base_joints_mm", ideal_a, bound=MM)
    c = s.matrix3("platform_joints_mm", ideal_c, bound=MM)
    n = s.matrix3("revolute_axes", ideal_n, bound=1e3)
    norms = np.linalg.norm(n, axis=1)
    if np.any(norms < 1e-9):
        raise ConfigError(path, "geometry.revolute_axes", "an axis has zero length")
    n = n / norms[:, None]
    off = s.vector("length_offsets_mm", 3, default=[0.0, 0.0, 0.0], lo=-1e3, hi=1e3)
    nominal = (np.array_equal(a, ideal_a) and np.array_equal(c, ideal_c)
               and np.allclose(n, ideal_n, atol=1e-15, rtol=0) and not np.any(off) and not np.any(tilt))
    s.finish()
    return Geometry(r_in, r_out, l_t, (float(tilt[0]), float(tilt[1])), z_home, z_table,
                    a, c, n, off, bool(nominal))


def load_machine(path: str | Path | None = None) -> Machine:
    """Load and validate a machine config. ``None`` or a bare name looks in config/."""
    if path is None:
        path = "prototype"
    p = Path(path)
    try:
        if not p.suffix and not p.exists():
            p = CONFIG_DIR / f"{p.name}.toml"
    except (OSError, ValueError) as e:
        raise ConfigError(p, "-", f"cannot read: {e}") from None
    return machine_from_dict(read_toml(p), p)


TABLES = ("machine", "geometry", "limits", "resolution", "mass", "sensors")
OPTIONAL_TABLES = ("stiffness", "compensation")


def machine_from_dict(data: dict, path="<dict>") -> Machine:
    check_tables(path, data, TABLES, OPTIONAL_TABLES)
    m = Table(path, data["machine"], "machine")
    name = m.string("name")
    if not name.strip():
        raise ConfigError(path, "machine.name", "must not be empty")
    desc = m.string("description", default="")
    m.finish()
    geom = _geometry(path, Table(path, data["geometry"], "geometry"))

    s = Table(path, data["limits"], "limits")
    limits = Limits(
        chain_length=s.range("chain_length_mm", lo=0.0, hi=MM),
        table_x=s.range("table_x_mm", lo=-MM, hi=MM),
        table_y=s.range("table_y_mm", lo=-MM, hi=MM),
        theta2_deg=s.range("theta2_deg", lo=-90.0, hi=90.0),
        spherical_swing_deg=s.number("spherical_swing_deg", positive=True, hi=90.0),
        chain_speed=s.number("chain_speed_mm_s", positive=True, hi=1e4),
        chain_accel=s.number("chain_accel_mm_s2", positive=True, hi=1e6),
        table_speed=s.number("table_speed_mm_s", positive=True, hi=1e4),
        table_accel=s.number("table_accel_mm_s2", positive=True, hi=1e6),
    )
    if limits.chain_length[0] <= 0:
        raise ConfigError(path, "limits.chain_length_mm", "lower limit must be > 0")
    s.finish()

    s = Table(path, data["resolution"], "resolution")
    res = Resolution(s.number("chain_pulses_per_mm", positive=True, hi=1e7),
                     s.number("table_pulses_per_mm", positive=True, hi=1e7),
                     s.number("screw_lead_mm", positive=True, hi=1e3, default=5.0),
                     s.number("table_screw_lead_mm", positive=True, hi=1e3, default=5.0))
    s.finish()

    s = Table(path, data["mass"], "mass")
    mass = Mass(s.number("platform_kg", positive=True, hi=1e5), s.vector("com_offset_mm", 3, lo=-MM, hi=MM),
                s.number("gravity_m_s2", positive=True, hi=100.0))
    s.finish()

    s = Table(path, data["sensors"], "sensors")
    gain = s.number("strain_gain_ue_per_N", positive=True, hi=1e6)
    s.finish()

    s = Table(path, data.get("stiffness", {}), "stiffness")
    stiff = Stiffness(s.number("chain_axial_N_per_mm", positive=True, hi=1e10, default=20000.0),
                      s.number("chain_lateral_N_per_mm", positive=True, hi=1e10, default=2000.0))
    s.finish()

    comp = None
    if "compensation" in data:
        comp = parse_compensation(path, data["compensation"])

    return Machine(name, desc, str(path), geom, limits, res, mass, gain, stiff, {}, comp)
