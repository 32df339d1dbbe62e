"""The step/dir bridge's framing, both sides: the Python framer/parser (pmctl.hal.bridge_protocol)
and the C parser (firmware_bridge/proto.c, run through the parser-harness program) must find the
same frames in the same byte streams, resynchronise after garbage and never accept a corrupted
frame."""

import subprocess
import time

import numpy as np

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pmctl.hal import bridge_protocol as bp
from pmctl.hal.stepdir import FIRMWARE_DIR, ensure_built

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

frames_st = st.lists(st.tuples(st.integers(0, 255), st.integers(0, 255), st.binary(max_size=bp.PAYLOAD_MAX)),
                     min_size=1, max_size=6)


@pytest.fixture(scope="module")
def harness():
    ensure_built()
    return FIRMWARE_DIR / "build" / "parser-harness"


def c_parse(harness, data: bytes):
    out = subprocess.run([str(harness)], input=data, capture_output=True, check=True).stdout.decode().split("\n")
    frames = []
    for line in out:
        if line.startswith("F "):
            _, seq, ty, *hexp = line.split(" ")
            frames.append(bp.Frame(int(seq), int(ty), bytes.fromhex(hexp[0] if hexp else "")))
        elif line.startswith("S "):
            stats = tuple(int(x) for x in line.split()[1:])
    return frames, stats


def test_crc_check_value():
    # CRC-16/CCITT-FALSE's catalogue check value
    assert bp.crc16(b"123456789") == 0x29B1
    assert bp.crc16_fast(b"123456789") == 0x29B1


def test_frame_layout():
    f = bp.frame(7, bp.T_TICK, bp.tick_payload(3, [1, -1, 200, -200, 0]))
    assert f[0] == bp.SYNC and f[1] == len(f) == 6 + 14 and f[2] == 7 and f[3] == bp.T_TICK
    assert (f[-2] << 8 | f[-1]) == bp.crc16(f[1:-2])


@settings(max_examples=60, deadline=None)
@given(frames_st, st.lists(st.binary(max_size=40), min_size=7, max_size=7))
def test_python_parser_recovers_frames_between_garbage(frames, garbage):
    stream = b""
    want = []
    for i, (seq, ty, pl) in enumerate(frames):
        stream += garbage[i] + bp.frame(seq, ty, pl)
        want.append(bp.Frame(seq, ty, pl))
    # a stray SYNC in the garbage makes the parser wait for the length it claims (at most FRAME_MAX
    # bytes), then drop it and rescan: trailing bytes let every candidate complete
    stream += garbage[-1] + bytes(bp.FRAME_MAX)
    got = bp.Parser().feed(stream)
    # every real frame is found, in order (garbage could add a chance frame: a 1 in 65536 CRC match)
    it = iter(got)
    assert all(any(g == w for g in it) for w in want)
    # fed one byte at a time: the same frames
    p = bp.Parser()
    one = [f for b in stream for f in p.feed(bytes([b]))]
    assert one == got


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 255), st.integers(0, 255), st.binary(max_size=bp.PAYLOAD_MAX), st.data())
def test_corrupted_frame_is_never_accepted(seq, ty, pl, data):
    f = bytearray(bp.frame(seq, ty, pl))
    # any change of one byte covered by the CRC (SEQ, TYPE, payload) or of the CRC itself
    i = data.draw(st.integers(2, len(f) - 1))
    x = data.draw(st.integers(1, 255))
    f[i] ^= x
    good = bp.frame(seq ^ 1, ty, pl)
    got = bp.Parser().feed(bytes(f) + good + bytes(bp.FRAME_MAX))
    assert got == [bp.Frame(seq ^ 1, ty, pl)]       # the bad one dropped, the next one found


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(frames_st, st.lists(st.binary(max_size=40), min_size=7, max_size=7), st.lists(st.integers(0, 10_000), max_size=3))
def test_c_parser_agrees_with_python(harness, frames, garbage, flips):
    stream = bytearray()
    for i, (seq, ty, pl) in enumerate(frames):
        stream += garbage[i] + bp.frame(seq, ty, pl)
    stream += garbage[-1] + bytes(bp.FRAME_MAX)
    for k in flips:                        # some corruption too
        if stream:
            stream[k % len(stream)] ^= 0x5A
    stream = bytes(stream)
    py = bp.Parser()
    want = py.feed(stream)
    got, (ok, bad, dropped) = c_parse(harness, stream)
    assert got == want
    assert (ok, bad) == (py.frames_ok, py.bad_frames)


