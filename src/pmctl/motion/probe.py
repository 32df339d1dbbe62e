"""Stop on contact: the per-tick monitor of probing moves (G38.2 / G38.3) on the rt side.

A probing move is a feed line (pmctl.core.job, ``Move.probe``) planned like any other. While the
path follower is on its samples, :meth:`ProbeMonitor.tick` (called once per tick by the control
loop, pmctl.motion.loop) compares the three plate-link strains the backend reports with the model:

- the model is the gravity statics of the commanded pose (pmctl.core.statics), precomputed at a few
  points along the line when the monitor is built and interpolated per tick (a few float operations);
- once the follower runs at its feed (sigma steady: an accelerating platform would read as a force)
  the first ``tare_ticks`` ticks are the reference: their mean departure from the model is taken off
  (gauge offsets, model error) and their spread is the noise;
- contact = a chain's axial-force departure beyond ``threshold_N`` for ``debounce_ticks`` ticks in a row
  (pmctl.core.strain_sensing.detect_contact's rule). The follower is then held on the path at the
  probe deceleration ``decel_mm_s2`` (sigma's rate and jerk raised for the stop only): the stop is
  along the programmed line, never off it. At rest the rest of the move is dropped (the follower's
  queue cleared, the job counted as ended) and the result kept: the contact point, tool tip in W,
  where the force ramp began, fitted once at rest through the moving average
  (strain_sensing.contact_onset) over the ticks up to the detection. The gauges read the plant after
  the previous tick's pulses: a tick's strain belongs to the previous tick's target.

Overtravel: past the point where the force crossed the threshold, the tool goes at most
``(debounce + 5) ticks x feed + feed^2 / (2 decel)`` (the debounce, one tick to act, two of the
stop's jerk ramp, two of the stop's geometric tail): :meth:`ProbeMonitor.bound_mm`. Past the true surface add
``threshold / (share x k_contact)``, the travel the force needs to reach the threshold on a surface of
stiffness k_contact (strain_sensing.overtravel_bound has both).

A G38.2 move that ends without contact is a probe failure (grbl's alarm 5): ``result.error`` says so;
the move itself ended at its programmed target, nothing went beyond it.

The same monitor runs in both places that drive the loop: ``pmctl run`` gives it the job's segments
up front (found by the follower's line); the daemon's rt process (pmctl.motion.rtproc) gives it a
``fetch`` callable instead, which hands over the one segment the supervisor announced in the
channel's probe table once the follower is on samples flagged ``FLAG_PROBE``
(pmctl.motion.timescale). The supervisor plans a probing move as a piece of its own (see
:func:`split_at_probes`), so at most one is in flight; the result goes back in the status block
(:meth:`ProbeResult.to_row` / :meth:`ProbeResult.from_row`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pmctl.core import kinematics as K, statics
from pmctl.core.errors import ConfigError, InputError
from pmctl.core.job import DWELL, Job
from pmctl.core.strain_sensing import contact_onset
from pmctl.core.strict_toml import Table
from pmctl.motion.timescale import FLAG_PROBE, JOINT_SHARE, S_CAP, S_FLAGS

# monitor states
IDLE, TARE, ARMED, STOPPING = 0, 1, 2, 3
GRID = 9                        # model points along a probing line
HISTORY = 32                    # ticks kept for the contact-point fit
SEGMENT_WIDTH = 12 + 4 * GRID   # floats of a segment in the channel's probe table (ProbeSegment.to_row)
RESULT_WIDTH = 22               # floats of a result in the status block (ProbeResult.to_row)
TARE_GUARD = 8                  # reference ticks before a contact during the tare is watched for


@dataclass
class ProbeConfig:
    """The ``[probe]`` table of the service config."""
    threshold_N: float = 5.0        # axial-force departure of any chain that means contact
    debounce_ticks: int = 2         # ticks in a row over the threshold
    tare_ticks: int = 32            # reference ticks at feed before the monitor is armed
    filter_ticks: int = 8           # moving average of the departures (longer than the chain modes' period)
    max_feed_mm_min: float = 300.0  # fastest probing feed a program may ask for
    decel_mm_s2: float = 1000.0     # deceleration of the stop on contact, along the path

    @classmethod
    def from_dict(cls, d: dict, path="<dict>") -> "ProbeConfig":
        if not isinstance(d, dict):
            raise ConfigError(path, "probe", "must be a table")
        t = Table(path, d, "probe")
        base = cls()
        o = cls(threshold_N=t.number("threshold_N", default=base.threshold_N, positive=True, hi=1e5),
                debounce_ticks=t.integer("debounce_ticks", default=base.debounce_ticks, lo=1, hi=100),
                tare_ticks=t.integer("tare_ticks", default=base.tare_ticks, lo=1, hi=10000),
                filter_ticks=t.integer("filter_ticks", default=base.filter_ticks, lo=1, hi=1000),
                max_feed_mm_min=t.number("max_feed_mm_min", default=base.max_feed_mm_min, positive=True, hi=1e5),
                decel_mm_s2=t.number("decel_mm_s2", default=base.decel_mm_s2, positive=True, hi=1e6))
        t.finish()
        return o


@dataclass
class ProbeSegment:
    line: int
    mode: int                       # 2: G38.2 (no contact is an error), 3: G38.3
    start: np.ndarray               # tool tip in W where the move starts, mm
    end: np.ndarray                 # its programmed target
    axis: np.ndarray
    feed: float                     # mm/s
    grid_s: list = field(default_factory=list)       # travel of the model points, mm
    grid_strain: list = field(default_factory=list)  # model strain there (3 per point), microstrain

    @property
    def direction(self):
        d = self.end - self.start
        return d / np.linalg.norm(d)

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.end - self.start))

    def to_row(self) -> list:
        """SEGMENT_WIDTH floats: line, mode, start, end, axis, feed, then the model grid (s, strain x 3)."""
        gs = list(self.grid_s) + [math.nan] * (GRID - len(self.grid_s))
        gst = [list(x) for x in self.grid_strain] + [[math.nan] * 3] * (GRID - len(self.grid_strain))
        return ([float(self.line), float(self.mode), *map(float, self.start), *map(float, self.end),
                 *map(float, self.axis), float(self.feed)] + [float(x) for x in gs]
                + [float(v) for x in gst for v in x])

    @classmethod
    def from_row(cls, row) -> "ProbeSegment":
        r = [float(x) for x in row[:SEGMENT_WIDTH]]
        gs = [x for x in r[12:12 + GRID] if not math.isnan(x)]
        n = len(gs)
        gst = [r[12 + GRID + 3 * i:12 + GRID + 3 * i + 3] for i in range(n)]
        return cls(int(r[0]), int(r[1]), np.array(r[2:5]), np.array(r[5:8]), np.array(r[8:11]), r[11], gs, gst)


@dataclass
class ProbeResult:
    line: int
    mode: int
    contact: bool
    point: np.ndarray               # contact point, tool tip in W, mm (NaN without contact)
    ab_deg: tuple                   # A, B of the tool axis, degrees
    stop: np.ndarray                # where the tool came to rest, W, mm
    tick: int = -1                  # tick of the detection
    speed_mm_s: float = 0.0         # feed at the detection
    overtravel_mm: float = 0.0      # rest point past the contact point, along the move
    after_trigger_mm: float = 0.0   # rest point past the first over-threshold tick
    bound_mm: float = 0.0           # bound on after_trigger_mm (ProbeMonitor.bound_mm)
    noise_N: float = 0.0            # force noise seen in the reference ticks (1 sigma, per chain)
    error: str = ""                 # G38.2 without contact
    counts: tuple | None = None     # pulse counters at rest after the probe (the daemon's rt side fills them)

    def prb(self) -> str:
        """grbl's probe report: ``[PRB:x,y,z,a,b:ok]`` (tool tip in W, mm; A, B in degrees)."""
        p = self.point if self.contact else self.stop
        v = list(p) + list(self.ab_deg)
        return "[PRB:" + ",".join(f"{round(x, 3) + 0.0:.3f}" for x in v) + f":{1 if self.contact else 0}]"

    def as_dict(self) -> dict:
        return {"line": self.line, "mode": f"G38.{self.mode}", "contact": self.contact,
                "point_mm": [float(x) for x in self.point] if self.contact else None,
                "ab_deg": [float(x) for x in self.ab_deg], "stop_mm": [float(x) for x in self.stop],
                "tick": self.tick, "speed_mm_s": self.speed_mm_s, "overtravel_mm": self.overtravel_mm,
                "after_trigger_mm": self.after_trigger_mm, "after_trigger_bound_mm": self.bound_mm,
                "noise_N": self.noise_N, "error": self.error,
                **({"counts": [int(c) for c in self.counts]} if self.counts is not None else {})}

    def to_row(self) -> list:
        """RESULT_WIDTH floats for the status block (the error text is rebuilt from mode and contact)."""
        c = list(self.counts) if self.counts is not None else [math.nan] * 5
        return ([float(self.line), float(self.mode), 1.0 if self.contact else 0.0, *map(float, self.point),
                 *map(float, self.ab_deg), *map(float, self.stop), float(self.tick), float(self.speed_mm_s),
                 float(self.overtravel_mm), float(self.after_trigger_mm), float(self.bound_mm), float(self.noise_N)]
                + [float(x) for x in c])

    @classmethod
    def from_row(cls, row) -> "ProbeResult":
        r = [float(x) for x in row[:RESULT_WIDTH]]
        line, mode, contact = int(r[0]), int(r[1]), r[2] != 0.0
        counts = None if math.isnan(r[17]) else tuple(int(x) for x in r[17:22])
        return cls(line, mode, contact, np.array(r[3:6]), (r[6], r[7]), np.array(r[8:11]), int(r[11]), r[12], r[13],
                   r[14], r[15], r[16], probe_fail_text(line) if (mode == 2 and not contact) else "", counts)


