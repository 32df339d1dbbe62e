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

import numpy as np

from pmctl.motion import channel as C
from pmctl.motion.probe import ProbeResult

# what the rt side is doing (``phase``) and how its last stop ended (``fault``)
PH_STARTING, PH_RUNNING, PH_EXITED = int(C.PH_STARTING), int(C.PH_RUNNING), int(C.PH_EXITED)
F_NONE, F_STOP, F_FAULT = int(C.F_NONE), int(C.F_STOP), int(C.F_FAULT)


# the block's fields: name, first slot, width (0: one number), type, meaning
LAYOUT = (
    ("seq", C.ST_SEQ, 0, int, "the block's write sequence (even: a whole write)"),
    ("tick", C.ST_TICK, 0, int, "ticks since the rt process started"),
    ("wall_s", C.ST_WALL, 0, float, "wall-clock time of the last write, s"),
    ("mode", C.ST_MODE, 0, int, "NC mode (pmctl.motion.nc: RUN, STOPPING, HALTED, ...)"),
    ("follow", C.ST_FOLLOW, 0, int, "path follower state (pmctl.motion.timescale: IDLE, MOVING, HOLDING, HELD, "
                                    "STARVED)"),
    ("sigma", C.ST_SIGMA, 0, float, "feed factor of the time-scaling (0: at rest on the path)"),
    ("line", C.ST_LINE, 0, int, "job line of the current target (0: none)"),
    ("path_s", C.ST_S, 0, float, "path clock: samples passed since the rt process started"),
    ("feed_override", C.ST_FEED_OV, 0, float, "feed override factor (1.0 = 100 %)"),
    ("rapid_override", C.ST_RAPID_OV, 0, float, "rapid override factor"),
    ("hold", C.ST_HOLD, 0, bool, "a feed hold is asked for (operator, event, stall, latch, stop)"),
    ("counts", C.ST_COUNTS, 5, int, "(5,) int64 pulse counters (commanded position), L1 L2 L3 X Y"),
    ("tip_mm", C.ST_TIP, 3, float, "(3,) model tool tip in W at the start of the last tick, mm"),
    ("axis", C.ST_AXIS, 3, float, "(3,) model tool axis (unit vector)"),
    ("ended", C.ST_ENDED, 0, int, "jobs whose last sample the follower passed"),
    ("dropped", C.ST_DROPPED, 0, int, "per-tick records the record ring could not take"),
    ("late_ns", C.ST_LATE_NS, 0, int, "the last tick's wake-up lateness, ns"),
    ("compute_ns", C.ST_COMPUTE_NS, 0, int, "the last tick's compute time, ns"),
    ("phase", C.ST_PHASE, 0, int, "PH_STARTING, PH_RUNNING or PH_EXITED"),
    ("reason_seq", C.ST_REASON_SEQ, 0, int, "counts the stop/fault reasons written (Channel.reason)"),
    ("cmd_ack", C.ST_CMD_ACK, 0, int, "sequence number of the last command taken"),
    ("ontime", C.ST_ONTIME, 0, int, "ticks on time in a row (late + compute within the period)"),
    ("fault", C.ST_FAULT, 0, int, "how the last stop ended: F_NONE, F_STOP (controlled stop) or F_FAULT"),
    ("pid", C.ST_PID, 0, int, "the rt process's id"),
    ("queued", C.ST_QUEUED, 0, int, "planned samples queued in the sample ring"),
    ("mono_s", C.ST_MONO, 0, float, "CLOCK_MONOTONIC time of the last write, s (the watchdog's freshness)"),
    ("sent", C.ST_SENT, 5, int, "(5,) int64 pulses written to the backend since the rt process started"),
    ("dev_counts", C.ST_DEV_COUNTS, 5, float, "(5,) the counters the device reports (NaN if it keeps none)"),
    ("counts0", C.ST_COUNTS0, 5, int, "(5,) int64 counters the rt process started from, moved by re-references "
                                      "(counts = counts0 + sent)"),
    ("latch_seq", C.ST_LATCH_SEQ, 0, int, "counts the home-switch latches"),
    ("latch", C.ST_LATCH, 5, int, "(5,) int64 counters at the tick the armed home switch reached its state"),
    ("home_in", C.ST_HOME_IN, 0, int, "home switches as a bit mask (bit i: axis i closed); -1: none / no homing"),
    ("probe_seq", C.ST_PROBE_SEQ, 0, int, "counts the probing moves ended"),
    ("probe_row", C.ST_PROBE, C.PROBE_RESULT_WIDTH, float, "the last probe's result as stored (see probe())"),
    ("hold_at_seq", C.ST_HOLD_AT_SEQ, 0, int, "counts the hold-at points the path reached"),
)


def _field(i: int, n: int, kind, doc: str) -> property:
    """A read-only field: one number of ``kind``, or ``n`` of them as a fresh array (int64 for int)."""
    if not n:
        return property(lambda self: kind(self._b[i]), doc=doc)
    if kind is int:
        return property(lambda self: self._b[i:i + n].astype(np.int64), doc=doc)
    return property(lambda self: self._b[i:i + n].copy(), doc=doc)


class RtStatus:
    """One consistent snapshot of the rt side's status block: a private copy of the block, read by
    name (each field reads its slot when asked: taking a snapshot costs one copy of the block).
    Read-only; the array fields are fresh arrays on every read. The fields are :data:`LAYOUT`'s."""

    __slots__ = ("_b",)
    FIELDS = tuple(f[0] for f in LAYOUT)

    def __init__(self, block):
        b = np.array(block, np.float64)          # a private copy
        if b.shape != (C.STATUS_WIDTH,):
            raise ValueError(f"a status block has {C.STATUS_WIDTH} floats, not {b.shape}")
        b.flags.writeable = False
        self._b = b

    @classmethod
    def from_block(cls, block) -> RtStatus:
        """The fields of a status block (copied: a later write to ``block`` does not show)."""
        return cls(block)

    def probe(self) -> ProbeResult:
        """The last ended probing move's result (meaningful once ``probe_seq`` counted it)."""
        return ProbeResult.from_row(self._b[C.ST_PROBE:C.ST_PROBE + C.PROBE_RESULT_WIDTH])

    @property
    def running(self) -> bool:
        """The rt process has started its loop and not exited."""
        return self.phase == PH_RUNNING

    @property
    def stopped(self) -> bool:
        """The rt side's last stop is reported (``fault`` is F_STOP or F_FAULT)."""
        return self.fault != F_NONE

    def as_dict(self) -> dict:
        return {f: getattr(self, f) for f in self.FIELDS}

    def __repr__(self) -> str:
        return f"RtStatus(tick={self.tick}, mode={self.mode}, follow={self.follow}, line={self.line}, " \
               f"counts={self.counts.tolist()}, fault={self.fault})"


def read_status(ch: C.Channel) -> RtStatus:
    """A consistent snapshot of the channel's status block (retries while the rt side writes)."""
    s = RtStatus.__new__(RtStatus)
    b = ch.status()                              # a copy already
    b.flags.writeable = False
    s._b = b
    return s


for _name, _i, _n, _kind, _doc in LAYOUT:
    setattr(RtStatus, _name, _field(_i, _n, _kind, _doc))
del _name, _i, _n, _kind, _doc
