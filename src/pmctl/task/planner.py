"""Path planner: a job (pmctl.task.job) -> a Trajectory (pmctl.task.trajectory) sampled at the tick period.

Public API (stable)::

    plan(job, machine, dt, *, feed_override=1.0, limits=PlannerLimits(), start=None) -> Trajectory
    home_pose(machine) -> (tip, axis)          # the default start pose (q at home)
    load_job(path, machine, **options)         # re-exported from pmctl.task.job, dispatches on suffix

``start`` is (tip, axis) in W where the tool is when the job begins (default: the home pose, tool
vertical at Z_home with the table centred). The first sample is exactly ``start``, the last exactly the
last programmed point; ``Trajectory.points`` holds the job's programmed points.

How it works (all vectorised with numpy):

1. **Geometry.** Each move becomes a segment with a path parameter s: the tip's arc length (for a
   pure reorientation, ``rotation_length_mm`` x the slerp angle). Tip: straight line, or arc/helix in
   XY about the centre; tool axis: slerp between the end axes. The path is exactly the programmed one:
   corners are never rounded.
2. **Limits along the path** on a grid in s (``grid_mm``): the feed (F x override, or the rapid speed)
   on the tip speed, the tool-axis angular rate, the tip's normal acceleration on curves, and the
   joint speed/acceleration limits of ``machine.limits``: q' = dq/ds and q'' from ``ik_batch`` by
   central differences give v <= qd_max/|q'|, v^2 |q''| <= qdd_max/2, |s''| |q'| <= qdd_max/2.
3. **Junctions** (grbl/Klipper-style look-ahead, adapted to a sampled trajectory that passes through
   the corner point): the velocity direction changes within one tick, so the corner speed is limited
   to v_j <= a_max dt / |d_out - d_in| for the tip and each joint. Exact stops at the start and end,
   dwells (G4), spindle changes and reversals.
4. **Velocity profile**: backward and forward passes of v^2 <= v_prev^2 + 2 a ds in closed form
   (prefix sums and running minima), giving a time-optimal, acceleration-limited profile s(t).
5. **Jerk limit**: s(t) is averaged over a moving window T = 2 a_t / j (exactly, via the integral of
   the piecewise-quadratic s(t)). Filtering the scalar s, not positions, keeps the tool on the path;
   the filtered profile has trapezoidal acceleration (an S-curve) with jerk <= 2 a_t / T. Limits are
   eroded beforehand (each cap extends c T around its point, every stop is held for T) so the filtered
   profile still respects them.
6. **Exact arrival**: a time warp puts every segment end on a tick, and that sample is set to the
   programmed pose itself (tip and axis, bit for bit). The warped clock lags real time by D(t), a
   monotone (PCHIP) interpolant of the lags at the ends, so the warp rate 1 - D' is <= 1: it only ever
   slows the profile (by at most about one tick per segment) and never breaks a limit. Samples held at
   a stop sit exactly on the point with zero velocity; those of a dwell carry the G4's line.
7. **Check and iterate**: the samples go through ``ik_batch``; an unreachable sample raises InputError
   with the job line; joint speed/acceleration, tip speed and acceleration are measured on the samples
   by finite differences, and where one exceeds its limit by more than ``VIOLATION_TOL`` the caps around
   it are lowered and the profile is re-planned (``max_iterations``, else PlanningError).

Resource bounds: the planner holds the whole trajectory in memory (about 0.75 kB per sample at its
peak), so it refuses, with the file, the line and the reason and before allocating anything large,
a job of more than ``MAX_MOVES`` moves (pmctl.task.job), of more than ``MAX_SAMPLES`` ticks (20 min
at 1 kHz) or a path of more than
``MAX_GRID_POINTS`` limit-grid points (500 m at the default 0.25 mm grid). The duration is checked
three times: a lower bound (length / feed + dwells) before the limit grid, the grid size before
it is built, and the profile's true duration before it is sampled. A typo such as ``F0.42`` or a
``G4`` of days is refused this way in well under a second.

Feeds are capped at ``rapid_mm_s``, the tool tip's top speed. Cost: a 10-minute 5-axis CL job
(18 000 moves, 614 000 samples at 1 kHz) plans in about 4 s of CPU (benchmarks/bench_planner.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PchipInterpolator

from pmctl.core import kinematics as K
from pmctl.core.errors import InputError, PmctlError
from pmctl.task.job import ARC, DWELL, MAX_MOVES, RAPID, Job, home_pose, load_job  # noqa: F401  (re-exported)
from pmctl.task.trajectory import Trajectory

__all__ = ["PlannerLimits", "plan", "home_pose", "load_job", "PlanningError"]


VIOLATION_TOL = 1e-6      # relative overshoot of a limit on the samples that triggers re-planning
MAX_SAMPLES = 1_200_000   # ticks of one planned job (20 min at 1 kHz; ~0.9 GB at the planner's peak)
MAX_GRID_POINTS = 2_000_000   # points of the limit grid along the path


class PlanningError(PmctlError):
    """The planner could not meet the limits (should not happen for a reachable job)."""


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

    @property
    def tangential_accel(self):
        return 0.7 * self.accel_mm_s2

    @property
    def normal_accel(self):
        return 0.7 * self.accel_mm_s2


# ---------------------------------------------------------------- geometry

class _Path:
    """Segments of a job as arrays; pose(seg, u) evaluates any number of points at once."""

    def __init__(self, job: Job, start, limits: PlannerLimits, feed_override: float):
        tip, axis = (np.asarray(start[0], float), np.asarray(start[1], float))
        axis = axis / np.linalg.norm(axis)
        rows = []
        stop = {0}                    # boundaries (index = segments completed) with an exact stop
        dwell, dwell_line = {}, {}
        rpm_prev = None
        self.start_line = job.moves[0].line if job.moves else 0
        for m in job.moves:
            if m.kind == DWELL:
                b = len(rows)
                stop.add(b)
                dwell[b] = dwell.get(b, 0.0) + float(m.dwell)
                dwell_line[b] = m.line
                continue
            t1 = np.asarray(m.tip, float)
            a1 = np.asarray(m.axis, float)
            a1 = a1 / np.linalg.norm(a1)
            phi = float(np.arccos(np.clip(np.dot(axis, a1), -1.0, 1.0)))
            r = dict(kind=0, p0=tip, p1=t1, a0=axis, a1=a1, phi=phi, c=np.zeros(2), r0=0.0, r1=0.0,
                     th0=0.0, sweep=0.0, line=m.line, rpm=m.spindle_rpm)
            if m.kind == ARC:
                c = np.asarray(m.center, float)[:2]
                r0 = float(np.hypot(*(tip[:2] - c)))
                r1 = float(np.hypot(*(t1[:2] - c)))
                rm = 0.5 * (r0 + r1)
                ltip = float(np.hypot(rm * m.sweep, t1[2] - tip[2]))
                r.update(kind=1, c=c, r0=r0, r1=r1, th0=float(np.arctan2(tip[1] - c[1], tip[0] - c[0])),
                         sweep=float(m.sweep))
            else:
                ltip = float(np.linalg.norm(t1 - tip))
            rot = ltip < 1e-6
            length = limits.rotation_length_mm * phi if rot else ltip
            if length < 1e-9:
                tip, axis = t1, a1         # nothing moves: the point is the current pose
                continue
            if rpm_prev is not None and m.spindle_rpm != rpm_prev:
                stop.add(len(rows))
            rpm_prev = m.spindle_rpm
            vmax = limits.rapid_mm_s if m.kind == RAPID else min(m.feed * feed_override, limits.rapid_mm_s)
            if not vmax > 0:
                raise InputError(job.source, m.line, f"move has no positive feed ({vmax!r} mm/s)")
            r.update(length=length, rot=rot, vmax=vmax)
            rows.append(r)
            tip, axis = t1, a1
        self.n = n = len(rows)
        stop.add(n)
        self.stop = np.zeros(n + 1, bool)
        self.stop[sorted(stop)] = True
        self.dwell = np.zeros(n + 1)
        self.dwell_line = np.zeros(n + 1, int)
        for b, d in dwell.items():
            self.dwell[b] = d
            self.dwell_line[b] = dwell_line[b]
        self.end_tip, self.end_axis = tip, axis
        self.start_tip, self.start_axis = np.asarray(start[0], float), np.asarray(start[1], float)
        get = lambda k, shape=(): np.array([r[k] for r in rows], float).reshape((n,) + shape)  # noqa: E731
        self.kind = np.array([r["kind"] for r in rows], int)
        self.p0, self.p1, self.a0, self.a1 = get("p0", (3,)), get("p1", (3,)), get("a0", (3,)), get("a1", (3,))
        self.phi, self.c, self.r0, self.r1 = get("phi"), get("c", (2,)), get("r0"), get("r1")
        self.th0, self.sweep, self.length, self.vmax = get("th0"), get("sweep"), get("length"), get("vmax")
        self.rot = np.array([r["rot"] for r in rows], bool)
        self.line = np.array([r["line"] for r in rows], int)
        self.rpm = get("rpm")
        self.s_end = np.cumsum(self.length)
        self.s_start = self.s_end - self.length
        self.total = float(self.s_end[-1]) if n else 0.0
        # Boundary poses, exact: b = 0 the start, b = i + 1 the end of segment i.
        self.b_tip = np.vstack([self.start_tip[None], self.p1]) if n else self.start_tip[None].copy()
        self.b_axis = np.vstack([self.start_axis[None] / np.linalg.norm(self.start_axis), self.a1]) if n \
            else self.start_axis[None].copy()
        self.b_s = np.concatenate([[0.0], self.s_end])

    def pose(self, seg, u):
        seg = np.asarray(seg, int)
        u = np.asarray(u, float)
        uu = u[..., None]
        p0, p1 = self.p0[seg], self.p1[seg]
        tip = p0 + uu * (p1 - p0)
        arc = self.kind[seg] == 1
        if np.any(arc):
            th = self.th0[seg] + self.sweep[seg] * u
            r = self.r0[seg] + (self.r1[seg] - self.r0[seg]) * u
            c = self.c[seg]
            at = np.stack([c[..., 0] + r * np.cos(th), c[..., 1] + r * np.sin(th),
                           p0[..., 2] + u * (p1[..., 2] - p0[..., 2])], -1)
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

    def derivatives(self, seg, u, machine, delta=1e-3):
        """d/ds and d2/ds2 of tip, axis and joints at (seg, u), central differences of step delta mm."""
        seg = np.asarray(seg, int)
        du = delta / self.length[seg]
        uu = np.concatenate([u - du, u, u + du])
        ss = np.concatenate([seg, seg, seg])
        tip, axis = self.pose(ss, uu)
        q = K.ik_batch(tip, axis, machine, check_limits=False).q
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
    """w[k] = min(w_lim[k], w[k-1] + c[k-1]), w[0] = w_lim[0], in closed form."""
    C = np.concatenate([[0.0], np.cumsum(c)])
    return C + np.minimum.accumulate(w_lim - C)


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
        self.t0 = np.concatenate([[0.0], np.cumsum(self.dur)[:-1]])
        self.t_end = float(self.t0[-1] + self.dur[-1])
        d = self.dur
        # The running integral of s grows like S t; keep it in extended precision so that the moving
        # average (a difference of two such integrals) stays accurate to ~1e-12 mm on long jobs.
        piece = (self.s0 * d + 0.5 * self.v0 * d**2 + self.a * d**3 / 6).astype(np.longdouble)
        cum = np.cumsum(piece)
        self.I0 = np.concatenate([np.zeros(1, np.longdouble), cum[:-1]])
        self.I_end = cum[-1]
        self.S = float(s[-1])
        self.T = T
        # Arrival time (after the hold) at every grid point.
        t_all = np.concatenate([[0.0], np.cumsum(t_dur)])
        self.t_arrive = t_all[0::2]           # start of hold at point k
        self.t_leave = t_all[0::2] + hold

    def _eval(self, t):
        t = np.asarray(t, float)
        i = np.clip(np.searchsorted(self.t0, t, "right") - 1, 0, len(self.t0) - 1)
        tau = np.clip(t - self.t0[i], 0.0, self.dur[i])
        s = self.s0[i] + self.v0[i] * tau + 0.5 * self.a[i] * tau**2
        v = self.v0[i] + self.a[i] * tau
        I = self.I0[i] + (self.s0[i] * tau + 0.5 * self.v0[i] * tau**2 + self.a[i] * tau**3 / 6)
        before, after = t < 0, t > self.t_end
        s = np.where(before, 0.0, np.where(after, self.S, s))
        v = np.where(before | after, 0.0, v)
        I = np.where(before, 0.0, np.where(after, self.I_end + np.longdouble(self.S) * (t - self.t_end), I))
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
    limits = limits or PlannerLimits()
    if not dt > 0:
        raise PlanningError(f"tick period must be > 0, got {dt!r}")
    if not feed_override > 0:
        raise PlanningError(f"feed override must be > 0, got {feed_override!r}")
    if start is None:
        start = home_pose(machine)
    if len(job.moves) > MAX_MOVES:
        raise InputError(job.source, int(job.moves[MAX_MOVES].line) or None,
                         f"more than {MAX_MOVES} moves: longer than the batch planner takes (split the job)")
    path = _Path(job, start, limits, feed_override)
    T = max(2.0 * limits.tangential_accel / limits.jerk_mm_s3, 2.0 * dt)
    _check_size(path, job, dt, limits)
    if path.n == 0:
        nt = int(np.ceil(path.dwell.sum() / dt)) + 1
        tip = np.repeat(path.start_tip[None], nt, 0)
        axis = np.repeat(path.b_axis[:1], nt, 0)
        z = np.zeros((nt, 3))
        return Trajectory(dt, tip, axis, z, z.copy(), np.full(nt, path.start_line, int), np.zeros(nt),
                          job.source, np.asarray(job.points, float))
    _check_reachable(path, job, machine)
    grid = _limit_grid(path, machine, limits, dt, T)
    scale = np.ones(len(grid["s"]))
    for it in range(limits.max_iterations):
        traj, worst = _sample(path, grid, scale, machine, limits, dt, T, job)
        if worst is None:
            return traj
        s_bad, factor, v_bad = worst
        # Lower the caps around the offending samples and plan again.
        radius = 1.1 * v_bad * T + 2 * limits.grid_mm
        lo = np.searchsorted(grid["s"], s_bad - radius, "left")
        hi = np.searchsorted(grid["s"], s_bad + radius, "right") - 1
        scale = np.minimum(scale, _range_min(len(scale), lo, hi, factor))
    raise PlanningError(f"{job.source}: could not meet the joint/feed limits after {limits.max_iterations} "
                        "re-planning iterations")


def _too_long(job, line, what, dt):
    return InputError(job.source, int(line) if line else None,
                      f"{what}: the batch planner holds at most {MAX_SAMPLES} ticks "
                      f"({MAX_SAMPLES * dt / 60:.0f} min at {1 / dt:g} Hz); check the feed (F is per minute), "
                      f"dwells (G4 P is in seconds) and arc turns (P), or split the job")


def _check_size(path: _Path, job, dt, limits: PlannerLimits):
    """Refuse, before anything large is allocated, a job whose lower-bound duration or limit grid
    exceeds the bounds; the line named is where the bound is crossed."""
    # Lower bound of the duration at every boundary: each segment at its top speed, dwells in full.
    seg_t = path.length / path.vmax if path.n else np.zeros(0)
    t_b = np.cumsum(path.dwell) + np.concatenate([[0.0], np.cumsum(seg_t)])   # at boundary b (dwell incl.)
    limit_t = MAX_SAMPLES * dt
    if not t_b[-1] < limit_t:
        b = int(np.argmax(~(t_b < limit_t)))
        if b > 0 and t_b[b] - path.dwell[b] >= limit_t:          # crossed while moving into boundary b
            line = path.line[b - 1]
            what = (f"this move alone takes at least {seg_t[b - 1]:.4g} s ({path.length[b - 1]:.4g} mm at "
                    f"{path.vmax[b - 1] * 60:.4g} mm/min)" if seg_t[b - 1] >= 0.5 * limit_t
                    else f"the job takes at least {t_b[-1]:.4g} s, over the bound by this line")
        else:                                                     # crossed during the dwell at b
            line = path.dwell_line[b]
            what = (f"the job takes at least {t_b[-1]:.4g} s, of which {path.dwell.sum():.4g} s of dwells; "
                    "over the bound by this line")
        raise _too_long(job, line, what, dt)
    if path.n:
        counts = np.maximum(2.0, np.ceil(path.length / limits.grid_mm))
        cum = np.cumsum(counts)
        if cum[-1] > MAX_GRID_POINTS:
            i = int(np.argmax(cum > MAX_GRID_POINTS))
            raise InputError(job.source, int(path.line[i]),
                             f"the path is {path.total:.6g} mm long: more than the batch planner's "
                             f"{MAX_GRID_POINTS} grid points of {limits.grid_mm:g} mm by this line "
                             f"(check arc turns P and the coordinates, or split the job)")


def _check_reachable(path, job, machine):
    r = K.ik_batch(path.b_tip, path.b_axis, machine)
    if not np.all(r.ok[1:]):
        b = int(np.argmax(~r.ok[1:])) + 1
        raise InputError(job.source, int(path.line[b - 1]), f"pose unreachable: {r.reason[b]}")


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


def _profile(path, grid, scale, T):
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
    hold = np.zeros(len(s))
    hold[stop_pts] = T + path.dwell[path.stop]
    hold[b_idx[0]] = path.dwell[0]
    hold[b_idx[-1]] = path.dwell[-1]
    return _Profile(s, w, hold, T), stop_pts


def _sample(path: _Path, grid, scale, machine, limits, dt, T, job):
    prof, stop_pts = _profile(path, grid, scale, T)
    b_idx = grid["b_idx"]
    n = path.n
    # Filtered arrival time at every boundary.
    tau = np.empty(n + 1)
    tau[0] = -0.5 * T
    tau[n] = prof.t_end + 0.5 * T
    inner = np.arange(1, n)
    st = path.stop[inner]
    tau[inner[st]] = prof.t_arrive[b_idx[inner[st]]] + 0.5 * (T + path.dwell[inner[st]])
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
        tau[mv] = 0.5 * (lo + hi)
    gaps = np.diff(tau)
    over = np.cumsum(gaps) / dt > MAX_SAMPLES - n - 1      # before anything of that size exists
    if np.any(over):
        b = int(np.argmax(over))
        raise _too_long(job, path.line[b], f"the planned job takes {tau[-1] - tau[0]:.6g} s "
                                           "(the joint and acceleration limits slow it down)", dt)
    ticks = np.maximum(1, np.ceil(gaps / dt - 1e-9).astype(int))
    K_b = np.concatenate([[0], np.cumsum(ticks)])
    # The warped clock lags real time by D(t) >= 0; D is a monotone (PCHIP) interpolant of its knot
    # values, so the warp rate 1 - D' never exceeds 1: the warp only ever slows the profile down.
    x_b = K_b * dt
    lag = PchipInterpolator(x_b, x_b - (tau - tau[0]))
    dlag = lag.derivative()
    k = np.arange(K_b[-1] + 1)
    tk = k * dt
    rate = 1.0 - dlag(tk)
    if np.any(rate < 0):              # only for segments far shorter than a tick
        warp = PchipInterpolator(x_b, tau)
        tt, rate = warp(tk), warp.derivative()(tk)
    else:
        tt = tk - lag(tk) + tau[0]
    sf, vf = prof.filtered(tt)
    v = vf * rate
    sf = np.clip(sf, 0.0, path.total)
    seg, u = path.locate(sf)
    # Samples on boundaries: exactly the programmed pose, arriving from the segment before.
    seg[K_b[1:]] = np.arange(n)
    u[K_b[1:]] = 1.0
    seg[0], u[0] = 0, 0.0
    # Samples held at a stop (within 1e-9 mm of it): exactly there, at rest.
    hold_ranges = {}
    for b in np.nonzero(path.stop)[0]:
        lo = int(np.searchsorted(sf, path.b_s[b] - 1e-9, "left"))
        hi = int(np.searchsorted(sf, path.b_s[b] + 1e-9, "right"))
        lo, hi = min(lo, K_b[b]), max(hi, K_b[b] + 1)
        hold_ranges[b] = (lo, hi)
        seg[lo:hi] = max(b - 1, 0)
        u[lo:hi] = 1.0 if b > 0 else 0.0
        v[lo:hi] = 0.0
    tip, axis = path.pose(seg, u)
    for b, (lo, hi) in hold_ranges.items():
        tip[lo:hi] = path.b_tip[b]
        axis[lo:hi] = path.b_axis[b]
    tip[K_b] = path.b_tip
    axis[K_b] = path.b_axis
    der_tip, der_ax = _tangent(path, seg, u)
    tip_vel = der_tip * v[:, None]
    axis_vel = der_ax * v[:, None]
    tip_vel[0] = 0.0
    axis_vel[0] = 0.0
    tip_vel[-1] = 0.0
    axis_vel[-1] = 0.0
    line = path.line[seg]
    rpm = path.rpm[seg]
    # Samples inside a dwell carry the G4's line (the dwell is the middle of the hold at its point).
    for b in np.nonzero(path.dwell > 0)[0]:
        lo, hi = hold_ranges[b]
        extra = (hi - lo) - int(round(path.dwell[b] / dt))
        a = lo + (0 if b == 0 else (extra // 2 if b < n else extra))
        line[a:a + int(round(path.dwell[b] / dt)) + 1] = path.dwell_line[b]
    # Reachability and limits on the samples.
    ik = K.ik_batch(tip, axis, machine)
    if not np.all(ik.ok):
        i = int(np.argmax(~ik.ok))
        raise InputError(job.source, int(line[i]), f"the path leaves the workspace at tip "
                                                   f"{np.round(tip[i], 4).tolist()}: {ik.reason[i]}")
    traj = Trajectory(dt, tip, axis, tip_vel, axis_vel, line.astype(int), rpm.astype(float), job.source,
                      np.asarray(job.points, float).reshape(-1, 3))
    worst = _violations(ik.q, tip, v, sf, seg, path, machine, limits, dt)
    return traj, worst


def _tangent(path, seg, u, delta=1e-4):
    """d(tip)/ds, d(axis)/ds by central differences inside the segment's own geometry."""
    du = delta / path.length[seg]
    tp, ap = path.pose(seg, u + du)
    tm, am = path.pose(seg, u - du)
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