def probe_fail_text(line: int) -> str:
    """The error of a G38.2 move that ended without contact (grbl's alarm 5)."""
    return f"probe fail: no contact along the G38.2 move of line {line} (alarm 5)"


def probe_segments(job, machine, start_tip) -> list[ProbeSegment]:
    """The probing moves of a job, each with its model strain along the line."""
    out = []
    prev = np.asarray(start_tip, float)
    for m in job.moves:
        if m.probe:
            seg = ProbeSegment(m.line, m.probe, prev.copy(), np.asarray(m.tip, float), np.asarray(m.axis, float),
                               float(m.feed))
            s = np.linspace(0.0, seg.length, GRID)
            tips = seg.start + s[:, None] * seg.direction
            r = K.ik_batch(tips, np.broadcast_to(seg.axis, tips.shape), machine)
            if not np.all(r.ok):
                raise InputError(job.source, m.line, "probing line not reachable along its length")
            pose, ok = K.fk_batch(r.q, machine)
            seg.grid_s = s.tolist()
            seg.grid_strain = statics.static_strain(pose.P, pose.R, machine).tolist()
            out.append(seg)
        if m.kind != "dwell":
            prev = np.asarray(m.tip, float)
    return out


def check_probe_feeds(job, cfg: ProbeConfig, path, feed_factor: float = 1.0):
    """Each probing move at most ``max_feed_mm_min`` (times the planner's feed override
    ``feed_factor``, which the plan applies). InputError naming the line."""
    for m in job.moves:
        if m.probe and m.feed * feed_factor * 60.0 > cfg.max_feed_mm_min * (1 + 1e-9):
            why = f" with the feed override x{feed_factor:g}" if feed_factor != 1.0 else ""
            raise InputError(path, m.line, f"G38.{m.probe} at F{m.feed * 60:g} mm/min{why} is faster than the probing "
                                           f"limit probe.max_feed_mm_min = {cfg.max_feed_mm_min:g}")


