"""The step/dir bridge's wire format, host side: CRC-16, frames, the resynchronising parser and the
payload codecs (firmware_bridge/PROTOCOL.md; the bridge's C side is firmware_bridge/proto.c).

Frame: ``SYNC(0x7E) LEN SEQ TYPE PAYLOAD[LEN-6] CRC_HI CRC_LO``; LEN is the whole frame length
(6 .. 125); the CRC is CRC-16/CCITT-FALSE over LEN, SEQ, TYPE and the payload. Payload integers are
little-endian. Pure Python, no I/O: the backend (pmctl.hal.stepdir) owns the port.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

SYNC = 0x7E
FRAME_MIN = 6
FRAME_MAX = 125        # < SYNC: a SYNC byte is never a valid LEN
PAYLOAD_MAX = FRAME_MAX - FRAME_MIN
PROTO_VERSION = 2      # 2: STATUS carries the home-switch latches
MAGIC = b"PMSB"
NAXES = 5

# host -> bridge
T_IDENT, T_CONFIG, T_RESET, T_TICK, T_END, T_STOP, T_STATUS_REQ = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07
# bridge -> host
T_ACK, T_STATUS, T_IDENT_REPLY = 0x81, 0x82, 0x83

ACK_NAK, ACK_FULL, ACK_REJECT, ACK_DUP = 0x01, 0x02, 0x04, 0x08

E_OK, E_BUSY, E_ARGS, E_FAULT, E_STATE, E_TICK, E_SPEED = range(7)
REJECT_TEXT = {E_OK: "ok", E_BUSY: "busy (moving)", E_ARGS: "bad arguments", E_FAULT: "a fault is latched",
               E_STATE: "not armed", E_TICK: "tick index out of order", E_SPEED: "too many pulses for one tick"}

S_IDLE, S_ARMED, S_RUNNING, S_DRAINING, S_FAULT = range(5)
STATE_NAMES = {S_IDLE: "idle", S_ARMED: "armed", S_RUNNING: "running", S_DRAINING: "draining", S_FAULT: "fault"}

F_WATCHDOG, F_ESTOP, F_ALARM, F_PROTOCOL, F_OVERSPEED, F_HOST_STOP, F_LATE = 0x01, 0x02, 0x04, 0x08, 0x10, 0x20, 0x40
FAULT_TEXT = {F_WATCHDOG: "watchdog: no valid tick within the watchdog time (host timeout)",
              F_ESTOP: "E-stop input", F_ALARM: "drive alarm input", F_PROTOCOL: "protocol error (tick out of order)",
              F_OVERSPEED: "more pulses than fit in a tick", F_HOST_STOP: "stopped by the host",
              F_LATE: "the bridge fell behind its step schedule (more steps than it can time)"}

WHY_TICK, WHY_OTHER = 0, 1
IN_ESTOP = 1 << 5
AXES = ("L1", "L2", "L3", "X", "Y")


def crc16(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, not reflected, no final xor)."""
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


_CRC_TABLE = []
for _i in range(256):
    _c = _i << 8
    for _ in range(8):
        _c = ((_c << 1) ^ 0x1021) & 0xFFFF if _c & 0x8000 else (_c << 1) & 0xFFFF
    _CRC_TABLE.append(_c)


def crc16_fast(data: bytes, crc: int = 0xFFFF) -> int:
    """Table-driven crc16 (same result; used on the hot path)."""
    t = _CRC_TABLE
    for b in data:
        crc = ((crc << 8) & 0xFFFF) ^ t[((crc >> 8) ^ b) & 0xFF]
    return crc


def frame(seq: int, type_: int, payload: bytes = b"") -> bytes:
    n = len(payload)
    if n > PAYLOAD_MAX:
        raise ValueError(f"payload of {n} bytes exceeds {PAYLOAD_MAX}")
    body = bytes((n + FRAME_MIN, seq & 0xFF, type_ & 0xFF)) + payload
    c = crc16_fast(body)
    return bytes((SYNC,)) + body + bytes((c >> 8, c & 0xFF))


@dataclass(frozen=True)
class Frame:
    seq: int
    type: int
    payload: bytes


class Parser:
    """Byte stream -> frames. After garbage or a bad frame it drops one byte and rescans for SYNC,
    so a good frame that starts inside a bad one is still found."""

    def __init__(self):
        self.buf = bytearray()
        self.frames_ok = 0
        self.bad_frames = 0
        self.dropped_bytes = 0

    def feed(self, data: bytes) -> list[Frame]:
        b = self.buf
        b += data
        out = []
        while True:
            i = b.find(SYNC)
            if i < 0:
                self.dropped_bytes += len(b)
                b.clear()
                break
            if i:
                self.dropped_bytes += i
                del b[:i]
            if len(b) < 2:
                break
            n = b[1]
            if n < FRAME_MIN or n > FRAME_MAX:
                self.bad_frames += 1
                self.dropped_bytes += 1
                del b[:1]
                continue
            if len(b) < n:
                break
            c = crc16_fast(bytes(b[1:n - 2]))
            if b[n - 2] != c >> 8 or b[n - 1] != c & 0xFF:
                self.bad_frames += 1
                self.dropped_bytes += 1
                del b[:1]
                continue
            out.append(Frame(b[2], b[3], bytes(b[4:n - 2])))
            self.frames_ok += 1
            del b[:n]
        return out


# ---------------------------------------------------------------- payloads

_TICK = struct.Struct("<I5h")
_RESET = struct.Struct("<5i")
_CONFIG = struct.Struct("<IIIIBB")
_STATUS = struct.Struct("<BBHHHIII5i5iI3hHIIIBB5i5BB")
_IDENT = struct.Struct("<4sHBBIIIIBB8s16s")
_ACK = struct.Struct("<BBB")


