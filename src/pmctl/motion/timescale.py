"""Time-scaling of a planned path: the loop follows planned samples at a feed factor sigma.

The planner samples a job at nominal time tau (period ``dt_plan``). The loop keeps its own path
clock s (in samples) and advances it every tick by sigma * dt / dt_plan. The target of a tick is
the pose at s (linear interpolation between the two neighbouring samples, axis renormalised); its
feed-forward is the difference to the pose at the next tick's s, so the pulses of a tick carry the
model exactly to the next target. At sigma = 1 and dt = dt_plan this is the planned trajectory
itself, sample for sample.

What moves sigma (each tick, :class:`TimeScaler`):
- its goal: the feed override (10-200 %) on feed moves, the rapid override (25/50/100 %) on rapids,
  0 while a feed hold (or a stop) is requested;
- a cap per sample (``S_CAP``): joint speeds sigma |q_tau| <= vmax, joint accelerations from the
  path's curvature sigma^2 |q_tautau| <= amax, the tool-tip speed <= the rapid speed; a backward pass
  along the samples lowers it ahead of a tighter point, so sigma is already down when it gets there;
- starvation: with the end of the queued samples ahead and no job end among them, sigma is held to
  what can still stop before the last queued sample (a feed hold with a reason, not a jerk);
- limits on sigma itself: |sigma'| <= ``accel`` and |sigma''| <= ``jerk``, and sigma' inside the
  interval that keeps every joint's acceleration q'' = sigma' q_tau + sigma^2 q_tautau within its
  limit at the current sample.
Every target is a point of the planned path: a hold stops ON the path, never by dropping targets.

The per-tick part exists twice: :class:`PathFollower` (with :class:`TimeScaler`) is the readable
reference, :class:`CompiledFollower` the same arithmetic in C99 (``follow/follow.c``, built at
install as pmctl.motion._follow), equal to it tick for tick (tests/motion/test_follow.py).
:func:`make_follower` picks one by ``nc.implementation`` ("compiled", the default, or "python").

Sample rows (``WIDTH`` floats): tip (3), axis (3), tip_tau (3), axis_tau (3), q_tau (5),
q_tautau (5), cap, line, flags (``FLAG_RAPID``, ``FLAG_END`` = last sample of a job, at rest,
``FLAG_PROBE`` = a sample of a probing move, pmctl.motion.probe.mark_probe_rows).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import numpy as np

from pmctl.core import kinematics as K, shaper as S

S_TIP, S_AXIS, S_TIPT, S_AXT, S_QT, S_QTT, S_CAP, S_LINE, S_FLAGS = 0, 3, 6, 9, 12, 17, 22, 23, 24
WIDTH = 25
FLAG_RAPID, FLAG_END = 1, 2
FLAG_PROBE = 4

FEED_OVERRIDE_RANGE = (0.10, 2.00)
RAPID_OVERRIDES = (0.25, 0.50, 1.00)
SIGMA_MAX = 2.0
JOINT_SHARE = 0.95            # share of the joint limits the time-scaling may use


def scaling_limits(params) -> tuple[float, float]:
    """Default (accel, jerk) of sigma for NC limits ``params``: at sigma' = accel a joint moving at
    its speed limit accelerates at 45 % of its acceleration limit; the jerk ramps that in 50 ms."""
    accel = 0.45 * float(np.min(np.asarray(params.amax) / np.asarray(params.vmax)))
    return accel, accel / 0.05


def sample_caps(q_t, q_tt, tip_t, params, rapid_mm_s: float) -> np.ndarray:
    """Per-sample sigma cap (joint speed, joint acceleration from curvature, tip speed), <= SIGMA_MAX."""
    vmax = np.asarray(params.vmax) * JOINT_SHARE
    amax = np.asarray(params.amax) * JOINT_SHARE
    with np.errstate(divide="ignore"):
        cv = np.min(vmax / np.maximum(np.abs(q_t), 1e-12), axis=1)
        ca = np.sqrt(np.min(amax / np.maximum(np.abs(q_tt), 1e-12), axis=1))
        ct = rapid_mm_s / np.maximum(np.linalg.norm(tip_t, axis=1), 1e-12)
    return np.minimum(np.minimum(cv, ca), np.minimum(ct, SIGMA_MAX))


def backward_pass(cap, dt_plan: float, decel: float, end_allowed: float = SIGMA_MAX) -> np.ndarray:
    """allowed_i = min(cap_i, sqrt(allowed_{i+1}^2 + 2 decel dt_plan)), closed form: sigma can come
    down from allowed_i to every later cap with sigma' >= -decel (d(sigma^2)/dtau = 2 sigma').
    ``end_allowed``: what is allowed just after the last sample (the next chunk's first value)."""
    n = len(cap)
    if n == 0:
        return cap
    tau = np.arange(n + 1) * dt_plan
    c2 = np.concatenate([np.asarray(cap, float) ** 2, [end_allowed ** 2]]) + 2 * decel * tau
    m = np.minimum.accumulate(c2[::-1])[::-1]
    return np.sqrt(np.maximum(m[:n] - 2 * decel * tau[:n], 0.0))


def full_speed_queue(params, dt: float, capacity: int) -> int:
    """Samples the path follower needs queued ahead (with no job end among them) to run at
    SIGMA_MAX: its starvation limit sigma <= 0.9 sqrt(accel remain) (PathFollower.next_target), in
    samples at the tick period ``dt``; at most half the ring's ``capacity``."""
    accel = scaling_limits(params)[0]
    tau = SIGMA_MAX ** 2 / (0.81 * accel)
    return min(int(math.ceil(tau / dt)) + 2, capacity // 2)


def derivatives(q, dt_plan: float, q_before=None, q_after=None):
    """q_tau, q_tautau of samples q (n, k) by central differences; the neighbours outside the chunk
    (or, at a job's ends, a linear extension) close the ends."""
    q = np.asarray(q, float)
    n = len(q)
    if n == 0:                      # nothing to differentiate (an item that plans to no samples)
        return q.copy(), q.copy()
    a = None if q_before is None else np.asarray(q_before, float).reshape(1, -1)
    b = None if q_after is None else np.asarray(q_after, float).reshape(1, -1)
    # a missing neighbour: the linear extension of the samples (one sample: mirrored about it
    # through the other neighbour, or at rest when it stands alone)
    if a is None:
        a = (2 * q[0] - q[1])[None] if n > 1 else (q[:1] if b is None else 2 * q[:1] - b)
    if b is None:
        b = (2 * q[-1] - q[-2])[None] if n > 1 else 2 * q[-1:] - a
    ext = np.concatenate([a, q, b])
    qt = (ext[2:] - ext[:-2]) / (2 * dt_plan)
    qtt = (ext[2:] - 2 * ext[1:-1] + ext[:-2]) / dt_plan ** 2
    return qt, qtt


def make_rows(tip, axis, q, line, dt_plan, params, *, rapid=None, rapid_mm_s=50.0, end=True,
              neighbours=((None, None, None), (None, None, None))) -> np.ndarray:
    """Sample rows of one stretch of path (no backward pass yet: S_CAP holds the raw caps).
    ``neighbours`` = ((tip, axis, q) before, (tip, axis, q) after) the stretch, or Nones at a job end."""
    (tb, ab, qb), (ta, aa, qa) = neighbours
    n = len(tip)
    rows = np.zeros((n, WIDTH))
    rows[:, S_TIP:S_TIP + 3] = tip
    rows[:, S_AXIS:S_AXIS + 3] = axis
    rows[:, S_TIPT:S_TIPT + 3] = derivatives(tip, dt_plan, tb, ta)[0]
    rows[:, S_AXT:S_AXT + 3] = derivatives(axis, dt_plan, ab, aa)[0]
    qt, qtt = derivatives(q, dt_plan, qb, qa)
    rows[:, S_QT:S_QT + 5] = qt
    rows[:, S_QTT:S_QTT + 5] = qtt
    rows[:, S_CAP] = sample_caps(qt, qtt, rows[:, S_TIPT:S_TIPT + 3], params, rapid_mm_s)
    rows[:, S_LINE] = line
    if rapid is not None:
        rows[:, S_FLAGS] = np.where(np.asarray(rapid, bool), FLAG_RAPID, 0)
    if end and n:
        rows[-1, S_FLAGS] += FLAG_END
    return rows


def iter_job_rows(traj, machine, params, *, rapid=None, rapid_mm_s=50.0, chunk=2000, decel=None):
    """Sample rows of a planned Trajectory, chunk by chunk (IK and derivatives per chunk: memory
    O(chunk), not O(job)); ``rapid`` flags the samples of rapid moves. See ``iter_stream_rows``."""
    pieces = ((traj.tip[a:a + chunk], traj.axis[a:a + chunk], traj.line[a:a + chunk],
               None if rapid is None else rapid[a:a + chunk]) for a in range(0, len(traj), chunk))
    return _rows(pieces, traj.dt, machine, params, rapid_mm_s, chunk, decel)


def iter_stream_rows(trajs, machine, params, *, rapid_lines=(), rapid_mm_s=50.0, chunk=2000, decel=None):
    """Sample rows of a job planned in pieces (an iterable of Trajectory, as the streaming planner
    yields them), ``chunk`` rows at a time: the same rows as ``iter_job_rows`` of the whole
    trajectory, in memory O(chunk + piece). Samples of the lines ``rapid_lines`` are rapids."""
    rl = np.asarray(sorted(rapid_lines), int)
    first = []

    def pieces():
        for tr in trajs:
            if not first:
                first.append(tr.dt)
            yield tr.tip, tr.axis, tr.line, (np.isin(np.asarray(tr.line), rl) if len(rl) else None)
    it = pieces()
    head = next(it, None)
    if head is None:
        return iter(())
    return _rows(itertools.chain([head], it), first[0], machine, params, rapid_mm_s, chunk, decel)


def _rows(pieces, dtp, machine, params, rapid_mm_s, chunk, decel):
    """Rows of samples arriving in pieces (tip, axis, line, rapid-or-None), ``chunk`` samples at a
    time (a RowStream fed piece by piece)."""
    rs = RowStream(dtp, machine, params, rapid_mm_s=rapid_mm_s, chunk=chunk, decel=decel)
    for tip, axis, line, rapid in pieces:
        rs.add(tip, axis, line, rapid)
        if rs.buffered > chunk:
            yield from rs.take()
    yield from rs.take(end=True)


class RowStream:
    """Sample rows of a path whose samples arrive in pieces (``add``), handed out as soon as they
    are final (``take``): rows of at most ``chunk`` samples, in memory O(chunk), the same rows
    whatever the pieces. A row needs the sample after it (the derivatives, by central differences
    with their neighbours), and its cap the caps ahead of it: the backward pass lowers sigma's cap
    ahead of a tighter point as far as sigma takes to come down from SIGMA_MAX (``hold`` samples,
    0.44 s at the default limits), so the last ``hold`` rows wait for the samples after them (or for
    the end, ``take(end=True)``: the last sample is the job's end, FLAG_END). The console's stream
    (pmctl.task.supervisor) takes rows as windows settle; a whole job's rows are taken chunk by
    chunk (iter_job_rows, iter_stream_rows)."""

    def __init__(self, dtp, machine, params, *, rapid_mm_s=50.0, chunk=2000, decel=None):
        self.dtp, self.machine, self.params, self.rapid_mm_s = dtp, machine, params, rapid_mm_s
        self.chunk = int(chunk)
        self.decel = decel if decel is not None else 0.5 * scaling_limits(params)[0]
        self.hold = int(math.ceil(SIGMA_MAX ** 2 / (2.0 * self.decel * dtp))) + 1
        self.buf = []                 # samples not yet made into rows: [tip, axis, line, rapid]
        self.buffered = 0
        self.before = (None, None, None)   # (tip, axis, q) of the sample before the next row
        self.rows = np.zeros((0, WIDTH))   # rows made whose caps may still come down (raw caps)
        self.any_rapid = False

    def add(self, tip, axis, line, rapid=None):
        tip, axis = np.asarray(tip, float), np.asarray(axis, float)
        if len(tip) == 0:
            return
        self.any_rapid |= rapid is not None
        self.buf.append([tip, axis, np.asarray(line), np.asarray(rapid, bool) if rapid is not None
                         else np.zeros(len(tip), bool)])
        self.buffered += len(tip)

    def _make(self, end):
        """Rows of the buffered samples but the last (all of them at the end), appended to ``rows``."""
        cat = [np.concatenate([b[i] for b in self.buf]) for i in range(4)] if self.buf else None
        while cat is not None and len(cat[0]) > (0 if end else 1):
            take = min(self.chunk, len(cat[0]) - (0 if end else 1))
            more = len(cat[0]) > take
            m = take + (1 if more else 0)
            tip, axis = cat[0][:m], cat[1][:m]
            q = K.ik_batch(tip, axis, self.machine, check_limits=False).q
            after = (tip[take], axis[take], q[take]) if more else (None, None, None)
            rows = make_rows(tip[:take], axis[:take], q[:take], cat[2][:take], self.dtp, self.params,
                             rapid=cat[3][:take] if self.any_rapid else None, rapid_mm_s=self.rapid_mm_s,
                             end=not more, neighbours=(self.before, after))
            self.before = (tip[take - 1], axis[take - 1], q[take - 1])
            self.rows = np.concatenate([self.rows, rows]) if len(self.rows) else rows
            cat = [x[take:] for x in cat]
            if len(self.rows) > self.chunk + self.hold:
                break                     # hand these out before making more (memory O(chunk))
        self.buf = [cat] if cat is not None and len(cat[0]) else []
        self.buffered = len(cat[0]) if self.buf else 0

    def take(self, end: bool = False):
        """Rows that are final now (each array at most ``chunk`` rows); ``end``: all of them, the last
        sample being the job's end."""
        while True:
            self._make(end)
            done = end and not self.buf
            keep = 0 if done else self.hold
            n_out = len(self.rows) - keep
            if n_out <= 0:
                return
            caps = backward_pass(self.rows[:, S_CAP], self.dtp, self.decel)
            out = self.rows[:n_out].copy()
            out[:, S_CAP] = caps[:n_out]
            self.rows = self.rows[n_out:]
            for a in range(0, n_out, self.chunk):
                yield out[a:a + self.chunk]
            if not self.buf:
                return


# ---------------------------------------------------------------- input shaping of the time law


def shape_trajectory(traj, shaper):
    """The shaping stage between the planner and the loop (``pmctl run --shaper``, ``[nc] shaper``):
    a planned Trajectory with its time law along the path shaped piece by piece between corners
    (``shaper``: a pmctl.core.shaper.Shaper for every piece, pmctl.core.shaper.shaped_index; or a
    ChainShaping, a shaper per chain chosen for the chains each piece moves). Every sample stays on
    the planned path, only later; the job line and spindle speed follow the path position;
    velocities are the forward differences (the NC's feed-forward). ``shaper`` None returns
    ``traj`` unchanged."""
    if shaper is None or len(traj) < 3:
        return traj

    tip, axis = np.asarray(traj.tip, float), np.asarray(traj.axis, float)
    if isinstance(shaper, S.ChainShaping):      # a shaper per chain, chosen piece by piece
        sig = shaper.index(tip, axis, traj.dt)
    else:
        sig = S.shaped_index(tip, axis, traj.dt, shaper)
    p, a = S.path_at_index(tip, axis, sig)
    i = np.minimum(np.floor(sig + 1e-9).astype(int), len(tip) - 1)
    tv, av = np.zeros_like(p), np.zeros_like(a)
    tv[:-1] = np.diff(p, axis=0) / traj.dt
    av[:-1] = np.diff(a, axis=0) / traj.dt
    return replace(traj, tip=p, axis=a, tip_vel=tv, axis_vel=av, line=np.asarray(traj.line)[i],
                   spindle_rpm=np.asarray(traj.spindle_rpm)[i])


# ---------------------------------------------------------------- the per-tick part


class TimeScaler:
    """sigma, its rate ``dsigma`` and the operator's requests (hold, overrides), per tick."""

    def __init__(self, params, dt: float, accel: float | None = None, jerk: float | None = None):
        a, j = scaling_limits(params)
        self.accel = float(accel or a)
        self.jerk = float(jerk or j)
        self.dt = float(dt)
        self.amax = [float(x) * JOINT_SHARE for x in params.amax]
        self.sigma = 0.0
        self.dsigma = 0.0
        self.feed_override = 1.0
        self.rapid_override = 1.0
        self.hold = False

    def set_feed_override(self, f: float) -> float:
        lo, hi = FEED_OVERRIDE_RANGE
        self.feed_override = min(hi, max(lo, float(f)))
        return self.feed_override

    def set_rapid_override(self, r: float) -> float:
        self.rapid_override = min(RAPID_OVERRIDES, key=lambda x: abs(x - float(r)))
        return self.rapid_override

    def step(self, goal: float, qt, qtt) -> float:
        """Move sigma one tick towards ``goal`` (already capped); returns the new sigma."""
        dt, A, J = self.dt, self.accel, self.jerk
        s, ds = self.sigma, self.dsigma
        e = goal - s
        if abs(e) < 1e-9 and abs(ds) < J * dt:
            self.sigma, self.dsigma = max(goal, 0.0), 0.0
            return self.sigma
        # the rate that still lets sigma' come back to 0 at the goal under the jerk limit
        v = math.sqrt(2.0 * J * 0.8 * abs(e))
        v = min(v, A, 0.5 * abs(e) / dt)
        v = v if e > 0 else -v
        dds = (v - ds) / dt
        if dds > J:
            dds = J
        elif dds < -J:
            dds = -J
        ds = ds + dds * dt
        if ds > A:
            ds = A
        elif ds < -A:
            ds = -A
        # joint accelerations: |ds qt_j + s^2 qtt_j| <= amax_j  ->  an interval for ds
        lo, hi = -math.inf, math.inf
        s2 = s * s
        amax = self.amax
        for j in range(5):
            t = qt[j]
            if abs(t) > 1e-9:
                b1 = (amax[j] - s2 * qtt[j]) / t
                b2 = (-amax[j] - s2 * qtt[j]) / t
                if b1 > b2:
                    b1, b2 = b2, b1
                if b1 > lo:
                    lo = b1
                if b2 < hi:
                    hi = b2
        # The joints may keep sigma from speeding up and limit how hard it slows down, but never force
        # it up nor keep it from slowing towards its goal at a quarter of its rate limit: near the
        # curvature cap (sigma^2 |q_tautau| at the joint limit) any deceleration adds to the
        # curvature term, speeding up to balance it runs away, and a feed hold must still come to rest.
        if lo <= hi:
            if ds > hi:
                ds = hi
            elif ds < lo:
                ds = min(lo, max(ds, -0.25 * A))
        if ds > A:
            ds = A
        elif ds < -A:
            ds = -A
        if e >= 0.0 and s + ds * dt > goal:
            # arrived: land on the goal and rest there, never past it (the discrete jerk-limited
            # approach overshoots by ~1e-5, which at the curvature cap is a joint over its limit)
            self.sigma, self.dsigma = goal, 0.0
            return goal
        s = s + ds * dt
        if s <= 0.0:
            s, ds = 0.0, 0.0
        self.sigma, self.dsigma = s, ds
        return s


IDLE, MOVING, HOLDING, HELD, STARVED = 0, 1, 2, 3, 4
FOLLOW_NAMES = {IDLE: "idle", MOVING: "moving", HOLDING: "holding", HELD: "held", STARVED: "starved"}


class PathFollower:
    """Follows the samples of a source (a Ring or an ArraySource) with a TimeScaler.

    ``next_target()`` once per tick returns the NC target (a reused (12,) array: tip, axis, tip_vel, axis_vel)
    and leaves ``line``, ``state``, ``reason`` and ``s_total`` (samples passed since the start) for
    the status. ``ended_jobs`` counts the job ends (FLAG_END) passed. ``hold`` and
    ``scaler.set_*_override`` are the operator's requests; ``stop_request`` holds and then reports
    ``stopped`` once at rest."""

    def __init__(self, source, params, dt: float, dt_plan: float | None = None, *, scaler=None, pose=None):
        self.src = source
        self.dt = float(dt)
        self.k = self.dt / float(dt_plan or dt)          # samples per tick at sigma = 1
        self.scaler = scaler or TimeScaler(params, dt)
        self.frac = 0.0                                   # position between row 0 and row 1
        self.line = 0
        self.state = IDLE
        self.reason = ""
        self.s_total = 0.0
        self.ended_jobs = 0
        self.at_end = False                               # resting on a job's last sample
        self._rest = list(pose) if pose is not None else None   # pose when nothing is queued (tip + axis)
        self._zero6 = [0.0] * 6
        self._tg = np.zeros(12)              # the target handed to the NC (reused every tick)

    @property
    def sigma(self) -> float:
        return self.scaler.sigma

    def progress(self) -> tuple:
        """(s_total, sigma, line, state) at once: what the loop's per-tick record reads."""
        return self.s_total, self.scaler.sigma, self.line, self.state

    def _pose(self, i, f):
        r0 = self.src.row(i)
        if f <= 0.0:
            return r0[:6].tolist()
        r1 = self.src.row(i + 1)
        a = r0[:6].tolist()
        b = r1[:6].tolist()
        p = [a[m] + f * (b[m] - a[m]) for m in range(6)]
        nrm = math.sqrt(p[3] * p[3] + p[4] * p[4] + p[5] * p[5])
        p[3] /= nrm
        p[4] /= nrm
        p[5] /= nrm
        return p

    def rest_here(self):
        """The path is held on a planned stop (a hold point at rest): the next start leaves it as a rest
        point, sigma stepping to its goal at once (the samples accelerate from rest themselves), so the
        path keeps its phase on the planned samples."""
        if self.state == HELD and self.scaler.sigma == 0.0:
            self.state = IDLE

    def clear(self):
        """Drop every queued sample (soft reset), keeping the current pose as the rest pose."""
        n = self.src.count()
        if n:
            self._rest = self._pose(0, self.frac) if (n > 1 or self.frac == 0.0) else self.src.row(0)[:6].tolist()
        self.src.clear()
        self.frac = 0.0
        self.scaler.sigma = self.scaler.dsigma = 0.0
        self.state = IDLE
        self.at_end = False           # the end it rested on is gone: the next job's end is a new one

    def next_target(self):
        src, sc = self.src, self.scaler
        n = src.count()
        if n == 0:
            self.state = HELD if sc.hold else IDLE
            sc.sigma = sc.dsigma = 0.0
            self._tg[:] = (self._rest or [0.0, 0.0, 0.0, 0.0, 0.0, 1.0]) + self._zero6
            return self._tg
        r0 = src.row(0)
        flags = int(r0[S_FLAGS])
        self.line = int(r0[S_LINE])
        f = self.frac
        if flags & FLAG_END and f == 0.0:
            # resting on a job's last sample: pass it on to the next job, if one is queued
            pose = r0[:6].tolist()
            if n == 1:
                if not self.at_end:
                    self.at_end = True
                    self.ended_jobs += 1
                self._rest = pose
                self.state = HELD if sc.hold else IDLE
                self._tg[:] = pose + self._zero6
                return self._tg
            if not self.at_end:
                self.ended_jobs += 1
            self.at_end = False
            src.advance(1)
            n -= 1
            r0 = src.row(0)
            flags = int(r0[S_FLAGS])
        self.at_end = False
        pose = self._pose(0, f) if n > 1 else r0[:6].tolist()
        # ---- sigma's goal
        goal = 0.0 if sc.hold else (sc.rapid_override if flags & FLAG_RAPID else sc.feed_override)
        r1 = src.row(1) if n > 1 else r0
        cap = min(r0[S_CAP], r1[S_CAP])
        if goal > cap:
            goal = cap
        starving = False
        last = src.row(n - 1)
        if not int(last[S_FLAGS]) & FLAG_END:
            remain = max(0.0, (n - 1 - f)) * self.dt / self.k        # tau left in the queue, s
            g = math.sqrt(2.0 * 0.5 * sc.accel * remain) * 0.9
            if g < goal:
                goal = g
                starving = True
        qt = r0[S_QT:S_QT + 5].tolist()
        qtt = r0[S_QTT:S_QTT + 5].tolist()
        if sc.sigma == 0.0 and self.state == IDLE and goal > 0.0 and \
                all(abs(qt[j]) * goal <= 0.5 * sc.amax[j] * self.dt for j in range(5)):
            sc.sigma = goal        # leaving a rest point of the path: a velocity step within one tick's accel
        sigma = sc.step(goal, qt, qtt)
        # ---- advance the path clock to the next tick's target
        f2 = f + sigma * self.k
        adv = int(f2)
        # never step over a job's end (at rest) short of the queue's last sample: stop on it, so it is
        # counted. Row 0 is one only for a job of one sample right after the end passed above.
        stop = 0 if flags & FLAG_END else -1
        if stop < 0:
            for i in range(1, min(adv, n - 2) + 1):
                if int(src.row(i)[S_FLAGS]) & FLAG_END:
                    stop = i
                    break
        if 0 <= stop < n - 1:
            adv, f2 = stop, 0.0
        elif adv >= n - 1:                 # the queue ends here (a job end or starvation)
            adv, f2 = n - 1, 0.0
            if not int(last[S_FLAGS]) & FLAG_END and sigma > 0:
                self.reason = "sample queue ran dry"
            sc.sigma = sc.dsigma = 0.0
        else:
            f2 -= adv
        self.s_total += (adv + f2) - f
        if adv:
            src.advance(adv)
        self.frac = f2
        nxt = self._pose(0, f2) if src.count() > 1 else src.row(0)[:6].tolist()
        inv = 1.0 / self.dt
        ff = [(nxt[m] - pose[m]) * inv for m in range(6)]
        if sc.sigma > 0.0 or any(ff):
            self.state = HOLDING if sc.hold else (STARVED if starving else MOVING)
            if starving:
                self.reason = "waiting for planned samples (queue starved)"
        else:
            self.state = HELD if sc.hold else (STARVED if starving else IDLE)
        self._rest = nxt
        self._tg[:] = pose + ff
        return self._tg


# ---------------------------------------------------------------- the compiled follower

try:
    from pmctl.motion import _follow
except ImportError as _e:         # pragma: no cover - a broken install; CompiledFollower() says so
    _follow, _FOLLOW_ERROR = None, _e

_REASONS = ("", "sample queue ran dry", "waiting for planned samples (queue starved)")   # follow.h FL_R_*


def _slot(name: str, kind=float, writable: bool = True):
    """A property over the compiled follower's state buffer item ``name`` (follow.h FL_*), read and
    written through ``self._v`` (a memoryview of the buffer)."""
    i = getattr(_follow, name, -1)

    def get(self):
        return kind(self._v[i])

    def put(self, value):
        self._v[i] = float(kind(value))
    return property(get, put if writable else None)


_PROGRESS = tuple(getattr(_follow, n, -1) for n in ("FL_S_TOTAL", "FL_SIGMA", "FL_LINE", "FL_STATE"))


class CompiledScaler(TimeScaler):
    """The TimeScaler of a :class:`CompiledFollower`: the same attributes and methods, its numbers
    kept in the follower's state buffer, where the compiled tick reads and writes them."""

    sigma = _slot("FL_SIGMA")
    dsigma = _slot("FL_DSIGMA")
    feed_override = _slot("FL_FEED_OV")
    rapid_override = _slot("FL_RAPID_OV")
    hold = _slot("FL_HOLD", bool)
    accel = _slot("FL_ACCEL")
    jerk = _slot("FL_JERK")

    def __init__(self, view, core, params, dt: float, accel: float | None = None, jerk: float | None = None):
        self._v, self._core = view, core
        super().__init__(params, dt, accel, jerk)

    def step(self, goal: float, qt, qtt) -> float:
        return self._core.sigma_step(float(goal), qt, qtt)


class CompiledFollower:
    """:class:`PathFollower` with its tick in C (pmctl.motion._follow: follow.c), the same
    attributes, methods and results, tick for tick (tests/motion/test_follow.py). ``next_target`` is the
    compiled call itself. The source is a Ring or an ArraySource: the C side reads their counters
    (``_ctr``) and rows (``data``) directly. Rows may be wider than WIDTH; the columns are this
    module's S_*."""

    implementation = "compiled"

    def __init__(self, source, params, dt: float, dt_plan: float | None = None, *, pose=None):
        if _follow is None:
            raise ImportError(
                "pmctl's compiled path follower (pmctl.motion._follow) is not built; reinstall with a C "
                "compiler (pip install -e .), or select the Python implementation with nc.implementation = "
                f"\"python\" in the service config ({_FOLLOW_ERROR})")
        F = _follow
        self.src = source
        self.dt = float(dt)
        self.k = self.dt / float(dt_plan or dt)
        data = source.data
        if data.ndim != 2 or data.dtype != np.float64 or not data.flags.c_contiguous:
            raise ValueError("CompiledFollower: the source's rows must be a C-contiguous (n, width) float64 array")
        self._st = np.zeros(F.FL_LEN)
        self._v = memoryview(self._st)
        self._tg = np.zeros(12)
        c = np.zeros(F.FLC_LEN)
        c[F.FLC_DT], c[F.FLC_K] = self.dt, self.k
        c[F.FLC_AMAX:F.FLC_AMAX + 5] = [float(x) * JOINT_SHARE for x in params.amax]     # = TimeScaler.amax
        c[[F.FLC_COL_CAP, F.FLC_COL_LINE, F.FLC_COL_FLAGS, F.FLC_COL_QT, F.FLC_COL_QTT]] = (
            S_CAP, S_LINE, S_FLAGS, S_QT, S_QTT)
        c[F.FLC_FLAG_RAPID], c[F.FLC_FLAG_END] = FLAG_RAPID, FLAG_END
        self._core = F.Follower(c, self._st, source._ctr, data, data.shape[1], self._tg)
        self.scaler = CompiledScaler(self._v, self._core, params, dt)
        self.next_target = self._core.next          # the tick: one C call, returns self._tg
        self._rest = pose

    sigma = _slot("FL_SIGMA", writable=False)
    frac = _slot("FL_FRAC", writable=False)
    line = _slot("FL_LINE", int, writable=False)
    state = _slot("FL_STATE", int, writable=False)
    s_total = _slot("FL_S_TOTAL", writable=False)
    ended_jobs = _slot("FL_ENDED", int)
    at_end = _slot("FL_AT_END", bool)

    @property
    def reason(self) -> str:
        return _REASONS[int(self._v[_follow.FL_REASON])]

    def progress(self) -> tuple:
        """(s_total, sigma, line, state) at once: what the loop's per-tick record reads, in one call
        instead of four properties (a third of the time)."""
        v, (i_s, i_sigma, i_line, i_state) = self._v, _PROGRESS
        return v[i_s], v[i_sigma], int(v[i_line]), int(v[i_state])

    @property
    def _rest(self):
        """The pose when nothing is queued (tip + axis), or None."""
        F = _follow
        return self._st[F.FL_REST:F.FL_REST + 6].tolist() if self._v[F.FL_HAS_REST] else None

    @_rest.setter
    def _rest(self, pose):
        F = _follow
        if pose is not None:
            self._st[F.FL_REST:F.FL_REST + 6] = [float(x) for x in pose]
        self._v[F.FL_HAS_REST] = float(pose is not None)

    def rest_here(self):
        """As :meth:`PathFollower.rest_here`."""
        F = _follow
        if int(self._v[F.FL_STATE]) == HELD and self._v[F.FL_SIGMA] == 0.0:
            self._v[F.FL_STATE] = float(IDLE)

    def clear(self):
        """Drop every queued sample (soft reset), keeping the current pose as the rest pose."""
        self._core.clear()


IMPLEMENTATIONS = ("compiled", "python")


def make_follower(source, params, dt: float, dt_plan: float | None = None, *, pose=None,
                  implementation: str | None = None):
    """The loop's path follower: ``implementation`` (default ``params.implementation``, the service
    config's ``nc.implementation``, which selects the NC core too) "compiled" ->
    :class:`CompiledFollower`, "python" -> :class:`PathFollower` (the reference)."""
    impl = implementation or getattr(params, "implementation", "compiled")
    if impl == "compiled":
        return CompiledFollower(source, params, dt, dt_plan, pose=pose)
    if impl == "python":
        return PathFollower(source, params, dt, dt_plan, pose=pose)
    raise ValueError(f"path follower implementation must be one of {', '.join(IMPLEMENTATIONS)}, got {impl!r}")
