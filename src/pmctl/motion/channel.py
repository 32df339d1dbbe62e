"""The channel between the rt motion process and the supervisor: one shared-memory segment.

Layout (all float64 unless noted), in this order:
- the status block (``STATUS_WIDTH`` floats): written by the rt side every tick under a sequence
  counter (odd while a write is under way), read by the supervisor with :meth:`Channel.status`
  (retries on a torn read; the rt side never waits);
- the reason text (``REASON_BYTES``): the last stop/fault reason, UTF-8, NUL-padded, with its own
  sequence number in the status block;
- the command ring (supervisor -> rt), ``CMD_CAPACITY`` rows of (seq, code, arg1, arg2);
- the sample ring (supervisor -> rt), planned samples (pmctl.motion.timescale.WIDTH floats);
- the record ring (rt -> supervisor), per-tick records (pmctl.motion.recorder.REC_WIDTH floats);
- the probe table (supervisor -> rt), ``PROBE_TABLE_WIDTH`` floats: a sequence number, then the
  probing segment the next ``FLAG_PROBE`` samples belong to (pmctl.motion.probe.ProbeSegment.to_row).
  The supervisor writes it (the number last) before it pushes those samples; one probe is in flight
  at a time.
- the result (``RESULT_BYTES``, last): written once by the rt side as it exits, a JSON
  object (the loop's end status and reason, ticks, and its timing summary: compute, NC step and
  lateness median/p99/max, overruns) preceded by its length as an int64 (0: not written yet); the
  supervisor reads it after the rt process ended (:meth:`Channel.result`), so a one-shot run
  (``pmctl run``) reports the rt side's timing figures.

The supervisor creates the segment and unlinks it at exit; the rt side attaches by name.
"""

from __future__ import annotations

import gc
import json
import math
from multiprocessing import shared_memory

import numpy as np

from pmctl.motion.probe import RESULT_WIDTH as PROBE_RESULT_WIDTH
from pmctl.motion.probe import SEGMENT_WIDTH as PROBE_SEGMENT_WIDTH
from pmctl.motion.recorder import REC_WIDTH
from pmctl.motion.ring import Ring, ring_bytes
from pmctl.motion.timescale import WIDTH as SAMPLE_WIDTH

# status block fields
(ST_SEQ, ST_TICK, ST_WALL, ST_MODE, ST_FOLLOW, ST_SIGMA, ST_LINE, ST_S, ST_FEED_OV, ST_RAPID_OV, ST_HOLD,
 ST_COUNTS) = range(12)
ST_TIP = ST_COUNTS + 5            # 16
ST_AXIS = ST_TIP + 3              # 19
(ST_ENDED, ST_DROPPED, ST_LATE_NS, ST_COMPUTE_NS, ST_PHASE, ST_REASON_SEQ, ST_CMD_ACK, ST_ONTIME,
 ST_FAULT, ST_PID, ST_QUEUED, ST_MONO) = range(ST_AXIS + 3, ST_AXIS + 15)
ST_SENT = ST_MONO + 1             # (5) pulses written to the backend since the rt process started
ST_DEV_COUNTS = ST_SENT + 5       # (5) the counters the device reports (NaN if it keeps none)
ST_COUNTS0 = ST_DEV_COUNTS + 5    # (5) the counters the rt process started from, moved by any re-reference
                                  # (homing): counters = ST_COUNTS0 + ST_SENT holds throughout
ST_LATCH_SEQ = ST_COUNTS0 + 5     # counts the home-switch latches (C_HOME_ARM)
ST_LATCH = ST_LATCH_SEQ + 1       # (5) the counters at the tick the armed switch reached the wanted state
ST_HOME_IN = ST_LATCH + 5         # home switches as a bit mask (bit i: axis i closed); -1: no switches, or a
                                  # backend that cannot re-reference its counters (no homing)
