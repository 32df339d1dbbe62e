"""The device simulator (pmctl.hal.devsim): simulated CiA 402 drives in a process of their own on
slcan links (loopback TCP and a pty), driven by the canopen backend through the control loop; the
wire checked with python-can's own ``slcan`` interface; faults injected across the process
boundary; a simulator that dies is a controlled stop."""

import time

import can
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from pmctl import hal
from pmctl.hal import cia402 as C
from pmctl.hal.slcan_link import decode, encode
from pmctl.motion.loop import ControlLoop, prepare
from pmctl.motion.nc import counts_of, initial_state
from pmctl.motion.service_config import LoopConfig

from test_canopen import DT, FAST, M, Listener, start_counts

# (an offline loop, the drives in another process without real-time priority: a loaded host may hold
# their answers back for a while, which is not what these tests are about; the read timeout that trips
# is tested in tests/hal/test_canopen.py)
DEVSIM = {**FAST, "interface": "slcan", "channel": "devsim", "simulate": True, "sim_link": "tcp",
          "sim_listen_links": 1, "sim_rt_priority": 0, "read_timeout_ms": 3000.0}


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 0x7FF), st.binary(min_size=0, max_size=8))
def test_slcan_line_round_trip_and_the_lawicel_form(cid, data):
    m = can.Message(arbitration_id=cid, data=data, is_extended_id=False)
    line = encode(m)
    assert line == f"t{cid:03X}{len(data)}{data.hex().upper()}\r".encode()
    back = decode(line[:-1])
    assert back.arbitration_id == cid and bytes(back.data) == data and not back.is_extended_id


def test_slcan_decode_refuses_a_short_frame_and_ignores_answers():
    assert decode(b"") is None and decode(b"z") is None and decode(b"V1013") is None
    for bad in (b"t1", b"t18160102", b"t8001"):
        try:
            decode(bad)
        except ValueError:
            continue
        raise AssertionError(bad)


def slcan_listener(path):
    """python-can's own slcan interface on one of the simulator's pty links, recording frames."""
    return Listener(None, can.Bus(interface="slcan", channel=path, bitrate=1_000_000, sleep_after_open=0))


def _answered(frames) -> bool:
    """Every drive (nodes 1-5) sent a TPDO after the last RPDO it received."""
    frames = list(frames)
    for n in range(1, 6):
        rx = [i for i, (cid, _) in enumerate(frames) if cid == 0x200 + n]
        tx = [i for i, (cid, _) in enumerate(frames) if cid == 0x180 + n]
        if not tx or (rx and tx[-1] < rx[-1]):
            return False
    return True


def _count(frames, cid) -> int:
    return sum(1 for c, _ in list(frames) if c == cid)


def _run(opts, during=None):
    tr, p = start_counts()
    tg = prepare(M, p, tr, DT, None)
    c0 = counts_of(tg.q[0], p)
    be = hal.create("canopen", M, DT, opts)
    be.open(c0)
    extra = during(be) if during else None
    if isinstance(extra, Listener):
        # the listener is on the wire once it hears the drives' heartbeats (an offline loop runs
        # its ticks back to back: started before it listens, the first part of the job is unseen)
        t0 = time.monotonic()
        while not extra.frames and time.monotonic() - t0 < 10:
            time.sleep(0.005)
        assert extra.frames, "the listener heard nothing on the simulator's link"
        extra.syncs_before = be._syncs
    cfg = LoopConfig(rate_hz=1000, realtime=False, stall_timeout_s=5.0)
    lp = ControlLoop(M, be, p, tg, cfg, initial_state(M, c0), log=lambda m: None)
    try:
        res = lp.run()
        before = be.devsim.call("drives", "positions") if be.devsim.alive() else None
        if isinstance(extra, Listener):
            # the serial link runs behind the loop (python-can's slcan reads a byte per system call,
            # and a loaded host starves its thread): let the listener read every SYNC the loop sent
            # and every drive's answer to its last set-point before the simulator goes
            extra.syncs_sent = be._syncs - extra.syncs_before
            t0 = time.monotonic()
            while time.monotonic() - t0 < 30 and not (
                    _answered(extra.frames) and _count(extra.frames, C.COB_SYNC) >= extra.syncs_sent):
                time.sleep(0.01)
    finally:
        be.close()
        if extra is not None:
            extra.close()
    return res, be, c0, before, extra


