"""Path planner: a job (pmctl.core.job) -> a Trajectory (pmctl.motion.trajectory) sampled at the tick period.

Public API (stable)::

    plan(job, machine, dt, *, feed_override=1.0, limits=PlannerLimits(), start=None) -> Trajectory
    validate(job, machine, dt, ..., full=False, problems=None) -> path index  # checked, bounded memory
    plan_stream(job, machine, dt, ..., path=None)  # Trajectory pieces; joined = plan(...)
    home_pose(machine) -> (tip, axis)          # the default start pose (q at home)
    load_job(path, machine, **options)         # re-exported from pmctl.task.job, dispatches on suffix

``start`` is (tip, axis) in W where the tool is when the job begins (default: the home pose, tool
vertical at Z_home with the table centred). The first sample is exactly ``start``, the last exactly the
last programmed point; ``Trajectory.points`` holds the job's programmed points. docs/planning.md says
what a user needs to know (CAM output, tolerances, the checks); this says how it is done.

How it works (all vectorised with numpy):

1. **Geometry.** Each move becomes a segment with a path parameter s: the tip's arc length (for a
   pure reorientation, or a tilt whose tip travels under ``ROT_SWITCH`` of it, ``rotation_length_mm``
   x the slerp angle, plus the change of the tool length offset). Tip: straight line, or arc/helix in
   any plane (``_arc_frame``: a centre point, the plane's normal; the radius and the height along the
   normal linear in the angle); tool axis: slerp between the end axes. A G93 move's top speed is its
   length / duration. A tool length offset (Move.tool_offset) moves every pose the planner plans to
   the controlled point tip + offset * axis (pmctl.core.job.controlled_point: the reference tool's tip,
   what the machine's model commands); IK, the joint limits and the samples are of that point, the
   feed and the tip's limits of the programmed tip. Corners are never rounded, except under G64 P
   (Move.tolerance > 0): a corner between two feed lines with the same feed, spindle speed, offset
   and axis, turning by less than ``BLEND_MAX_TURN``, is replaced by a tangent arc whose middle is P
   from the corner (``_blend``; at most half of each line). **CAM output**: a run
   of feed lines with the same feed, spindle speed, offset, tolerance and tool axis is simplified
   before anything else (``_merged_away``, LinuxCNC's naive-CAM detector, Douglas-Peucker): every
   dropped point within the run's tolerance (G64 P, Move.tolerance; without one the larger of
   ``naive_cam_mm`` and the resolution the coordinates are written at, at most ``MAX_QUANTUM_MM``) of
   the line that replaces it, never across a turn back. Samples of a merged segment carry the line
   of the absorbed move they are on (``_Path.lines``).
2. **Limits along the path** on a grid in s (``grid_mm``): the feed (F x override, or the rapid speed)
   on the tip speed, the tool-axis angular rate, the tip's normal acceleration on curves, and the
   joint speed/acceleration limits of ``machine.limits``: q' = dq/ds and q'' from ``ik_batch`` by
   central differences give v <= qd_max/|q'|, v^2 |q''| <= qdd_max/2, |s''| |q'| <= qdd_max/2.
3. **Junctions** (grbl/Klipper-style look-ahead, adapted to a sampled trajectory that passes through
   the corner point): the velocity direction changes within one tick, so the corner speed is limited
   to v_j <= a_max dt / |d_out - d_in| for the tip and each joint. Exact stops at the start and end,
   dwells (G4), EVENT moves (spindle, coolant, tool change, pause...: pmctl.core.job), spindle changes
   and reversals.
4. **Velocity profile**: backward and forward passes of v^2 <= v_prev^2 + 2 a ds in closed form
   (prefix sums and running minima), giving a time-optimal, acceleration-limited profile s(t).
5. **Jerk limit**: s(t) is averaged over a moving window T = 2 a_t / j (exactly, via the integral of
   the piecewise-quadratic s(t)). Filtering the scalar s, not positions, keeps the tool on the path;
   the filtered profile has trapezoidal acceleration (an S-curve) with jerk <= 2 a_t / T. Limits are
   eroded beforehand (each cap extends c T around its point, every stop is held for T) so the filtered
   profile still respects them.
6. **Exact arrival**: a time warp puts every knot on a tick, and that sample is set to the programmed
   pose itself (tip and axis, bit for bit). The knots (``_Path.pin``) are the stops and, walking along
   the path, every boundary at least two ticks of top speed past the last knot: every segment end of
   ordinary moves; inside a run of micro-segments (shorter than that, left after merging) the points
   between knots are passed through on the path, not sampled (a tick each would make the samples'
   speed follow the segments' lengths). The warped clock lags real time by D(t), a
   monotone (PCHIP) interpolant of the lags at the knots, so the warp rate 1 - D' is <= 1: it only ever
   slows the profile (by at most about one tick per knot) and never breaks a limit. Samples held at
   a stop sit exactly on the point with zero velocity; those of a dwell carry the G4's line. Each
   EVENT move puts a mark (sample index in the piece, line, events) into ``Trajectory.marks`` on a
   sample held at its stop: the boundary's own tick, or, where a dwell is programmed at the same
   point, the dwell's sample after the part of the dwell programmed before the EVENT. Marks are in
   program order and the same from ``plan`` and ``plan_stream`` (``Trajectory.join`` keeps them); a job
   that does not move (only EVENTs and dwells) plans to its dwells' samples (one sample without a
   dwell) at the start pose, carrying the marks.
7. **Check and iterate**: the samples go through ``ik_batch``; an unreachable sample raises InputError
   with the job line; joint speed/acceleration, tip speed and acceleration are measured on the samples
   by finite differences, and where one exceeds its limit by more than ``VIOLATION_TOL`` the caps around
   it are lowered and the profile is re-planned (``max_iterations``). Where that does not meet the
   limits, the **fallback** (``_fall_back``): the segments around the offending samples get exact stops
   at both ends and half their top speed, and the path is planned again; after ``MAX_FALLBACKS``
   rounds PlanningError names the line.

Resource bounds: the batch planner holds the whole trajectory in memory (about 0.75 kB per sample at
its peak), so it refuses, with the file, the line and the reason and before allocating anything large,
a job of more than ``MAX_SAMPLES`` ticks (20 min at 1 kHz) or a path of more than ``MAX_GRID_POINTS``
limit-grid points (500 m at the default 0.25 mm grid). The duration is checked
three times: a lower bound (length / feed + dwells) before the limit grid, the grid size before
it is built, and the profile's true duration before it is sampled. A typo such as ``F0.42`` or a
``G4`` of days is refused this way in well under a second. There is no bound on the number of moves.

Streaming (``plan_stream``, what the daemon and ``pmctl run`` use): ``validate`` checks the whole job
first in chunks (feeds, a duration bound of ``MAX_STREAM_SECONDS``, the size of each move, the
reachability of every programmed pose and of the path between them every ``grid_mm``), so a bad line
is refused, named, before anything moves; ``validate(full=True)`` also plans the whole job, window by
window without keeping samples, and puts the fallback into the path where it is needed, so that
``plan_stream(path=...)`` of that path cannot fail midway (pmctl check, pmctl run and the supervisor
do this). Then windows of about ``STREAM_WINDOW`` segments, from knot to knot, are planned
by steps 2-7 above, each with margins of path on both sides: everything a sample depends on (cap
erosion, junction caps, the jerk filter, the warp's neighbouring knots, re-planning around a
violation) reaches a bounded distance of about v T, and the look-ahead of the speeds is checked (the
passes run again with the margins' ends at rest and must agree inside, else the margin doubles). A
window is computed in the job's own path coordinate and time is summed in extended precision, so
the pieces agree with ``plan`` to ~1e-11 mm on the bundled jobs (a few 1e-9 mm where a boundary is
passed at nearly zero speed). Memory: the job's segment index (~0.4 kB per move) and one window,
sampled ``SAMPLE_CHUNK`` ticks at a time.

Feeds are capped at ``rapid_mm_s``, the tool tip's top speed. Cost: a 10-minute 5-axis CL job
(18 000 moves, 614 000 samples at 1 kHz) plans in about 4 s of CPU (benchmarks/bench_planner.py); a
1.10 MB V-carve program of 31 000 steps of 1 um and less is read, checked and planned in about 1.1 s of
CPU (benchmarks/bench_microsegments.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PchipInterpolator

from pmctl.core import kinematics as K
from pmctl.core.errors import InputError, PmctlError, Problem
from pmctl.task.job import load_job
from pmctl.core.job import ARC, DWELL, EVENT, Job, LINE, RAPID, controlled_point, home_pose  # noqa: F401
from pmctl.motion.trajectory import Trajectory

__all__ = ["PlannerLimits", "plan", "plan_stream", "validate", "home_pose", "load_job", "PlanningError"]


VIOLATION_TOL = 1e-6      # relative overshoot of a limit on the samples that triggers re-planning
ROT_SWITCH = 0.1          # a move whose tip travels less than this x its rotation length is parameterised
                          # by the rotation (see _Path); above it, by the tip (faster with the caps as built)
MAX_SAMPLES = 1_200_000   # ticks of one planned job (20 min at 1 kHz; ~0.9 GB at the planner's peak)
MAX_GRID_POINTS = 2_000_000   # points of the limit grid along the path
# the streaming planner (plan_stream)
MAX_STREAM_SECONDS = 24 * 3600.0   # lower bound of a job's duration (a typo such as F0.42 is refused)
MAX_SEGMENT_GRID = 400_000    # grid points of one move (100 m at the default grid)
STREAM_WINDOW = 128           # segments planned together (each with margins of path on both sides)
STREAM_MARGIN_MM = 20.0       # first margin beyond what a window provably needs (doubled when too short)
STREAM_CHECK_MM = 20.0        # limits are checked this far beyond a window too
STREAM_KEEP = 60_000          # a window's samples up to this count are kept from its check, else sampled again


class PlanningError(PmctlError):
    """The planner could not meet the limits (should not happen for a reachable job); ``path`` and
    ``line`` say where, when known."""

    def __init__(self, msg, path=None, line=None):
        self.path, self.line = path, line
        super().__init__(msg)


class _NotConverged(Exception):
    """The limits still fail on the samples after ``max_iterations``: the segments of the offending
    samples and the line of the first."""

    def __init__(self, path, s_bad):
        super().__init__()
        seg, u = path.locate(np.sort(s_bad))
        self.segs = seg
        self.line = int(path.lines(seg[:1], u[:1])[0])


@dataclass(frozen=True)
class PlannerLimits:
    rapid_mm_s: float = 50.0          # G0 / link moves, tool tip speed; also the ceiling of any feed
    accel_mm_s2: float = 500.0        # tool tip acceleration (tangential and normal share it)
    jerk_mm_s3: float = 10000.0       # tangential jerk of the S-curve
    axis_rate_rad_s: float = 1.0      # tool axis angular speed
    rotation_length_mm: float = 100.0  # path length per radian of a pure reorientation move
    joint_fraction: float = 0.9       # share of the joint speed/accel limits the plan may use
    grid_mm: float = 0.25             # spacing of the limit grid along the path
    max_iterations: int = 10
    naive_cam_mm: float = 0.0005      # least path tolerance of a run of feed lines without G64 P (a chain pulse)

    @property
    def tangential_accel(self):
        return 0.7 * self.accel_mm_s2

    @property
    def normal_accel(self):
        return 0.7 * self.accel_mm_s2


# ---------------------------------------------------------------- geometry

MERGE_CHUNK = 4096            # points one merged line may pass through (bounds the work of a run)
SIMPLIFY_BATCH = 32           # the next ends of a merged line tried at once (_simplify)
MAX_QUANTUM_MM = 0.01         # the coarsest coordinate resolution taken as a run's default tolerance
_QUANTA = sorted([10.0 ** -k for k in range(2, 7)] + [25.4 * 10.0 ** -k for k in range(3, 8)], reverse=True)


def _quanta(pts):
    """The resolutions the points' coordinates may be written at (the coarsest first: 10^-k mm and
    10^-k inch, at most MAX_QUANTUM_MM) and, per point, a bit mask of those every coordinate of the
    point is a multiple of (bit k: the k-th resolution)."""
    qs = [q for q in _QUANTA if q <= MAX_QUANTUM_MM * (1 + 1e-9)]
    mask = np.zeros(len(pts), np.int64)
    for k, q in enumerate(qs):
        x = np.asarray(pts, float) / q
        mask |= np.all(np.abs(x - np.round(x)) < 1e-6, axis=1).astype(np.int64) << k
    return qs, mask


def _quantum_of(qs, mask) -> float:
    """The resolution a set of points is written at, from the AND of their masks (_quanta): the
    coarsest that every coordinate is a multiple of; 0 when none is."""
    mask = int(mask)
    return qs[(mask & -mask).bit_length() - 1] if mask else 0.0


def _merged_away(moves, start, limits: PlannerLimits, open_end: bool = False):
    """Which of ``moves``' end points the planner drops (a bool per move): LinuxCNC's naive-CAM
    detector. A run of consecutive feed lines (LINE, no probing, no G93 duration) with the same feed,
    spindle speed, tool offset, tolerance and tool axis (the axis of the point before the run too) is
    simplified within its tolerance: G64 P (``Move.tolerance``), or where that is 0 the larger of
    ``limits.naive_cam_mm`` and the resolution the points are written at (``_quanta``: a point
    written to 4 decimals in inches is only known to 2.54 um; dropping it within that loses nothing
    the program says). Along the run, from the last point kept, the line goes on to the next point
    as long as every point it passes is within the tolerance of it and none turns back along it by
    more than the tolerance (at most ``MERGE_CHUNK`` points a line); where the next point breaks
    that, the point before it is kept (``_simplify``). So the path stays within the tolerance of the
    programmed one, the lines kept run through kept points exactly, and each decision depends only
    on the points from the last kept one to the one after it: a job planned as its blocks arrive
    (pmctl.task.stream_planner) merges them as the whole job does.

    ``open_end`` (a job still growing): more moves may follow the last one. Returns (drop, n_final):
    the decisions for ``moves[:n_final]`` are final, those after the last point kept of a trailing
    run of lines (which the next move may continue) wait for the moves after them. ``start`` is the
    programmed pose before the first move."""
    nm = len(moves)
    drop = np.zeros(nm, bool)
    line_kind = np.fromiter((m.kind == "line" and not m.probe and not m.duration > 0 for m in moves), bool, nm)
    n_final = nm
    if open_end and nm and line_kind[-1]:
        n_final = nm - 1              # the last line may start a run with the next move
    if nm < 2 or line_kind.sum() < 2:
        return (drop, n_final) if open_end else drop
    tips = np.array([m.tip for m in moves], float)
    axes = np.array([m.axis for m in moves], float)
    attrs = np.array([(m.feed, m.spindle_rpm, m.tool_offset, m.tolerance) for m in moves], float)
    moving = np.fromiter((m.kind not in (DWELL, EVENT) for m in moves), bool, nm)
    # the point before each move (its start) and the axis there
    prev_tip = np.empty_like(tips)
    prev_axis = np.empty_like(axes)
    last_tip, last_axis = np.asarray(start[0], float), np.asarray(start[1], float)
    for i in range(nm):
        prev_tip[i], prev_axis[i] = last_tip, last_axis
        if moving[i]:
            last_tip, last_axis = tips[i], axes[i]
    # move i continues the run of move i-1: both lines, nothing between them, the same attributes, the
    # same axis all along
    same = np.zeros(nm, bool)
    same[1:] = (line_kind[1:] & line_kind[:-1] & np.all(attrs[1:] == attrs[:-1], axis=1)
                & np.all(axes[1:] == axes[:-1], axis=1) & np.all(prev_axis[:-1] == axes[:-1], axis=1))
    i = 1
    while i < nm:
        if not same[i]:
            i += 1
            continue
        a = i - 1                         # the run: moves a .. b, points prev_tip[a], tips[a .. b]
        b = i
        while b + 1 < nm and same[b + 1]:
            b += 1
        trailing = open_end and b == nm - 1
        keep, anchor = _simplify(np.vstack([prev_tip[a][None], tips[a:b + 1]]), attrs[a, 3], limits.naive_cam_mm,
                                 open_end=trailing)
        drop[a:b + 1] = ~keep[1:]
        if trailing:
            n_final = a + anchor          # the points after the last one kept wait for the next moves
        i = b + 1
    return (drop, n_final) if open_end else drop


def _simplify(pts, tol_fixed, naive_mm, open_end=False):
    """The points of a run to keep (``_merged_away``): from the last point kept (the first point
    always), the line goes on to the next point while every point between is within the tolerance of
    it and does not turn back along it by more than the tolerance (at most MERGE_CHUNK points a
    line); where the next point breaks that, the point before it is kept. The tolerance: ``tol_fixed``
    (G64 P) when > 0, else the larger of ``naive_mm`` and the resolution the points of the line are
    written at. Returns (keep, the index of the last point kept); ``open_end``: the last point is
    not decided (kept only where the end is the run's). The next ends are tried ``SIMPLIFY_BATCH``
    at a time, each on its own (the same numbers whatever the batch)."""
    m = len(pts)
    keep = np.zeros(m, bool)
    keep[0] = True
    qs, masks = _quanta(pts) if not tol_fixed > 0 else ([], np.zeros(m, np.int64))
    i0, j = 0, 1
    while j + 1 < m:
        ks = np.arange(j + 1, min(m, j + 1 + SIMPLIFY_BATCH))          # the next ends to try
        p = pts[i0]
        w = pts[i0 + 1:ks[-1]] - p                                       # the points a line to k passes
        d = pts[ks] - p
        dd = (d * d).sum(-1)
        along = (w[:, None, :] * d[None]).sum(-1)                        # (point, end)
        pos = dd > 0
        ddp = np.where(pos, dd, 1.0)
        t = np.where(pos, np.clip(along / ddp, 0.0, 1.0), 0.0)
        off = w[:, None, :] - t[..., None] * d[None]
        dist = np.sqrt((off * off).sum(-1))
        al = along / np.sqrt(ddp)
        dist = np.where(pos, np.maximum(dist, np.maximum.accumulate(al, axis=0) - al), dist)
        passed = np.arange(len(w))[:, None] < (ks - i0 - 1)[None]        # point r lies before end k
        worst = np.where(passed, dist, 0.0).max(axis=0) if len(w) else np.zeros(len(ks))
        if tol_fixed > 0:
            tol = np.full(len(ks), float(tol_fixed))
        else:
            cm = np.bitwise_and.accumulate(masks[i0:ks[-1] + 1])[ks - i0]
            tol = np.array([max(naive_mm, _quantum_of(qs, c)) for c in cm])
        ok = (worst <= tol) & (ks - i0 <= MERGE_CHUNK)
        bad = np.nonzero(~ok)[0]
        if not len(bad):
            j = int(ks[-1])
            continue
        j = int(ks[bad[0]]) - 1          # the line to the first end that fails: the point before is kept
        keep[j] = True
        i0, j = j, j + 1
    if not open_end:
        keep[m - 1] = True
    return keep, i0


SYNTH_KNOT_TICKS = 25         # ticks of top speed between knots that are no programmed point
BLEND_MAX_TURN = np.radians(170.0)   # a corner turning more than this is not rounded (nearly a reversal)


def _blend(tip, corner, m, m2, axis, a_1):
    """The arc rounding the corner at the end of feed line ``m`` (from ``tip``; the corner before it,
    the last programmed point, is ``corner``) into the next move ``m2``, within the tolerance G64 P:
    (end of the shortened line, end of the arc, arc frame, turn angle), or None where the corner is not
    rounded (m2 not a feed line with the same feed, spindle speed, offset and tool axis; no turn; a
    turn of more than BLEND_MAX_TURN). The arc is tangent to both lines; its middle is within the
    tolerance of the corner; it takes at most half of each line (corner to corner)."""
    if (m2.kind != LINE or m2.probe or m2.duration > 0 or not m2.tolerance > 0 or m2.feed != m.feed
            or m2.spindle_rpm != m.spindle_rpm or m2.tool_offset != m.tool_offset):
        return None
    a2 = np.asarray(m2.axis, float)
    if not (np.allclose(a2 / np.linalg.norm(a2), a_1, rtol=0, atol=1e-12) and np.allclose(axis, a_1, rtol=0,
                                                                                        atol=1e-12)):
        return None
    c = np.asarray(m.tip, float)
    v_in, v_out = c - np.asarray(corner, float), np.asarray(m2.tip, float) - c
    l_in, l_out = float(np.linalg.norm(v_in)), float(np.linalg.norm(v_out))
    if l_in < 1e-9 or l_out < 1e-9 or float(np.linalg.norm(c - tip)) < 1e-9:
        return None
    d_in, d_out = v_in / l_in, v_out / l_out
    turn = float(np.arccos(np.clip(d_in @ d_out, -1.0, 1.0)))
    if not 1e-7 < turn < BLEND_MAX_TURN:
        return None
    tol = min(float(m.tolerance), float(m2.tolerance))
    h = 0.5 * turn
    r = tol * np.cos(h) / (1.0 - np.cos(h))       # the arc's middle is tol from the corner
    d = r * np.tan(h)
    dmax = 0.5 * min(l_in, l_out, 2.0 * float(np.linalg.norm(c - tip)))
    if d > dmax:
        d = dmax
        r = d / np.tan(h)
    q1, q2 = c - d * d_in, c + d * d_out
    n = np.cross(d_in, d_out)
    n = n / np.linalg.norm(n)
    centre = q1 + r * np.cross(n, d_in)
    e1 = (q1 - centre) / r
    return q1, q2, (centre, n, e1, np.cross(n, e1), r, r, 0.0, 0.0), turn


def _arc_frame(p_start, p_end, m):
    """The frame of an ARC move from ``p_start``: (centre point, unit normal, e1, e2, r0, r1, h0, h1);
    the tip is c + h n + r (cos(sweep u) e1 + sin(sweep u) e2) with r and h linear in u (e1 towards the
    start, e2 = n x e1: a positive sweep turns counter-clockwise seen from the tip of n). A 2-vector
    centre is an XY arc's (x, y); a missing normal is +z (G17)."""
    c = np.asarray(m.center, float)
    if c.shape == (2,):
        c = np.array([c[0], c[1], 0.0])
    n = np.array([0.0, 0.0, 1.0]) if m.normal is None else np.asarray(m.normal, float)
    n = n / np.linalg.norm(n)
    w0, w1 = p_start - c, p_end - c
    h0, h1 = float(np.dot(w0, n)), float(np.dot(w1, n))
    d0, d1 = w0 - h0 * n, w1 - h1 * n
    r0, r1 = float(np.linalg.norm(d0)), float(np.linalg.norm(d1))
    if r0 > 1e-12:
        e1 = d0 / r0
    elif r1 > 1e-12:              # starting on the axis: e1 is where the end lies, turned back by the sweep
        f1 = d1 / r1
        e1 = np.cos(m.sweep) * f1 - np.sin(m.sweep) * np.cross(n, f1)
    else:
        e1 = K._perp_basis(n)[0]
    return c, n, e1, np.cross(n, e1), r0, r1, h0, h1


_SEG_FIELDS = ("kind", "p0", "p1", "a0", "a1", "phi", "c", "nrm", "e1", "e2", "r0", "r1", "h0", "h1", "sweep",
               "length", "vmax", "rot", "feed_length", "line", "rpm", "off0", "off1")


_SEG_DTYPES = {"kind": int, "rot": bool, "line": int}
_SEG_VECTORS = ("p0", "p1", "a0", "a1", "c", "nrm", "e1", "e2")


class _PathBuilder:
    """A job's segments built move by move (the path of ``_Path``): the arrays grow as moves are
    added, so the same code builds a whole job's path (``_Path(job, ...)``) and the path of a job that
    grows as blocks arrive (pmctl.task.stream_planner). ``add(m, nxt)`` takes a move the planner keeps
    (``nxt``: the next move it keeps, for rounding a corner under G64 P; None at the end), ``absorb(m)``
    one it drops (merged into the next segment). Everything about boundaries before the last one
    (``n``) is final once a segment starts there; the last boundary is the job's end so far.
    ``base``: the index of the first segment held (segments before it were let go, ``forget``)."""

    def __init__(self, start, limits: PlannerLimits, feed_override: float, dt: float, source="",
                 capacity: int = 64):
        tip, axis = (np.asarray(start[0], float), np.asarray(start[1], float))
        self.start_tip, self.start_axis = tip, axis
        self.limits, self.feed_override, self.dt, self.source = limits, feed_override, dt, source
        self.tip, self.axis = tip, axis / np.linalg.norm(axis)
        self.off = 0.0                # the tool length offset at the start pose: none (the reference tool)
        self.corner = tip             # the last programmed point kept (a rounded corner is not reached)
        self.rpm_prev = None
        self.n = 0                    # segments built (absolute index of the next one)
        self.base = 0                 # absolute index of the first segment held in the arrays
        self.cap = max(int(capacity), 1)
        self.a = {k: np.zeros((self.cap, 3) if k in _SEG_VECTORS else self.cap, _SEG_DTYPES.get(k, float))
                  for k in _SEG_FIELDS}
        self.s_end = np.zeros(self.cap)
        self.s_last = 0.0             # the path coordinate at boundary n
        self.stop = {0}               # boundaries (index = segments completed) with an exact stop
        self.dwell, self.dwell_line = {}, {}
        self.ev = []                  # EVENT moves: (boundary, dwell before, line, events)
        self.synth = set()            # boundaries that are no programmed point (the ends of rounding arcs)
        self.absorbed = []            # (end point, line) of the moves merged into the next segment
        self.mrg = []                 # (segment, u, line) of the moves merged into a segment
        self.has_off = False
        self.start_line = None
        # the knots (pin) decided so far, walking along the path (_pin_walk): boundaries <= pin_done
        self.pin = {0}
        self.pin_done, self.pin_last, self.pin_top = 0, 0.0, 0.0
        self.need = np.zeros(self.cap)   # 2 ticks of the top speed on each segment (_pin_walk)

    def _grow(self, n_more):
        need = self.n - self.base + n_more
        if need <= self.cap:
            return
        cap = max(need, 2 * self.cap)
        for k, v in self.a.items():
            w = np.zeros((cap,) + v.shape[1:], v.dtype)
            w[:len(v)] = v
            self.a[k] = w
        for k in ("s_end", "need"):
            v = getattr(self, k)
            w = np.zeros(cap)
            w[:len(v)] = v
            setattr(self, k, w)
        self.cap = cap

    def absorb(self, m):
        """A move whose end point is merged away (``_merged_away``): passed through, not a boundary."""
        if self.start_line is None:
            self.start_line = m.line
        self.absorbed.append((m.tip, m.line))

    def add(self, m, nxt=None):
        if self.start_line is None:
            self.start_line = m.line
        n = self.n
        if m.kind == DWELL:
            self.stop.add(n)
            self.dwell[n] = self.dwell.get(n, 0.0) + float(m.dwell)
            self.dwell_line[n] = m.line
            return
        if m.kind == EVENT:           # an exact stop; its mark goes on the stop's sample (after the
            self.stop.add(n)          # dwells programmed before it at this point)
            self.ev.append((n, self.dwell.get(n, 0.0), int(m.line), tuple(m.events)))
            return
        limits, tip, axis, off = self.limits, self.tip, self.axis, self.off
        t1 = np.asarray(m.tip, float)
        a_1 = np.asarray(m.axis, float)
        a_1 = a_1 / np.linalg.norm(a_1)
        o1 = float(m.tool_offset)
        # the pieces of this move: (end point, arc frame or None, sweep); a corner between two feed
        # lines under G64 P is rounded by an arc within the tolerance (_blend)
        bl = _blend(tip, self.corner, m, nxt, axis, a_1) if nxt is not None and _blendable(m) else None
        if bl is None:
            pieces = [(t1, _arc_frame(tip, t1, m) if m.kind == ARC else None, float(m.sweep))]
        else:
            pieces = [(bl[0], None, 0.0), (bl[1], bl[2], bl[3])]
        self.corner = t1
        self._grow(len(pieces))
        a = self.a
        for t1, arc, sw in pieces:
            ph = float(np.arccos(np.clip(np.dot(axis, a_1), -1.0, 1.0)))
            if arc is not None:
                ltip = float(np.hypot(0.5 * (arc[4] + arc[5]) * sw, arc[7] - arc[6]))
            else:
                ltip = float(np.linalg.norm(t1 - tip))
            rot = ltip < 1e-6
            # s is the tip's arc length, but for a tilt with a tiny tip motion (under ROT_SWITCH x
            # the rotation length) it is the rotation length: with 1e-5 mm of tip for 2 degrees the
            # joint derivatives dq/ds would be 1e6 and the acceleration caps crawl (2300 s for a
            # 3 s move). The feed still caps the tip's speed (v <= F / |dtip/ds|). A change of the
            # tool length offset alone moves the machine by that change along the tool axis.
            rl = limits.rotation_length_mm * ph + abs(o1 - off)
            ln = rl if rot or ltip < ROT_SWITCH * rl else ltip
            if ln < 1e-9:
                tip, axis, off = t1, a_1, o1     # nothing moves: the point is the current pose
                continue
            if self.rpm_prev is not None and m.spindle_rpm != self.rpm_prev:
                self.stop.add(n)
            self.rpm_prev = m.spindle_rpm
            flen = ln if rot else ltip
            if m.kind == RAPID:
                vm = limits.rapid_mm_s
            elif m.duration > 0:          # G93: the move takes `duration` s at 100 % feed
                vm = min(flen / float(m.duration) * self.feed_override, limits.rapid_mm_s)
            else:
                vm = min(m.feed * self.feed_override, limits.rapid_mm_s)
            if not vm > 0:
                raise InputError(self.source, m.line, f"move has no positive feed ({vm!r} mm/s)")
            i = n - self.base
            a["p0"][i], a["p1"][i], a["a0"][i], a["a1"][i], a["phi"][i] = tip, t1, axis, a_1, ph
            a["off0"][i], a["off1"][i] = off, o1
            if self.absorbed:             # where along this (merged) segment each absorbed move ended
                d = t1 - tip
                q = np.array([a_[0] for a_ in self.absorbed], float) - tip
                u_ = np.maximum.accumulate(np.clip(q @ d / max(float(d @ d), 1e-300), 0.0, 1.0))
                self.mrg.extend((n, float(uu), int(a_[1])) for uu, a_ in zip(u_, self.absorbed))
                self.absorbed = []
            if arc is not None:
                a["kind"][i] = 1
                a["c"][i], a["nrm"][i], a["e1"][i], a["e2"][i], a["r0"][i], a["r1"][i], a["h0"][i], a["h1"][i] = arc
                a["sweep"][i] = sw
            a["line"][i], a["rpm"][i], a["length"][i], a["rot"][i], a["vmax"][i] = m.line, m.spindle_rpm, ln, rot, vm
            a["feed_length"][i] = flen
            self.has_off = self.has_off or off != 0.0 or o1 != 0.0
            self.s_last = self.s_last + ln        # the path coordinate: the same sums as np.cumsum
            self.s_end[i] = self.s_last
            self.need[i] = _knot_need(vm, ln, flen, rot, ph, limits, self.dt)
            n += 1
            tip, axis, off = t1, a_1, o1
            if bl is not None:
                self.synth.add(n)         # a point of a rounded corner, not a programmed one
        self.n = n
        self.tip, self.axis, self.off = tip, axis, off

    def walk_pins(self):
        """Decide the knots of every boundary before the last (whose stops are final; the last is the
        job's end so far, a knot only as the end)."""
        hi = self.n - 1
        if self.pin_done < hi:
            b_s = lambda b: self.s_end[b - 1 - self.base] if b > 0 else 0.0  # noqa: E731
            self.pin_last, self.pin_top = _pin_walk(
                self.pin_done + 1, hi, lambda b: self.need[b - 1 - self.base], b_s, self.stop, self.synth,
                self.pin, self.pin_last, self.pin_top)
            self.pin_done = hi

    def forget(self, b):
        """Let go of the segments before boundary ``b`` (a long stream: memory bounded by what the
        windows still need)."""
        k = b - self.base
        if k <= 0:
            return
        j = k - 1                     # the pose and path coordinate at boundary b, kept
        self.base_pose = (self.a["p1"][j].copy(), self.a["a1"][j].copy(), float(self.a["off1"][j]),
                          float(self.s_end[j]))
        for key in self.a:
            self.a[key][:self.n - b] = self.a[key][k:self.n - self.base]
        self.s_end[:self.n - b] = self.s_end[k:self.n - self.base]
        self.need[:self.n - b] = self.need[k:self.n - self.base]
        self.base = b
        self.stop = {x for x in self.stop if x >= b}
        self.synth = {x for x in self.synth if x >= b}
        self.pin = {x for x in self.pin if x >= b}
        self.dwell = {x: v for x, v in self.dwell.items() if x >= b}
        self.dwell_line = {x: v for x, v in self.dwell_line.items() if x >= b}
        self.ev = [e for e in self.ev if e[0] >= b]
        self.mrg = [e for e in self.mrg if e[0] >= b]

    def path(self, end: bool = True, i0: int | None = None) -> "_Path":
        """The segments from ``i0`` (default: the first held) to the last as a _Path, in the job's path
        coordinate. ``end``: the last boundary is the job's end (an exact stop); else it is only where
        the job known so far ends (``job_end`` False: windows must not treat it as an end)."""
        i0 = self.base if i0 is None else i0
        lo, hi = i0 - self.base, self.n - self.base
        p = object.__new__(_Path)
        for k in _SEG_FIELDS:
            setattr(p, k, self.a[k][lo:hi].copy())
        n = p.n = self.n - i0
        p.has_off = self.has_off
        p.job_start, p.job_end = i0 == 0, bool(end)
        bs = np.arange(i0, self.n + 1)
        p.stop = np.fromiter((b in self.stop for b in bs), bool, n + 1)
        if end:
            p.stop[-1] = True
        p.synth = np.fromiter((b in self.synth for b in bs), bool, n + 1)
        p.dwell = np.array([self.dwell.get(b, 0.0) for b in bs], float)
        p.dwell_line = np.array([self.dwell_line.get(b, 0) for b in bs], int)
        ev = [e for e in self.ev if e[0] >= i0]
        p.ev_b = np.array([e[0] - i0 for e in ev], int)
        p.ev_before = np.array([e[1] for e in ev], float)
        p.ev_line, p.ev_data = np.array([e[2] for e in ev], int), tuple(e[3] for e in ev)
        mrg = [e for e in self.mrg if e[0] >= i0]
        p.mrg_seg = np.array([e[0] - i0 for e in mrg], int)
        p.mrg_u, p.mrg_line = np.array([e[1] for e in mrg], float), np.array([e[2] for e in mrg], int)
        p.end_tip, p.end_axis = self.tip, self.axis
        p.start_line = self.start_line if self.start_line is not None else 0
        if i0 == 0:
            p.start_tip, p.start_axis = self.start_tip, self.start_axis
            start_axis = self.start_axis / np.linalg.norm(self.start_axis)
            s0, off0 = 0.0, 0.0
        else:
            if lo > 0:
                p.start_tip, p.start_axis = self.a["p1"][lo - 1].copy(), self.a["a1"][lo - 1].copy()
                s0, off0 = float(self.s_end[lo - 1]), float(self.a["off1"][lo - 1])
            else:                     # the first boundary held (forget)
                p.start_tip, p.start_axis, off0, s0 = self.base_pose
            start_axis = p.start_axis
            p.start_line = int(p.line[0]) if n else p.start_line
        p._bounds(start_axis, self.s_end[lo:hi].copy(), s0, off0)
        self.walk_pins()
        p.pin = np.fromiter((b in self.pin for b in bs), bool, n + 1)
        p.pin |= p.stop & (bs < self.n)
        p.pin[0] = p.pin[-1] = True
        p.pin_idx = np.nonzero(p.pin)[0]
        return p


def _blendable(m) -> bool:
    """A feed line that may round its corner into the next (G64 P)."""
    return m.kind == LINE and m.tolerance > 0 and not m.probe and not m.duration > 0


def _knot_need(vmax, length, feed_length, rot, phi, limits, dt):
    """Two ticks of an upper bound of ds/dt on a segment: the path a knot needs before the next."""
    vs = vmax
    if not rot and feed_length < length:       # parameterised by the rotation
        vs = vmax * length / max(feed_length, 1e-300)
        if phi > 0:
            vs = min(vs, limits.axis_rate_rad_s * length / phi)
    return 2.0 * dt * vs


def _pin_walk(b_lo, b_hi, need, b_s, stop, synth, pin, last, top):
    """The knots of boundaries b_lo .. b_hi (added to the set ``pin``), walking along the path from
    the state (``last``: the path coordinate of the last knot, ``top``: the largest need since) and
    returning that state after b_hi: every stop, and every boundary at least ``need`` (two ticks of
    the top speed since the last knot) past the last knot; the ends of the arcs rounding corners
    (``synth``) only SYNTH_KNOT_TICKS ticks of top speed past it. ``need(b)`` is the need of the
    segment ending at b, ``b_s(b)`` the path coordinate of b."""
    for b in range(b_lo, b_hi + 1):                 # (a loop of ~1 us a boundary)
        top = max(top, need(b))
        sb = b_s(b)
        if b in stop or sb - last >= top * (0.5 * SYNTH_KNOT_TICKS if b in synth else 1.0):
            pin.add(b)
            last, top = sb, 0.0
    return last, top


class _Path:
    """Segments of a job as arrays; pose(seg, u) evaluates any number of points at once.

    The tip is the programmed (cutting) tip; ``controlled`` adds the tool length offset
    (pmctl.core.job.controlled_point): the point the machine's model, built for the reference tool,
    must put its tip on. Every IK of the planner and every sample it hands out is of that point.
    ``job_start`` / ``job_end``: whether its first / last boundary is the job's start / end (a path of
    a job still growing, pmctl.task.stream_planner, ends where the job known so far ends)."""

    job_start = job_end = True

    def __init__(self, job: Job, start, limits: PlannerLimits, feed_override: float, dt: float):
        # Filled move by move into arrays of the job's size (no per-move objects: a long job's index
        # stays at ~0.4 kB per move).
        moves = job.moves
        cap = len(moves) + sum(1 for m in moves if m.tolerance > 0)   # room for the arcs rounding corners
        b = _PathBuilder(start, limits, feed_override, dt, job.source, capacity=cap)
        drop = _merged_away(moves, start, limits)
        # the next move kept after each (-1: none), with which it may round its corner (G64 P)
        nxt = np.full(len(moves), -1)
        kept = np.nonzero(~drop)[0]
        if len(kept) > 1:
            nxt[kept[:-1]] = kept[1:]
        for i_m, m in enumerate(moves):
            if drop[i_m]:
                b.absorb(m)
            else:
                b.add(m, moves[nxt[i_m]] if nxt[i_m] >= 0 else None)
        full = b.path(end=True)
        self.__dict__.update(full.__dict__)
        self.start_line = moves[0].line if moves else 0

    def _pins(self, dt, limits):
        """Which boundaries get a tick of their own (the knots of the time warp: exact arrival,
        ``pin``): the stops, and, walking along the path, every boundary at least two ticks of the top
        speed since the last knot (every boundary of a path of ordinary moves). The points between
        knots (inside runs of micro-segments) are passed through on the path, not sampled: a tick for
        each would make every segment last at least a tick, and the samples' speed would follow the
        segments' lengths and jump from tick to tick. The ends of the arcs rounding corners (no
        programmed point) are knots only ``SYNTH_KNOT_TICKS`` ticks of top speed past the last: the warp
        then changes the speed by a few percent at most from knot to knot. (Again after a fallback
        changed stops and speeds; _PathBuilder walks them as the path grows.)"""
        n = self.n
        need = [_knot_need(self.vmax[i], self.length[i], self.feed_length[i], self.rot[i], self.phi[i], limits, dt)
                for i in range(n)]
        pin = {0}
        _pin_walk(1, n, lambda b: need[b - 1], lambda b: self.b_s[b], set(np.nonzero(self.stop)[0].tolist()),
                  set(np.nonzero(self.synth)[0].tolist()), pin, float(self.b_s[0]), 0.0)
        self.pin = np.zeros(n + 1, bool)
        self.pin[sorted(pin)] = True
        self.pin[0] = self.pin[n] = True
        self.pin_idx = np.nonzero(self.pin)[0]

    def _bounds(self, start_axis, s_end, s0=0.0, off0=0.0):
        n = self.n
        self.s_end = s_end
        self.s_start = self.s_end - self.length
        self.total = float(self.s_end[-1]) if n else s0
        # Boundary poses, exact: b = 0 the start, b = i + 1 the end of segment i.
        self.b_tip = np.vstack([self.start_tip[None], self.p1]) if n else self.start_tip[None].copy()
        self.b_axis = np.vstack([start_axis[None], self.a1]) if n else self.start_axis[None].copy()
        self.b_off = np.concatenate([[off0], self.off1])
        self.b_ctl = controlled_point(self.b_tip, self.b_axis, self.b_off) if self.has_off else self.b_tip
        self.b_s = np.concatenate([[s0], self.s_end])

    def sub(self, i0, i1):
        """The segments i0 .. i1-1 as a path of their own, in the job's path coordinate s (the same
        floats as the whole job's, so a window computes with the same numbers). Its ends are exact
        stops only where the job has one (the job's ends, dwells, EVENTs, spindle changes)."""
        p = object.__new__(_Path)
        for k in _SEG_FIELDS:
            setattr(p, k, getattr(self, k)[i0:i1])
        p.n = i1 - i0
        p.has_off = self.has_off
        p.synth = self.synth[i0:i1 + 1]
        p.pin = self.pin[i0:i1 + 1].copy()
        p.pin[0] = p.pin[-1] = True            # a window's ends are its knots (far from what it emits)
        p.pin_idx = np.nonzero(p.pin)[0]
        p.stop, p.dwell, p.dwell_line = self.stop[i0:i1 + 1], self.dwell[i0:i1 + 1], self.dwell_line[i0:i1 + 1]
        p.start_tip, p.start_axis = self.b_tip[i0], self.b_axis[i0]
        p.end_tip, p.end_axis = self.b_tip[i1], self.b_axis[i1]
        p.start_line = int(self.line[i0]) if p.n else self.start_line
        p.s_end, p.s_start, p.b_s = self.s_end[i0:i1], self.s_start[i0:i1], self.b_s[i0:i1 + 1]
        p.total = float(self.b_s[i1])
        p.b_tip, p.b_axis = self.b_tip[i0:i1 + 1], self.b_axis[i0:i1 + 1]
        p.b_off, p.b_ctl = self.b_off[i0:i1 + 1], self.b_ctl[i0:i1 + 1]
        e0, e1 = np.searchsorted(self.ev_b, i0, "left"), np.searchsorted(self.ev_b, i1, "right")
        p.ev_b, p.ev_before, p.ev_line = self.ev_b[e0:e1] - i0, self.ev_before[e0:e1], self.ev_line[e0:e1]
        p.ev_data = self.ev_data[e0:e1]
        m0, m1 = np.searchsorted(self.mrg_seg, i0, "left"), np.searchsorted(self.mrg_seg, i1, "left")
        p.mrg_seg, p.mrg_u, p.mrg_line = self.mrg_seg[m0:m1] - i0, self.mrg_u[m0:m1], self.mrg_line[m0:m1]
        return p

    def lines(self, seg, u):
        """The source line of points (seg, u): the segment's, or inside a merged segment the line of
        the move being executed there (the first absorbed move ending at or after u)."""
        line = self.line[seg]
        if len(self.mrg_seg):
            key = self.mrg_seg + self.mrg_u
            i = np.minimum(np.searchsorted(key, seg + u, "left"), len(key) - 1)
            inside = self.mrg_seg[i] == seg
            line = np.where(inside & (seg + u <= key[i]), self.mrg_line[i], line)
        return line

    def rest_marks(self, dt, n_samples):
        """Marks of a path that does not move (n == 0): every EVENT at boundary 0, after the dwells
        before it: ((sample, line, events), ...)."""
        return tuple((min(int(round(b4 / dt)), n_samples - 1), int(ln), ev)
                     for b4, ln, ev in zip(self.ev_before, self.ev_line, self.ev_data))

    def pose(self, seg, u):
        """Programmed tip and unit tool axis at (seg, u)."""
        seg = np.asarray(seg, int)
        u = np.asarray(u, float)
        uu = u[..., None]
        p0, p1 = self.p0[seg], self.p1[seg]
        tip = p0 + uu * (p1 - p0)
        arc = self.kind[seg] == 1
        if np.any(arc):
            th = (self.sweep[seg] * u)[..., None]
            r = (self.r0[seg] + (self.r1[seg] - self.r0[seg]) * u)[..., None]
            h = (self.h0[seg] + (self.h1[seg] - self.h0[seg]) * u)[..., None]
            at = self.c[seg] + h * self.nrm[seg] + r * (np.cos(th) * self.e1[seg] + np.sin(th) * self.e2[seg])
            tip = np.where(arc[..., None], at, tip)
        phi = self.phi[seg][..., None]
        a0, a1 = self.a0[seg], self.a1[seg]
        small = phi < 1e-9
        sp = np.where(small, 1.0, np.sin(phi))
        w0 = np.where(small, 1.0 - uu, np.sin((1.0 - uu) * phi) / sp)
        w1 = np.where(small, uu, np.sin(uu * phi) / sp)
        axis = w0 * a0 + w1 * a1
        axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
        return tip, axis

    def controlled(self, seg, u, tip, axis):
        """The point the reference tool's tip goes to for the programmed ``tip``, ``axis`` at (seg, u):
        the tool length offset goes linearly from the segment's start to its end (a change of offset
        is taken up by the move after it, as in LinuxCNC)."""
        if not self.has_off:
            return tip
        u = np.asarray(u, float)
        return controlled_point(tip, axis, self.off0[seg] * (1.0 - u) + self.off1[seg] * u)

    def point(self, seg, u):
        """Controlled point and axis at (seg, u) (what IK and the samples take)."""
        tip, axis = self.pose(seg, u)
        return self.controlled(seg, u, tip, axis), axis

    def derivatives(self, seg, u, machine, delta=1e-3):
        """d/ds and d2/ds2 of tip, axis and joints at (seg, u), central differences of step delta mm."""
        seg = np.asarray(seg, int)
        du = delta / self.length[seg]
        uu = np.concatenate([u - du, u, u + du])
        ss = np.concatenate([seg, seg, seg])
        tip, axis = self.pose(ss, uu)
        q = K.ik_batch(self.controlled(ss, uu, tip, axis), axis, machine, check_limits=False).q
        m = len(seg)
        out = {}
        for name, x in (("tip", tip), ("axis", axis), ("q", q)):
            xm, x0, xp = x[:m], x[m:2 * m], x[2 * m:]
            out[name] = x0
            out[name + "1"] = (xp - xm) / (2 * delta)
            out[name + "2"] = (xp - 2 * x0 + xm) / delta**2
        return out

    def locate(self, s):
        seg = np.clip(np.searchsorted(self.s_end, s, "left"), 0, self.n - 1)
        u = np.clip((s - self.s_start[seg]) / self.length[seg], 0.0, 1.0)
        return seg, u


# ---------------------------------------------------------------- helpers

def _range_min(n, lo, hi, val):
    """out[m] = min(val[k] for every k with lo[k] <= m <= hi[k]) (inf where none); vectorised."""
    out = np.full(n, np.inf)
    if n == 0 or len(val) == 0:
        return out
    lo = np.clip(lo, 0, n - 1)
    hi = np.clip(hi, lo, n - 1)
    length = hi - lo + 1
    p = np.floor(np.log2(length)).astype(int)
    top = int(p.max())
    tables = [np.full(n, np.inf) for _ in range(top + 1)]
    for lev in range(top + 1):
        sel = p == lev
        if np.any(sel):
            np.minimum.at(tables[lev], lo[sel], val[sel])
            np.minimum.at(tables[lev], hi[sel] - (1 << lev) + 1, val[sel])
    for lev in range(top, 0, -1):
        half = 1 << (lev - 1)
        t = tables[lev]
        below = tables[lev - 1]
        np.minimum(below, t, out=below)
        np.minimum(below[half:], t[:n - half], out=below[half:])
    return tables[0]


def _erode(s, cap, radius, ext):
    """Each cap[k] also applies within radius[k] of s[k], and where ext[k] to the first grid point
    beyond it on either side, so that the interpolated profile between grid points obeys it too
    (junctions do not need that: their grid has points exactly at the plateau edges)."""
    lo = np.searchsorted(s, s - radius, "left")
    hi = np.searchsorted(s, s + radius, "right") - 1
    ext = ext & (radius > 0)
    lo = np.where(ext, lo - 1, lo)
    hi = np.where(ext, hi + 1, hi)
    return np.minimum(cap, _range_min(len(s), lo, hi, cap))


def _forward_pass(w_lim, c):
    """w[k] = min(w_lim[k], w[k-1] + c[k-1]), w[0] = w_lim[0], in closed form. The prefix sums are
    in extended precision: the result then hardly depends on how far back they start (a window of
    the streaming planner agrees with the whole job's plan to ~1e-12 mm)."""
    C = np.concatenate([np.zeros(1, np.longdouble), np.cumsum(np.asarray(c, np.longdouble))])
    return (C + np.minimum.accumulate(w_lim - C)).astype(float)


class _Profile:
    """Piecewise-quadratic raw profile s(t) (holds included) and its moving average over T."""

    def __init__(self, s, w, hold, T):
        v = np.sqrt(np.maximum(w, 0.0))
        ds = np.diff(s)
        vs = v[:-1] + v[1:]
        dur = np.where(ds > 0, 2 * ds / np.where(vs > 0, vs, 1.0), 0.0)
        if np.any((ds > 0) & ~(vs > 0)):
            raise PlanningError("velocity profile stalls (a zero speed limit inside a move)")
        acc = np.where(ds > 0, (w[1:] - w[:-1]) / (2 * np.where(ds > 0, ds, 1.0)), 0.0)
        n = len(s)
        # Interleave: hold at point k, then interval k -> k+1.
        t_dur = np.zeros(2 * n - 1)
        t_dur[0::2] = hold
        t_dur[1::2] = dur
        p_s0 = np.zeros(2 * n - 1)
        p_s0[0::2] = s
        p_s0[1::2] = s[:-1]
        p_v0 = np.zeros(2 * n - 1)
        p_v0[1::2] = v[:-1]
        p_a = np.zeros(2 * n - 1)
        p_a[1::2] = acc
        keep = t_dur > 0
        keep[0] = True
        self.dur, self.s0, self.v0, self.a = t_dur[keep], p_s0[keep], p_v0[keep], p_a[keep]
        # Piece start times in extended precision: a rounding error e of t0 would shift the integral
        # below by s e, which the moving average divides by T (a noise of ~1e-10 mm on long jobs).
        self.t0 = np.concatenate([np.zeros(1, np.longdouble), np.cumsum(self.dur.astype(np.longdouble))[:-1]])
        self.t_end = float(self.t0[-1] + self.dur[-1])
        d = self.dur
        # The running integral of s grows like S t; keep it in extended precision so that the moving
        # average (a difference of two such integrals) stays accurate to ~1e-12 mm on long jobs.
        piece = (self.s0 * d + 0.5 * self.v0 * d**2 + self.a * d**3 / 6).astype(np.longdouble)
        cum = np.cumsum(piece)
        self.I0 = np.concatenate([np.zeros(1, np.longdouble), cum[:-1]])
        self.I_end = cum[-1]
        self.S = float(s[-1])
        self.S0 = float(s[0])             # where the path (a window of a longer one) starts
        self.T = T
        # Arrival time (after the hold) at every grid point.
        t_all = np.concatenate([[0.0], np.cumsum(t_dur.astype(np.longdouble)).astype(float)])
        self.t_arrive = t_all[0::2]           # start of hold at point k
        self.t_leave = t_all[0::2] + hold

    def _eval(self, t):
        t = np.asarray(t, float)
        i = np.clip(np.searchsorted(self.t0, t, "right") - 1, 0, len(self.t0) - 1)
        tau = np.clip((t - self.t0[i]).astype(float), 0.0, self.dur[i])
        s = self.s0[i] + self.v0[i] * tau + 0.5 * self.a[i] * tau**2
        v = self.v0[i] + self.a[i] * tau
        I = self.I0[i] + (self.s0[i] * tau + 0.5 * self.v0[i] * tau**2 + self.a[i] * tau**3 / 6)
        before, after = t < 0, t > self.t_end
        s = np.where(before, self.S0, np.where(after, self.S, s))
        v = np.where(before | after, 0.0, v)
        I = np.where(before, np.longdouble(self.S0) * t,
                     np.where(after, self.I_end + np.longdouble(self.S) * (t - self.t_end), I))
        return s, v, I

    def filtered(self, t):
        """Moving average over [t - T/2, t + T/2]: s_f(t), v_f(t)."""
        h = 0.5 * self.T
        s_a, _, I_a = self._eval(t - h)
        s_b, _, I_b = self._eval(t + h)
        return ((I_b - I_a) / self.T).astype(float), (s_b - s_a) / self.T


# ---------------------------------------------------------------- the planner

def plan(job: Job, machine, dt: float, *, feed_override: float = 1.0, limits: PlannerLimits | None = None,
         start=None) -> Trajectory:
    """Plan ``job`` into a Trajectory sampled every ``dt`` seconds (see the module docstring)."""
    limits, start = _start(job, machine, dt, feed_override, limits, start)
    path = _Path(job, start, limits, feed_override, dt)
    T = max(2.0 * limits.tangential_accel / limits.jerk_mm_s3, 2.0 * dt)
    _check_size(path, job, dt, limits)
    if path.n == 0:
        nt = int(np.ceil(path.dwell.sum() / dt)) + 1
        tip = np.repeat(path.start_tip[None], nt, 0)
        axis = np.repeat(path.b_axis[:1], nt, 0)
        z = np.zeros((nt, 3))
        return Trajectory(dt, tip, axis, z, z.copy(), np.full(nt, path.start_line, int), np.zeros(nt),
                          job.source, np.asarray(job.points, float), marks=path.rest_marks(dt, nt))
    _check_reachable(path, job, machine)
    while True:
        grid = _limit_grid(path, machine, limits, dt, T)
        scale = np.ones(len(grid["s"]))
        for it in range(max(1, limits.max_iterations)):
            traj, worst = _sample(path, grid, scale, machine, limits, dt, T, job)
            if worst is None:
                return traj
            scale = _lower_caps(grid, scale, worst, limits, T)
        _fall_back(path, _NotConverged(path, worst[0]), dt, limits, job)


def _lower_caps(grid, scale, worst, limits, T):
    """Lower the caps around the offending samples (to plan again)."""
    s_bad, factor, v_bad = worst
    radius = 1.1 * v_bad * T + 2 * limits.grid_mm
    lo = np.searchsorted(grid["s"], s_bad - radius, "left")
    hi = np.searchsorted(grid["s"], s_bad + radius, "right") - 1
    return np.minimum(scale, _range_min(len(scale), lo, hi, factor))


MAX_FALLBACKS = 6        # rounds of the fallback (exact stops, half the speed) before a job is refused


def _fall_back(path, e, dt, limits, job):
    """The guaranteed-feasible fallback where re-planning did not meet the limits: the segments
    ``segs`` and their neighbours get exact stops at both ends and half their top speed (each round
    halves it again; ``path.fallbacks`` counts the rounds); after ``MAX_FALLBACKS`` rounds
    PlanningError names the line. ``e``: the _NotConverged. The path is changed in place: plan again."""
    n = path.n
    segs = np.unique(np.clip(np.concatenate([e.segs - 1, e.segs, e.segs + 1]), 0, n - 1))
    path.fallbacks = getattr(path, "fallbacks", 0) + 1
    if path.fallbacks > MAX_FALLBACKS:
        line = e.line
        raise PlanningError(f"{job.source}:{line}: the planner could not meet the joint and feed limits here, "
                            f"not even with exact stops at 1/{2 ** MAX_FALLBACKS} of the feed (its fallback): "
                            f"lower the feed of these moves, or report the job", path=job.source, line=line)
    path.stop[segs] = True
    path.stop[segs + 1] = True
    path.vmax[segs] *= 0.5
    path._pins(dt, limits)


def _start(job, machine, dt, feed_override, limits, start):
    limits = limits or PlannerLimits()
    if not dt > 0:
        raise PlanningError(f"tick period must be > 0, got {dt!r}")
    if not feed_override > 0:
        raise PlanningError(f"feed override must be > 0, got {feed_override!r}")
    if start is None:
        start = home_pose(machine)
    return limits, start


# ---------------------------------------------------------------- the streaming planner

def validate(job: Job, machine, dt: float, *, feed_override: float = 1.0, limits: PlannerLimits | None = None,
             start=None, batch: bool = False, full: bool = False, window: int = STREAM_WINDOW,
             problems: list | None = None) -> "_Path":
    """Check a whole job for the streaming planner before anything moves, in bounded memory: every
    move has a positive feed, the duration's lower bound is within ``MAX_STREAM_SECONDS``, no single
    move needs more than ``MAX_SEGMENT_GRID`` grid points, every programmed pose is reachable and so
    is the path between them (checked every ``grid_mm`` along it). InputError names the file and line.
    Returns the job's segment index, which ``plan_stream(path=...)`` takes. ``batch``: the batch
    planner's bounds on the duration and the whole grid instead (for a caller that holds the whole
    trajectory).

    ``full``: the job is also planned, whole, window by window as ``plan_stream`` will (no samples
    kept), and where re-planning does not meet the limits the fallback (``_fall_back``: exact stops
    and a lower speed there) goes into the returned path and the job is planned again, until it
    passes or PlanningError names the line. ``plan_stream(path=...)`` of that path (with the same
    arguments) then cannot fail: what ``pmctl check``, ``pmctl run`` and the supervisor's queue do
    before anything moves. The path's ``planned_samples`` is then the trajectory's length.

    ``problems`` (a list): every unreachable pose and every stretch of path between poses that
    leaves the workspace is appended to it as a Problem (kind ``machine``, one per line) instead of
    raising the first, and the job is then not planned; the other refusals still raise."""
    limits, start = _start(job, machine, dt, feed_override, limits, start)
    path = _Path(job, start, limits, feed_override, dt)
    if batch:
        _check_size(path, job, dt, limits)
    else:
        _check_size(path, job, dt, limits, max_samples=int(MAX_STREAM_SECONDS / dt), whole_grid=False)
    if path.n == 0:
        path.planned_samples = int(np.ceil(path.dwell.sum() / dt)) + 1
        return path
    check_segments(path, job, machine, limits, problems)
    if problems:                  # (only with a list) not planned: the path leaves the workspace
        return path
    if full:
        _plan_whole(path, machine, limits, dt, job, window)
    return path


def check_segments(path, job, machine, limits, problems=None):
    """The checks of each segment of ``path``: no move needs more than ``MAX_SEGMENT_GRID`` grid
    points, every programmed pose is reachable and so is the path between them (every ``grid_mm``,
    in chunks of about SAMPLE_CHUNK points). InputError with the line (``problems``: appended)."""
    counts = np.maximum(2, np.ceil(path.length / limits.grid_mm).astype(np.int64))
    if np.any(counts > MAX_SEGMENT_GRID):
        i = int(np.argmax(counts > MAX_SEGMENT_GRID))
        raise InputError(job.source, int(path.line[i]),
                         f"this move is {path.length[i]:.6g} mm long: more than {MAX_SEGMENT_GRID} grid points "
                         f"of {limits.grid_mm:g} mm (check arc turns P and the coordinates, or split the move)")
    seen = set()
    _check_reachable(path, job, machine, problems, seen)
    i = 0
    while i < path.n:
        j = i + 1 + int(np.searchsorted(np.cumsum(counts[i + 1:]), SAMPLE_CHUNK))
        c = counts[i:j]
        seg = np.repeat(np.arange(i, j), c)
        u = (np.arange(len(seg)) - np.repeat(np.cumsum(c) - c, c)) / np.repeat(c, c)
        tip, axis = path.point(seg, u)
        _check_samples(tip, axis, path.lines(seg, u), machine, job, problems, seen)
        i = j


def _plan_whole(path, machine, limits, dt, job, window):
    """Plan the whole path window by window (nothing kept), with the fallback (see validate). The
    settled windows (their extents and the caps re-planning lowered) are kept on the path
    (``path.settled``): plan_stream of this path samples them without planning them again."""
    T = max(2.0 * limits.tangential_accel / limits.jerk_mm_s3, 2.0 * dt)
    while True:
        n_samples = 0
        settled = []
        try:
            for w in _windows(path, machine, limits, dt, T, job, window, keep=False):
                n_samples += w.e1 - w.e0
                settled.append(w.record)
        except _NotConverged as e:
            _fall_back(path, e, dt, limits, job)
            continue
        path.planned_samples = n_samples
        path.settled, path.settled_for = settled, (dt, limits, machine)
        return


def plan_stream(job: Job, machine, dt: float, *, feed_override: float = 1.0, limits: PlannerLimits | None = None,
                start=None, path=None, window: int = STREAM_WINDOW):
    """Plan ``job`` as ``plan`` does, chunk by chunk: yields Trajectory pieces (each at most
    ``SAMPLE_CHUNK`` samples) whose concatenation is ``plan``'s trajectory (to rounding, ~1e-12 mm).

    The job is validated first (``validate``; pass its ``path`` to skip that). Then it is planned in
    windows of ``window`` segments, each with margins of the path on both sides: the limit grid,
    the velocity profile, the jerk filter and the time warp of the window are those of the whole
    job wherever the margins hold everything they depend on. The profile is checked for that (the
    speeds with the margin's ends free and at rest must agree in the window), else the margin grows.
    Where re-planning does not meet the limits before the first piece is handed out, the fallback
    goes into ``path`` and the job is planned again; after that, PlanningError (with the line) stops
    the stream: pass the path of ``validate(full=True)`` (same arguments) and that cannot happen.
    That path also holds its settled windows: they are sampled as they were planned there (the same
    samples), not planned again (``window`` is then the check's).
    Memory: the job's segment index (~0.4 kB per move) and one window with its margins."""
    limits, start = _start(job, machine, dt, feed_override, limits, start)
    if path is None:
        path = validate(job, machine, dt, feed_override=feed_override, limits=limits, start=start)
    T = max(2.0 * limits.tangential_accel / limits.jerk_mm_s3, 2.0 * dt)
    points = np.asarray(job.points, float).reshape(-1, 3)
    if path.n == 0:
        yield from _rest_pieces(path, dt, job.source, points)
        return
    settled = getattr(path, "settled", None)
    if settled is not None:
        pdt, plim, pm = path.settled_for
        if pdt == dt and plim == limits and _same(pm, machine):
            for rec in settled:
                yield from _replay_window(path, rec, machine, limits, dt, T, job).pieces(job.source, points)
            return
    emitted = False
    while True:
        try:
            for w in _windows(path, machine, limits, dt, T, job, window):
                for piece in w.pieces(job.source, points):
                    emitted = True
                    yield piece
            return
        except _NotConverged as e:
            if not emitted:           # nothing handed out yet: the fallback, and start again
                _fall_back(path, e, dt, limits, job)
                continue
            # only without the full check (validate(full=True)), which falls back before anything moves
            raise PlanningError(f"{job.source}:{e.line}: could not meet the joint/feed limits here after "
                                f"{limits.max_iterations} re-planning iterations (the job was not checked in "
                                "full before it was streamed)", path=job.source, line=e.line) from None


def _same(a, b) -> bool:
    """Whether two configs (dataclasses of numbers, arrays, tuples) hold the same values."""
    if a is b:
        return True
    if type(a) is not type(b):
        return False
    if isinstance(a, np.ndarray):
        return a.shape == b.shape and bool(np.array_equal(a, b))
    if hasattr(a, "__dataclass_fields__"):
        return all(_same(getattr(a, f), getattr(b, f)) for f in a.__dataclass_fields__)
    if isinstance(a, (tuple, list)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    return bool(a == b)


def _rest_pieces(path, dt, source, points):
    """The pieces of a path that does not move (only dwells and EVENTs): its dwells' samples at the
    start pose (one sample without a dwell), carrying the marks."""
    nt = int(np.ceil(path.dwell.sum() / dt)) + 1
    marks = path.rest_marks(dt, nt)
    for k0 in range(0, nt, SAMPLE_CHUNK):
        m = min(nt, k0 + SAMPLE_CHUNK) - k0
        z = np.zeros((m, 3))
        yield Trajectory(dt, np.repeat(path.start_tip[None], m, 0), np.repeat(path.b_axis[:1], m, 0), z,
                         z.copy(), np.full(m, path.start_line, int), np.zeros(m), source, points,
                         marks=tuple((i - k0, ln, ev) for i, ln, ev in marks if k0 <= i < k0 + m))


def _reach(path, T, limits):
    """How far along the path what a window's samples depend on reaches (the erosion of the caps,
    the jerk filter, the re-planning radius around a violation: all ~ v T, at the path's top speed)."""
    return 1.1 * float(path.vmax.max()) * T + 4 * limits.grid_mm


def _windows(path, machine, limits, dt, T, job, window=STREAM_WINDOW, keep=True):
    """The windows of the streaming planner, in order (_Window each); _NotConverged where
    re-planning does not meet the limits."""
    # reach of what a window's result depends on: the erosion of the caps, the jerk filter, the
    # re-planning radius around a violation (all ~ v T), and the look-ahead of the speeds (checked)
    vt = _reach(path, T, limits)
    pins = path.pin_idx
    c1 = 0
    while c1 < path.n:                 # windows of about `window` segments, from knot to knot
        c0 = c1
        c1 = int(pins[min(len(pins) - 1, np.searchsorted(pins, c0 + window, "left"))])
        yield _settle_growing(path, c0, c1, max(STREAM_MARGIN_MM, 2 * vt), vt, machine, limits, dt, T, job, keep)


def _settle_growing(path, c0, c1, margin, vt, machine, limits, dt, T, job, keep=True, check_mm=STREAM_CHECK_MM):
    """_settle_window, the margin doubled until the window's speeds do not depend on what lies beyond
    it (``_NotLocal``)."""
    while True:
        try:
            return _settle_window(path, c0, c1, margin, vt, machine, limits, dt, T, job, keep, check_mm)
        except _NotLocal:
            margin *= 2


class _Window:
    """A settled window: its timing, the tick range it emits (e0 .. e1-1 of its own ticks), the sample
    chunks kept from its check (or None: sampled again), and ``record`` = (w0, w1, c0, c1, indices and
    values of the lowered caps) from which ``_replay_window`` samples it again without planning."""

    def __init__(self, tm, e0, e1, keep, record):
        self.tm, self.e0, self.e1, self.keep, self.record = tm, e0, e1, keep, record

    def pieces(self, source, points):
        """Its samples as Trajectory pieces of at most SAMPLE_CHUNK samples, with their marks."""
        tm, dt = self.tm, self.tm.dt
        if self.keep is not None:
            for k0, part in self.keep:
                yield Trajectory(dt, *part, source, points, marks=tm.marks(k0, k0 + len(part[0])))
            return
        for k0 in range(self.e0, self.e1, SAMPLE_CHUNK):
            k1 = min(self.e1, k0 + SAMPLE_CHUNK)
            part, _ = tm.samples(k0, k1)
            yield Trajectory(dt, *part, source, points, marks=tm.marks(k0, k1))


def _window_extent(path, c0, c1, margin, vt, check_mm=STREAM_CHECK_MM, ahead=None):
    """Where the window c0 .. c1 looks: (w0, w1, kb_lo, kb_hi, zone) -- the segments planned with it
    (its margins), the knots between which the limits are checked, and the zone of _profile -- or None
    on a path whose end is not the job's (``path.job_end`` False) when it would look beyond that end.
    ``margin``, ``vt`` (the reach of what a sample depends on) and ``check_mm`` hold on both sides,
    unless ``ahead`` = (margin, vt, check_mm, reach of the path beyond the margin) gives the side
    after the window its own (pmctl.task.stream_planner: a rapid before the window does not make it
    look further ahead)."""
    n, b_s = path.n, path.b_s
    margin_hi, vt_hi, check_hi, vt_out = ahead if ahead is not None else (margin, vt, check_mm, vt)
    # the limits are checked on the samples between knots kb_lo and kb_hi (the window and at least
    # check_mm around it; knots are the boundaries with a tick of their own, _Path.pin); their
    # times depend on the warp's knots one further out, which must not be a window end (those knots
    # are not the whole job's); the profile must be the whole job's from there on, within vt
    # (and at least vt beyond the knots next to the window: a violation there moves their ticks)
    start, end = c0 == 0 and path.job_start, c1 == n and path.job_end
    P = path.pin_idx
    bp = b_s[P]
    ic0, ic1 = int(np.searchsorted(P, c0)), int(np.searchsorted(P, c1))
    if start:
        i_lo = 0
    else:
        reach = min(b_s[c0] - check_mm, bp[max(ic0 - 1, 0)] - vt)
        i_lo = max(0, min(ic0 - 1, int(np.searchsorted(bp, reach, "right")) - 1))
    if end:
        i_hi = len(P) - 1
    else:
        reach = max(b_s[c1] + check_hi, bp[min(ic1 + 1, len(P) - 1)] + vt_hi)
        i_hi = min(len(P) - 1, max(ic1 + 1, int(np.searchsorted(bp, reach, "left"))))
    kb_lo, kb_hi = int(P[i_lo]), int(P[i_hi])
    lo_need = bp[max(i_lo - 1, 0)] - vt
    hi_need = bp[min(i_hi + 1, len(P) - 1)] + vt_hi
    if path.job_start:
        w0 = 0 if i_lo <= 1 else max(0, min(int(P[i_lo - 2]), int(np.searchsorted(b_s, lo_need - margin, "right")) - 1))
    else:                              # the segments before were let go: as far back as they are held
        w0 = max(0, min(int(P[max(i_lo - 2, 0)]), int(np.searchsorted(b_s, lo_need - margin, "right")) - 1))
    if path.job_end:
        w1 = n if i_hi >= len(P) - 2 else min(n, max(int(P[i_hi + 2]), int(np.searchsorted(b_s, hi_need + margin_hi, "left"))))
    else:                              # the job goes on beyond n: the window must not look that far
        if i_hi >= len(P) - 2 or hi_need + margin_hi > b_s[n]:
            return None
        w1 = min(n, max(int(P[i_hi + 2]), int(np.searchsorted(b_s, hi_need + margin_hi, "left"))))
    zone = None
    if w0 > 0 or w1 < n or not (path.job_start and path.job_end):
        zone = (b_s[w0] + vt if (w0 > 0 or not path.job_start) else -np.inf,
                b_s[w1] - vt_out if (w1 < n or not path.job_end) else np.inf,
                lo_need if not start else -np.inf, hi_need if not end else np.inf)
    return w0, w1, kb_lo, kb_hi, zone


def _settle_window(path, c0, c1, margin, vt, machine, limits, dt, T, job, keep_ok=True, check_mm=STREAM_CHECK_MM,
                   ahead=None):
    """Plan segments c0 .. c1-1 with margins; returns the _Window once the limits hold on the samples
    of the window and ``check_mm`` around it (``ahead``: see _window_extent)."""
    n = path.n
    w0, w1, kb_lo, kb_hi, zone = _window_extent(path, c0, c1, margin, vt, check_mm, ahead)
    end = path.job_end
    sp = path.sub(w0, w1)
    grid = _limit_grid(sp, machine, limits, dt, T)
    scale = np.ones(len(grid["s"]))
    for it in range(max(1, limits.max_iterations)):
        tm = _Timing(sp, grid, scale, dt, T, job, zone=zone)
        e0 = int(tm.K_b[c0 - w0])
        e1 = int(tm.K_b[c1 - w0]) + (1 if c1 == n and end else 0)
        k_lo = int(tm.K_b[kb_lo - w0])
        k_hi = int(tm.K_b[kb_hi - w0]) + (1 if kb_hi == n and end else 0)
        keep = [] if keep_ok and e1 - e0 <= STREAM_KEEP else None
        bad = []
        prev = None
        for k0 in range(k_lo, k_hi, SAMPLE_CHUNK):
            k1 = min(k_hi, k0 + SAMPLE_CHUNK)
            part, (sf, v, seg, tip) = tm.samples(k0, k1)
            q = _check_samples(part[0], part[1], part[4], machine, job)
            if keep is not None and k1 > e0 and k0 < e1:
                a, b = max(k0, e0) - k0, min(k1, e1) - k0
                keep.append((k0 + a, tuple(x[a:b] for x in part)))
            cur = (q, tip, v, sf, seg)
            if prev is not None:       # two samples of overlap: the differences across the chunk edge
                cur_x = tuple(np.concatenate([p_[-2:], c_]) for p_, c_ in zip(prev, cur))
            else:
                cur_x = cur
            w = _violations(*cur_x, sp, machine, limits, dt)
            if w is not None:
                bad.append(w)
            prev = cur
        if not bad:
            low = np.nonzero(scale < 1.0)[0]
            return _Window(tm, e0, e1, keep, (w0, w1, c0, c1, low, scale[low]))
        worst = tuple(np.concatenate(x) for x in zip(*bad))
        scale = _lower_caps(grid, scale, worst, limits, T)
    raise _NotConverged(path, worst[0])


def _replay_window(path, record, machine, limits, dt, T, job):
    """A window settled before (``_Window.record``), sampled again as it was planned: its limit grid,
    the caps re-planning lowered, its timing; no check, no iteration (the same samples)."""
    w0, w1, c0, c1, low, val = record
    sp = path.sub(w0, w1)
    grid = _limit_grid(sp, machine, limits, dt, T)
    scale = np.ones(len(grid["s"]))
    scale[low] = val
    tm = _Timing(sp, grid, scale, dt, T, job)
    e1 = int(tm.K_b[c1 - w0]) + (1 if c1 == path.n and path.job_end else 0)
    return _Window(tm, int(tm.K_b[c0 - w0]), e1, None, record)


def _too_long(job, line, what, dt, max_samples=None):
    bound = (f"the batch planner holds at most {MAX_SAMPLES} ticks ({MAX_SAMPLES * dt / 60:.0f} min at {1 / dt:g} Hz)"
             if max_samples is None else f"a job may take at most {max_samples * dt / 3600:g} h")
    return InputError(job.source, int(line) if line else None,
                      f"{what}: {bound}; check the feed (F is per minute), "
                      f"dwells (G4 P is in seconds) and arc turns (P), or split the job")


def _check_size(path: _Path, job, dt, limits: PlannerLimits, max_samples=None, whole_grid=True):
    """Refuse, before anything large is allocated, a job whose lower-bound duration or limit grid
    exceeds the bounds (the batch planner's, unless given; ``whole_grid=False``: no bound on the
    whole grid); the line named is where the bound is crossed."""
    # Lower bound of the duration at every boundary: each segment at its top speed, dwells in full.
    seg_t = path.feed_length / path.vmax if path.n else np.zeros(0)
    t_b = np.cumsum(path.dwell) + np.concatenate([[0.0], np.cumsum(seg_t)])   # at boundary b (dwell incl.)
    limit_t = (MAX_SAMPLES if max_samples is None else max_samples) * dt
    if not t_b[-1] < limit_t:
        b = int(np.argmax(~(t_b < limit_t)))
        if b > 0 and t_b[b] - path.dwell[b] >= limit_t:          # crossed while moving into boundary b
            line = int(path.lines(b - 1, 0.0))
            which = ("this move alone takes" if line == path.line[b - 1] else
                     f"the moves from this line to line {path.line[b - 1]} (one straight line) take")
            what = (f"{which} at least {seg_t[b - 1]:.4g} s ({path.feed_length[b - 1]:.4g} mm at "
                    f"{path.vmax[b - 1] * 60:.4g} mm/min)" if seg_t[b - 1] >= 0.5 * limit_t
                    else f"the job takes at least {t_b[-1]:.4g} s, over the bound by this line")
        else:                                                     # crossed during the dwell at b
            line = path.dwell_line[b]
            what = (f"the job takes at least {t_b[-1]:.4g} s, of which {path.dwell.sum():.4g} s of dwells; "
                    "over the bound by this line")
        raise _too_long(job, line, what, dt, max_samples)
    if path.n and whole_grid:
        counts = np.maximum(2.0, np.ceil(path.length / limits.grid_mm))
        cum = np.cumsum(counts)
        max_grid = MAX_GRID_POINTS
        if cum[-1] > max_grid:
            i = int(np.argmax(cum > max_grid))
            u = (max_grid - (cum[i] - counts[i])) / counts[i]
            raise InputError(job.source, int(path.lines(i, u)),
                             f"the path is {path.total:.6g} mm long: more than the batch planner's "
                             f"{MAX_GRID_POINTS} grid points of {limits.grid_mm:g} mm by this line "
                             f"(check arc turns P and the coordinates, or split the job)")


def _reach_advice(reason: str) -> str:
    """What to do about an unreachable pose, from the limit its reason names."""
    if reason.startswith(("tilt", "spherical")):
        return "reduce the tool tilt (A, B) there"
    if reason.startswith("chain"):
        return "the tool is too high or too low there: move the program (or the part) in Z"
    if reason.startswith("table"):
        return "move the program (or the part on the table) in X/Y so that the tool stays over the table's travel"
    return "keep the tool inside the machine's workspace there"


def _reach_problems(problems, seen, job, lines, reason, where):
    """One Problem (kind machine) per line not reported yet, for the unreachable poses ``lines``."""
    for ln, why in zip(lines, reason):
        ln = int(ln)
        if ln in seen:
            continue
        seen.add(ln)
        problems.append(Problem(job.source, ln or None, None, "machine",
                                f"{where}unreachable: {why}; {_reach_advice(str(why))}"))


def _check_reachable(path, job, machine, problems=None, seen=None):
    """IK of every boundary pose: InputError at the first unreachable one, or with ``problems`` (a list)
    one Problem per line appended."""
    for b0 in range(1, path.n + 1, SAMPLE_CHUNK):        # the boundaries after the start, in chunks
        b1 = min(path.n + 1, b0 + SAMPLE_CHUNK)
        r = K.ik_batch(path.b_ctl[b0:b1], path.b_axis[b0:b1], machine)
        if not np.all(r.ok):
            if problems is None:
                i = int(np.argmax(~r.ok))
                raise InputError(job.source, int(path.line[b0 + i - 1]), f"pose unreachable: {r.reason[i]}")
            bad = np.nonzero(~r.ok)[0]
            _reach_problems(problems, seen, job, path.line[b0 + bad - 1], r.reason[bad], "the programmed pose is ")


def _limit_grid(path: _Path, machine, limits: PlannerLimits, dt, T):
    """Speed caps (with junction caps and erosion) and acceleration caps on a grid along s."""
    n = path.n
    jl = machine.limits
    qd = limits.joint_fraction * jl.joint_speed
    qdd = limits.joint_fraction * jl.joint_accel
    amax = limits.accel_mm_s2
    # --- junction caps from the one-sided derivatives at both ends of every segment
    seg2 = np.concatenate([np.arange(n), np.arange(n)])
    u2 = np.concatenate([np.zeros(n), np.ones(n)])
    d = path.derivatives(seg2, u2, machine)
    out_tip, in_tip = d["tip1"][:n], d["tip1"][n:]          # leaving boundary i, arriving at boundary i+1
    out_q, in_q = d["q1"][:n], d["q1"][n:]
    vj = np.full(n + 1, np.inf)
    dtip = np.linalg.norm(out_tip[1:] - in_tip[:-1], axis=-1)
    dq = np.abs(out_q[1:] - in_q[:-1])
    with np.errstate(divide="ignore"):
        vj[1:n] = np.minimum(amax * dt / dtip, (qdd * dt / dq).min(-1))
    vmax_adj = np.maximum(np.concatenate([path.vmax[:1], path.vmax]), np.concatenate([path.vmax, path.vmax[-1:]]))
    vj = np.where(vj < vmax_adj, vj, np.inf)           # no junction cap where the feed is lower anyway
    vj[path.stop] = 0.0
    # --- grid: n_i intervals per segment (at least 2), plus the junction plateau edges
    counts = np.maximum(2, np.ceil(path.length / limits.grid_mm).astype(int))
    seg = np.repeat(np.arange(n), counts)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    j = np.arange(len(seg)) - np.repeat(first, counts)
    u = j / np.repeat(counts, counts)
    vj_f = np.where(np.isfinite(vj), vj, 0.0)
    r_start = 1.05 * vj_f[:-1] * T / path.length      # plateau in u after boundary i, before boundary i+1
    r_end = 1.05 * vj_f[1:] * T / path.length
    ex_seg, ex_u = [], []
    for rr, uu in ((r_start, r_start), (r_end, 1.0 - r_end)):
        ok = (rr > 0) & (rr < 1.0)
        ex_seg.append(np.nonzero(ok)[0])
        ex_u.append(uu[ok])
    seg = np.concatenate([seg] + ex_seg + [np.arange(n)])
    u = np.concatenate([u] + ex_u + [np.ones(n)])
    order = np.lexsort((u, seg))
    seg, u = seg[order], u[order]
    s = path.s_start[seg] + u * path.length[seg]
    s[-1] = path.total
    is_end = u >= 1.0
    # --- continuous caps at the grid points
    d = path.derivatives(seg, u, machine)
    sig = np.linalg.norm(d["tip1"], axis=-1)
    vmax = path.vmax[seg]
    rot = path.rot[seg]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        caps = [np.where(rot, vmax, vmax / sig),
                limits.axis_rate_rad_s / np.linalg.norm(d["axis1"], axis=-1),
                np.sqrt(limits.normal_accel / np.linalg.norm(d["tip2"], axis=-1)),
                (qd / np.abs(d["q1"])).min(-1),
                np.sqrt(0.5 * qdd / np.abs(d["q2"])).min(-1)]
        vcap = np.minimum.reduce(caps)
        acap = np.minimum(np.where(sig > 1e-9, limits.tangential_accel / sig, limits.tangential_accel),
                          (0.5 * qdd / np.abs(d["q1"])).min(-1))
    # Boundary points appear twice (end of i at u=1, start of i+1 at u=0): merge, keeping the minimum.
    start_of = np.nonzero(u == 0.0)[0]                 # one per segment, in order
    merge_to = np.where(is_end[:-1], start_of[np.minimum(seg[:-1] + 1, n - 1)], np.arange(len(seg) - 1))
    keep = np.ones(len(seg), bool)
    keep[:-1] = ~is_end[:-1]
    vg = vcap.copy()
    ag = acap.copy()
    np.minimum.at(vg, merge_to, vcap[:-1])
    np.minimum.at(ag, merge_to, acap[:-1])
    idx = np.nonzero(keep)[0]
    s, seg, u, vg, ag = s[idx], seg[idx], u[idx], vg[idx], ag[idx]
    # Boundary grid indices (b = 0..n).
    b_idx = np.concatenate([np.nonzero(u == 0.0)[0], [len(s) - 1]])
    vg[b_idx] = np.minimum(vg[b_idx], vj)
    vg = np.maximum(np.nan_to_num(vg, nan=np.inf), 0.0)
    ag = np.maximum(np.nan_to_num(ag, nan=np.inf), 1e-6)
    jrad = np.zeros(len(s))
    has_plateau = np.isfinite(vj) & (vj > 0)
    jrad[b_idx[has_plateau]] = 1.05 * vj[has_plateau] * T * (1 + 1e-9)
    return dict(s=s, seg=seg, u=u, vcap=vg, acap=ag, b_idx=b_idx, vmax_seg=path.vmax[seg], jrad=jrad)


def _profile(path, grid, scale, T, zone=None):
    """The raw profile on the grid. ``zone`` = (z_lo, z_hi, c_lo, c_hi) for a window of a longer job:
    outside [z_lo, z_hi] the caps miss their neighbours beyond the window's ends; the speeds are
    computed again with zero there (a lower bound of the true ones, the caps as they are giving an
    upper bound) and must agree on [c_lo, c_hi], else _NotLocal (the window needs a wider margin)."""
    s = grid["s"]
    vcap = np.minimum(grid["vcap"] * scale, grid["vmax_seg"])
    b_idx = grid["b_idx"]
    stop_pts = b_idx[path.stop]
    vcap[stop_pts] = 0.0
    jrad = grid["jrad"]
    junction = jrad > 0
    vcap = _erode(s, vcap, np.maximum(1.06 * vcap * T, jrad), ~junction)
    acap = grid["acap"] * scale
    acap = _erode(s, acap, 1.05 * grid["vmax_seg"] * T, np.ones(len(s), bool))
    vcap = np.maximum(vcap, np.where(vcap > 0, 1e-6, 0.0))
    vcap[stop_pts] = 0.0
    ds = np.diff(s)
    a = np.minimum(acap[:-1], acap[1:])
    c = 2 * a * ds
    w_lim = vcap**2
    w = _forward_pass(w_lim, c)
    w = _forward_pass(w[::-1], c[::-1])[::-1]
    if zone is not None:
        z_lo, z_hi, c_lo, c_hi = zone
        out = (s < z_lo) | (s > z_hi)
        i_out = np.nonzero(out)[0]
        out[np.clip(np.concatenate([i_out - 1, i_out + 1]), 0, len(s) - 1)] = True
        w_lo = _forward_pass(np.where(out, 0.0, w_lim), c)
        w_lo = _forward_pass(w_lo[::-1], c[::-1])[::-1]
        chk = (s >= c_lo) & (s <= c_hi)
        if not np.array_equal(w[chk], w_lo[chk]):
            raise _NotLocal()
    hold = np.zeros(len(s))
    hold[stop_pts] = T + path.dwell[path.stop]
    hold[b_idx[0]] = path.dwell[0]
    hold[b_idx[-1]] = path.dwell[-1]
    return _Profile(s, w, hold, T), stop_pts


class _NotLocal(Exception):
    """A window's speeds depend on more of the path than its margins hold."""


class _Timing:
    """When the samples of a planned path are: the filtered profile, the tick of every boundary
    (``K_b``) and the time warp that puts each boundary on its tick. Samples are then evaluated for
    any range of ticks (``samples``), so a long path is sampled chunk by chunk."""

    def __init__(self, path: _Path, grid, scale, dt, T, job, max_samples=None, zone=None):
        prof, stop_pts = _profile(path, grid, scale, T, zone)
        b_idx = grid["b_idx"]
        n = path.n
        self.path, self.prof, self.dt, self.job = path, prof, dt, job
        # Filtered arrival time at every knot (the boundaries with a tick of their own, _Path.pin).
        P = path.pin_idx
        tau = np.empty(len(P))
        tau[0] = -0.5 * T
        tau[-1] = prof.t_end + 0.5 * T
        inner = P[1:-1]
        st = path.stop[inner]
        tau[1:-1][st] = prof.t_arrive[b_idx[inner[st]]] + 0.5 * (T + path.dwell[inner[st]])
        mv = inner[~st]
        if len(mv):
            target = path.b_s[mv]
            lo = prof.t_arrive[b_idx[mv]] - 0.5 * T
            hi = prof.t_arrive[b_idx[mv]] + 0.5 * T
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                sf, _ = prof.filtered(mid)
                below = sf < target
                lo = np.where(below, mid, lo)
                hi = np.where(below, hi, mid)
            tau[1:-1][~st] = 0.5 * (lo + hi)
        gaps = np.diff(tau)
        if max_samples is not None:
            over = np.cumsum(gaps) / dt > max_samples - len(P)      # before anything of that size exists
            if np.any(over):
                b = int(P[int(np.argmax(over))])
                raise _too_long(job, path.line[min(b, n - 1)], f"the planned job takes {tau[-1] - tau[0]:.6g} s "
                                                               "(the joint and acceleration limits slow it down)", dt)
        ticks = np.maximum(1, np.ceil(gaps / dt - 1e-9).astype(int))
        K_p = np.concatenate([[0], np.cumsum(ticks)])
        self.K_b = K_b = np.full(n + 1, -1, int)          # the tick of each knot; -1 for other boundaries
        K_b[P] = K_p
        self.n_samples = int(K_p[-1]) + 1
        # The warped clock lags real time by D(t) >= 0; D is a monotone (PCHIP) interpolant of its knot
        # values, so the warp rate 1 - D' never exceeds 1: the warp only ever slows the profile down.
        x_b = K_p * dt
        self.tau0 = tau[0]
        self.lag = PchipInterpolator(x_b, x_b - (tau - tau[0]))
        self.dlag = self.lag.derivative()
        self.warp = None
        for k0 in range(0, self.n_samples, SAMPLE_CHUNK):
            if np.any(1.0 - self.dlag(np.arange(k0, min(k0 + SAMPLE_CHUNK, self.n_samples)) * dt) < 0):
                self.warp = PchipInterpolator(x_b, tau)    # only for knots far closer than a tick
                self.dwarp = self.warp.derivative()
                break
        # Samples held at a stop (within 1e-9 mm of it) sit exactly there, at rest: the tick range of each.
        stops = np.nonzero(path.stop)[0]
        lo = self._first(path.b_s[stops] - 1e-9, strict=False)
        hi = self._first(path.b_s[stops] + 1e-9, strict=True)
        self.hold = {int(b): (min(int(l_), int(K_b[b])), max(int(h_), int(K_b[b]) + 1))
                     for b, l_, h_ in zip(stops, lo, hi)}
        # Samples inside a dwell carry the G4's line (the dwell is the middle of the hold at its point).
        self.dwells = {}
        for b in np.nonzero(path.dwell > 0)[0]:
            lo_, hi_ = self.hold[int(b)]
            nd = int(round(path.dwell[b] / dt))
            extra = (hi_ - lo_) - nd
            a = lo_ + (0 if b == 0 else (extra // 2 if b < n else extra))
            self.dwells[int(b)] = (a, a + nd + 1)
        # The tick of every EVENT's mark: the boundary's own tick (the exact stop, at rest), or inside
        # a dwell at that point after the part of the dwell programmed before the EVENT (within the
        # samples held on the point).
        mk = K_b[path.ev_b].astype(int) if len(path.ev_b) else np.zeros(0, int)
        for i, b in enumerate(path.ev_b):
            if int(b) in self.dwells:
                a, e = self.dwells[int(b)]
                lo_, hi_ = self.hold[int(b)]
                mk[i] = max(lo_, min(a + int(round(path.ev_before[i] / dt)), e - 1, hi_ - 1, self.n_samples - 1))
        self.mark_tick = mk

    def marks(self, k0, k1):
        """The marks on ticks k0 .. k1-1, in program order, indexed from k0."""
        p = self.path
        sel = np.nonzero((self.mark_tick >= k0) & (self.mark_tick < k1))[0]
        return tuple((int(self.mark_tick[i]) - k0, int(p.ev_line[i]), p.ev_data[i]) for i in sel)

    def _clock(self, k):
        """Profile time and warp rate of ticks k."""
        tk = np.asarray(k) * self.dt
        if self.warp is not None:
            return self.warp(tk), self.dwarp(tk)
        return tk - self.lag(tk) + self.tau0, 1.0 - self.dlag(tk)

    def _s(self, k):
        tt, rate = self._clock(k)
        sf, vf = self.prof.filtered(tt)
        return np.clip(sf, self.path.b_s[0], self.path.total), vf * rate

    def _first(self, x, strict):
        """First tick whose s is >= x (> x if strict), for every x; n_samples where none (s is monotone)."""
        lo = np.zeros(len(x), int)
        hi = np.full(len(x), self.n_samples)
        while np.any(lo < hi):
            mid = (lo + hi) // 2
            sm, _ = self._s(np.minimum(mid, self.n_samples - 1))
            ok = ((sm > x) if strict else (sm >= x)) & (mid < self.n_samples)
            hi = np.where(ok & (lo < hi), mid, hi)
            lo = np.where(~ok & (lo < hi), mid + 1, lo)
        return lo

    def samples(self, k0, k1):
        """Ticks k0 .. k1-1: (tip, axis, tip_vel, axis_vel, line, rpm) of the controlled point (the tip
        of the reference tool: pmctl.core.job.controlled_point) and, for the limit check, (s, v, seg,
        programmed tip)."""
        path, K_b, n = self.path, self.K_b, self.path.n
        k = np.arange(k0, k1)
        sf, v = self._s(k)
        seg, u = path.locate(sf)
        # Samples on boundaries: exactly the programmed pose, arriving from the segment before.
        on = np.nonzero((K_b >= k0) & (K_b < k1))[0]
        seg[K_b[on[on > 0]] - k0] = on[on > 0] - 1
        u[K_b[on[on > 0]] - k0] = 1.0
        if k0 == 0:
            seg[0], u[0] = 0, 0.0
        ranges = []
        for b, (lo, hi) in self.hold.items():
            lo, hi = max(lo, k0), min(hi, k1)
            if lo < hi:
                ranges.append((b, lo - k0, hi - k0))
                seg[lo - k0:hi - k0] = max(b - 1, 0)
                u[lo - k0:hi - k0] = 1.0 if b > 0 else 0.0
                v[lo - k0:hi - k0] = 0.0
        tip, axis = path.pose(seg, u)
        for b, lo, hi in ranges:
            tip[lo:hi] = path.b_tip[b]
            axis[lo:hi] = path.b_axis[b]
        tip[K_b[on] - k0] = path.b_tip[on]
        axis[K_b[on] - k0] = path.b_axis[on]
        ctl = path.controlled(seg, u, tip, axis)          # on boundaries and holds: exactly b_ctl (u is 0 or 1)
        der_tip, der_ax = _tangent(path, seg, u)
        tip_vel = der_tip * v[:, None]
        axis_vel = der_ax * v[:, None]
        for end in (0, self.n_samples - 1):
            if k0 <= end < k1:
                tip_vel[end - k0] = 0.0
                axis_vel[end - k0] = 0.0
        line = path.lines(seg, u) if n else np.full(len(k), path.start_line, int)
        rpm = path.rpm[seg]
        for b, (a, e) in self.dwells.items():
            a, e = max(a, k0), min(e, k1)
            if a < e:
                line[a - k0:e - k0] = path.dwell_line[b]
        return (ctl, axis, tip_vel, axis_vel, line.astype(int), rpm.astype(float)), (sf, v, seg, tip)


SAMPLE_CHUNK = 20_000     # ticks sampled at once (the planner's peak is ~0.75 kB per sample)


def _sample(path: _Path, grid, scale, machine, limits, dt, T, job):
    """The whole path sampled at once (the batch planner): (Trajectory, violations or None)."""
    tm = _Timing(path, grid, scale, dt, T, job, max_samples=MAX_SAMPLES)
    (ctl, axis, tip_vel, axis_vel, line, rpm), (sf, v, seg, tip) = tm.samples(0, tm.n_samples)
    q = _check_samples(ctl, axis, line, machine, job)
    traj = Trajectory(dt, ctl, axis, tip_vel, axis_vel, line, rpm, job.source,
                      np.asarray(job.points, float).reshape(-1, 3), marks=tm.marks(0, tm.n_samples))
    worst = _violations(q, tip, v, sf, seg, path, machine, limits, dt)
    return traj, worst


def _check_samples(tip, axis, line, machine, job, problems=None, seen=None):
    """Reachability of the samples (InputError with the job line, or with ``problems`` one Problem per
    line appended); their joint positions."""
    ik = K.ik_batch(tip, axis, machine)
    if not np.all(ik.ok):
        if problems is None:
            i = int(np.argmax(~ik.ok))
            raise InputError(job.source, int(line[i]), f"the path leaves the workspace at tip "
                                                       f"{np.round(tip[i], 4).tolist()}: {ik.reason[i]}")
        bad = np.nonzero(~ik.ok)[0]
        _reach_problems(problems, seen, job, line[bad], ik.reason[bad], "the path between the programmed poses is ")
    return ik.q


def _tangent(path, seg, u, delta=1e-4):
    """d(controlled point)/ds, d(axis)/ds by central differences inside the segment's own geometry."""
    du = delta / path.length[seg]
    tp, ap = path.point(seg, u + du)
    tm, am = path.point(seg, u - du)
    return (tp - tm) / (2 * delta), (ap - am) / (2 * delta)


def _violations(q, tip, v, s, seg, path, machine, limits, dt):
    """None when every limit holds on the samples; else (s of offending samples, cap factor)."""
    jl = machine.limits
    tol = 1.0 + VIOLATION_TOL
    ratios = []
    qv = np.abs(np.diff(q, axis=0)) / dt / jl.joint_speed
    ratios.append(("v", np.concatenate([qv.max(-1), [0.0]])))
    qa = np.abs(np.diff(q, 2, axis=0)) / dt**2 / jl.joint_accel
    ratios.append(("a", np.concatenate([[0.0], qa.max(-1), [0.0]])))
    tv = np.linalg.norm(np.diff(tip, axis=0), axis=-1) / dt / np.maximum(path.vmax[seg[1:]], 1e-300)
    rot = path.rot[seg[1:]]
    ratios.append(("v", np.concatenate([np.where(rot, 0.0, tv), [0.0]])))
    ta = np.linalg.norm(np.diff(tip, 2, axis=0), axis=-1) / dt**2 / limits.accel_mm_s2
    ratios.append(("a", np.concatenate([[0.0], ta, [0.0]])))
    bad_s, bad_f, bad_v = [], [], []
    for kind, r in ratios:
        m = r > tol
        if np.any(m):
            bad_s.append(s[m])
            bad_f.append(0.97 / r[m])
            bad_v.append(np.abs(v[m]))
    if not bad_s:
        return None
    return np.concatenate(bad_s), np.concatenate(bad_f), np.concatenate(bad_v)