ST_PROBE_SEQ = ST_HOME_IN + 1     # counts the probing moves ended (G38.2/G38.3, pmctl.motion.probe)
ST_PROBE = ST_PROBE_SEQ + 1       # (PROBE_RESULT_WIDTH) the last one's result (ProbeResult.to_row)
ST_HOLD_AT_SEQ = ST_PROBE + PROBE_RESULT_WIDTH  # counts the C_HOLD_AT points the path reached (held there)
STATUS_WIDTH = ST_HOLD_AT_SEQ + 1
PROBE_TABLE_WIDTH = 1 + PROBE_SEGMENT_WIDTH
REASON_BYTES = 512

# rt phases
PH_STARTING, PH_RUNNING, PH_EXITED = 0.0, 1.0, 2.0
# fault kinds in ST_FAULT
F_NONE, F_STOP, F_FAULT = 0.0, 1.0, 2.0

# commands
C_HOLD, C_RESUME, C_FEED_OV, C_RAPID_OV, C_RESET, C_QUIT, C_ESTOP, C_UNLOCK, C_SET_COUNTS, C_HOME_ARM = range(1, 11)
# C_SET_COUNTS (axis, counter): re-reference one axis's pulse counter at rest (homing; the motor does not move).
# C_HOME_ARM (axis, state): latch the counters and feed-hold at the first tick the home switch of ``axis``
# reads ``state`` (1 closed, 0 open); axis -1 disarms.
C_CHAIN_OFFSET = 11
# C_CHAIN_OFFSET (chain, mm): the chain-length offset input of chain 0..2 (slow compensation; ControlLoop.set_chain_offset).
C_HOLD_AT = 12
# C_HOLD_AT (row, rest): feed-hold on the path when it reaches sample ``row`` of the sample ring (its
# absolute index: Ring.written when it was pushed), e.g. a spindle speed change inside a job waiting
# for at speed; ``rest`` 1: the path is at rest there (a planned stop). Points queue in order; each
# reached one counts up ST_HOLD_AT_SEQ. A soft reset or a fault drops them.
CMD_WIDTH = 4
CMD_CAPACITY = 64

SAMPLE_CAPACITY = 16384           # 16 s of samples at 1 kHz, 3.2 MB
RECORD_CAPACITY = 8192            # 8 s of records at 1 kHz, 2 MB
RESULT_BYTES = 8192


def segment_size(sample_capacity=SAMPLE_CAPACITY, record_capacity=RECORD_CAPACITY) -> int:
    return (8 * STATUS_WIDTH + REASON_BYTES + ring_bytes(CMD_CAPACITY, CMD_WIDTH)
            + ring_bytes(sample_capacity, SAMPLE_WIDTH) + ring_bytes(record_capacity, REC_WIDTH)
            + 8 * PROBE_TABLE_WIDTH + RESULT_BYTES)


