"""CANopen CiA 402 backend against simulated drives on a python-can virtual bus (the real canopen
stack on both sides), with a plain python-can listener on the same wire checking the frames:
jobs through the control loop, each injected fault ending in a controlled stop with its reason,
re-enabling through fault reset, bus-load arithmetic and config refusals."""

import itertools
import struct
import threading
import time

import can
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pmctl import hal
from pmctl.core.config import load_machine
from pmctl.core.errors import ConfigError
from pmctl.hal import HalError
from pmctl.hal import cia402 as C
from pmctl.hal.canopen_csp import CanopenCSP, CanopenOptions
from pmctl.hal.cia402_sim import SimDriveSet
from pmctl.motion.loop import ControlLoop, prepare
from pmctl.motion.nc import NCParams, counts_of, initial_state
from pmctl.motion.service_config import LoopConfig, load_service_config

from test_loop import line_traj, rp

M = load_machine()
DT = 1e-3
_chan = itertools.count()

# generous timeouts: the suite runs on a loaded 2-core host (no timing is asserted here)
FAST = {"heartbeat_ms": 20, "heartbeat_timeout_ms": 1000, "host_heartbeat_ms": 10, "host_timeout_ms": 1500,
        "read_timeout_ms": 200.0, "sdo_timeout_ms": 500.0, "bus_thread_priority": 0, "late_cycles": 0}


def channel():
    return f"pmctl-test-{next(_chan)}"


class Listener:
    """A plain python-can bus recording every frame: on the same virtual channel, or ``bus``."""

    def __init__(self, ch, bus=None):
        self.bus = bus or can.Bus(interface="virtual", channel=ch)
        self.frames = []
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self):
        while not self._stop.is_set():
            try:
                m = self.bus.recv(0.05)
            except can.CanOperationError:      # the other side closed the link
                return
            if m is not None:
                self.frames.append((m.arbitration_id, bytes(m.data)))

    def close(self):
        self._stop.set()
        self._t.join()
        try:
            self.bus.shutdown()
        except can.CanError:                   # a link whose other side is gone
            pass


def start_counts():
    tr = line_traj([0, 0, 0], [4, 3, 2], rp(0, 0), rp(2, -1), 10.0, DT)
    p = NCParams.from_machine(M, DT, kv=400.0)
    return tr, p


def run_job(opts, tr=None, sims=None, traj_len=None):
    """A short tilted line through the loop on the canopen backend; returns (res, backend, c0)."""
    tr0, p = start_counts()
    tr = tr or tr0
    tg = prepare(M, p, tr, DT, None)
    c0 = counts_of(tg.q[0], p)
    be = hal.create("canopen", M, DT, opts)
    be.open(c0)
    if sims is not None:
        sims(be)
    cfg = LoopConfig(rate_hz=1000, realtime=False, stall_timeout_s=5.0)
    lp = ControlLoop(M, be, p, tg, cfg, initial_state(M, c0), log=lambda m: None)
    try:
        res = lp.run()
    finally:
        be.close()
    return res, be, c0


# ---------------------------------------------------------------- pure: bits and load

@settings(max_examples=60, deadline=None)
@given(st.integers(0, 0x7FF), st.binary(min_size=0, max_size=8))
def test_stuffed_frame_has_no_six_equal_bits_and_destuffs_to_the_frame(cid, data):
    bits, sent = C.frame_bitstream(cid, data)
    assert len(bits) == 34 + 8 * len(data)        # SOF .. CRC
    runs = [len(list(g)) for _, g in itertools.groupby(sent)]
    assert max(runs) <= 5
    # the receiver drops the bit after every five equal bits and gets the frame back
    out, run_bit, run, skip = [], None, 0, False
    for b in sent:
        if skip:
            assert b != run_bit
            skip, run_bit, run = False, b, 1
            continue
        out.append(b)
        run = run + 1 if b == run_bit else 1
        run_bit = b
        if run == 5:
            skip = True
    assert out == bits
    n = C.frame_bits_stuffed(cid, data)
    assert 47 + 8 * len(data) <= n <= 47 + 8 * len(data) + (34 + 8 * len(data) - 1) // 4


def test_crc15_of_a_known_frame_is_its_remainder():
    # appending the CRC to the bits makes the whole sequence divisible by the generator (remainder 0)
    bits, _ = C.frame_bitstream(0x181, b"\x01\x02\x03\x04\x37\x06")
    assert C._crc15(bits) == 0


