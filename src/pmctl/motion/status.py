"""The rt side's status as named fields: :class:`RtStatus`, the one reader of the shared status block.

The rt process (pmctl.motion.rtproc) writes the status block of the channel (pmctl.motion.channel)
every tick under a sequence counter; everything outside motion/ reads it through
:func:`read_status` (the supervisor's ``status()``), never by index. A snapshot is consistent
(taken between two writes of the rt side) and does not change afterwards.

Units are in the names where they are not obvious: ``counts`` are pulse counters (integers),
``tip_mm`` the tool tip in W, ``late_ns`` / ``compute_ns`` nanoseconds, ``mono_s`` / ``wall_s``
seconds on CLOCK_MONOTONIC / the wall clock; ``path_s`` is the path clock in samples passed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pmctl.motion import channel as C
from pmctl.motion.probe import ProbeResult

# what the rt side is doing (``phase``) and how its last stop ended (``fault``)
PH_STARTING, PH_RUNNING, PH_EXITED = int(C.PH_STARTING), int(C.PH_RUNNING), int(C.PH_EXITED)
F_NONE, F_STOP, F_FAULT = int(C.F_NONE), int(C.F_STOP), int(C.F_FAULT)


@dataclass(frozen=True, slots=True)
class RtStatus:
    """One consistent snapshot of the rt side's status block."""

    seq: int                    # the block's write sequence (even: a whole write)
    tick: int                   # ticks since the rt process started
    wall_s: float               # wall-clock time of the last write, s
    mode: int                   # NC mode (pmctl.motion.nc: RUN, STOPPING, HALTED, ...)
    follow: int                 # path follower state (pmctl.motion.timescale: IDLE, MOVING, HOLDING, HELD, STARVED)
    sigma: float                # feed factor of the time-scaling (0: at rest on the path)
    line: int                   # job line of the current target (0: none)
    path_s: float               # path clock: samples passed since the rt process started
    feed_override: float        # feed override factor (1.0 = 100 %)
    rapid_override: float       # rapid override factor
    hold: bool                  # a feed hold is asked for (operator, event, stall, latch, stop)
    counts: np.ndarray          # (5,) int64 pulse counters (commanded position), L1 L2 L3 X Y
    tip_mm: np.ndarray          # (3,) model tool tip in W at the start of the last tick, mm
    axis: np.ndarray            # (3,) model tool axis (unit vector)
    ended: int                  # jobs whose last sample the follower passed
    dropped: int                # per-tick records the record ring could not take
    late_ns: int                # the last tick's wake-up lateness, ns
    compute_ns: int             # the last tick's compute time, ns
    phase: int                  # PH_STARTING, PH_RUNNING or PH_EXITED
    reason_seq: int             # counts the stop/fault reasons written (Channel.reason)
    cmd_ack: int                # sequence number of the last command taken
    ontime: int                 # ticks on time in a row (late + compute within the period)
    fault: int                  # how the last stop ended: F_NONE, F_STOP (controlled stop) or F_FAULT
    pid: int                    # the rt process's id
    queued: int                 # planned samples queued in the sample ring
    mono_s: float               # CLOCK_MONOTONIC time of the last write, s (the watchdog's freshness)
    sent: np.ndarray            # (5,) int64 pulses written to the backend since the rt process started
    dev_counts: np.ndarray      # (5,) the counters the device reports (NaN if it keeps none)
    counts0: np.ndarray         # (5,) int64 counters the rt process started from, moved by re-references
    latch_seq: int              # counts the home-switch latches
    latch: np.ndarray           # (5,) int64 counters at the tick the armed home switch reached its state
    home_in: int                # home switches as a bit mask (bit i: axis i closed); -1: none / no homing
    probe_seq: int              # counts the probing moves ended
    probe_row: np.ndarray       # the last probe's result as stored (see :meth:`probe`)
    hold_at_seq: int            # counts the hold-at points the path reached

    @classmethod
    def from_block(cls, block) -> RtStatus:
        """The fields of a status block (a copy: ``Channel.status()``, or the block itself)."""
        v = np.asarray(block, float)
        x = v.tolist()
        return cls(int(x[C.ST_SEQ]), int(x[C.ST_TICK]), x[C.ST_WALL], int(x[C.ST_MODE]), int(x[C.ST_FOLLOW]),
                   x[C.ST_SIGMA], int(x[C.ST_LINE]), x[C.ST_S], x[C.ST_FEED_OV], x[C.ST_RAPID_OV],
                   x[C.ST_HOLD] != 0.0, v[C.ST_COUNTS:C.ST_COUNTS + 5].astype(np.int64),
                   v[C.ST_TIP:C.ST_TIP + 3].copy(), v[C.ST_AXIS:C.ST_AXIS + 3].copy(),
                   int(x[C.ST_ENDED]), int(x[C.ST_DROPPED]), int(x[C.ST_LATE_NS]), int(x[C.ST_COMPUTE_NS]),
                   int(x[C.ST_PHASE]), int(x[C.ST_REASON_SEQ]), int(x[C.ST_CMD_ACK]), int(x[C.ST_ONTIME]),
                   int(x[C.ST_FAULT]), int(x[C.ST_PID]), int(x[C.ST_QUEUED]), x[C.ST_MONO],
                   v[C.ST_SENT:C.ST_SENT + 5].astype(np.int64), v[C.ST_DEV_COUNTS:C.ST_DEV_COUNTS + 5].copy(),
                   v[C.ST_COUNTS0:C.ST_COUNTS0 + 5].astype(np.int64), int(x[C.ST_LATCH_SEQ]),
                   v[C.ST_LATCH:C.ST_LATCH + 5].astype(np.int64), int(x[C.ST_HOME_IN]), int(x[C.ST_PROBE_SEQ]),
                   v[C.ST_PROBE:C.ST_PROBE + C.PROBE_RESULT_WIDTH].copy(), int(x[C.ST_HOLD_AT_SEQ]))

    def probe(self) -> ProbeResult:
        """The last ended probing move's result (meaningful once ``probe_seq`` counted it)."""
        return ProbeResult.from_row(self.probe_row)

    @property
    def running(self) -> bool:
        """The rt process has started its loop and not exited."""
        return self.phase == PH_RUNNING

    @property
    def stopped(self) -> bool:
        """The rt side's last stop is reported (``fault`` is F_STOP or F_FAULT)."""
        return self.fault != F_NONE


def read_status(ch: C.Channel) -> RtStatus:
    """A consistent snapshot of the channel's status block (retries while the rt side writes)."""
    return RtStatus.from_block(ch.status())