def check_probe_job(job, cfg: ProbeConfig, path, feed_factor: float = 1.0):
    """What ``pmctl run`` can do with a job's probing moves: each within the feed limit
    (:func:`check_probe_feeds`), and the probe the last motion of the job (the in-process run ends
    at the contact: motion after it would start from a position nobody planned). InputError naming
    the line."""
    check_probe_feeds(job, cfg, path, feed_factor)
    moves = job.moves
    for i, m in enumerate(moves):
        if not m.probe:
            continue
        after = [n for n in moves[i + 1:] if n.kind != "dwell"]
        if after:
            raise InputError(path, after[0].line, f"motion after the probing move of line {m.line}: pmctl run ends "
                                                  f"the job at the contact, so a probe must be the job's last move")


def split_at_probes(job) -> list:
    """The job cut into pieces the daemon plans one after the other: ``(piece, probe)`` pairs, where a
    probing move is a piece of its own (``probe`` its Move; None for the others). Every piece starts
    and ends at rest; the piece after a probe is planned only once the probe has ended, from where
    it stopped (grbl: motion after a probe starts at the probed position). A dwell goes with the
    moves around it (after a probe: with the piece after it)."""
    out, cur = [], []

    def piece(moves):
        pts = np.array([m.tip for m in moves if m.kind != DWELL], float).reshape(-1, 3)
        return Job(tuple(moves), job.source, pts, np.array([m.line for m in moves if m.kind != DWELL], int))
    for m in job.moves:
        if m.probe:
            if cur:
                out.append((piece(cur), None))
                cur = []
            out.append((piece([m]), m))
        else:
            cur.append(m)
    if cur:
        out.append((piece(cur), None))
    return out


