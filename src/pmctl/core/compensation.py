"""Per-axis backlash and screw compensation (docs/machine.md §6): the table, its strict reading,
and its per-tick evaluation.

The NC's model joints are q = counts x resolution + c, where the compensation c of an axis is

    c = b + s(x, d)

- x = counts x resolution, the motor-side position (mm);
- d = the direction of the axis: +1 / -1 by the sign of the last commanded joint rate, held while
  the rate is zero (below ``STILL_MM_S``), 0 before the first move;
- b = the backlash term: it moves toward -d * backlash/2 at no more than ``backlash_rate_mm_s``
  (starting at 0, the middle of the play). Moving up, the load lags the motor by half the play
  (b = -backlash/2); after a reversal the motor first crosses the play, and the model says so;
- s = the screw table: the load-side error (true position - motor position, mm) interpolated
  linearly between the table's positions, ``forward_mm`` when d = +1, ``reverse_mm`` when d = -1,
  their mean when d = 0, and the end value beyond either end.

The NC drives the model joints to the target, so the *true* (load-side) positions follow it. This
is LinuxCNC's BACKLASH and COMP_FILE per joint, seen from the feedback side: LinuxCNC adds the
correction to the motor command and subtracts it from the feedback; here the pulse counters are the
motor command and the model is the feedback, so the correction enters once, where counters
become joints.

:func:`comp_tick` is the readable reference of one tick; the compiled NC core
(pmctl/motion/ncore/ncore.c, ``comp_tick``) does the same arithmetic in the same order on the flat
layout of :meth:`Compensation.flat`. Pure math; no I/O except :func:`read_compensation_file`.
"""

from __future__ import annotations

import difflib
import math
import re
from bisect import bisect_right
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pmctl.core.errors import ConfigError
from pmctl.core.strict_toml import Table, _kind, check_tables, read_toml

# A commanded rate below this (mm/s; a pulse in about six days) leaves the direction as it was: the
# pseudo-inverse leaves rounding residue (~1e-17 mm/s) on a joint that does not move while others
# do, and its sign is no direction (the two NCs, whose pseudo-inverses differ in the last bits,
# would read opposite ones, and the backlash term would jump half the play on a standing joint).
# ncore.h NC_COMP_STILL is the same number.
STILL_MM_S = 1e-9

AXES = ("L1", "L2", "L3", "X", "Y")
MAX_POINTS = 10_000                # per axis table
MAX_BACKLASH_MM = 5.0
MAX_ERROR_MM = 5.0
DEFAULT_RATE_MM_S = 5.0            # backlash take-up rate: 0.02 mm of play in 4 ms
HEADER = 4                         # per axis in the flat layout: backlash, rate, points, data offset


@dataclass(frozen=True)
class AxisComp:
    """One axis: backlash (mm, the full play) taken up at ``backlash_rate_mm_s``, and a screw table
    (strictly increasing positions, the load-side error at each, per direction)."""

    backlash_mm: float = 0.0
    backlash_rate_mm_s: float = DEFAULT_RATE_MM_S
    positions_mm: tuple = ()
    forward_mm: tuple = ()
    reverse_mm: tuple = ()

    def screw(self, x: float, d: float) -> float:
        """s(x, d): see the module docstring (plain floats, the core's operation order)."""
        P = self.positions_mm
        n = len(P)
        if n == 0:
            return 0.0
        if d > 0:
            return _interp(P, self.forward_mm, x)
        if d < 0:
            return _interp(P, self.reverse_mm, x)
        return 0.5 * (_interp(P, self.forward_mm, x) + _interp(P, self.reverse_mm, x))


def _interp(P, Y, x):
    n = len(P)
    if not x > P[0]:
        return Y[0]
    if not x < P[n - 1]:
        return Y[n - 1]
    k = bisect_right(P, x) - 1          # P[k] <= x < P[k + 1]
    return Y[k] + (x - P[k]) * ((Y[k + 1] - Y[k]) / (P[k + 1] - P[k]))


@dataclass(frozen=True)
class Compensation:
    axes: tuple                        # 5 AxisComp, in the order L1, L2, L3, X, Y
    source: str = ""

    @property
    def zero(self) -> bool:
        """True when it changes nothing (no backlash, every table entry 0)."""
        return all(a.backlash_mm == 0.0 and not any(a.forward_mm) and not any(a.reverse_mm) for a in self.axes)

    def flat(self) -> np.ndarray:
        """The compiled core's layout: 5 x (backlash, rate, points, offset), then per axis its
        positions, forward and reverse values (offset = index of its positions)."""
        head, data = [], []
        off = HEADER * 5
        for a in self.axes:
            n = len(a.positions_mm)
            head += [float(a.backlash_mm), float(a.backlash_rate_mm_s), float(n), float(off)]
            data += list(a.positions_mm) + list(a.forward_mm) + list(a.reverse_mm)
            off += 3 * n
        return np.array(head + data, float)

    def screw_error(self, axis: int, x, d=1.0) -> np.ndarray:
        """s(x, d) of one axis at many positions (for plots, the writer and tests)."""
        a = self.axes[axis]
        return np.array([a.screw(float(v), d) for v in np.atleast_1d(x)])

    def to_toml(self, header: str = "") -> str:
        """The ``[compensation.<axis>]`` tables (only axes that compensate something)."""
        out = [f"# {line}" if line else "#" for line in header.splitlines()] if header else []
        for name, a in zip(AXES, self.axes):
            if a.backlash_mm == 0.0 and not a.positions_mm:
                continue
            out += ["", f"[compensation.{name}]", f"backlash_mm = {_num(a.backlash_mm)}",
                    f"backlash_rate_mm_s = {_num(a.backlash_rate_mm_s)}"]
            if a.positions_mm:
                out.append(f"positions_mm = {_arr(a.positions_mm)}")
                out.append(f"forward_mm = {_arr(a.forward_mm)}")
                if tuple(a.reverse_mm) != tuple(a.forward_mm):
                    out.append(f"reverse_mm = {_arr(a.reverse_mm)}")
        return "\n".join(out).lstrip("\n") + "\n"