def test_status_and_ident_codecs_roundtrip():
    import struct
    payload = struct.pack("<BBHHHIII5i5iI3hHIIIBB5i5BB", 2, 3, 0x06, 0x0220, 7, 100, 99, 104,
                          1, -2, 3, -4, 2**31 - 1, 0, 0, -5, 0, 0, 1, 10, -20, 30, 4, 123456, 123000, 0, 0, 1,
                          11, -12, 13, 14, -(2**31), 1, 0, 255, 2, 9, 0b01001)
    s = bp.decode_status(bp.Frame(9, bp.T_STATUS, payload))
    assert s.next_seq == 9 and s.state == bp.S_RUNNING and s.counters == (1, -2, 3, -4, 2**31 - 1)
    assert s.latches() == ((1, True, 11), (0, False, -12), (255, False, 13), (2, True, 14), (9, False, -(2**31)))
    assert s.not_executed[2] == -5 and s.adc == (10, -20, 30) and s.room == 1
    assert "E-stop" in s.fault_text() and "drive alarm input (L2)" in s.fault_text()
    with pytest.raises(ValueError):
        bp.decode_status(bp.Frame(0, bp.T_STATUS, payload[:-1]))
    with pytest.raises(ValueError, match="PMSB"):
        bp.decode_ident(bp.Frame(0, bp.T_IDENT_REPLY, b"GRBL" + bytes(46)))
    with pytest.raises(ValueError, match="protocol version 1"):       # version 1: no home latches in STATUS
        bp.decode_ident(bp.Frame(0, bp.T_IDENT_REPLY, b"PMSB" + struct.pack("<H", 1) + bytes(44)))


# ---------------------------------------------------------------- the live bridge under garbage

_COMMANDS = {bp.T_IDENT, bp.T_CONFIG, bp.T_RESET, bp.T_TICK, bp.T_END, bp.T_STOP, bp.T_STATUS_REQ}


@pytest.fixture(scope="module", params=["host-pty", "rp2040"])
def live_bridge(request, tmp_path_factory):
    """The same protocol tests against both builds: the host build on a pty, and the RP2040 image in
    the emulated chip (tests/hal/test_rp2040.py has its HIL tests)."""
    from stepdir_support import Bridge, EmulatedBridge
    b = (Bridge if request.param == "host-pty" else EmulatedBridge)(tmp_path_factory.mktemp("fuzz"))
    b.board = request.param
    yield b
    b.stop()


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.one_of(
    st.binary(min_size=1, max_size=200),                                        # line noise
    st.builds(lambda s, t, p: bp.frame(s, t, p), st.integers(0, 255),           # valid CRC, unknown type
              st.integers(0, 255).filter(lambda t: t not in _COMMANDS), st.binary(max_size=40)),
    st.builds(lambda s, t, p: bp.frame(s, t, p), st.integers(0, 255),           # command, wrong length
              st.sampled_from([bp.T_CONFIG, bp.T_RESET, bp.T_TICK]), st.binary(max_size=12)),
), min_size=1, max_size=12))
def test_the_running_bridge_survives_garbage_and_executes_none_of_it(live_bridge, chunks):
    import serial
    with serial.Serial(live_bridge.port, timeout=0) as s:
        s.write(bp.frame(0, bp.T_IDENT))
        for c in chunks:
            s.write(c)
        s.write(bytes(bp.FRAME_MAX))              # let any half candidate complete and be dropped
        p = bp.Parser()
        s.write(bp.frame(0, bp.T_IDENT))          # still answers, and understands
        t_end = time.monotonic() + 20
        ident = None
        while ident is None and time.monotonic() < t_end:
            for f in p.feed(s.read(4096)):
                if f.type == bp.T_IDENT_REPLY:
                    ident = bp.decode_ident(f)
            time.sleep(0.002)
        assert ident is not None and ident.board == live_bridge.board
    st_ = live_bridge.status()
    assert st_.state in (bp.S_IDLE, bp.S_FAULT) and st_.started == 0 and st_.counters == (0, 0, 0, 0, 0)
    log = live_bridge.edges()
    assert not np.any(log["kind"] == bp.EDGE_HIGH)
