"""LinuxCNC's interpreter as the oracle of pmctl's: run ``rs274`` (Debian's linuxcnc-uspace, listed in
tests/peers/linuxcnc.apt) on a program and parse its canonical machining calls into what pmctl's
moves carry, in mm and in the workpiece frame W.

``rs274 -t TOOLS -g FILE OUT`` prints one canonical call a line (``STRAIGHT_FEED(x, y, z, a, b, c)``,
``ARC_FEED(first_end, second_end, first_centre, second_centre, turns, axis_end, a, b, c)``, ...) with
positions in program units and program coordinates; the offsets come as ``SET_G5X_OFFSET``,
``SET_G92_OFFSET`` and ``SET_XY_ROTATION``, the units as ``USE_LENGTH_UNITS``. The standalone rs274
reads its tool table in inches, so :func:`run` writes lengths and diameters given in mm divided by
25.4. A program runs from machine position 0 with every parameter 0.

Everything the oracle gives is in mm: W = R(rotation) (p + G92) + G5x for X Y (Z, A, B add the
offsets), feeds in mm/min (a feed is fixed in the units in force when F was set, as LinuxCNC's canon
keeps it), tool length offsets in mm.
"""

from __future__ import annotations

import fcntl
import math
import os
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass, field

RS274 = shutil.which("rs274")
# rs274 keeps its tool data in shared memory: two at once crash each other (SIGBUS). Runs from this
# machine's test workers take turns on this lock; a run that still dies of SIGBUS (another program's
# rs274) is repeated.
LOCK = os.path.join(tempfile.gettempdir(), "pmctl-rs274.lock")
SIGBUS_RETRIES = 5
_CALL = re.compile(r"^\s*\d+\s+N\S*\s+([A-Z_0-9]+)\((.*)\)\s*$")


@dataclass
class Motion:
    kind: str                    # rapid | line | arc | probe | dwell
    end: tuple                   # X Y Z A B in W (mm, deg)
    feed: float = 0.0            # mm/min (line, arc, probe)
    center: tuple | None = None  # arc: centre in W (x, y, z; the plane's third coordinate = the start's)
    normal: tuple | None = None  # arc: +z (G17), +y (G18), +x (G19)
    sweep: float = 0.0           # arc: signed radians about the normal
    dwell: float = 0.0
    tlo: float = 0.0             # tool length offset in force, mm
    inverse_time: bool = False
    spindle: float = 0.0         # signed rpm (0: stopped)
    unit: float = 1.0            # mm per program unit when rs274 printed it (its 4 decimals: the resolution)


@dataclass
class Result:
    ok: bool
    error: str
    motions: list = field(default_factory=list)
    events: list = field(default_factory=list)       # (name, value) in order: spindle, coolant, tool_change, ...
    raw: list = field(default_factory=list)          # (call, args) as printed
    messages: list = field(default_factory=list)


PLANES = {"CANON_PLANE_XY": ((0, 1, 2), (0.0, 0.0, 1.0)), "CANON_PLANE_XZ": ((2, 0, 1), (0.0, 1.0, 0.0)),
          "CANON_PLANE_YZ": ((1, 2, 0), (1.0, 0.0, 0.0))}


def available() -> bool:
    return RS274 is not None


def tool_table_text(tools) -> str:
    """A .tbl for rs274 from (number, length mm, diameter mm) triples (rs274 reads inches)."""
    lines = []
    for k, (n, length, diameter) in enumerate(tools, 1):
        lines.append(f"T{n} P{k} Z{length / 25.4:.10f} D{diameter / 25.4:.10f} ;t{n}")
    return "\n".join(lines) + "\n"


