"""The streaming planner of a job that grows as blocks arrive: the console's stream of G-code lines.

``plan_stream`` (pmctl.task.planner) plans a known job in windows, each with margins of path on both
sides, whose samples do not depend on what lies beyond the margins. A sender streaming a program
line by line hands the planner a job whose end is not known yet. :class:`StreamPlanner` plans it
with the same windows over the job known so far:

- ``extend(moves)`` appends the moves of accepted blocks. The segment index grows move by move
  (pmctl.task.planner._PathBuilder); a move waits only where its segment may still change: the
  trailing run of feed lines that the next move may continue (merged within its tolerance:
  ``_merged_away``), and a line that may round its corner into the next (G64 P). A straight run
  of short lines waits at most ``RUN_CUT_MM`` (``cut_run``): it would otherwise wait for its end,
  more blocks than the console's queue holds.
- ``settled()`` yields the samples of every window whose look-ahead (its check region, its margins
  and the reach of what it depends on, ``_window_extent``) the blocks known beyond it already
  cover. Those samples are the whole program's: they are what ``plan`` of the finished program
  gives there (to rounding, ~1e-11 mm), whatever blocks come after.
- ``close()`` ends the job where the blocks end: the rest is planned to rest at the last block
  (an exact stop there, never past it). The supervisor does that when the program ends (M2/M30),
  at a G4 or a probe, or when the sample queue is about to run dry and no block comes to settle
  more (the sender starved the queue): the machine then stops on the path at the last block it
  has. The blocks after that start a new job from rest there.

The look-ahead a window needs grows with the speed: the check region (``2 vt`` plus the stopping
distance at the top speed) and a first margin of ``2 vt`` beyond it, where ``vt = 1.1 v T + 4
grid_mm`` is the reach of the jerk filter, the erosion of the caps and re-planning (T = 2 a / j,
70 ms by default): about 10 mm at 600 mm/min, 30 mm at the rapid speed. docs/console.md says how
deep the console's queue is for that.

Memory: the segments of the windows to come and ``KEEP_BEHIND_MM`` of path behind the last sample
handed out (what the next windows' margins look back on); nothing grows with the stream's length.
"""

from __future__ import annotations

import numpy as np

from pmctl.core.errors import PmctlError
from pmctl.core.job import DWELL, EVENT, Job
from pmctl.task.planner import (STREAM_WINDOW, PlannerLimits, PlanningError, _blendable, _merged_away, _NotConverged,
                                _NotLocal, _PathBuilder, _rest_pieces, _settle_window, _start,
                                _window_extent, check_segments)

KEEP_BEHIND_MM = 200.0        # path kept behind the last sample handed out (the next windows look back on it)
RUN_CUT_MM = 8.0              # a trailing run of lines waits for the move after it at most this long (``extend``)


