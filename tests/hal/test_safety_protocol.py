"""The host side of the step/dir bridge protocol (pmctl.hal.bridge_protocol) pinned where a slip
would let a bad command through or misreport the machine: the per-tick pulse limit at its bounds
(firmware_bridge/PROTOCOL.md section 4: floor((T - d) / (2 w)) pulses, d only after a direction
change, at most 32767), frame and payload sizes at their limits, the parser's counts of what it
dropped, and every field of ACK, STATUS and IDENT in its place (distinct values, so a field read
from a neighbour's slot shows)."""

import struct

import pytest
from hypothesis import given, settings, strategies as st

from pmctl.hal import bridge_protocol as bp


@settings(max_examples=200, deadline=None)
@given(tick=st.integers(50_000, 100_000_000), width=st.integers(100, 1_000_000), setup=st.integers(0, 1_000_000),
       change=st.booleans())
def test_max_pulses_is_the_protocols_formula(tick, width, setup, change):
    n = bp.max_pulses(tick, width, setup, change)
    assert isinstance(n, int)
    assert n == min((tick - (setup if change else 0)) // (2 * width), 32767)


def test_max_pulses_at_the_shipped_timing_and_at_the_cap():
    assert bp.max_pulses(1_000_000, 2500, 5000, False) == 200         # 200 kpulse/s at 1 kHz
    assert bp.max_pulses(1_000_000, 2500, 5000, True) == 199          # the direction set-up costs one
    assert bp.max_pulses(100_000_000, 100, 0, False) == 32767        # an int16 per axis in TICK
    assert bp.max_pulses(100_000_000, 100, 0, True) == 32767
    assert bp.max_pulses(2 * 32767 * 100 + 199, 100, 0, False) == 32767
    assert bp.max_pulses(2 * 32766 * 100 + 199, 100, 0, False) == 32766


def test_the_largest_payload_frames_and_parses_and_one_more_byte_is_refused():
    data = bytes(range(bp.PAYLOAD_MAX))
    f = bp.frame(7, bp.T_TICK, data)
    assert len(f) == bp.FRAME_MAX and f[1] == bp.FRAME_MAX          # LEN counts the whole frame
    p = bp.Parser()
    assert p.feed(f) == [bp.Frame(7, bp.T_TICK, data)] and (p.bad_frames, p.dropped_bytes) == (0, 0)
    with pytest.raises(ValueError, match=f"payload of {bp.PAYLOAD_MAX + 1} bytes exceeds {bp.PAYLOAD_MAX}"):
        bp.frame(0, bp.T_TICK, bytes(bp.PAYLOAD_MAX + 1))


@settings(max_examples=100, deadline=None)
@given(garbage=st.binary(max_size=60).map(lambda b: bytes(x for x in b if x != bp.SYNC)),
       payload=st.binary(max_size=bp.PAYLOAD_MAX), split=st.integers(0, 200))
def test_the_parser_counts_exactly_the_garbage_it_drops(garbage, payload, split):
    """Garbage without a SYNC byte, then a frame, fed in two pieces cut anywhere: one frame, every
    garbage byte counted as dropped, none of the frame's; twice over, the counts add up."""
    f = bp.frame(3, bp.T_STATUS_REQ, payload)
    stream = garbage + f + garbage + f
    p = bp.Parser()
    cut = min(split, len(stream))
    got = p.feed(stream[:cut]) + p.feed(stream[cut:])
    assert got == [bp.Frame(3, bp.T_STATUS_REQ, payload)] * 2
    assert p.dropped_bytes == 2 * len(garbage) and p.bad_frames == 0 and p.frames_ok == 2


@pytest.mark.parametrize("length", [0, 1, bp.FRAME_MIN - 1, bp.FRAME_MAX + 1, 200, 255])
def test_a_sync_with_an_impossible_length_is_one_bad_frame_and_one_dropped_byte(length):
    f = bp.frame(1, bp.T_END)
    p = bp.Parser()
    assert p.feed(bytes((bp.SYNC, length)) + f) == [bp.Frame(1, bp.T_END, b"")]
    # the SYNC is dropped and the scan goes on; a LEN byte equal to SYNC (126 = FRAME_MAX + 1) is
    # itself taken as the next start, and refused the same way against the frame's own SYNC
    assert (p.bad_frames, p.dropped_bytes) == ((2, 2) if length == bp.SYNC else (1, 2))


def test_a_length_at_the_frame_limits_waits_for_the_rest():
    p = bp.Parser()
    assert p.feed(bytes((bp.SYNC,))) == [] and p.feed(bytes((bp.FRAME_MAX,))) == []   # incomplete, kept
    assert (p.bad_frames, p.dropped_bytes) == (0, 0) and len(p.buf) == 2
    p2 = bp.Parser()
    assert p2.feed(bytes((bp.SYNC, bp.FRAME_MIN))) == [] and p2.bad_frames == 0


def test_every_ack_field_in_its_place():
    a = bp.decode_ack(bp.Frame(17, bp.T_ACK, struct.pack("<BBB", 0x05, bp.E_SPEED, bp.T_TICK)))
    assert (a.next_seq, a.flags, a.code, a.type) == (17, 0x05, bp.E_SPEED, bp.T_TICK)
    for bad in (b"", b"\x01\x02", b"\x01\x02\x03\x04"):
        with pytest.raises(ValueError, match=f"ACK payload of {len(bad)} bytes, expected 3"):
            bp.decode_ack(bp.Frame(0, bp.T_ACK, bad))


def test_every_status_field_in_its_place():
    v = [2, 9, 0x1234, 0x0203, 0x4321, 111_111, 222_222, 333_333,
         11, -12, 13, -14, 15, 21, -22, 23, -24, 25, 444_444, 31, -32, 33, 4444,
         555_555, 666_666, 777_777, 1, 77, 41, -42, 43, -44, 45, 51, 52, 53, 54, 55, 0b10101]
    s = bp.decode_status(bp.Frame(99, bp.T_STATUS, struct.pack("<BBHHHIII5i5iI3hHIIIBB5i5BB", *v)))
    assert s == bp.BridgeStatus(99, 2, 9, 0x1234, 0x0203, 0x4321, 111_111, 222_222, 333_333,
                                (11, -12, 13, -14, 15), (21, -22, 23, -24, 25), 444_444, (31, -32, 33), 4444,
                                555_555, 666_666, 777_777, 1, 77, (41, -42, 43, -44, 45), (51, 52, 53, 54, 55), 0b10101)
    with pytest.raises(ValueError, match="STATUS payload of 117 bytes"):
        bp.decode_status(bp.Frame(0, bp.T_STATUS, bytes(117)))


def test_every_ident_field_in_its_place():
    payload = struct.pack("<4sHBBIIIIBB8s16s", bp.MAGIC, bp.PROTO_VERSION, 5, 64, 1_000_000, 2500, 5000, 50_000,
                          32, 4, b"fw-1.2\0\0", b"host-pty\0\0\0\0\0\0\0\0")
    i = bp.decode_ident(bp.Frame(0, bp.T_IDENT_REPLY, payload))
    assert i == bp.Ident(bp.PROTO_VERSION, 5, 64, 1_000_000, 2500, 5000, 50_000, 32, 4, "fw-1.2", "host-pty")
    with pytest.raises(ValueError, match=f"protocol version {bp.PROTO_VERSION}"):      # right version, wrong size
        bp.decode_ident(bp.Frame(0, bp.T_IDENT_REPLY, payload + b"\0"))
    with pytest.raises(ValueError, match="PMSB"):
        bp.decode_ident(bp.Frame(0, bp.T_IDENT_REPLY, bp.MAGIC[:3]))


def test_two_bytes_of_an_impossible_frame_are_refused_without_waiting_for_more():
    p = bp.Parser()
    assert p.feed(bytes((bp.SYNC, 3))) == []
    assert (p.bad_frames, p.dropped_bytes, len(p.buf)) == (1, 2, 0)


def test_corrupted_frames_are_counted_once_each_with_every_byte_dropped():
    good = bp.frame(5, bp.T_END)
    bad = []
    for k, pl in enumerate((b"\x01\x02\x03", b"\x10" * 9)):
        f = bytearray(bp.frame(k, bp.T_TICK, pl))
        f[-1] ^= 0x55                                    # the CRC's low byte wrong
        assert bp.SYNC not in f[1:]
        bad.append(bytes(f))
    p = bp.Parser()
    assert p.feed(b"".join(bad) + good) == [bp.Frame(5, bp.T_END, b"")]
    assert (p.bad_frames, p.dropped_bytes) == (2, sum(len(b) for b in bad))


def test_an_ident_reply_is_refused_for_the_right_reason():
    with pytest.raises(ValueError, match=r"^not a pmctl step/dir bridge \(no PMSB magic\)$"):
        bp.decode_ident(bp.Frame(0, bp.T_IDENT_REPLY, b"GRBL" + bytes(46)))
    # the magic and a version but nothing else: the version check speaks (6 bytes is enough to read it)
    with pytest.raises(ValueError, match=f"^bridge speaks protocol version {bp.PROTO_VERSION}; "):
        bp.decode_ident(bp.Frame(0, bp.T_IDENT_REPLY, bp.MAGIC + struct.pack("<H", bp.PROTO_VERSION)))
    with pytest.raises(ValueError, match="^bridge speaks protocol version 32770; "):      # unsigned
        bp.decode_ident(bp.Frame(0, bp.T_IDENT_REPLY, bp.MAGIC + struct.pack("<H", 0x8002) + bytes(44)))


def test_ident_names_keep_their_own_characters_and_survive_bad_bytes():
    payload = struct.pack("<4sHBBIIIIBB8s16s", bp.MAGIC, bp.PROTO_VERSION, 5, 64, 1_000_000, 2500, 5000, 50_000,
                          32, 4, b"fw-X\xffX\0\0", b"bd\xfe-X\0")
    i = bp.decode_ident(bp.Frame(0, bp.T_IDENT_REPLY, payload))
    assert (i.firmware, i.board) == ("fw-X\ufffdX", "bd\ufffd-X")


def test_executed_steps_counts_rising_edges_in_the_direction_last_set():
    """The host bridge's edge log (the oracle of "pulses counted = pulses sent"): every axis starts
    positive; a direction record changes the sign of the rising edges after it; falling edges and
    tick marks do not count."""
    E = bp
    rows = [(0, E.EDGE_HIGH), (0, E.EDGE_LOW), (0, E.EDGE_HIGH), (0, E.EDGE_DIR_NEG), (0, E.EDGE_HIGH),
            (0, E.EDGE_HIGH), (0, E.EDGE_HIGH), (0, E.EDGE_DIR_POS), (0, E.EDGE_HIGH),
            (1, E.EDGE_DIR_NEG), (1, E.EDGE_HIGH), (1, E.EDGE_LOW), (1, E.EDGE_HIGH), (2, E.EDGE_TICK),
            (4, E.EDGE_DIR_POS), (4, E.EDGE_HIGH)]
    import numpy as np
    log = np.zeros(len(rows), dtype=np.dtype(bp.EDGE_DTYPE))
    log["axis"] = [a for a, _ in rows]
    log["kind"] = [k for _, k in rows]
    log["t"] = np.arange(len(rows))
    out = bp.executed_steps(log)
    assert out.dtype == np.int64 and out.tolist() == [0, -2, 0, 0, 1]