def test_job_through_drives_in_another_process_ends_where_commanded_and_the_wire_shows_it():
    res, be, c0, before, lst = _run(DEVSIM, lambda be: slcan_listener(be.devsim.links[0]))
    assert res.status == "done", res.reason
    assert np.array_equal(c0 + res.pulses_sent, res.state.counts)
    # the drives' own positions, asked across the process boundary at the end of the loop, within
    # the last CAN cycle's motion of the counters; after close they are the counters
    assert np.abs(np.array(before) - res.state.counts).max() <= 5
    assert np.array_equal(be.positions(), res.state.counts)
    assert not be.devsim.alive()                           # stopped on close
    f = lst.frames
    syncs = [i for i, (cid, d) in enumerate(f) if cid == C.COB_SYNC]
    # every SYNC the loop sent crossed the wire, one per CAN cycle (2 ticks), and none has data
    assert lst.syncs_sent >= res.ticks // 2 - 2, (res.ticks, lst.syncs_sent)
    assert len(syncs) >= lst.syncs_sent, (len(syncs), lst.syncs_sent)
    assert all(f[i][1] == b"" for i in syncs)
    tpdo = [(cid, d) for cid, d in f if 0x181 <= cid <= 0x185]
    assert {cid for cid, _ in tpdo} == {0x181, 0x182, 0x183, 0x184, 0x185}
    assert all(len(d) == 7 for _, d in tpdo)                 # position, statusword, 0x60FD low byte
    last = {}
    for cid, d in f:
        if 0x201 <= cid <= 0x205:
            pos, cw = np.frombuffer(d[:4], "<i4")[0], int.from_bytes(d[4:6], "little")
            if cw == C.CW_ENABLE_OPERATION:
                last[cid - 0x200] = int(pos)
    assert [last[n] for n in (1, 2, 3, 4, 5)] == res.state.counts.tolist()
    # the last TPDOs on the wire: every drive's position actual = its final counter
    act = {cid - 0x180: int(np.frombuffer(d[:4], "<i4")[0]) for cid, d in tpdo}
    assert [act[n] for n in (1, 2, 3, 4, 5)] == res.state.counts.tolist()
    # the host's heartbeat, operational
    assert (0x77F, bytes([5])) in f


def test_emcy_injected_across_the_process_boundary_stops_with_node_and_code():
    def inject(be):
        be.devsim.call("drive:2", "emcy", 0x4210, at_sync=40)
    res, be, c0, end, _ = _run(DEVSIM, inject)
    assert res.status == "fault"
    assert "node 2 (L2): EMCY 0x4210 (temperature)" in res.reason
    assert np.array_equal(c0 + res.pulses_sent, res.state.counts)


def test_simulator_killed_mid_job_is_a_controlled_stop_that_says_so():
    tr, p = start_counts()
    tg = prepare(M, p, tr, DT, None)
    c0 = counts_of(tg.q[0], p)
    be = hal.create("canopen", M, DT, {**DEVSIM, "sim_listen_links": 0})
    be.open(c0)

    def hook(lp, k, st):
        if k == 300:
            be.devsim.kill()
        return st
    cfg = LoopConfig(rate_hz=1000, realtime=False, stall_timeout_s=5.0)
    lp = ControlLoop(M, be, p, tg, cfg, initial_state(M, c0), log=lambda m: None)
    lp.hook = hook
    try:
        res = lp.run()
    finally:
        be.close()
    assert res.status == "fault"
    assert "canopen" in res.reason and "device simulator" in res.reason and "exited" in res.reason
    assert np.array_equal(c0 + res.pulses_sent, res.state.counts)


def test_a_listener_that_stalls_loses_no_frame_and_gets_them_in_order():
    """A reader of a pty link that does not read for 0.6 s while 3000 frames (about 75 kB, far past
    the pty's 4 kB) cross the wire gets every one, in order, once it reads again. CI saw a listener
    thread stall on a loaded host and its link given up after 0.2 s: the wire showed 224 of 305
    cycles."""
    import os
    import select

    from pmctl.hal.devsim import Hub
    from pmctl.hal.slcan_link import raw
    hub = Hub(n_pty=1, tcp=False).start()
    fd = os.open(hub.paths[0], os.O_RDWR | os.O_NOCTTY)
    try:
        raw(fd)
        lines = [b"t%03X8%016X\r" % (0x181 + k % 5, k) for k in range(3000)]
        for ln in lines:
            hub.broadcast(ln)                  # as a frame from another link or a local drive
        time.sleep(0.6)
        want = b"".join(lines)
        got = b""
        t0 = time.monotonic()
        while len(got) < len(want) and time.monotonic() - t0 < 10:
            if select.select([fd], [], [], 0.2)[0]:
                got += os.read(fd, 65536)
        assert got == want
        assert hub.dropped_links == set()
    finally:
        os.close(fd)
        hub.stop()