def invoke(args, *, cwd, timeout, **kw) -> subprocess.CompletedProcess:
    """Run an rs274 command line (stdin closed, output captured, ``kw`` to subprocess.run) on its turn
    of this machine's lock, again if it died of SIGBUS; raises subprocess.TimeoutExpired. Every
    rs274 the tests start goes through here (this oracle, tests/corpus_support.py)."""
    with open(LOCK, "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        for _ in range(SIGBUS_RETRIES):
            p = subprocess.run(args, cwd=cwd, stdin=subprocess.DEVNULL, capture_output=True, timeout=timeout, **kw)
            if p.returncode not in (-7, 135):        # SIGBUS: another rs274 shared its memory
                break
    return p


def run(text: str, tools=(), *, timeout=60, block_delete=False) -> Result:
    """Run rs274 on a program; parse its output (see the module doc)."""
    if RS274 is None:
        raise RuntimeError("rs274 (LinuxCNC) is not installed: tests/peers/install installs linuxcnc-uspace")
    with tempfile.TemporaryDirectory(prefix="pmctl-rs274-") as d:
        prog = os.path.join(d, "prog.ngc")
        tbl = os.path.join(d, "tools.tbl")
        out = os.path.join(d, "out.txt")
        with open(prog, "w") as f:
            f.write(text if text.endswith("\n") else text + "\n")
        with open(tbl, "w") as f:
            f.write(tool_table_text(tools))
        args = [RS274, "-t", tbl] + (["-b"] if block_delete else []) + ["-g", prog, out]
        p = invoke(args, cwd=d, timeout=timeout, text=True, errors="replace")
        with open(out, errors="replace") as f:
            lines = f.read().splitlines()
    err = "\n".join(x for x in (p.stdout + "\n" + p.stderr).splitlines() if x.strip() and x.strip() != "executing")
    return parse(lines, ok=p.returncode == 0, error=err)


def _nums(s):
    return [float(x) for x in re.split(r"[,\s]+", s.strip()) if x]


def parse(lines, ok=True, error="") -> Result:
    res = Result(ok, error)
    unit = 1.0
    g5x = [0.0] * 5
    g92 = [0.0] * 5
    rot = 0.0
    plane = PLANES["CANON_PLANE_XY"]
    feed = 0.0
    feed_mode = 0                  # 1: per revolution (G95)
    inverse = False                # G93 (rs274 says so in a comment; its feed is then the equivalent rate)
    tlo = 0.0
    speed, direction = 0.0, 0
    pos = [0.0] * 5

    def to_w(p):
        x, y = (p[0] + g92[0]), (p[1] + g92[1])
        r = math.radians(rot)
        c, s = math.cos(r), math.sin(r)
        return (c * x - s * y + g5x[0], s * x + c * y + g5x[1], p[2] + g92[2] + g5x[2], p[3] + g92[3] + g5x[3],
                p[4] + g92[4] + g5x[4])

    def to_prog(w):
        x, y = w[0] - g5x[0], w[1] - g5x[1]
        r = math.radians(rot)
        c, s = math.cos(r), math.sin(r)
        return [c * x + s * y - g92[0], -s * x + c * y - g92[1], w[2] - g5x[2] - g92[2], w[3] - g5x[3] - g92[3],
                w[4] - g5x[4] - g92[4]]

    for line in lines:
        m = _CALL.match(line)
        if not m:
            continue
        call, args = m.group(1), m.group(2)
        res.raw.append((call, args))
        if call == "USE_LENGTH_UNITS":
            unit = 25.4 if "INCHES" in args else 1.0
        elif call == "SET_G5X_OFFSET":
            v = _nums(args)
            g5x = [v[1] * unit, v[2] * unit, v[3] * unit, v[4], v[5]]
        elif call == "SET_G92_OFFSET":
            v = _nums(args)
            g92 = [v[0] * unit, v[1] * unit, v[2] * unit, v[3], v[4]]
        elif call == "SET_XY_ROTATION":
            rot = _nums(args)[0]
        elif call == "SELECT_PLANE":
            plane = PLANES[args.strip()]
        elif call == "SET_FEED_RATE":
            feed = _nums(args)[0] * unit
        elif call == "SET_FEED_MODE":
            feed_mode = int(_nums(args)[1])
        elif call == "COMMENT" and "feed mode set to" in args:
            inverse = "inverse time" in args
        elif call == "USE_TOOL_LENGTH_OFFSET":
            new = _nums(args)[2] * unit
            pos[2] -= new - tlo              # the controlled point stays: the tip moves by the change
            tlo = new
        elif call == "SET_SPINDLE_SPEED":
            speed = _nums(args)[1]
            if direction:
                res.events.append(("spindle", speed * direction))
        elif call in ("START_SPINDLE_CLOCKWISE", "START_SPINDLE_COUNTERCLOCKWISE"):
            direction = 1 if "COUNTER" not in call else -1
            res.events.append(("spindle", speed * direction))
        elif call == "STOP_SPINDLE_TURNING":
            if direction:
                res.events.append(("spindle", 0.0))
            direction = 0
        elif call in ("FLOOD_ON", "MIST_ON", "FLOOD_OFF", "MIST_OFF"):
            res.events.append(("coolant", call))
        elif call == "CHANGE_TOOL":
            res.events.append(("tool_change", args))
        elif call in ("PROGRAM_STOP", "OPTIONAL_PROGRAM_STOP", "PALLET_SHUTTLE"):
            res.events.append(("pause", call))
        elif call == "MESSAGE":
            res.messages.append(args.strip().strip('"'))
        elif call in ("SET_MOTION_OUTPUT_BIT", "CLEAR_MOTION_OUTPUT_BIT", "SET_AUX_OUTPUT_BIT", "CLEAR_AUX_OUTPUT_BIT",
                      "SET_MOTION_OUTPUT_VALUE", "SET_AUX_OUTPUT_VALUE"):
            res.events.append(("output", call, args))
        elif call in ("STRAIGHT_TRAVERSE", "STRAIGHT_FEED", "STRAIGHT_PROBE"):
            v = _nums(args)
            p = [v[0] * unit, v[1] * unit, v[2] * unit, v[3], v[4]]
            end = to_w(p)
            kind = {"STRAIGHT_TRAVERSE": "rapid", "STRAIGHT_FEED": "line", "STRAIGHT_PROBE": "probe"}[call]
            f = feed * speed if feed_mode == 1 else feed
            res.motions.append(Motion(kind, end, 0.0 if kind == "rapid" else f, tlo=tlo,
                                      inverse_time=inverse, spindle=speed * direction, unit=unit))
            pos = list(end)
        elif call == "ARC_FEED":
            v = _nums(args)
            (fi, si, ti), normal = plane
            e1, e2, c1, c2, turn, e3 = v[0] * unit, v[1] * unit, v[2] * unit, v[3] * unit, int(v[4]), v[5] * unit
            p = [0.0] * 5
            p[fi], p[si], p[ti], p[3], p[4] = e1, e2, e3, v[6], v[7]
            prog_pos = to_prog(pos)          # the offsets may have changed since the last move
            cp = list(prog_pos[:5])
            cp[fi], cp[si] = c1, c2
            sweep = find_turn((prog_pos[fi], prog_pos[si]), (c1, c2), turn, (e1, e2))
            end = to_w(p)
            cw = to_w(cp)
            n = normal
            if rot:
                r = math.radians(rot)
                n = (math.cos(r) * normal[0] - math.sin(r) * normal[1],
                     math.sin(r) * normal[0] + math.cos(r) * normal[1], normal[2])
            f = feed * speed if feed_mode == 1 else feed
            res.motions.append(Motion("arc", end, f, center=tuple(cw[:3]), normal=tuple(n), sweep=sweep, tlo=tlo,
                                      inverse_time=inverse, spindle=speed * direction, unit=unit))
            pos = list(end)
        elif call == "DWELL":
            res.motions.append(Motion("dwell", tuple(pos), dwell=_nums(args)[0], tlo=tlo, unit=unit))
    return res


def find_turn(start, center, turn, end):
    if turn == 0:
        return 0.0
    a = math.atan2(start[1] - center[1], start[0] - center[0])
    b = math.atan2(end[1] - center[1], end[0] - center[0])
    if turn > 0:
        if b <= a:
            b += 2 * math.pi
        return (b - a) + (turn - 1) * 2 * math.pi
    if a <= b:
        a += 2 * math.pi
    return (b - a) + (turn + 1) * 2 * math.pi


def pmctl_motions(job):
    """pmctl's moves in the oracle's terms (EVENT moves dropped; feeds in mm/min)."""
    out = []
    prev = None
    for m in job.moves:
        end = (*map(float, m.tip), *_ab(m.axis))
        if m.kind == "event":
            prev = end                   # a tool offset change moves the tip (its event is at the new tip)
            continue
        if m.kind == "dwell":
            out.append(Motion("dwell", end, dwell=m.dwell, tlo=m.tool_offset))
            continue
        kind = {"rapid": "rapid", "line": "probe" if m.probe else "line", "arc": "arc"}[m.kind]
        center = normal = None
        if m.kind == "arc":
            c = [float(x) for x in m.center]
            if len(c) == 2:
                c.append(float(prev[2]) if prev is not None else 0.0)
            center = tuple(c)
            normal = tuple(map(float, m.normal)) if m.normal is not None else (0.0, 0.0, 1.0)
        out.append(Motion(kind, end, m.feed * 60.0, center=center, normal=normal, sweep=m.sweep, tlo=m.tool_offset,
                          inverse_time=m.duration > 0, spindle=m.spindle_rpm))
        prev = end
    return out


def _ab(axis):
    from pmctl.core import kinematics as K
    a, b = K.roll_pitch_from_axis(tuple(float(x) for x in axis))
    return math.degrees(float(a)), math.degrees(float(b))


def compare(mine, theirs, *, tol=2e-4, skip_zero=True):
    """Differences between two motion lists (pmctl_motions vs Result.motions), as a list of
    strings (empty: they agree). ``tol``: in program units (rs274 prints 4 decimals, in the units in
    force: 1e-4 in = 2.5e-3 mm), so in mm x each rs274 motion's unit.
    Zero-length moves (rs274 prints a G0/G1 without axis words) and 0 s dwells are left out of both.
    Returns (problems, number of motions compared, max deviation mm)."""
    def keep(lst):
        # zero-length moves are left out: a line with only G0/G1 (rs274 prints a move to where it is), and a
        # move that only takes up a change of the tool length offset (the controlled point, tip + offset
        # along Z, stays: rs274's G28 after G43 moves "to the current position" that the offset moved)
        out, prev, prev_unit = [], (0.0, 0.0, 0.0, 0.0, 0.0), 1.0
        for m in lst:
            if skip_zero and m.kind == "dwell" and m.dwell == 0.0:
                continue
            cp = (m.end[0], m.end[1], m.end[2] + m.tlo, m.end[3], m.end[4])
            if skip_zero and m.kind in ("rapid", "line") and prev is not None and \
                    max(abs(a - b) for a, b in zip(cp, prev)) <= 6e-5 * max(m.unit, prev_unit):   # rs274's rounding
                continue                                  # (of this point or of the last, printed in inches)
            out.append(m)
            if m.kind != "dwell":
                prev, prev_unit = cp, m.unit
        return out
    a, b = keep(mine), keep(theirs)
    probs = []
    worst = 0.0
    if len(a) != len(b):
        probs.append(f"{len(a)} motions in pmctl, {len(b)} in rs274")
    for k, (x, y) in enumerate(zip(a, b)):
        t = tol * y.unit
        unit = y.unit
        if x.kind != y.kind:
            probs.append(f"motion {k}: {x.kind} in pmctl, {y.kind} in rs274")
            break
        d = max(abs(p - q) for p, q in zip(x.end[:3], y.end[:3]))
        d_ang = max(abs((p - q + 180.0) % 360.0 - 180.0) for p, q in zip(x.end[3:], y.end[3:]))   # A -181 = A 179
        worst = max(worst, d)
        if d > t or d_ang > 1e-3:
            probs.append(f"motion {k} ({x.kind}): end {fmt(x.end)} in pmctl, {fmt(y.end)} in rs274")
        if x.kind == "arc":
            dc = max(abs(p - q) for p, q in zip(x.center, y.center) if True)
            worst = max(worst, dc)
            nx, ny = x.normal, y.normal
            rad = math.dist(y.center, y.end[:3]) or 1.0
            if dc > t * 10 or max(abs(p - q) for p, q in zip(nx, ny)) > 1e-9 or \
                    abs(x.sweep - y.sweep) > max(1e-3, 20 * t / rad):
                probs.append(f"motion {k} (arc): centre {fmt(x.center)} normal {nx} sweep {x.sweep:.5f} in pmctl, "
                             f"{fmt(y.center)} {ny} {y.sweep:.5f} in rs274")
        if x.kind in ("line", "arc", "probe") and not x.inverse_time:
            if abs(x.feed - y.feed) > max(1e-3 * y.feed, 1e-3 * unit):
                probs.append(f"motion {k} ({x.kind}): feed {x.feed:.4f} in pmctl, {y.feed:.4f} mm/min in rs274")
        if x.kind == "dwell" and abs(x.dwell - y.dwell) > 1e-6:
            probs.append(f"motion {k}: dwell {x.dwell} in pmctl, {y.dwell} in rs274")
        if abs(x.tlo - y.tlo) > t:
            probs.append(f"motion {k}: tool offset {x.tlo:.4f} in pmctl, {y.tlo:.4f} in rs274")
        if len(probs) > 8:
            break
    return probs, min(len(a), len(b)), worst


def compare_merged(mine, theirs, tol_mm):
    """For programs of micro-segments (below the 4 decimals rs274 prints, consecutive points print the
    same) or whose points rs274 merged: every rs274 motion end must be a pmctl motion end, in order, and
    the pmctl points between two of them must lie within ``tol_mm`` of rs274's segment. Returns
    (problems, rs274 motions matched, pmctl points between matched ones)."""
    import numpy as np
    a = [m for m in mine if m.kind != "dwell"]
    b = [m for m in theirs if m.kind != "dwell"]
    j, prev, merged = 0, None, 0
    for k, y in enumerate(b):
        start = j
        t = 2e-4 * y.unit
        while j < len(a) and max(abs(p - q) for p, q in zip(a[j].end[:3], y.end[:3])) > t:
            j += 1
        if j == len(a):
            return [f"rs274 motion {k} {fmt(y.end)} is not a pmctl motion end"], k, merged
        if prev is not None and y.kind == "line":
            p0, p1 = np.array(prev[:3]), np.array(y.end[:3])
            d = p1 - p0
            n = float(np.linalg.norm(d)) or 1.0
            for m in a[start:j]:
                q = np.array(m.end[:3]) - p0
                dev = float(np.linalg.norm(q - d * (q @ d) / (n * n)))
                if dev > tol_mm + t:
                    return [f"pmctl point {fmt(m.end)} is {dev:.4f} mm off rs274's merged segment"], k, merged
        merged += j - start
        prev = y.end
        j += 1
    return [], len(b), merged


def fmt(v):
    return "(" + ", ".join(f"{x:.4f}" for x in v) + ")"