class Channel:
    """Views on the segment. ``create=True``: the supervisor's side (new segment, zeroed)."""

    def __init__(self, name: str | None = None, *, create: bool = False, sample_capacity=SAMPLE_CAPACITY,
                 record_capacity=RECORD_CAPACITY):
        size = segment_size(sample_capacity, record_capacity)
        if create:
            self.shm = shared_memory.SharedMemory(create=True, size=size)
        else:
            self.shm = shared_memory.SharedMemory(name=name)
            _untrack(self.shm)
        self.name = self.shm.name
        self.sample_capacity, self.record_capacity = sample_capacity, record_capacity
        buf = self.shm.buf
        off = 0
        self.st = np.ndarray((STATUS_WIDTH,), np.float64, buf, off)
        off += 8 * STATUS_WIDTH
        self._reason = np.ndarray((REASON_BYTES,), np.uint8, buf, off)
        off += REASON_BYTES
        self.commands = Ring(CMD_CAPACITY, CMD_WIDTH, buf[off:off + ring_bytes(CMD_CAPACITY, CMD_WIDTH)], reset=create)
        off += ring_bytes(CMD_CAPACITY, CMD_WIDTH)
        n = ring_bytes(sample_capacity, SAMPLE_WIDTH)
        self.samples = Ring(sample_capacity, SAMPLE_WIDTH, buf[off:off + n], reset=create)
        off += n
        n = ring_bytes(record_capacity, REC_WIDTH)
        self.records = Ring(record_capacity, REC_WIDTH, buf[off:off + n], reset=create)
        off += n
        self.probe = np.ndarray((PROBE_TABLE_WIDTH,), np.float64, buf, off)
        off += 8 * PROBE_TABLE_WIDTH
        self._result = np.ndarray((RESULT_BYTES,), np.uint8, buf, off)
        if create:
            self.st[:] = 0.0
            self._reason[:] = 0
            self.probe[:] = 0.0
            self._result[:8] = 0
        self._cmd_seq = 0

    # ---- rt side
    def begin_status(self):
        self.st[ST_SEQ] += 1.0            # odd: a write is under way

    def end_status(self):
        self.st[ST_SEQ] += 1.0

    def set_reason(self, text: str):
        b = text.encode("utf-8", "replace")[:REASON_BYTES - 1]
        self._reason[:] = 0
        self._reason[:len(b)] = np.frombuffer(b, np.uint8)
        self.st[ST_REASON_SEQ] += 1.0

    def set_result(self, result: dict):
        """The rt side's end result (JSON; written once, as it exits): the body first, then its length."""
        b = json.dumps(result).encode()[:RESULT_BYTES - 8]
        self._result[8:8 + len(b)] = np.frombuffer(b, np.uint8)
        self._result[:8] = np.frombuffer(np.int64(len(b)).tobytes(), np.uint8)

    # ---- supervisor side
    def reset_status(self, counts):
        """Before an rt process starts: a zeroed status block (nothing of a previous rt process's
        status may count), phase PH_STARTING, and the counters it starts from."""
        self.st[:] = 0.0
        self.st[ST_PHASE] = PH_STARTING
        self.st[ST_COUNTS:ST_COUNTS + 5] = np.asarray(counts, float)

    def result(self) -> dict | None:
        """The rt side's end result, or None when it has not written one (killed, or still running)."""
        n = int(np.frombuffer(bytes(self._result[:8]), np.int64)[0])
        if n <= 0:
            return None
        try:
            return json.loads(bytes(self._result[8:8 + n]).decode())
        except ValueError:
            return None

    def clear_result(self):
        self._result[:8] = 0

    def status(self) -> np.ndarray:
        """A consistent copy of the status block (retries while the rt side writes)."""
        for _ in range(1000):
            s0 = self.st[ST_SEQ]
            if int(s0) % 2 == 0:
                out = self.st.copy()
                if self.st[ST_SEQ] == s0:
                    return out
        return self.st.copy()

    def reason(self) -> str:
        b = bytes(self._reason)
        return b.split(b"\0", 1)[0].decode("utf-8", "replace")

    def command(self, code: int, a1: float = 0.0, a2: float = 0.0) -> bool:
        self._cmd_seq += 1
        return self.commands.push_row([float(self._cmd_seq), float(code), float(a1), float(a2)])

    def close(self, unlink: bool = False):
        # numpy views keep the buffer exported: drop them first
        for a in ("st", "_reason", "commands", "samples", "records", "probe", "_result"):
            if hasattr(self, a):
                delattr(self, a)
        gc.collect()
        try:
            self.shm.close()
        except BufferError:
            pass
        if unlink:
            try:
                self.shm.unlink()
            except FileNotFoundError:
                pass


def _untrack(shm):
    """An attaching process must not unlink the segment at its exit (Python < 3.13 registers every
    SharedMemory with the resource tracker)."""
    try:
        from multiprocessing import resource_tracker
        resource_tracker.unregister(shm._name, "shared_memory")
    except Exception:
        pass


def finite(x) -> bool:
    return math.isfinite(float(x))
