"""A machining job: the list of moves both readers (CL data, G-code) produce and the planner consumes.

All in the workpiece frame W: tool tip in mm, tool axis a unit vector (tip -> spindle). A move goes
from where the previous one ended (the first from the planner's start pose) to its end pose:

- ``RAPID``  straight line at the planner's rapid speed (G0, CL links);
- ``LINE``   straight line at ``feed`` (G1, CL cutting points);
- ``ARC``    circular/helical arc (G2/G3) in the plane whose unit normal is ``normal`` (None: +z, the XY
             plane of G17; G18: +y, G19: +x, as LinuxCNC's canon) about the axis through ``center`` (a
             point in W; a 2-vector (x, y) is an XY arc's centre), sweeping ``sweep`` radians (positive:
             counter-clockwise seen from the tip of ``normal``); the radius goes linearly from the
             start radius to the end radius (a tolerated mismatch becomes a tiny spiral), the
             component along ``normal`` linearly (a helix);
- ``DWELL``  no motion for ``dwell`` seconds (G4);
- ``EVENT``  no motion: what happens when the path reaches this point, in program order (``events``,
             below). The planner makes it an exact stop and marks the stop's sample (Trajectory.marks).

A probing move (G38.2 / G38.3) is a ``LINE`` with ``probe`` = 2 or 3: planned like any feed line to
its target, it is where the control loop stops on contact (pmctl.motion.probe); ``probe`` = 2 makes a
move that ends without contact an error (grbl's probe-fail alarm), 3 does not.

The tool axis of every moving kind is interpolated by slerp from the start axis to the end axis.
``line`` is the source line (1-based; 0 for moves the reader added), ``spindle_rpm`` the commanded
spindle speed during the move (0 = off; negative: M4).

Fields added for the full RS-274 reader (each defaults to the old meaning):
- ``tool_offset``: the tool length offset in force (G43 H / G43.1, mm; 0 with G49): the tool is that much
  longer than the machine config's reference tool (``geometry.tool_length``), so the platform sits
  ``tool_offset`` further up the tool axis for the same tip; every IK of the move's poses uses
  ``tool_length + tool_offset``, which is IK of ``controlled_point(tip, axis, tool_offset)`` with the
  reference tool: the planner converts every pose it plans, once, and its samples are of that point;
  a change of offset is taken up by the move after it;
- ``duration``: G93 inverse-time feed: the move takes this many seconds at 100 % feed (0: ``feed`` applies);
- ``tolerance``: G64 P, the path tolerance (mm) the planner may use to blend or merge (0: exact path);
- ``events``: for ``EVENT``, a tuple of (name, value) in program order: ``("spindle", rpm)`` (signed, 0
  = stop), ``("coolant", "mist" | "flood" | "off")``, ``("tool_change", n)`` (M6: wait for the operator),
  ``("tool_offset", mm)`` (G43/G43.1/G49 changed the tool length offset at rest: the EVENT's tip is the
  new tip, the reference tool's point has not moved), ``("pause", "M0" | "M1" | "M60")``,
  ``("output", (name, index, value))`` (M62-M68, name "digital" or "analog"; the sim records them),
  ``("message", text)``, ``("user_m", (code, p, q))`` (a configured M100-M199); docs/gcode.md, "Events";
- ``file``: the source file when it is not the job's own (an external O-word subroutine); "" otherwise.

``load_job(path, machine)`` reads a file of either format by its suffix; ``read_job_text(path)`` is how
both readers get the text (UTF-8, at most ``MAX_JOB_BYTES`` and ``MAX_JOB_LINES``; a bad byte is reported with its line and
column). There is no bound on the number of moves: the streaming planner holds an index of the
job's segments and one window of it (docs/planning.md). ``Job.messages`` holds the program's operator messages (G-code ``(MSG, ...)`` comments) as
(line, text) pairs, for the operator to see before the job runs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pmctl.core import kinematics as K
from pmctl.core.errors import InputError, JobProblems, Problem

RAPID, LINE, ARC, DWELL, EVENT = "rapid", "line", "arc", "dwell", "event"
KINDS = (RAPID, LINE, ARC, DWELL, EVENT)

GCODE_SUFFIXES = (".ngc", ".nc", ".gcode", ".tap")
CL_SUFFIXES = (".cl", ".cls", ".txt", ".csv")
MAX_JOB_BYTES = 8 * 2**20         # a job file larger than this is refused before it is parsed (~300k lines)
MAX_JOB_LINES = 200_000           # lines in a job file (4x the move bound: room for comments and modal lines)


@dataclass(frozen=True)
class Move:
    kind: str
    tip: np.ndarray                  # (3,) end tool tip in W, mm
    axis: np.ndarray                 # (3,) end unit tool axis
    line: int = 0                    # source line, 1-based (0: added by the reader)
    feed: float = 0.0                # mm/s for LINE and ARC (0 for RAPID and DWELL)
    spindle_rpm: float = 0.0
    center: np.ndarray | None = None  # ARC: a point on the arc's axis in W (x, y, z), or (x, y) for XY
    sweep: float = 0.0               # ARC: signed sweep angle, rad (+ = counter-clockwise about normal)
    dwell: float = 0.0               # DWELL: seconds
    probe: int = 0                   # LINE: 0, or 2 / 3 for a G38.2 / G38.3 probing move
    normal: np.ndarray | None = None  # ARC: unit normal of the arc's plane (None: +z)
    tool_offset: float = 0.0         # mm the tool is longer than the reference tool (G43 H / G43.1)
    duration: float = 0.0            # G93: seconds for the move at 100 % feed (0: use feed)
    tolerance: float = 0.0           # G64 P: path tolerance the planner may use, mm (0: exact)
    events: tuple = ()               # EVENT: ((name, value), ...) in program order
    file: str = ""                   # source file if not the job's own (external subroutine)


@dataclass(frozen=True)
class Job:
    moves: tuple[Move, ...]
    source: str = ""
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # programmed tip points in W
    point_lines: np.ndarray = field(default_factory=lambda: np.zeros(0, int))  # their source lines
    messages: tuple = ()             # (line, text) operator messages of the program, in order

    def __len__(self):
        return len(self.moves)


def read_job_text(path) -> str:
    """The text of a job file: UTF-8 (a leading BOM is dropped), at most ``MAX_JOB_BYTES``. InputError
    with the line and column of the first byte that is not UTF-8."""
    path = Path(path)
    try:
        with open(path, "rb") as f:          # never more than the limit (a device, a growing file)
            raw = f.read(MAX_JOB_BYTES + 1)
    except OSError as e:
        raise InputError(path, None, f"cannot read: {e.strerror or e}") from None
    if len(raw) > MAX_JOB_BYTES:
        raise InputError(path, None, f"job file is larger than the limit of {MAX_JOB_BYTES // 2**20} MiB")
    lines = raw.count(b"\n") + 1
    if lines > MAX_JOB_LINES:
        raise InputError(path, MAX_JOB_LINES + 1, f"job file has {lines} lines; the limit is {MAX_JOB_LINES} "
                                                  "(split the job)")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = raw.count(b"\n", 0, e.start) + 1
        col = e.start - (raw.rfind(b"\n", 0, e.start) + 1) + 1
        raise InputError(path, line, f"byte 0x{raw[e.start]:02x} is not UTF-8 text", column=col) from None


def controlled_point(tip, axis, tool_offset):
    """The point the machine's model must put its tip on for the tool tip ``tip`` with the tool axis
    ``axis`` (unit) and a tool ``tool_offset`` mm longer than the reference tool: ``tip + tool_offset *
    axis`` (any leading dimensions; ``tool_offset`` broadcasts). The machine model (pmctl.core.kinematics,
    the rt side, the simulation, recordings) knows only the reference tool (``geometry.tool_length``):
    IK of this point with it is IK of ``tip`` with a tool of ``tool_length + tool_offset``. The planner
    applies it, once, to every pose it plans (its samples are of this point); this is the one place
    where the conversion is written."""
    tip = np.asarray(tip, float)
    off = np.asarray(tool_offset, float)
    return tip + off[..., None] * np.asarray(axis, float)


def home_pose(machine):
    """Tool tip (W) and axis at home: P = (0, 0, Z_home), level platform, table at X = Y = 0."""
    g = machine.geometry
    tip, axis = K.tool_of_platform(np.array([0.0, 0.0, g.z_home]), np.eye(3), np.zeros(2), g)
    return tip, axis / np.linalg.norm(axis)


def check_reach(tip, axis, lines, machine, path, tool_offset=None) -> K.IKResult:
    """IK of every pose (with the tool length offsets ``tool_offset`` of the poses, mm; None: the
    reference tool); InputError at the first line whose pose is out of the tilt range or unreachable."""
    lo, hi = machine.limits.theta2_deg
    tilt = np.degrees(np.arccos(np.clip(axis[:, 2], -1.0, 1.0)))
    bad = tilt > min(abs(lo), abs(hi)) + 1e-9
    if np.any(bad):
        k = int(np.argmax(bad))
        raise InputError(path, int(lines[k]), f"tool axis tilted {tilt[k]:.4f} deg, beyond the machine's "
                                              f"theta2 limit {min(abs(lo), abs(hi)):g} deg")
    if tool_offset is not None:
        tip = controlled_point(tip, axis / np.linalg.norm(axis, axis=-1, keepdims=True), tool_offset)
    r = K.ik_batch(tip, axis, machine)
    if not np.all(r.ok):
        k = int(np.argmax(~r.ok))
        more = int(np.count_nonzero(~r.ok)) - 1
        raise InputError(path, int(lines[k]), f"pose unreachable: {r.reason[k]}"
                                              + (f" (and {more} more unreachable lines)" if more else ""))
    return r


def load_job(path, machine, *, start=None, **options) -> Job:
    """Read a job file, dispatching on its suffix (G-code: .ngc .nc .gcode .tap; CL: .cl .cls .txt .csv).

    ``start`` = (tip, axis) where the machine is when the job begins (default: the home pose). G-code
    needs it (G91 moves, arcs and the initial A/B are relative to it), so pass the planner's start
    pose here too; CL data is absolute and ignores it. ``options`` go to the reader (CL data:
    ``vector``, ``feed_mm_min``, ``clearance_mm``, ``spindle_rpm``)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in GCODE_SUFFIXES:
        from pmctl.task.gcode import read_gcode
        return read_gcode(path, machine, start=start, **options)
    if suffix in CL_SUFFIXES:
        from pmctl.task.cldata import read_cl_job
        return read_cl_job(path, machine, **options)
    raise InputError(path, None, f"unknown job format {suffix!r}: use G-code ({' '.join(GCODE_SUFFIXES)}) "
                                 f"or CL data ({' '.join(CL_SUFFIXES)})")


