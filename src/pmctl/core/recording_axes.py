"""Recordings of a machine of independent axes: ``"machine": "axes"`` (docs/recording.md, "Generic axes").

A test bench, a drive's scope export, a LinuxCNC halsampler log or an accelerometer on a spindle
records single axes before the whole machine exists. Such a recording names its axes by its
``cmd_<A>`` columns (``A``: a letter, then letters or digits: ``X``, ``Z2``, ``spindle``) and may
carry, per axis:

- ``enc_<A>``: the motor-side position (the drive's encoder);
- ``load_<A>``: a second, load-side encoder (a linear scale on the table);
- ``effort_<A>``: the drive's force, torque or motor current;
- ``acc_<A>``: an accelerometer on the moving part, along the axis;

and any ``temp_<name>``. Units are per channel in recording.json's ``channels`` notes
(``{"cmd_X": {"unit": "m"}}``) and converted on read to the units the twin works in:

=============  ==========================================  ===================
channel        units accepted                              converted to
=============  ==========================================  ===================
t              s, ms, us, min                              s
cmd/enc/load   linear: mm, m, cm, um (µm), nm, in;         mm (linear axis)
               rotary: deg, rad, mrad, rev, arcmin, arcsec  deg (rotary axis)
effort         force: N, kN, mN, lbf; torque: N m (Nm,      N, N m or A
               N·m), mN m, kN m; current: A, mA
acc            m/s^2, mm/s^2, um/s^2, g (linear);           mm/s^2 or deg/s^2
               rad/s^2, deg/s^2 (rotary)
temp_*         C (°C, degC), K, F                          °C
=============  ==========================================  ===================

An axis is rotary when its ``cmd_<A>`` unit is an angle, linear otherwise (the default unit is mm).
Its other channels must be of the same kind: an angle for ``enc``/``load``, a torque (or current)
for ``effort`` of a rotary axis, a force (or current) of a linear one. A current is kept in A
unless the effort channel's notes give the drive's constant (``"force_constant_N_per_A"`` for a
linear axis, ``"torque_constant_Nm_per_A"`` for a rotary one), which converts it. Optional notes of
the ``cmd_<A>`` channel: ``"lead_mm"`` (the screw lead, so a periodic error at the lead is named a
pitch error).

Pure functions; errors are :class:`pmctl.core.errors.InputError` naming recording.json and the
field (``channels.effort_X.unit``).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pmctl.core.errors import InputError

GENERIC = "axes"                      # the recording.json "machine" of a recording of independent axes
KINDS = ("cmd", "enc", "load", "effort", "acc")
_NAME_RE = re.compile(r"^(cmd|enc|load|effort|acc)_([A-Za-z][A-Za-z0-9]*)$")
_TEMP_RE = re.compile(r"^temp_[A-Za-z0-9_.\-]+$")

LENGTH = {"mm": 1.0, "m": 1e3, "cm": 10.0, "um": 1e-3, "µm": 1e-3, "μm": 1e-3, "micron": 1e-3,
          "nm": 1e-6, "in": 25.4, "inch": 25.4}
ANGLE = {"deg": 1.0, "°": 1.0, "degree": 1.0, "degrees": 1.0, "rad": 180.0 / math.pi,
         "mrad": 0.18 / math.pi, "rev": 360.0, "turn": 360.0, "arcmin": 1.0 / 60, "arcsec": 1.0 / 3600}
FORCE = {"N": 1.0, "kN": 1e3, "mN": 1e-3, "lbf": 4.4482216152605}
TORQUE = {"N m": 1.0, "Nm": 1.0, "mN m": 1e-3, "mNm": 1e-3, "kN m": 1e3, "kNm": 1e3}
CURRENT = {"A": 1.0, "mA": 1e-3}
ACC_LINEAR = {"mm/s^2": 1.0, "m/s^2": 1e3, "um/s^2": 1e-3, "µm/s^2": 1e-3, "g": 9806.65}
ACC_ROTARY = {"deg/s^2": 1.0, "rad/s^2": 180.0 / math.pi}
TIME = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "min": 60.0}
TEMP = {"C": (1.0, 0.0), "°C": (1.0, 0.0), "degC": (1.0, 0.0), "K": (1.0, -273.15),
        "F": (5.0 / 9.0, -32.0 * 5.0 / 9.0), "°F": (5.0 / 9.0, -32.0 * 5.0 / 9.0)}


def channel_kind(name: str) -> str | None:
    """'time', 'cmd', 'enc', 'load', 'effort', 'acc', 'temp' or None (an unknown channel)."""
    if name == "t":
        return "time"
    m = _NAME_RE.match(name)
    if m:
        return m.group(1)
    return "temp" if _TEMP_RE.match(name) else None


def axis_of(name: str) -> str | None:
    """The axis of a ``cmd_/enc_/load_/effort_/acc_`` channel, else None."""
    m = _NAME_RE.match(name)
    return m.group(2) if m else None


def axes_of(names) -> list[str]:
    """The axes of a recording: its ``cmd_<A>`` columns, in their order."""
    return [axis_of(n) for n in names if channel_kind(n) == "cmd"]


def check_required(names, path) -> None:
    """InputError unless the header has ``t`` and at least one ``cmd_<A>``, and every other axis
    channel belongs to an axis with a command."""
    if "t" not in names:
        raise InputError(path, 1, "missing required channel 't' (required: t and at least one cmd_<A>)")
    axes = set(axes_of(names))
    if not axes:
        raise InputError(path, 1, 'a "machine": "axes" recording needs at least one cmd_<A> channel '
                                  "(A: the axis name, e.g. cmd_X)")
    for j, n in enumerate(names, 1):
        a = axis_of(n)
        if a is not None and a not in axes:
            raise InputError(path, 1, f"channel {n!r} belongs to axis {a!r}, which has no cmd_{a}", column=j)


def _norm(u: str) -> str:
    """A unit as written, with its spelling variants folded (N·m, N*m -> N m; m/s², m/s2 -> m/s^2)."""
    s = " ".join(str(u).replace("·", " ").replace("⋅", " ").replace("*", " ").split())
    s = s.replace("²", "^2").replace("s2", "s^2").replace("s^^2", "s^2")
    s = s.replace("deg C", "degC")
    return s


@dataclass
class AxesMachine:
    """What the twin knows of a machine of independent axes: only what its recording says."""

    axes: tuple                         # axis names, in the order of the cmd_<A> columns
    rotary: dict                        # axis -> True (deg) / False (mm)
    units: dict                         # channel -> unit after conversion ("mm", "deg", "N", "N m", "A", ...)
    effort: dict                        # axis -> "force" | "torque" | "current" (only axes with effort_<A>)
    lead_mm: dict = field(default_factory=dict)   # axis -> screw lead (cmd_<A> note "lead_mm"), when given
    name: str = GENERIC
    source: str = GENERIC
    compensation: object = None

    def pos_unit(self, axis: str) -> str:
        return "deg" if self.rotary.get(axis) else "mm"

    def effort_unit(self, axis: str) -> str:
        return self.units.get(f"effort_{axis}", "N")


def _bad(meta_path, text, key, reason):
    from pmctl.core.recording import _key_line
    return InputError(meta_path, _key_line(text, key) if text else None, f"channels.{key}.unit: {reason}")


def axes_machine(names, meta: dict, meta_path: Path | None = None, text: str = "") -> tuple[AxesMachine, dict]:
    """(the machine, {channel: (scale, offset)}) for a recording with these channel names and
    metadata: measured = raw·scale + offset in the units of the twin. InputError naming the field
    for a unit that is not known or not of the channel's kind."""
    notes = meta.get("channels", {}) or {}
    axes = axes_of(names)
    conv, units, rotary, effort, lead = {}, {}, {}, {}, {}

    def unit_of(ch):
        u = notes.get(ch, {}).get("unit")
        if u is not None and not isinstance(u, str):
            raise _bad(meta_path, text, ch, f"must be a string, got {u!r}")
        return None if u is None else _norm(u)

    for a in axes:
        u = unit_of(f"cmd_{a}")
        if u is None or u in LENGTH:
            rotary[a] = False
        elif u in ANGLE:
            rotary[a] = True
        else:
            raise _bad(meta_path, text, f"cmd_{a}", f"{u!r} is not a unit of length (mm, m, um, in) or angle (deg, rad, rev)")
        ld = notes.get(f"cmd_{a}", {}).get("lead_mm")
        if ld is not None:
            if isinstance(ld, bool) or not isinstance(ld, (int, float)) or not 0 < ld < 1e4:
                raise InputError(meta_path, None, f"channels.cmd_{a}.lead_mm: must be a positive number of mm")
            lead[a] = float(ld)
    for ch in names:
        k = channel_kind(ch)
        u = unit_of(ch)
        if k == "time":
            if u is not None:
                if u not in TIME:
                    raise _bad(meta_path, text, ch, f"{u!r} is not a unit of time (s, ms, us)")
                conv[ch] = (TIME[u], 0.0)
            units[ch] = "s"
        elif k in ("cmd", "enc", "load"):
            a = axis_of(ch)
            table, kind = (ANGLE, "angle (deg, rad, rev)") if rotary[a] else (LENGTH, "length (mm, m, um, in)")
            uu = u or ("deg" if rotary[a] else "mm")
            if uu not in table:
                raise _bad(meta_path, text, ch, f"{u!r} is not a unit of {kind}, as axis {a}'s cmd_{a} is")
            conv[ch] = (table[uu], 0.0)
            units[ch] = "deg" if rotary[a] else "mm"
        elif k == "effort":
            a = axis_of(ch)
            uu = u or ("N m" if rotary[a] else "N")
            own = TORQUE if rotary[a] else FORCE
            if uu in own:
                conv[ch] = (own[uu], 0.0)
                units[ch] = "N m" if rotary[a] else "N"
                effort[a] = "torque" if rotary[a] else "force"
            elif uu in CURRENT:
                key = "torque_constant_Nm_per_A" if rotary[a] else "force_constant_N_per_A"
                kc = notes.get(ch, {}).get(key)
                if kc is not None:
                    if isinstance(kc, bool) or not isinstance(kc, (int, float)) or not 0 < abs(kc) < 1e9:
                        raise InputError(meta_path, None, f"channels.{ch}.{key}: must be a non-zero number")
                    conv[ch] = (CURRENT[uu] * float(kc), 0.0)
                    units[ch] = "N m" if rotary[a] else "N"
                    effort[a] = "torque" if rotary[a] else "force"
                else:
                    conv[ch] = (CURRENT[uu], 0.0)
                    units[ch] = "A"
                    effort[a] = "current"
            else:
                what = "a torque (N m, mN m) or a current (A)" if rotary[a] else "a force (N, kN, lbf) or a current (A)"
                raise _bad(meta_path, text, ch, f"{uu!r} is not {what}, as the effort of "
                                                f"{'rotary' if rotary[a] else 'linear'} axis {a} must be")
        elif k == "acc":
            a = axis_of(ch)
            table = ACC_ROTARY if rotary[a] else ACC_LINEAR
            uu = u or ("deg/s^2" if rotary[a] else "mm/s^2")
            if uu not in table:
                raise _bad(meta_path, text, ch, f"{uu!r} is not an acceleration of a "
                                                f"{'rotary' if rotary[a] else 'linear'} axis "
                                                f"({', '.join(table)})")
            conv[ch] = (table[uu], 0.0)
            units[ch] = "deg/s^2" if rotary[a] else "mm/s^2"
        elif k == "temp":
            uu = u or "C"
            if uu not in TEMP:
                raise _bad(meta_path, text, ch, f"{uu!r} is not a temperature unit (C, K, F)")
            conv[ch] = TEMP[uu]
            units[ch] = "°C"
    conv = {k: v for k, v in conv.items() if v != (1.0, 0.0)}
    return AxesMachine(tuple(axes), rotary, units, effort, lead), conv


def convert(columns: dict, conv: dict) -> dict:
    """Apply the unit conversions of :func:`axes_machine` to the columns (in place; returned)."""
    for ch, (scale, off) in conv.items():
        if ch in columns:
            dt = columns[ch].dtype if isinstance(columns[ch], np.ndarray) else np.float64
            columns[ch] = (np.asarray(columns[ch], np.float64) * scale + off).astype(dt)
    return columns