def test_bus_load_of_the_shipped_config_and_the_1ms_refusal():
    svc = load_service_config()
    o = CanopenOptions.from_dict(svc.backend_tables["canopen"])
    bl = o.bus_load()
    # 5 drives: SYNC 47 + 5 x RPDO 95 (6 bytes) + 5 x TPDO 103 (7 bytes: position, statusword, the low
    # byte of the digital inputs 0x60FD with the home switch) = 1037 bits, x1.2 = 1244 bits per 2 ms
    # cycle at 1 Mbit/s
    assert bl.bits_per_cycle == 1037
    assert abs(bl.load - (1037 * 1.2 / 2e-3 + bl.heartbeat_bits_per_s) / 1e6) < 1e-12
    assert 0.62 < bl.load < 0.65 < 0.70
    with pytest.raises(ConfigError) as e:
        CanopenOptions.from_dict({**svc.backend_tables["canopen"], "cycle_ms": 1.0})
    msg = str(e.value)
    assert "cycle_ms" in msg and "1037 bits" in msg and "70 %" in msg and "125." in msg


@pytest.mark.parametrize("table,key", [
    ({"node_ids": [1, 2, 3, 4]}, "node_ids"), ({"node_ids": [1, 2, 3, 4, 4]}, "node_ids"),
    ({"node_ids": [1, 2, 3, 4, 200]}, "node_ids"), ({"bitrate": 900_000}, "bitrate"),
    ({"interface": "udp_multicast"}, "interface"), ({"heartbeat_timeout_ms": 10}, "heartbeat_timeout_ms"),
    ({"cycle_ms": 0}, "cycle_ms"), ({"cycl_ms": 2}, "cycl_ms"), ({"simulate": "yes"}, "simulate"),
    ({"host_node_id": 3}, "host_node_id"), ({"increments_per_mm": [1, 2]}, "increments_per_mm"),
])
def test_bad_options_name_the_key(table, key):
    with pytest.raises(ConfigError) as e:
        CanopenCSP.validate_options(table, "service.toml: hal.canopen")
    assert key in str(e.value)


def test_cycle_must_be_a_whole_number_of_ticks():
    with pytest.raises(ConfigError) as e:
        hal.create("canopen", M, 1 / 1200, {"cycle_ms": 2.0})     # 2.4 ticks
    assert "whole multiple" in str(e.value)
    assert hal.create("canopen", M, 1e-3, {"cycle_ms": 3.0}).cycle_ticks == 3


def test_state_machine_transitions():
    s = C.SWITCH_ON_DISABLED
    s = C.next_state(s, C.CW_SHUTDOWN, 0)
    assert s == C.READY_TO_SWITCH_ON
    s = C.next_state(s, C.CW_SWITCH_ON, C.CW_SHUTDOWN)
    assert s == C.SWITCHED_ON
    s = C.next_state(s, C.CW_ENABLE_OPERATION, C.CW_SWITCH_ON)
    assert s == C.OPERATION_ENABLED
    assert C.next_state(s, C.CW_QUICK_STOP, C.CW_ENABLE_OPERATION) == C.QUICK_STOP_ACTIVE
    # a fault leaves only by the rising edge of bit 7
    assert C.next_state(C.FAULT, C.CW_ENABLE_OPERATION, 0) == C.FAULT
    assert C.next_state(C.FAULT, C.CW_FAULT_RESET, C.CW_FAULT_RESET) == C.FAULT
    assert C.next_state(C.FAULT, C.CW_FAULT_RESET, 0) == C.SWITCH_ON_DISABLED
    for st_, sw in C.STATUSWORD_OF.items():
        assert C.state_of(sw) == st_


# ---------------------------------------------------------------- HIL: jobs and frames