_UNSUPPORTED_WORDS = ("not supported", "unsupported", "refused", "unknown job format", "is not implemented")


def problem_kind(reason: str) -> str:
    """The kind of a reader's refusal (``syntax`` or ``unsupported``) from its message: what the reader
    understood but does not do is ``unsupported``, anything malformed ``syntax``."""
    low = reason.lower()
    return "unsupported" if any(w in low for w in _UNSUPPORTED_WORDS) else "syntax"


def parse_job(path, machine, *, start=None, **options) -> tuple:
    """Read and parse a job file without checking it against the machine, and without raising:
    (Job or None, [Problem, ...]). Every problem the reader reports is listed: the G-code reader
    (pmctl.task.rs274) finds them all and gives the job of the blocks that had none; the CL reader
    stops at its first refusal (no job). The machine and the planner are checked by pmctl.task.jobcheck.
    ``start`` and ``options`` as for :func:`load_job`."""
    path = Path(path)
    suffix = path.suffix.lower()
    try:
        if suffix in GCODE_SUFFIXES:
            from pmctl.task.gcode import interpret_file      # (job, problems): every problem, no raise
            return interpret_file(path, machine, start=start, **options)
        if suffix in CL_SUFFIXES:
            from pmctl.task.cldata import cl_job, parse_cl
            vector = options.pop("vector", "axis")
            return cl_job(parse_cl(read_job_text(path), path, vector=vector), None, **options), []
        raise InputError(path, None, f"unknown job format {suffix!r}: use G-code ({' '.join(GCODE_SUFFIXES)}) "
                                     f"or CL data ({' '.join(CL_SUFFIXES)})")
    except JobProblems as e:
        return None, list(e.problems)
    except InputError as e:
        return None, [Problem(e.path, e.line, e.column, problem_kind(e.reason), e.reason)]