def _num(x: float) -> str:
    return repr(float(x))


def _arr(v) -> str:
    items = [_num(x) for x in v]
    lines = [", ".join(items[i:i + 8]) for i in range(0, len(items), 8)]
    return "[\n  " + ",\n  ".join(lines) + ",\n]"


NO_COMPENSATION = Compensation(tuple(AxisComp() for _ in AXES))


# ---------------------------------------------------------------- the tick (reference)

def comp_tick(comp: Compensation, x, qdot_prev, d, b, dt):
    """One tick of the compensation (plain float lists of 5): x motor positions, qdot_prev the last
    commanded joint rates, d and b the direction and backlash term of the last tick. Returns
    (c, d, b) of this tick. The compiled core's comp_tick does the same operations in this order."""
    c, d2, b2 = [0.0] * 5, [0.0] * 5, [0.0] * 5
    for i, a in enumerate(comp.axes):
        di = d[i]
        v = qdot_prev[i]
        if v > STILL_MM_S:
            di = 1.0
        elif v < -STILL_MM_S:
            di = -1.0
        tgt = -0.5 * a.backlash_mm * di
        step = a.backlash_rate_mm_s * dt
        bi = b[i]
        if tgt - bi > step:
            bi = bi + step
        elif bi - tgt > step:
            bi = bi - step
        else:
            bi = tgt
        c[i] = bi + a.screw(x[i], di)
        d2[i], b2[i] = di, bi
    return c, d2, b2


def replay(comp: Compensation, t, x) -> np.ndarray:
    """The compensation the NC applied along a recorded motion: x (n, 5) commanded (motor-side)
    positions at times t (n,). :func:`comp_tick` in closed form, vectorised (10^7 rows in seconds):
    the direction is the sign of the last nonzero position increment (the NC uses the commanded
    rate, of the same sign), the backlash term moves toward its side at its rate over the time
    elapsed since the previous sample of the other direction, the screw table is interpolated."""
    x = np.asarray(x, float)
    t = np.asarray(t, float)
    n = len(x)
    out = np.zeros_like(x)
    if n == 0:
        return out
    ar = np.arange(n)
    for i, a in enumerate(comp.axes):
        s = np.sign(np.diff(x[:, i], prepend=x[0, i]))
        last = np.maximum.accumulate(np.where(s != 0, ar, -1))
        d = np.where(last >= 0, s[np.maximum(last, 0)], 0.0)
        if a.backlash_mm:
            tgt = -0.5 * a.backlash_mm * d
            starts = np.flatnonzero(np.diff(d, prepend=d[0] - 1.0) != 0)     # first row of each run of d
            ends = np.append(starts[1:], n)
            b_prev, t_prev = 0.0, t[0]
            for s0, e in zip(starts, ends):
                gap = b_prev - tgt[s0]
                left = np.maximum(abs(gap) - a.backlash_rate_mm_s * (t[s0:e] - t_prev), 0.0)
                out[s0:e, i] = tgt[s0] + math.copysign(1.0, gap) * left
                b_prev, t_prev = out[e - 1, i], t[e - 1]
        if a.positions_mm:
            f = np.interp(x[:, i], a.positions_mm, a.forward_mm)
            r = np.interp(x[:, i], a.positions_mm, a.reverse_mm)
            out[:, i] += np.where(d > 0, f, np.where(d < 0, r, 0.5 * (f + r)))
    return out


# ---------------------------------------------------------------- reading

def _line_of(path, table: str, key: str) -> int | None:
    """Line of ``key`` inside ``[table]`` in the TOML file (for error messages), if found."""
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except (OSError, ValueError):
        return None
    inside = False
    head = re.compile(r"^\s*\[\s*([^\]]+?)\s*\]")
    for i, line in enumerate(text.splitlines(), 1):
        m = head.match(line)
        if m:
            inside = m.group(1).replace('"', "").replace(" ", "") == table
            continue
        if inside and re.match(rf"^\s*{re.escape(key)}\s*=", line):
            return i
    return None


