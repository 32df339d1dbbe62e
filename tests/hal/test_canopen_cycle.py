"""The canopen backend's cycle on the wire, as a plain python-can listener and a raw slcan link
see it: per cycle the RPDO1 of each drive in node order (target position INTEGER32 + controlword
UNSIGNED16, little endian, 6 bytes), then the SYNC (no data), then, when due, the host's heartbeat;
and a batch of frames on an slcan link is byte for byte the lines of the frames sent one by one."""

import socket
import struct
import time

import can
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pmctl.hal import cia402 as C
from pmctl.hal.canopen_csp import CanopenCSP
from pmctl.hal.slcan_link import SlcanLinkBus, encode

from test_canopen import FAST, M, Listener, channel

DT = 1e-3


@pytest.mark.parametrize("link", ["virtual", "slcan"])
def test_each_cycle_is_the_rpdos_in_node_order_then_sync_then_the_heartbeat(link):
    """On the virtual bus (one send per frame) and on the device simulator's slcan link (a
    process of its own; the cycle written by the backend's cycle writer thread), heard by python-can's
    own slcan interface on a second link of the simulator."""
    ch = channel()
    lis = None
    if link == "virtual":
        lis = Listener(ch)
        opts = {**FAST, "channel": ch, "simulate": True}
    else:
        opts = {**FAST, "interface": "slcan", "channel": "devsim", "simulate": True, "sim_link": "tcp",
                "sim_listen_links": 1, "sim_rt_priority": 0}
    be = CanopenCSP(M, DT, {**opts, "host_heartbeat_ms": 5})
    ppm = M.resolution.pulses_per_mm
    c0 = np.rint(np.array([250.0, 250.0, 250.0, 0.0, 0.0]) * ppm).astype(np.int64)
    sent = []
    try:
        be.open(c0)
        if link == "slcan":
            lis = Listener(None, can.Bus(interface="slcan", channel=be.devsim.links[0], bitrate=1_000_000,
                                         sleep_after_open=0))
            time.sleep(0.2)
        n0 = len(lis.frames)
        for k in range(60):
            be.read()
            c = c0 + np.array([k, -k, 2 * k, 3, -(k // 3)])           # within the following window
            be.write_positions(c / ppm)
            if k % be.cycle_ticks == 0:
                sent.append(c.tolist())
            time.sleep(DT)
        if link == "slcan":
            assert be._writer is not None                   # the loop's cycles went through the writer
            # the simulator relays the wire to the listener's link with a delay; closing the backend
            # stops it, and what it has not relayed yet is lost (CI under load heard the last cycle
            # cut after its first RPDO): wait until the last cycle's SYNC has come through
            last = [(C.cob_rpdo1(n), struct.pack("<iH", t, C.CW_ENABLE_OPERATION))
                    for n, t in zip(be.opt.node_ids, sent[-1])] + [(C.COB_SYNC, b"")]
            t0 = time.time()
            while time.time() - t0 < 10.0:
                fr = [f for f in lis.frames[n0:] if f[0] != C.cob_heartbeat(127)]
                if any(fr[i:i + len(last)] == last for i in range(len(fr) - len(last) + 1)):
                    break
                time.sleep(0.01)
    finally:
        be.close()
        time.sleep(0.05)
        if lis is not None:
            lis.close()
    host = [(cid, d) for cid, d in lis.frames[n0:]
            if 0x201 <= cid <= 0x205 or cid in (C.COB_SYNC, C.cob_heartbeat(127))]
    ids = list(be.opt.node_ids)
    opening = [(C.cob_rpdo1(n), struct.pack("<iH", t, C.CW_ENABLE_OPERATION)) for n, t in zip(ids, c0.tolist())]
    while host and (host[0][0] == C.cob_heartbeat(127) or host[:5] == opening):
        # the start-up timer's heartbeats, and a cycle it sent at the opening positions (seen after
        # n0 on a loaded machine), until the first tick takes over
        host = host[1:] if host[0][0] == C.cob_heartbeat(127) else host[6 if host[5:6] == [(C.COB_SYNC, b"")] else 5:]
    i = cyc = 0
    beats = 0
    while cyc < len(sent):
        rpdos, i = host[i:i + 5], i + 5
        assert [cid for cid, _ in rpdos] == [C.cob_rpdo1(n) for n in ids], rpdos
        assert [d for _, d in rpdos] == [struct.pack("<iH", t, C.CW_ENABLE_OPERATION) for t in sent[cyc]]
        assert host[i] == (C.COB_SYNC, b"")
        i += 1
        if i < len(host) and host[i][0] == C.cob_heartbeat(127):
            assert host[i][1] == bytes([5])                 # operational
            beats += 1
            i += 1
        cyc += 1
    assert beats >= 5                                       # 5 ms heartbeat over a 60 ms run


FRAMES = st.lists(st.builds(
    lambda cid, ext, data, rtr: can.Message(arbitration_id=cid if ext else cid & 0x7FF, is_extended_id=ext,
                                            is_remote_frame=rtr, data=b"" if rtr else data,
                                            dlc=len(data) if rtr else None),
    st.integers(0, 0x1FFFFFFF), st.booleans(), st.binary(max_size=8), st.booleans()), min_size=1, max_size=12)


def _read(conn, n):
    got = b""
    while len(got) < n:
        chunk = conn.recv(65536)
        assert chunk, "link closed"
        got += chunk
    return got


@settings(max_examples=40, deadline=None)
@given(FRAMES)
def test_a_batch_on_an_slcan_link_is_the_lines_of_its_frames_in_order(msgs):
    srv = socket.create_server(("127.0.0.1", 0))
    try:
        bus = SlcanLinkBus(f"socket://127.0.0.1:{srv.getsockname()[1]}")
        conn, _ = srv.accept()
        try:
            assert _read(conn, 5) == b"S8\rO\r"
            one_by_one = b"".join(encode(m) for m in msgs)
            bus.send_batch(msgs)
            assert _read(conn, len(one_by_one)) == one_by_one
            for m in msgs:
                bus.send(m)
            assert _read(conn, len(one_by_one)) == one_by_one
        finally:
            bus.shutdown()
            conn.close()
    finally:
        srv.close()