def mark_probe_rows(rows, seg_feed_mm_s: float, cfg: ProbeConfig):
    """Sample rows of a probing piece (pmctl.motion.timescale): flagged ``FLAG_PROBE`` (the rt side
    runs the monitor on them), and their sigma cap lowered so that no feed override takes the probe
    past ``max_feed_mm_min`` (grbl ignores feed overrides while probing; here they may slow it)."""
    rows[:, S_FLAGS] += FLAG_PROBE
    cap = min(1.0, cfg.max_feed_mm_min / 60.0 / max(seg_feed_mm_s, 1e-9))
    np.minimum(rows[:, S_CAP], cap, out=rows[:, S_CAP])
    return rows


class ProbeMonitor:
    """Per-tick stop-on-contact for the probing segments of one job (or stream).

    ``segments``: the job's probing segments, found by the follower's line (``pmctl run``); or
    ``fetch(fol)`` -> ProbeSegment | None: a stream's next segment, asked for at every idle tick
    (the daemon's rt side; its segments are used once and dropped)."""

    def __init__(self, machine, segments, cfg: ProbeConfig, dt: float, params=None, fetch=None):
        self.machine, self.cfg, self.dt = machine, cfg, float(dt)
        self.params, self.fetch = params, fetch
        self.by_line = {s.line: s for s in segments}
        self.gain = float(machine.strain_gain)
        self.results: list[ProbeResult] = []
        self.state = IDLE
        self.seg = None
        self.done_line = None
        self._decel = {}
        for s in segments:        # the stop's deceleration: the configured one, within the joints' limits
            self._decel[s.line] = self._effective_decel(s, params)

    # ---------------------------------------------------------------- bounds
    def _effective_decel(self, seg, params) -> float:
        a = self.cfg.decel_mm_s2
        if params is None:
            return a
        h = min(0.01, 0.5 * seg.length)
        tips = np.stack([seg.start, seg.start + h * seg.direction])
        r = K.ik_batch(tips, np.broadcast_to(seg.axis, tips.shape), self.machine)
        dq = np.abs(r.q[1] - r.q[0]) / h                      # joint mm per mm along the line
        with np.errstate(divide="ignore"):
            lim = np.min(np.asarray(params.amax) * JOINT_SHARE / np.maximum(dq, 1e-12))
        return float(min(a, lim))

    def bound_mm(self, seg, speed_mm_s: float) -> float:
        """Travel past the first over-threshold tick before rest (see the module text)."""
        v = abs(speed_mm_s)
        return v * (self.cfg.debounce_ticks + 5) * self.dt + v * v / (2.0 * self._decel[seg.line])

    # ---------------------------------------------------------------- per tick
    def _model(self, s):
        seg = self.seg
        gs = seg.grid_s
        h = gs[1] - gs[0] if len(gs) > 1 else 1.0
        u = s / h if h > 0 else 0.0
        if u <= 0.0:
            return seg.grid_strain[0]
        i = int(u)
        if i >= len(gs) - 1:
            return seg.grid_strain[-1]
        f = u - i
        a, b = seg.grid_strain[i], seg.grid_strain[i + 1]
        return [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]), a[2] + f * (b[2] - a[2])]

    def _begin(self, seg):
        self.seg = seg
        self.state = TARE
        self.n_tare = 0
        self.sum = [0.0, 0.0, 0.0]          # raw model departures over the reference ticks (strain)
        self.fsum = [0.0, 0.0, 0.0]         # filtered ones, and their squares: the noise
        self.fsum2 = [0.0, 0.0, 0.0]
        self.ring = [[0.0, 0.0, 0.0] for _ in range(self.cfg.filter_ticks)]
        self.acc = [0.0, 0.0, 0.0]
        self.n_ring = 0
        self.run = 0
        self.hist_s, self.hist_dep = [], []
        self.d = seg.direction.tolist()
        self.o = seg.start.tolist()
        self.k_first = -1
        self.s_first = 0.0
        self.noise_N = 0.0
        self.s_prev = 0.0

    def _finish(self, contact: bool, tip, **kw):
        seg = self.seg
        a, b = K.roll_pitch_from_axis(seg.axis)
        res = ProbeResult(seg.line, seg.mode, contact, kw.pop("point", np.full(3, np.nan)),
                          (math.degrees(float(a)), math.degrees(float(b))), np.array(tip[:3], float), **kw)
        if not contact and seg.mode == 2:
            res.error = probe_fail_text(seg.line)
        self.results.append(res)
        self.done_line = seg.line
        self.state = IDLE
        self.seg = None
        return res

    def tick(self, fol, tg, strain, k: int) -> None:
        """One tick: ``fol`` the path follower, ``tg`` this tick's target (tip, axis, ...), ``strain``
        the three gauges as read at the tick's start (the plant at this target)."""
        state = self.state
        if state == IDLE:
            if self.fetch is not None:
                seg = self.fetch(fol)
                if seg is None:
                    return
                self._decel[seg.line] = self._effective_decel(seg, self.params)
            else:
                line = fol.line
                if line == self.done_line:       # resting where a finished probe left the follower
                    return
                self.done_line = None
                seg = self.by_line.get(line)
                if seg is None:
                    return
            self._begin(seg)
            state = TARE
        seg = self.seg
        sc = fol.scaler
        d, o = self.d, self.o
        s = (tg[0] - o[0]) * d[0] + (tg[1] - o[1]) * d[1] + (tg[2] - o[2]) * d[2]
        s_prev, self.s_prev = self.s_prev, s
        if state == STOPPING:
            if sc.sigma == 0.0:
                sc.accel, sc.jerk = self._saved
                fol.clear()                   # the rest of the probing move is not run
                fol.ended_jobs += 1
                fol.at_end = True
                if not self._held_before:
                    sc.hold = False
                self.s_contact = self._onset()
                p0 = seg.start + self.s_contact * seg.direction
                self._finish(True, tg, point=p0, tick=self.k_detect, speed_mm_s=self.v_detect,
                             overtravel_mm=float(s - self.s_contact), after_trigger_mm=float(s - self.s_first),
                             bound_mm=self.bound_mm(seg, self.v_detect), noise_N=self.noise_N)
            return
        if fol.line != seg.line or fol.at_end:
            # the move ended (its target reached) without a contact
            self._finish(False, tg, tick=-1, speed_mm_s=0.0, noise_N=getattr(self, "noise_N", 0.0))
            if fol.line in self.by_line and not fol.at_end:
                self._begin(self.by_line[fol.line])
            return
        m = self._model(s)
        e0, e1, e2 = strain[0] - m[0], strain[1] - m[1], strain[2] - m[2]
        # moving average over filter_ticks (the chain modes the pulses excite ring far above it)
        W = self.cfg.filter_ticks
        ring, acc = self.ring, self.acc
        old = ring[self.n_ring % W]
        acc[0] += e0 - old[0]
        acc[1] += e1 - old[1]
        acc[2] += e2 - old[2]
        old[0], old[1], old[2] = e0, e1, e2
        self.n_ring += 1
        a0, a1, a2 = acc[0] / W, acc[1] / W, acc[2] / W
        hs, hd = self.hist_s, self.hist_dep
        g = self.gain
        thr = self.cfg.threshold_N
        if state == TARE:
            if sc.sigma > 0.0 and sc.dsigma == 0.0 and self.n_ring >= W:     # at feed: a reference tick
                self.sum[0] += e0
                self.sum[1] += e1
                self.sum[2] += e2
                fs, fs2 = self.fsum, self.fsum2
                fs[0] += a0
                fs[1] += a1
                fs[2] += a2
                fs2[0] += a0 * a0
                fs2[1] += a1 * a1
                fs2[2] += a2 * a2
                self.n_tare += 1
                n = self.n_tare
                self._push(hs, hd, s_prev, a0, a1, a2)
                if n >= self.cfg.tare_ticks:
                    self._arm()
                elif n >= TARE_GUARD:
                    # started too close: a force growing already while taring is a contact too
                    # (against the running reference; its point is less certain)
                    t = [x / n for x in self.sum]
                    if max(abs(a0 - t[0]), abs(a1 - t[1]), abs(a2 - t[2])) / g > 2.0 * thr:
                        self._arm()
                        self.run = self.cfg.debounce_ticks
                        self.k_first, self.s_first = k, s
                        self._contact(fol, k, s)
            return
        # ARMED: filtered axial-force departures (N, compression positive)
        t = self.tare
        self._push(hs, hd, s_prev, a0, a1, a2)    # the gauges lag the target by a tick (the plant after its pulses)
        if abs(a0 - t[0]) / g > thr or abs(a1 - t[1]) / g > thr or abs(a2 - t[2]) / g > thr:
            if self.run == 0:
                self.k_first, self.s_first = k, s
            self.run += 1
        else:
            self.run = 0
        if self.run >= self.cfg.debounce_ticks:
            self._contact(fol, k, s)

    def cancel(self, fol) -> None:
        """Forget the segment under way without a result (a soft reset or a fault dropped the motion):
        the stop's raised rate limits go back."""
        if self.state == STOPPING:
            fol.scaler.accel, fol.scaler.jerk = self._saved
        self.state = IDLE
        self.seg = None

    @staticmethod
    def _push(hs, hd, s, a0, a1, a2):
        hs.append(s)
        hd.append((a0, a1, a2))
        if len(hs) > HISTORY:
            del hs[0]
            del hd[0]

    def _arm(self):
        n = self.n_tare
        fs, fs2 = self.fsum, self.fsum2
        self.tare = [x / n for x in self.sum]
        var = [max(0.0, fs2[i] / n - (fs[i] / n) ** 2) for i in range(3)]
        self.noise_N = math.sqrt(sum(var) / 3.0) / self.gain
        self.state = ARMED

    def _contact(self, fol, k, s):
        sc = fol.scaler
        seg = self.seg
        self.k_detect = k
        self.v_detect = sc.sigma * seg.feed
        # the stop: a feed hold on the path at the probe deceleration
        self._held_before = sc.hold
        self._saved = (sc.accel, sc.jerk)
        a = self._decel[seg.line] / max(seg.feed, 1e-9)        # sigma per second
        sc.accel = max(sc.accel, a)
        sc.jerk = max(sc.jerk, sc.accel / (2.0 * self.dt))
        sc.hold = True
        self.state = STOPPING

    def _onset(self) -> float:
        """Travel (mm from the move's start) where the contact force began: fitted once at rest
        (strain_sensing.contact_onset, ~0.1 ms) on the departures up to the detection."""
        hs = np.array(self.hist_s)
        dep = -(np.array(self.hist_dep) - np.array(self.tare)) / self.gain       # N, the averaged departures
        c = contact_onset(dep, self.cfg.filter_ticks)
        if len(hs) < 2:
            return float(hs[-1])
        if c <= 0.0:
            return float(hs[0] + c * (hs[1] - hs[0]))
        return float(np.interp(c, np.arange(len(hs), dtype=float), hs))