def test_job_through_canopen_drives_ends_where_commanded_and_the_wire_shows_the_protocol():
    ch = channel()
    lis = Listener(ch)
    try:
        res, be, c0 = run_job({**FAST, "channel": ch, "simulate": True})
    finally:
        time.sleep(0.05)
        lis.close()
    assert res.status == "done", res.reason
    assert np.array_equal(c0 + res.pulses_sent, res.state.counts)
    # drive position actual (increments = pulses here) = the controller's commanded position
    assert np.array_equal(be.positions(), res.state.counts)
    assert np.array_equal(be.sim.positions(), res.state.counts)
    assert res.state.counts[0] != c0[0]                # it moved
    f = lis.frames
    ids = (1, 2, 3, 4, 5)
    # NMT: all pre-operational, then start per node
    assert (0x000, bytes([0x80, 0])) in f
    for n in ids:
        assert (0x000, bytes([0x01, n])) in f
        assert (0x700 + n, bytes([0])) in f            # boot-up of the simulated drive
        assert (0x700 + n, bytes([0x05])) in f         # heartbeat: operational
    # SDO expedited downloads of the interpolation period 0x60C2:01 = 2 (ms) and :02 = -3, mode 8
    for n in ids:
        assert (0x600 + n, bytes([0x2F, 0xC2, 0x60, 0x01, 2, 0, 0, 0])) in f
        assert (0x600 + n, bytes([0x2F, 0xC2, 0x60, 0x02, 0xFD, 0, 0, 0])) in f
        assert (0x600 + n, bytes([0x2F, 0x60, 0x60, 0x00, 8, 0, 0, 0])) in f
        # RPDO1 map entry 1 = 0x607A:00, 32 bit; TPDO1 map entry 1 = 0x6064:00, 32 bit
        assert (0x600 + n, bytes([0x23, 0x00, 0x16, 0x01]) + struct.pack("<I", 0x607A0020)) in f
        assert (0x600 + n, bytes([0x23, 0x00, 0x1A, 0x01]) + struct.pack("<I", 0x60640020)) in f
        # TPDO1 map entry 3 = 0x60FD:00 (digital inputs), its low 8 bits: the home switch is bit 2
        assert (0x600 + n, bytes([0x23, 0x00, 0x1A, 0x03]) + struct.pack("<I", 0x60FD0008)) in f
    syncs = [i for i, (cid, d) in enumerate(f) if cid == 0x080]
    assert all(f[i][1] == b"" for i in syncs)
    assert len(syncs) >= res.ticks // 2
    # a cycle in operation: 5 RPDOs then SYNC then 5 TPDOs with the drives enabled
    k = syncs[len(syncs) // 2]
    rpdos = [(cid, d) for cid, d in f[syncs[len(syncs) // 2 - 1] + 1:k] if 0x201 <= cid <= 0x205]
    assert sorted(c for c, _ in rpdos) == [0x201, 0x202, 0x203, 0x204, 0x205]
    for cid, d in rpdos:
        assert len(d) == 6 and struct.unpack("<iH", d)[1] == C.CW_ENABLE_OPERATION
    tpdos = [(cid, d) for cid, d in f[k + 1:syncs[len(syncs) // 2 + 1]] if 0x181 <= cid <= 0x185]
    assert sorted(c for c, _ in tpdos) == [0x181, 0x182, 0x183, 0x184, 0x185]
    for cid, d in tpdos:
        pos, sw, din = struct.unpack("<iHB", d)
        assert C.state_of(sw) == C.OPERATION_ENABLED and din == 0       # no home switch configured
    # the last RPDO targets on the wire are the final commanded counters
    last = {}
    for cid, d in f:
        if 0x201 <= cid <= 0x205:
            pos, cw = struct.unpack("<iH", d)
            if cw == C.CW_ENABLE_OPERATION:
                last[cid - 0x200] = pos
    assert [last[n] for n in ids] == res.state.counts.tolist()


def test_targets_are_converted_with_the_configured_resolution():
    ch = channel()
    lis = Listener(ch)
    try:
        res, be, c0 = run_job({**FAST, "channel": ch, "simulate": True, "increments_per_mm": 10000})
    finally:
        lis.close()
    assert res.status == "done", res.reason
    ppm = M.resolution.pulses_per_mm
    np.testing.assert_array_equal(be.positions(), np.rint(res.state.counts / ppm * 10000).astype(int))


# ---------------------------------------------------------------- HIL: faults

def _fault_run(inject, tr=None, **extra):
    ch = channel()

    def sims(be):
        inject(be.sim.by_id)
    res, be, c0 = run_job({**FAST, "channel": ch, "simulate": True, **extra}, tr=tr, sims=sims)
    assert res.status == "fault"
    assert res.reason.startswith("backend fault: canopen node")
    # nothing lost: the counters are what was sent, and the drives hold (quick stop or fault)
    assert np.array_equal(c0 + res.pulses_sent, res.state.counts)
    states = [d.state for d in be.sim.drives]
    assert all(s in (C.QUICK_STOP_ACTIVE, C.FAULT, C.SWITCH_ON_DISABLED) for s in states), states
    return res, be


def test_emcy_stops_with_node_and_code():
    res, be = _fault_run(lambda d: d[2].at_sync(40, lambda: d[2].emcy(0x4210)))
    assert "node 2 (L2): EMCY 0x4210 (temperature)" in res.reason


def test_statusword_fault_without_emcy_stops_with_the_error_code():
    res, be = _fault_run(lambda d: d[4].at_sync(40, lambda: d[4].fault(0x7500, emcy=False)))
    assert "node 4 (X): statusword 0x0218: Fault" in res.reason
    assert "0x7500" in res.reason


def test_drive_following_error_bit_stops():
    res, be = _fault_run(lambda d: d[1].at_sync(40, d[1].following_error))
    assert "node 1 (L1)" in res.reason
    assert "following error" in res.reason.lower() or "0x8611" in res.reason


def test_dropped_tpdo_is_older_than_its_cycle():
    res, be = _fault_run(lambda d: d[5].at_sync(40, lambda: d[5].drop_tpdos(1)), read_timeout_ms=30.0)
    assert "node 5 (Y): TPDO1 0x185 older than its cycle" in res.reason


def test_dropped_tpdo_with_late_answers_allowed_is_a_lost_frame():
    # up to 4 answers may be late, yet one lost outright is seen at once: the others answer the next SYNC
    res, be = _fault_run(lambda d: d[3].at_sync(40, lambda: d[3].drop_tpdos(1)), late_cycles=4)
    assert "node 3 (L3): TPDO1 0x183 older than its cycle: no answer to SYNC" in res.reason
    assert "(frame lost)" in res.reason


def test_late_answers_allowed_job_still_ends_where_commanded():
    res, be, c0 = run_job({**FAST, "channel": channel(), "simulate": True, "late_cycles": 8})
    assert res.status == "done", res.reason
    assert np.array_equal(be.sim.positions(), res.state.counts)


def test_lost_heartbeat_stops():
    # the drive keeps answering PDOs; only its heartbeat goes (a 12 s job: the timeout comes first)
    tr = line_traj([-30, -20, 0], [30, 20, 5], rp(0, 0), rp(2, -1), 10.0, DT)
    res, be = _fault_run(lambda d: d[3].at_sync(5, d[3].silence_heartbeat), tr=tr, read_timeout_ms=30.0,
                         heartbeat_timeout_ms=150)
    assert "node 3 (L3): heartbeat lost" in res.reason


def _drives_at_start():
    """Five simulated drives on a fresh virtual bus, at the start of the test job: (bus channel, NC
    parameters, the job's targets, start counters, the drives)."""
    ch = channel()
    tr, p = start_counts()
    tg = prepare(M, p, tr, DT, None)
    c0 = counts_of(tg.q[0], p)
    return ch, p, tg, c0, SimDriveSet((1, 2, 3, 4, 5), c0.tolist(), channel=ch, lag_s=1e-3)


def test_cut_off_drive_stops_the_others_and_then_itself():
    ch, p, tg, c0, sims = _drives_at_start()
    try:
        be = hal.create("canopen", M, DT, {**FAST, "channel": ch, "read_timeout_ms": 30.0})
        be.open(c0)
        sims.by_id[2].at_sync(30, sims.by_id[2].go_silent)
        cfg = LoopConfig(rate_hz=1000, realtime=False, stall_timeout_s=5.0)
        res = ControlLoop(M, be, p, tg, cfg, initial_state(M, c0), log=lambda m: None).run()
        be.close()
        assert res.status == "fault"
        assert "node 2 (L2)" in res.reason
        assert "older than its cycle" in res.reason or "heartbeat lost" in res.reason
        assert np.array_equal(c0 + res.pulses_sent, res.state.counts)
        assert all(d.state != C.OPERATION_ENABLED for d in sims.drives if d.id != 2)
        # the cut-off drive hears no host heartbeat and faults by itself
        t_end = time.monotonic() + 5.0
        while time.monotonic() < t_end and sims.by_id[2].state != C.FAULT:
            time.sleep(0.02)
        assert sims.by_id[2].state == C.FAULT and sims.by_id[2].error_code == C.EMCY_HEARTBEAT
    finally:
        sims.stop()


def test_drives_fault_by_themselves_when_the_host_stops_and_reenable_through_fault_reset():
    ch, p, tg, c0, sims = _drives_at_start()
    try:
        opts = {**FAST, "channel": ch, "simulate": False}
        be = hal.create("canopen", M, DT, opts)
        be.open(c0)
        be.read()
        be.write_positions(c0 / p.pulses_per_mm)        # the ticks carry the host heartbeat now ...
        t_end = time.monotonic() + 5.0                  # ... and then they stop (a hung host)
        while time.monotonic() < t_end and not all(d.state == C.FAULT for d in sims.drives):
            time.sleep(0.02)
        assert all(d.state == C.FAULT for d in sims.drives)
        assert all(d.error_code == C.EMCY_HEARTBEAT for d in sims.drives)
        while time.monotonic() < t_end and be.status().ok:     # the EMCY frames follow the state change
            time.sleep(0.02)
        with pytest.raises(HalError) as e:
            be.read()
        assert "EMCY 0x8130" in str(e.value)
        be.close()
        assert all(d.fault_resets == 0 for d in sims.drives)
        # a new start goes through fault reset and runs a job
        be2 = hal.create("canopen", M, DT, opts)
        be2.open(c0)
        assert all(d.fault_resets == 1 for d in sims.drives)
        assert all(d.state == C.OPERATION_ENABLED for d in sims.drives)
        cfg = LoopConfig(rate_hz=1000, realtime=False, stall_timeout_s=5.0)
        res = ControlLoop(M, be2, p, tg, cfg, initial_state(M, c0), log=lambda m: None).run()
        be2.close()
        assert res.status == "done", res.reason
        assert sims.positions() == res.state.counts.tolist()
    finally:
        sims.stop()


def test_missing_drive_is_refused_before_anything_is_written():
    ch = channel()
    lis = Listener(ch)
    sims = SimDriveSet((1, 2, 3, 4), [0, 0, 0, 0], channel=ch)      # node 5 absent
    try:
        be = hal.create("canopen", M, DT, {**FAST, "channel": ch, "sdo_timeout_ms": 100.0})
        with pytest.raises(HalError) as e:
            be.open(np.zeros(5, np.int64))
        assert "node 5 (Y): SDO read 0x1000" in str(e.value)
    finally:
        sims.stop()
        time.sleep(0.05)
        lis.close()
    # no SDO download (command specifier 001) went to any node, and no NMT start
    assert not [d for cid, d in lis.frames if 0x601 <= cid <= 0x67F and d and d[0] >> 5 == 1]
    assert not [d for cid, d in lis.frames if cid == 0 and d[0] == 0x01]


def test_a_refused_configuration_leaves_every_drive_disabled_and_preoperational():
    ch = channel()
    sims = SimDriveSet((1, 2, 3, 4, 5), [0] * 5, channel=ch)
    d3 = sims.by_id[3]
    orig = d3._on_write

    def refuse_csp(index, subindex, od, data):
        if index == C.OD_MODE:
            raise __import__("canopen").SdoAbortedError(0x06090030)
        return orig(index, subindex, od, data)
    d3.node._write_callbacks[d3.node._write_callbacks.index(orig)] = refuse_csp
    try:
        be = hal.create("canopen", M, DT, {**FAST, "channel": ch})
        with pytest.raises(HalError) as e:
            be.open(np.zeros(5, np.int64))
        assert "node 3 (L3): SDO write 0x6060" in str(e.value)
        time.sleep(0.05)
        assert all(d.state != C.OPERATION_ENABLED for d in sims.drives)
        assert all(d.node.nmt.state == "PRE-OPERATIONAL" for d in sims.drives)
    finally:
        sims.stop()


def test_drive_position_disagreeing_with_the_counters_is_refused():
    ch = channel()
    sims = SimDriveSet((1, 2, 3, 4, 5), [0, 0, 5000, 0, 0], channel=ch)
    try:
        be = hal.create("canopen", M, DT, {**FAST, "channel": ch})
        with pytest.raises(HalError) as e:
            be.open(np.zeros(5, np.int64))
        assert "node 3 (L3): drive at 2.5000 mm" in str(e.value) and "re-home" in str(e.value)
        assert all(d.state != C.OPERATION_ENABLED for d in sims.drives)
    finally:
        sims.stop()
