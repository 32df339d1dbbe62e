"""Machine configuration: TOML file -> typed, validated, immutable objects.

Every value is checked on load. A bad file is rejected whole with the file, key and reason;
nothing is half-applied. Units are part of the key names (``_mm``, ``_deg``, ...): a key with
the wrong unit suffix is reported with the key that was expected.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pmctl.core.errors import ConfigError

_SRC_CONFIG = Path(__file__).resolve().parents[3] / "config"      # a source checkout (editable install)
_PKG_CONFIG = Path(__file__).resolve().parents[1] / "config"      # shipped as package data
CONFIG_DIR = _SRC_CONFIG if (_SRC_CONFIG / "prototype.toml").is_file() else _PKG_CONFIG

# Unit directions of the three chain planes (MACHINE.md §2).
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
    extra: dict = field(default_factory=dict)   # unknown top-level tables (service config etc.)


UNIT_SUFFIXES = ("_ue_per_N", "_N_per_mm", "_mm_s2", "_mm_s", "_m_s2", "_mm", "_deg", "_kg", "_hz", "_s")


class _Section:
    """Reads one TOML table, tracking which keys were used so leftovers can be reported."""

    def __init__(self, path, data, name):
        self.path, self.name = path, name
        if not isinstance(data, dict):
            raise ConfigError(path, name, "must be a table")
        self.data = data
        self.used: set[str] = set()

    def _key(self, key):
        return f"{self.name}.{key}"

    def _missing(self, key):
        stem = key
        for unit in UNIT_SUFFIXES:
            if key.endswith(unit):
                stem = key[: -len(unit)]
                break
        near = [k for k in self.data if k != key and k.startswith(stem) and k not in self.used]
        if near:
            return ConfigError(self.path, self._key(near[0]),
                               f"wrong unit or name: expected '{key}'")
        return ConfigError(self.path, self._key(key), "missing")

    def number(self, key, *, default=None, positive=False, nonneg=False):
        if key not in self.data:
            if default is None:
                raise self._missing(key)
            return float(default)
        self.used.add(key)
        v = self.data[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ConfigError(self.path, self._key(key), f"must be a number, got {type(v).__name__} {v!r}")
        v = float(v)
        if not math.isfinite(v):
            raise ConfigError(self.path, self._key(key), "must be finite")
        if positive and v <= 0:
            raise ConfigError(self.path, self._key(key), f"must be > 0, got {v}")
        if nonneg and v < 0:
            raise ConfigError(self.path, self._key(key), f"must be >= 0, got {v}")
        return v

    def vector(self, key, n, *, default=None):
        if key not in self.data:
            if default is None:
                raise self._missing(key)
            return np.array(default, dtype=float)
        self.used.add(key)
        v = self.data[key]
        if not isinstance(v, list) or len(v) != n or any(
                isinstance(x, bool) or not isinstance(x, (int, float)) for x in v):
            raise ConfigError(self.path, self._key(key), f"must be a list of {n} numbers, got {v!r}")
        arr = np.array(v, dtype=float)
        if not np.all(np.isfinite(arr)):
            raise ConfigError(self.path, self._key(key), "must be finite")
        return arr

    def matrix3(self, key, default):
        if key not in self.data:
            return default
        self.used.add(key)
        v = self.data[key]
        try:
            arr = np.array(v, dtype=float)
        except (TypeError, ValueError):
            arr = None
        if arr is None or arr.shape != (3, 3) or not np.all(np.isfinite(arr)):
            raise ConfigError(self.path, self._key(key), "must be 3 rows of [x, y, z] numbers")
        return arr

    def range(self, key):
        lo, hi = self.vector(key, 2)
        if not lo < hi:
            raise ConfigError(self.path, self._key(key), f"limits reversed or empty: [{lo}, {hi}]")
        return (float(lo), float(hi))

    def string(self, key, default=None):
        if key not in self.data:
            if default is None:
                raise self._missing(key)
            return default
        self.used.add(key)
        v = self.data[key]
        if not isinstance(v, str):
            raise ConfigError(self.path, self._key(key), "must be a string")
        return v

    def finish(self):
        extra = set(self.data) - self.used
        if extra:
            k = sorted(extra)[0]
            raise ConfigError(self.path, self._key(k), "unknown key")


def _geometry(path, s: _Section) -> Geometry:
    r_in = s.number("base_radius_mm", positive=True)
    r_out = s.number("platform_radius_mm", positive=True)
    l_t = s.number("tool_length_mm", positive=True)
    tilt = s.vector("tool_tilt_deg", 2, default=[0.0, 0.0])
    if np.any(np.abs(tilt) > 10):
        raise ConfigError(path, "geometry.tool_tilt_deg", "a tool tilt over 10 deg is not a calibration value")
    z_home = s.number("z_home_mm", positive=True)
    z_table = s.number("z_table_mm")
    ideal_a = r_in * E_DIRS
    ideal_c = r_out * E_DIRS
    ideal_n = np.cross([0.0, 0.0, 1.0], E_DIRS)
    a = s.matrix3("base_joints_mm", ideal_a)
    c = s.matrix3("platform_joints_mm", ideal_c)
    n = s.matrix3("revolute_axes", ideal_n)
    norms = np.linalg.norm(n, axis=1)
    if np.any(norms < 1e-9):
        raise ConfigError(path, "geometry.revolute_axes", "an axis has zero length")
    n = n / norms[:, None]
    off = s.vector("length_offsets_mm", 3, default=[0.0, 0.0, 0.0])
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
    if not p.suffix and not p.exists():
        p = CONFIG_DIR / f"{p.name}.toml"
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as e:
        raise ConfigError(p, "-", f"cannot read: {e.strerror or e}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(p, "-", f"not valid TOML: {e}") from None
    return machine_from_dict(data, p)


def machine_from_dict(data: dict, path="<dict>") -> Machine:
    known = {"machine", "geometry", "limits", "resolution", "mass", "sensors", "stiffness"}
    for sec in ("machine", "geometry", "limits", "resolution", "mass", "sensors"):
        if sec not in data:
            raise ConfigError(path, sec, "missing table")
    m = _Section(path, data["machine"], "machine")
    name = m.string("name")
    desc = m.string("description", default="")
    m.finish()
    geom = _geometry(path, _Section(path, data["geometry"], "geometry"))

    s = _Section(path, data["limits"], "limits")
    limits = Limits(
        chain_length=s.range("chain_length_mm"),
        table_x=s.range("table_x_mm"),
        table_y=s.range("table_y_mm"),
        theta2_deg=s.range("theta2_deg"),
        spherical_swing_deg=s.number("spherical_swing_deg", positive=True),
        chain_speed=s.number("chain_speed_mm_s", positive=True),
        chain_accel=s.number("chain_accel_mm_s2", positive=True),
        table_speed=s.number("table_speed_mm_s", positive=True),
        table_accel=s.number("table_accel_mm_s2", positive=True),
    )
    if limits.chain_length[0] <= 0:
        raise ConfigError(path, "limits.chain_length_mm", "lower limit must be > 0")
    s.finish()

    s = _Section(path, data["resolution"], "resolution")
    res = Resolution(s.number("chain_pulses_per_mm", positive=True),
                     s.number("table_pulses_per_mm", positive=True),
                     s.number("screw_lead_mm", positive=True, default=5.0),
                     s.number("table_screw_lead_mm", positive=True, default=5.0))
    s.finish()

    s = _Section(path, data["mass"], "mass")
    mass = Mass(s.number("platform_kg", positive=True), s.vector("com_offset_mm", 3),
                s.number("gravity_m_s2", positive=True))
    s.finish()

    s = _Section(path, data["sensors"], "sensors")
    gain = s.number("strain_gain_ue_per_N", positive=True)
    s.finish()

    s = _Section(path, data.get("stiffness", {}), "stiffness")
    stiff = Stiffness(s.number("chain_axial_N_per_mm", positive=True, default=20000.0),
                      s.number("chain_lateral_N_per_mm", positive=True, default=2000.0))
    s.finish()

    extra = {k: v for k, v in data.items() if k not in known}
    return Machine(name, desc, str(path), geom, limits, res, mass, gain, stiff, extra)
