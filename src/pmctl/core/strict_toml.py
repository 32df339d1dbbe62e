"""Strict reading of pmctl's TOML files (the machine config, the service config).

One loader for both, so that every config is read the same way:

- ``read_toml(path)``: at most ``MAX_TOML_BYTES``, UTF-8 (a leading BOM is tolerated; a bad byte is
  reported with its line and column), TOML syntax errors with their line and column, integers of
  thousands of digits and absurdly deep nesting refused as ConfigError (never a ValueError or a
  RecursionError);
- ``check_tables(path, data, required, optional)``: unknown top-level tables are refused (with the
  nearest known name: ``[stifness]`` is not silently ignored);
- ``Table``: reads one table and refuses, with file, key and reason, anything that is not exactly
  the expected type. No coercion: a string is never a number (``"0.5"``), a bool is never a number
  (``true``), a string is never a bool (``"no"``), a float is never an integer; integers beyond
  +-2^53 are refused before they become floats; every number is finite and within the range the key
  allows; ``finish()`` refuses the keys nobody read (misspellings), naming the expected key when only
  the unit suffix differs.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from pathlib import Path

import numpy as np

from pmctl.core.errors import ConfigError

MAX_TOML_BYTES = 1 * 2**20
MAX_EXACT_INT = 2**53
UNIT_SUFFIXES = ("_ue_per_N", "_N_per_mm", "_mm_s2", "_mm_s", "_m_s2", "_mm", "_deg", "_kg", "_hz", "_s",
                 "_ms", "_us", "_per_s")


def read_toml(path) -> dict:
    """Read and parse a TOML file strictly (see the module docstring); ConfigError(path, "-", ...)."""
    p = Path(path)
    try:
        with open(p, "rb") as f:
            raw = f.read(MAX_TOML_BYTES + 1)
    except (OSError, ValueError) as e:
        raise ConfigError(p, "-", f"cannot read: {getattr(e, 'strerror', None) or e}") from None
    if len(raw) > MAX_TOML_BYTES:
        raise ConfigError(p, "-", f"larger than {MAX_TOML_BYTES // 2**20} MiB: not a config file")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = raw.count(b"\n", 0, e.start) + 1
        col = e.start - (raw.rfind(b"\n", 0, e.start) + 1) + 1
        raise ConfigError(p, "-", f"line {line}, column {col}: byte 0x{raw[e.start]:02x} is not UTF-8 text") from None
    return loads(text, p)


def loads(text: str, path="<string>") -> dict:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(path, "-", f"not valid TOML: {e}") from None
    except ValueError as e:              # e.g. an integer of more than 4300 digits
        raise ConfigError(path, "-", f"not valid TOML: {e}") from None
    except RecursionError:
        raise ConfigError(path, "-", "not valid TOML: arrays or tables nested too deeply") from None


def check_tables(path, data: dict, required=(), optional=()):
    """Refuse a missing required table and any unknown top-level key (with the nearest known name)."""
    known = list(required) + list(optional)
    for k, v in data.items():
        if k not in known:
            near = difflib.get_close_matches(k, known, n=1, cutoff=0.6)
            raise ConfigError(path, k, "unknown table" + (f" (did you mean [{near[0]}]?)" if near else "")
                              + f"; known: {', '.join(known)}")
        if not isinstance(v, dict):
            raise ConfigError(path, k, f"must be a table [{k}], got {_kind(v)}")
    for k in required:
        if k not in data:
            raise ConfigError(path, k, "missing table")


def _kind(v) -> str:
    if isinstance(v, bool):
        return f"a bool ({str(v).lower()})"
    if isinstance(v, (int, float)):
        if isinstance(v, int) and abs(v) > MAX_EXACT_INT:
            return f"an integer of {len(str(abs(v)))} digits (beyond +-2^53)"
        return f"a number ({v!r})"
    if isinstance(v, str):
        show = v if len(v) <= 40 else v[:37] + "..."
        return f"a string ({show!r})"
    if isinstance(v, list):
        return f"an array of {len(v)}"
    if isinstance(v, dict):
        return "a table"
    return type(v).__name__


def _real(v):
    """The float of a TOML/Python real number, or None if ``v`` is not one (bools and strings are not)."""
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        return None
    if isinstance(v, (int, np.integer)) and abs(int(v)) > MAX_EXACT_INT:
        return None
    return float(v)


def _g(x):
    return str(x) if isinstance(x, int) else f"{x:g}"


def _range_text(lo, hi, lo_open, hi_open):
    if lo is not None and hi is not None:
        return f"within {'(' if lo_open else '['}{_g(lo)}, {_g(hi)}{')' if hi_open else ']'}"
    if lo is not None:
        return f"{'>' if lo_open else '>='} {_g(lo)}"
    return f"{'<' if hi_open else '<='} {_g(hi)}"


class Table:
    """Reads one TOML table, tracking which keys were used so leftovers can be reported."""

    def __init__(self, path, data, name):
        self.path, self.name = path, name
        if not isinstance(data, dict):
            raise ConfigError(path, name, f"must be a table, got {_kind(data)}")
        self.data = data
        self.used: set[str] = set()
        self.asked: set[str] = set()     # every key this table knows (read or defaulted)

    def _key(self, key):
        return f"{self.name}.{key}" if self.name else key

    def error(self, key, reason) -> ConfigError:
        return ConfigError(self.path, self._key(key), reason)

    def _missing(self, key):
        stem = key
        for unit in sorted(UNIT_SUFFIXES, key=len, reverse=True):
            if key.endswith(unit):
                stem = key[: -len(unit)]
                break
        near = [k for k in self.data if k != key and k.startswith(stem) and k not in self.used]
        if near:
            return self.error(near[0], f"wrong unit or name: expected '{key}'")
        return self.error(key, "missing")

    def _get(self, key, default, required):
        self.asked.add(key)
        if key not in self.data:
            if required:
                raise self._missing(key)
            return False, default
        self.used.add(key)
        return True, self.data[key]

    @staticmethod
    def _check_real(x, lo, hi, lo_open, hi_open):
        if lo is not None and (x < lo or (lo_open and x == lo)):
            return False
        if hi is not None and (x > hi or (hi_open and x == hi)):
            return False
        return True

    def number(self, key, *, default=None, positive=False, nonneg=False, lo=None, hi=None) -> float:
        """A finite real number (TOML integer or float, never a bool or a string) within the range:
        ``positive`` (> 0), ``nonneg`` (>= 0), ``lo``/``hi`` inclusive."""
        present, v = self._get(key, default, default is None)
        if not present:
            return float(default)
        x = _real(v)
        if x is None:
            raise self.error(key, f"must be a number, got {_kind(v)}")
        if not math.isfinite(x):
            raise self.error(key, f"must be finite, got {v!r}")
        lo_open = positive
        if positive or nonneg:
            lo = 0.0 if lo is None else max(lo, 0.0)
        if not self._check_real(x, lo, hi, lo_open, False):
            raise self.error(key, f"must be {_range_text(lo, hi, lo_open, False)}, got {x:g}")
        return x

    def integer(self, key, *, default=None, lo=None, hi=None) -> int:
        """A TOML integer (never a float, a bool or a string) within [lo, hi]."""
        present, v = self._get(key, default, default is None)
        if not present:
            return int(default)
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise self.error(key, f"must be an integer, got {_kind(v)}")
        v = int(v)
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            if abs(v) > 10**15:
                raise self.error(key, f"must be {_range_text(lo, hi, False, False)}, got an integer of "
                                      f"{len(str(abs(v)))} digits")
            raise self.error(key, f"must be {_range_text(lo, hi, False, False)}, got {v}")
        return v

    def boolean(self, key, *, default=None) -> bool:
        """``true`` or ``false`` (never a string such as "no", never 0/1)."""
        present, v = self._get(key, default, default is None)
        if not present:
            return bool(default)
        if not isinstance(v, bool):
            raise self.error(key, f"must be true or false, got {_kind(v)}")
        return v

    def string(self, key, default=None, *, choices=None) -> str:
        present, v = self._get(key, default, default is None)
        if not present:
            return default
        if not isinstance(v, str):
            raise self.error(key, f"must be a string, got {_kind(v)}")
        if "\0" in v:
            raise self.error(key, "must not contain a NUL character")
        if choices is not None and v not in choices:
            raise self.error(key, f"must be one of {', '.join(repr(c) for c in choices)}, got {_kind(v)}")
        return v

    def vector(self, key, n, *, default=None, lo=None, hi=None, positive=False, nonneg=False,
               scalar_ok=False) -> np.ndarray:
        """A list of ``n`` finite numbers within the range (``scalar_ok``: one number for all n)."""
        present, v = self._get(key, default, default is None)
        if not present:
            return np.array(default, dtype=float)
        seq = isinstance(v, (list, tuple)) or (isinstance(v, np.ndarray) and v.ndim == 1)
        if scalar_ok and not seq and not isinstance(v, np.ndarray):
            items = [v] * n
        else:
            items = list(v) if seq else None
        vals = None if items is None or len(items) != n else [_real(x) for x in items]
        if vals is None or any(x is None for x in vals):
            what = f"a number or a list of {n} numbers" if scalar_ok else f"a list of {n} numbers"
            raise self.error(key, f"must be {what}, got {_kind(v)}"
                             + (f" holding {_kind(items[[_real(x) for x in items].index(None)])}"
                                if seq and items and len(items) == n else ""))
        arr = np.array(vals, dtype=float)
        if not np.all(np.isfinite(arr)):
            raise self.error(key, "must be finite")
        lo_open = positive
        if positive or nonneg:
            lo = 0.0 if lo is None else max(lo, 0.0)
        for x in arr:
            if not self._check_real(x, lo, hi, lo_open, False):
                raise self.error(key, f"every value must be {_range_text(lo, hi, lo_open, False)}, got {x:g}")
        return arr

    def number_list(self, key, *, default=None, min_len=0, max_len=None, lo=None, hi=None):
        """A list of finite numbers (any length in [min_len, max_len]) within [lo, hi], as a tuple
        of floats; ``default`` when absent."""
        present, v = self._get(key, default, False)
        if not present:
            return default
        if not isinstance(v, list):
            raise self.error(key, f"must be a list of numbers, got {_kind(v)}")
        if len(v) < min_len or (max_len is not None and len(v) > max_len):
            raise self.error(key, f"must hold {min_len} to {max_len} numbers, got {len(v)}")
        out = []
        for i, x in enumerate(v):
            r = _real(x)
            if r is None:
                raise self.error(key, f"item {i} must be a number, got {_kind(x)}")
            if not math.isfinite(r) or not self._check_real(r, lo, hi, False, False):
                raise self.error(key, f"item {i} must be {_range_text(lo, hi, False, False)}, got {r:g}")
            out.append(r)
        return tuple(out)

    def matrix3(self, key, default, *, bound=None) -> np.ndarray:
        """3 rows of 3 finite numbers (|x| <= bound)."""
        self.asked.add(key)
        if key not in self.data:
            return default
        self.used.add(key)
        v = self.data[key]
        ok = isinstance(v, list) and len(v) == 3 and all(isinstance(r, list) and len(r) == 3 for r in v)
        vals = [[_real(x) for x in r] for r in v] if ok else None
        if not ok or any(x is None for r in vals for x in r):
            raise self.error(key, "must be 3 rows of [x, y, z] numbers")
        arr = np.array(vals, dtype=float)
        if not np.all(np.isfinite(arr)):
            raise self.error(key, "must be 3 rows of [x, y, z] finite numbers")
        if bound is not None and np.any(np.abs(arr) > bound):
            raise self.error(key, f"every value must be within [-{bound:g}, {bound:g}]")
        return arr

    def range(self, key, *, lo=None, hi=None):
        a, b = self.vector(key, 2, lo=lo, hi=hi)
        if not a < b:
            raise self.error(key, f"limits reversed or empty: [{a:g}, {b:g}]")
        return (float(a), float(b))

    def finish(self):
        extra = set(self.data) - self.used
        if extra:
            k = sorted(extra)[0]
            known = sorted(self.asked - self.used)
            near = difflib.get_close_matches(k, known, n=1, cutoff=0.6) if known else []
            raise self.error(k, "unknown key" + (f" (did you mean '{near[0]}'?)" if near else ""))