class StreamPlanner:
    """Plans a job that grows as blocks arrive (see the module docstring). ``start`` = (tip, axis)
    where the machine is when the job begins; ``machine``, ``dt``, ``feed_override`` and ``limits``
    as for ``plan``."""

    def __init__(self, machine, dt: float, *, start, feed_override: float = 1.0,
                 limits: PlannerLimits | None = None, source: str = "console", window: int = STREAM_WINDOW,
                 run_cut_mm: float = RUN_CUT_MM):
        self.job = Job((), source)       # (what the planner's errors name)
        self.limits, start = _start(self.job, machine, dt, feed_override, limits, start)
        self.machine, self.dt, self.window = machine, dt, int(window)
        self.run_cut_mm = float(run_cut_mm)
        self.T = max(2.0 * self.limits.tangential_accel / self.limits.jerk_mm_s3, 2.0 * dt)
        self.b = _PathBuilder(start, self.limits, feed_override, dt, source)
        self.pending = []             # moves not yet given to the path (their segment may still change)
        self.prev = (np.asarray(start[0], float), np.asarray(start[1], float))   # programmed pose before them
        self.emitted = 0              # the knot up to which samples were handed out
        self.closed = False
        self.n_samples = 0            # samples handed out
        self.n_moves = 0              # moves accepted

    # ------------------------------------------------------------ blocks in
    def extend(self, moves):
        """Append the moves of accepted blocks (in program order). InputError (the move's line) where
        a move cannot be planned: no positive feed, or its path leaves the workspace."""
        if self.closed:
            raise PmctlError("the stream was closed: a new one starts from rest")
        self.pending.extend(moves)
        self.n_moves += len(moves)
        self._build(final=False)
        if len(self.pending) > 1 and self._pending_mm() >= self.run_cut_mm:
            self.cut_run()

    def _pending_mm(self) -> float:
        """Length of the path of the moves waiting (the trailing run of lines), programmed points."""
        pts = [self.prev[0]] + [np.asarray(m.tip, float) for m in self.pending if m.kind not in (DWELL, EVENT)]
        return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum()) if len(pts) > 1 else 0.0

    def _build(self, final: bool):
        """Give the path every pending move whose segment can no longer change (all of them when
        ``final``), and check the new segments (pmctl.task.planner.check_segments)."""
        pend = self.pending
        if not pend:
            return
        drop, k = _merged_away(pend, self.prev, self.limits, open_end=True)
        if final:
            drop, k = _merged_away(pend, self.prev, self.limits), len(pend)
        kept = [i for i in range(len(pend)) if not drop[i]]
        nxt = {}                      # kept move -> the next kept move, where that is known now
        for a, b in zip(kept, kept[1:]):
            if b < k:
                nxt[a] = pend[b]
        if not final:                 # a line that may round its corner into a move not settled yet waits
            for i in kept:
                if i < k and i not in nxt and _blendable(pend[i]):
                    k = i
                    break
        n0 = self.b.n
        for i in range(k):
            m = pend[i]
            if drop[i]:
                self.b.absorb(m)
            else:
                self.b.add(m, nxt.get(i))
            if m.kind not in (DWELL, EVENT):
                self.prev = (np.asarray(m.tip, float), np.asarray(m.axis, float))
        self.pending = pend[k:]
        if self.b.n > n0:
            check_segments(self.b.path(end=False, i0=n0), self.job, self.machine, self.limits)

    def cut_run(self):
        """End the trailing run of lines that waits for the next move (``_merged_away``: a straight
        run of short lines is merged into one line that the next move may still continue) at its
        last block, as if the next move turned: its moves go to the path now. ``extend`` does this
        once the run waiting is ``run_cut_mm`` long, the supervisor when the console's queue is full
        of such blocks and nothing settles without them. The path then has a knot at that block (a
        programmed point, within the merge tolerance of ``plan``'s line), where the samples differ
        from ``plan``'s by a little more than rounding (tests/task/test_stream_planner.py states how much)."""
        self._build(final=True)

    # ------------------------------------------------------------ samples out
    def settled(self, eager: bool = True):
        """Trajectory pieces of the windows the blocks known so far settle (see the module
        docstring), in order; nothing when the look-ahead is not there yet. ``eager`` False: only
        whole windows (``window`` segments: a window's margins are planned with it, so small windows
        cost more planning per sample); the supervisor asks eagerly when the samples queued ahead
        of the tool run low."""
        while not self.closed:
            w = self._next_window(end=False, whole=not eager)
            if w is None:
                return
            yield from self._emit(w)

    def close(self):
        """End the job at the last block: Trajectory pieces of everything not handed out yet, planned
        to rest there (its marks with them). The planner takes no more blocks."""
        if self.closed:
            return
        self._build(final=True)
        self.closed = True
        b = self.b
        if b.n == 0:                  # nothing moves: the dwells and EVENTs at the start pose
            p = b.path(end=True)
            pieces = list(_rest_pieces(p, self.dt, self.job.source, np.zeros((0, 3))))
            self.n_samples += sum(len(x) for x in pieces)
            yield from pieces
            return
        while self.emitted < b.n:
            w = self._next_window(end=True)
            yield from self._emit(w)

    def _emit(self, w):
        """The window's pieces; then the path behind it that no window looks at any more is let go."""
        for piece in w.pieces(self.job.source, np.zeros((0, 3))):
            self.n_samples += len(piece)
            yield piece
        self.emitted = w.record[3] + self._base
        b = self.b
        cut = self.emitted
        s_cut = b.s_end[cut - 1 - b.base] - KEEP_BEHIND_MM if cut > b.base else -np.inf
        lo = int(np.searchsorted(b.s_end[:b.n - b.base], s_cut, "right")) + b.base
        lo = min(lo, cut, b.pin_done)
        if lo - b.base > 64 and lo - b.base > (b.n - b.base) // 2:
            b.forget(lo)

    def _next_window(self, end: bool, whole: bool = False):
        """The next window to hand out (pmctl.task.planner._Window), from the last knot handed out:
        as many segments as the look-ahead known allows (at most ``window``), its margin doubled
        while its speeds depend on more path (``_NotLocal``); None when no window is settled yet.
        ``end``: the job ends at the last block (close)."""
        b = self.b
        path = b.path(end=end)
        self._base = base = b.base
        n = path.n
        c0 = self.emitted - base
        if c0 >= n:
            return None
        # what a sample depends on reaches ~ v T along the path (vt): behind the window at the top
        # speed from a rapid's reach before it on (a rapid just before it erodes the caps that far);
        # ahead of it at the top speed after it (the speed at its end is capped there too: a rapid at
        # the window's end does not make it look further ahead); beyond the blocks known a rapid may
        # come (the zone's reach there). The limits are checked 2 vt and a stop at that speed around it
        # (re-planning around a violation there reaches into the window no further), with a margin of
        # 2 vt beyond, and at least what a stop takes after a rapid's reach (the zone check)
        lim, T = self.limits, self.T
        reach = lambda v: 1.1 * v * T + 4 * lim.grid_mm            # noqa: E731
        brake = lambda v: v * v / (2.0 * lim.tangential_accel)      # noqa: E731
        vt_rapid = reach(lim.rapid_mm_s)
        i = int(np.searchsorted(path.s_end, path.b_s[c0] - vt_rapid, "left"))
        v_lo = float(path.vmax[i:].max())
        vt = reach(v_lo)
        check, margin = 2.0 * vt + brake(v_lo), 2.0 * vt
        v_after = np.maximum.accumulate(path.vmax[::-1])[::-1]       # the top speed from each segment on

        def ahead(c):
            v = float(v_after[min(c, n - 1)])
            return [max(2.0 * reach(v), vt_rapid + brake(v)), reach(v), 2.0 * reach(v) + brake(v), vt_rapid]
        P = path.pin_idx
        j = int(np.searchsorted(P, c0, "right"))
        hi = int(np.searchsorted(P, c0 + self.window, "left"))
        cands = P[j:min(hi, len(P) - 1) + 1]
        if end:
            c1 = int(cands[-1])
        else:
            c1 = None
            for c in cands[::-1]:        # the furthest knot the known blocks settle
                if whole and c - c0 < self.window:
                    break
                if _window_extent(path, c0, int(c), margin, vt, check, ahead(int(c))) is not None:
                    c1 = int(c)
                    break
            if c1 is None:
                return None
        ahead = ahead(c1)
        while True:
            if not end and _window_extent(path, c0, c1, margin, vt, check, ahead) is None:
                return None               # its margin must grow beyond the blocks known: wait for more
            try:
                return _settle_window(path, c0, c1, margin, vt, self.machine, lim, self.dt, T, self.job, True,
                                      check, ahead)
            except _NotLocal:
                if not path.job_start and margin > path.b_s[c0] - path.b_s[0]:
                    raise PlanningError(f"{self.job.source}: the speeds here depend on more than "
                                        f"{KEEP_BEHIND_MM:g} mm of path behind (the stream's look-back)") from None
                margin *= 2
                ahead[0] *= 2
            except _NotConverged as e:
                raise PlanningError(f"{self.job.source}:{e.line}: could not meet the joint/feed limits here after "
                                    f"{lim.max_iterations} re-planning iterations (a streamed program is "
                                    "planned as it comes: lower the feed here)", path=self.job.source,
                                    line=e.line) from None

    # ------------------------------------------------------------ state
    @property
    def end_pose(self):
        """(tip, axis) where the blocks known so far end (programmed)."""
        for m in reversed(self.pending):
            if m.kind not in (DWELL, EVENT):
                return np.asarray(m.tip, float), np.asarray(m.axis, float)
        return self.prev