def tick_payload(index: int, pulses) -> bytes:
    return _TICK.pack(index & 0xFFFFFFFF, *(int(p) for p in pulses))


def reset_payload(counters) -> bytes:
    return _RESET.pack(*(int(c) for c in counters))


def config_payload(tick_ns, step_width_ns, dir_setup_ns, watchdog_us, queue, prime) -> bytes:
    return _CONFIG.pack(int(tick_ns), int(step_width_ns), int(dir_setup_ns), int(watchdog_us), int(queue), int(prime))


@dataclass
class Ack:
    next_seq: int
    flags: int
    code: int
    type: int


def decode_ack(f: Frame) -> Ack:
    if len(f.payload) != _ACK.size:
        raise ValueError(f"ACK payload of {len(f.payload)} bytes, expected {_ACK.size}")
    fl, code, ty = _ACK.unpack(f.payload)
    return Ack(f.seq, fl, code, ty)


@dataclass
class BridgeStatus:
    next_seq: int
    state: int
    queue: int
    faults: int
    inputs: int
    rx_bad: int
    started: int
    done: int
    next_tick: int
    counters: tuple
    not_executed: tuple
    dropped_ticks: int
    adc: tuple
    underruns: int
    time_us: int
    last_tick_rx_us: int
    fault_us: int
    why: int            # WHY_TICK: sent at a tick start, counters = exactly the ticks before it
    room: int           # free queue slots
    home_latch: tuple = (0,) * NAXES   # per axis: the counter at the last home-switch transition (exact)
    home_edges: tuple = (0,) * NAXES   # per axis: transitions latched so far, mod 256
    home_level: int = 0                # bit per axis: the level the last transition went to (1 closed)

    def latches(self) -> tuple:
        """Per axis (transitions mod 256, closed after the last one, counter at it): the backend's
        ``Inputs.latch``."""
        return tuple((self.home_edges[i], bool(self.home_level >> i & 1), self.home_latch[i]) for i in range(NAXES))

    def fault_text(self) -> str:
        parts = [t for b, t in FAULT_TEXT.items() if self.faults & b]
        if self.faults & F_ALARM:
            ax = [AXES[i] for i in range(5) if self.inputs & (1 << (8 + i))]
            if ax:
                parts[parts.index(FAULT_TEXT[F_ALARM])] += f" ({', '.join(ax)})"
        return "; ".join(parts) or "none"


def decode_status(f: Frame) -> BridgeStatus:
    if len(f.payload) != _STATUS.size:
        raise ValueError(f"STATUS payload of {len(f.payload)} bytes, expected {_STATUS.size}")
    v = _STATUS.unpack(f.payload)
    return BridgeStatus(f.seq, v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], tuple(v[8:13]), tuple(v[13:18]),
                        v[18], tuple(v[19:22]), v[22], v[23], v[24], v[25], v[26], v[27], tuple(v[28:33]),
                        tuple(v[33:38]), v[38])


@dataclass
class Ident:
    proto_version: int
    naxes: int
    queue_max: int
    tick_ns: int
    step_width_ns: int
    dir_setup_ns: int
    watchdog_us: int
    queue: int
    prime: int
    firmware: str
    board: str


def decode_ident(f: Frame) -> Ident:
    if len(f.payload) < 6 or f.payload[:4] != MAGIC:
        raise ValueError("not a pmctl step/dir bridge (no PMSB magic)")
    version = struct.unpack_from("<H", f.payload, 4)[0]
    if version != PROTO_VERSION or len(f.payload) != _IDENT.size:
        raise ValueError(f"bridge speaks protocol version {version}; this host speaks {PROTO_VERSION}")
    v = _IDENT.unpack(f.payload)
    return Ident(v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8], v[9],
                 v[10].rstrip(b"\0").decode("ascii", "replace"), v[11].rstrip(b"\0").decode("ascii", "replace"))


def max_pulses(tick_ns: int, step_width_ns: int, dir_setup_ns: int, dir_change: bool) -> int:
    """Largest pulse count per tick the step width allows (the bridge's sb_max_pulses)."""
    span = tick_ns - (dir_setup_ns if dir_change else 0)
    return min(span // (2 * step_width_ns), 32767)


# ---------------------------------------------------------------- the host build's edge log

EDGE_DTYPE = [("t", "<u8"), ("tick", "<u4"), ("axis", "u1"), ("kind", "u1"), ("pad", "<u2")]
EDGE_LOW, EDGE_HIGH, EDGE_DIR_NEG, EDGE_DIR_POS, EDGE_TICK = 0, 1, 2, 3, 4


def read_edge_log(path):
    """The host bridge's --edge-log: a numpy record array (t ns, tick, axis, kind)."""
    import numpy as np
    return np.fromfile(path, dtype=np.dtype(EDGE_DTYPE))


def executed_steps(log):
    """Signed steps per axis in an edge log (each rising edge counts in the direction last set;
    the bridge starts with every direction positive)."""
    import numpy as np
    out = np.zeros(NAXES, np.int64)
    for a in range(NAXES):
        ev = log[(log["axis"] == a) & (log["kind"] != EDGE_LOW)]
        sign = np.where(ev["kind"] == EDGE_DIR_NEG, -1, np.where(ev["kind"] == EDGE_DIR_POS, 1, 0))
        # direction in force at each event: the last dir record at or before it (forward fill)
        idx = np.where(sign != 0, np.arange(len(ev)), -1)
        np.maximum.accumulate(idx, out=idx)
        d = np.where(idx >= 0, sign[np.maximum(idx, 0)], 1)
        out[a] = int(np.sum(d[ev["kind"] == EDGE_HIGH]))
    return out