def _error(path, table, key, reason) -> ConfigError:
    ln = _line_of(path, table, key) if key else None
    return ConfigError(path, f"{table}.{key}" if key else table, (f"line {ln}: " if ln else "") + reason)


def parse_compensation(path, data: dict, *, allow_file=True) -> Compensation:
    """The ``[compensation]`` table (already parsed TOML) of the file ``path``: either
    ``file = "other.toml"`` (relative to ``path``; that file holds its own ``[compensation]``) or
    one sub-table per axis. Strict: ConfigError naming file, line and key."""
    if not isinstance(data, dict):
        raise ConfigError(path, "compensation", f"must be a table, got {_kind(data)}")
    if "file" in data:
        if not allow_file:
            raise _error(path, "compensation", "file", "a compensation file cannot name another one")
        t = Table(path, data, "compensation")
        name = t.string("file")
        others = [k for k in data if k != "file"]
        if others:
            raise _error(path, "compensation", others[0] if not isinstance(data[others[0]], dict) else "file",
                         f"with 'file' the tables are in that file; [compensation.{others[0]}] here is refused")
        return read_compensation_file(Path(path).parent / name if not Path(name).is_absolute() else Path(name))
    axes = []
    for k, v in data.items():
        if k not in AXES:
            near = difflib.get_close_matches(str(k), AXES + ("file",), n=1, cutoff=0.5)
            raise _error(path, "compensation", k, "unknown axis" + (f" (did you mean '{near[0]}'?)" if near else "")
                         + f"; axes: {', '.join(AXES)}, or file = \"...\"")
    for name in AXES:
        axes.append(_axis(path, name, data.get(name, {})))
    return Compensation(tuple(axes), str(path))


def _axis(path, name, d) -> AxisComp:
    tname = f"compensation.{name}"
    t = Table(path, d, tname)
    try:
        bl = t.number("backlash_mm", default=0.0, nonneg=True, hi=MAX_BACKLASH_MM)
        rate = t.number("backlash_rate_mm_s", default=DEFAULT_RATE_MM_S, positive=True, hi=1e4)
        pos = t.number_list("positions_mm", default=(), min_len=2, max_len=MAX_POINTS, lo=-1e4, hi=1e4)
        fwd = t.number_list("forward_mm", default=(), min_len=2, max_len=MAX_POINTS,
                            lo=-MAX_ERROR_MM, hi=MAX_ERROR_MM)
        rev = t.number_list("reverse_mm", default=None, min_len=2, max_len=MAX_POINTS,
                            lo=-MAX_ERROR_MM, hi=MAX_ERROR_MM)
        t.finish()
    except ConfigError as e:          # add the line
        key = e.key.rsplit(".", 1)[-1] if isinstance(e.key, str) else None
        raise _error(path, tname, key, e.reason) from None
    if len(pos) and not len(fwd):
        raise _error(path, tname, "forward_mm", "missing: positions_mm needs the error at each position")
    if len(fwd) and not len(pos):
        raise _error(path, tname, "positions_mm", "missing: forward_mm needs the positions it is at")
    if rev is None:
        rev = fwd
    elif not len(pos):
        raise _error(path, tname, "positions_mm", "missing: reverse_mm needs the positions it is at")
    for key, v in (("forward_mm", fwd), ("reverse_mm", rev)):
        if len(v) != len(pos):
            raise _error(path, tname, key, f"has {len(v)} values for {len(pos)} positions")
    for i in range(1, len(pos)):
        if not pos[i] > pos[i - 1]:
            raise _error(path, tname, "positions_mm", f"must increase strictly: item {i} is {pos[i]:g} "
                                                      f"after {pos[i - 1]:g}")
    return AxisComp(bl, rate, tuple(pos), tuple(fwd), tuple(rev))


def read_compensation_file(path) -> Compensation:
    """A compensation file: a TOML file holding one ``[compensation]`` table (as written by
    ``pmctl twin diagnose --write-compensation``)."""
    data = read_toml(path)
    check_tables(path, data, ("compensation",))
    return parse_compensation(path, data["compensation"], allow_file=False)


def compensated_columns(columns: dict, comp: Compensation | None) -> dict:
    """A recording's columns as the compensated NC saw them: ``cmd_<axis>`` and ``enc_<axis>`` shifted
    by the compensation replayed along ``cmd`` (:func:`replay`), so that a model that reads them
    as joint positions predicts what the controller aimed at. Unchanged without a compensation."""
    if comp is None or comp.zero:
        return columns
    t = np.asarray(columns["t"], float)
    x = np.stack([np.asarray(columns[f"cmd_{a}"], float) for a in AXES], 1)
    ok = np.all(np.isfinite(x), 1)
    c = np.zeros_like(x)
    if ok.any():
        c[ok] = replay(comp, t[ok], x[ok])
    out = dict(columns)
    for i, a in enumerate(AXES):
        out[f"cmd_{a}"] = x[:, i] + c[:, i]
        if f"enc_{a}" in columns:
            out[f"enc_{a}"] = np.asarray(columns[f"enc_{a}"], float) + c[:, i]
    return out
