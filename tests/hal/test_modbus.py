"""Spindle VFD over Modbus TCP against the simulated VFD (a real pymodbus server on 127.0.0.1):
the register map checked with the pymodbus client and with a Modbus/TCP request built by hand on a
raw socket; at speed; a VFD fault and a lost link mid-job end in a controlled stop with the reason;
`pmctl run` with a spindle job records spindle_rpm."""

import json
import socket
import struct
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest

from pmctl import hal
from pmctl.core.config import load_machine
from pmctl.core.errors import ConfigError
from pmctl.hal import HalError
from pmctl.hal.modbus_vfd import SpindleSession, SpindleVFD, VfdOptions, job_speed, simulated, speed_changes, REST_STEP_MM
from pmctl.motion.loop import ControlLoop, prepare
from pmctl.motion.nc import NCParams, counts_of, initial_state
from pmctl.motion.service_config import LoopConfig, service_from_dict

from test_loop import line_traj, rp

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

M = load_machine()


@pytest.fixture
def vfd():
    o = VfdOptions.from_dict({"simulate": True, "port": 0, "sim_ramp_rpm_per_s": 40000.0})
    srv, dev = simulated(o)
    yield o, dev, srv
    srv.stop()


def mbap_request(port, unit, pdu, tid=7):
    """One Modbus/TCP transaction by hand: MBAP header (transaction, protocol 0, length, unit) + PDU."""
    with socket.create_connection(("127.0.0.1", port), timeout=2.0) as s:
        s.sendall(struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu)
        head = b""
        while len(head) < 7:
            head += s.recv(7 - len(head))
        t, proto, length, u = struct.unpack(">HHHB", head)
        body = b""
        while len(body) < length - 1:
            body += s.recv(length - 1 - len(body))
    assert (t, proto, u) == (tid, 0, unit)
    return body


def test_registers_by_hand_on_a_raw_socket(vfd):
    o, dev, srv = vfd
    # function 06: write single register 0x2000 = 5000 (half the maximum frequency); echo
    assert mbap_request(o.port, 1, struct.pack(">BHH", 6, 0x2000, 5000)) == struct.pack(">BHH", 6, 0x2000, 5000)
    assert dev.setpoint == 5000
    assert mbap_request(o.port, 1, struct.pack(">BHH", 6, 0x1000, 1)) == struct.pack(">BHH", 6, 0x1000, 1)
    assert dev.run == 1
    t_end = time.monotonic() + 5
    while time.monotonic() < t_end and dev.rpm < 12000:
        time.sleep(0.02)
    # function 03: read holding registers 0x3005 (rpm), 0x3000 (0.01 Hz), 0x5000 (fault)
    body = mbap_request(o.port, 1, struct.pack(">BHH", 3, 0x3005, 1))
    fc, nbytes, rpm = struct.unpack(">BBH", body)
    assert (fc, nbytes, rpm) == (3, 2, 12000)                # 5000/10000 of 400 Hz at 60 rpm/Hz
    fc, nbytes, f = struct.unpack(">BBH", mbap_request(o.port, 1, struct.pack(">BHH", 3, 0x3000, 1)))
    assert f == 20000                                         # 200.00 Hz
    assert mbap_request(o.port, 1, struct.pack(">BHH", 3, 0x5000, 1)) == struct.pack(">BBH", 3, 2, 0)
    # the register below is not in the map: exception 0x83, code 2 (illegal data address) -- no off-by-one
    assert mbap_request(o.port, 1, struct.pack(">BHH", 3, 0x3004, 1)) == bytes([0x83, 0x02])
    assert mbap_request(o.port, 1, struct.pack(">BHH", 6, 0x1000, 5)) == struct.pack(">BHH", 6, 0x1000, 5)
    assert dev.run == 0


def test_pymodbus_client_m3_m4_m5_and_at_speed(vfd):
    o, dev, srv = vfd
    v = SpindleVFD(o).connect()
    try:
        v.start(8000)
        assert dev.commands[-2:] == [(0x2000, 3333), (0x1000, 1)]
        got = v.wait_at_speed()
        assert abs(got - 8000) <= 0.02 * 8000
        v.start(-6000)                                     # M4: reverse, through zero
        assert dev.commands[-1] == (0x1000, 2)
        got = v.wait_at_speed()
        assert abs(got - 6000) <= 0.02 * 6000 and dev.direction == -1
        v.stop()
        assert dev.commands[-1] == (0x1000, 5)
        # S1 (LinuxCNC's samples say "spindle on" so) is below one set-point step (2.4 rpm): it commands 0,
        # and the spindle is at that speed, not waited for until the spin-up timeout
        v.start(1)
        assert dev.commands[-2] == (0x2000, 0) and abs(v.wait_at_speed()) <= 2.4
        v.stop()
        with pytest.raises(HalError) as e:
            v.start(30000)
        assert "exceeds" in str(e.value)
    finally:
        v.close()


def test_fault_and_link_loss_errors_name_device_and_register(vfd):
    o, dev, srv = vfd
    v = SpindleVFD(o).connect()
    dev.fault(11)
    with pytest.raises(HalError) as e:
        v.start(8000)
    assert f"spindle VFD 127.0.0.1:{o.port} (unit 1): fault code 11 in register 0x5000 (fault)" in str(e.value)
    srv.stop()
    with pytest.raises(HalError) as e:
        v.read_rpm()
    assert "register 0x3005 (speed, rpm): link lost" in str(e.value)
    v.close()


def test_config_errors_name_the_key():
    for table, key in (({"port": 0}, "port"), ({"registers": {"speed": 1}}, "registers.speed"),
                       ({"registers": {"fault": 0x1000}}, "registers"), ({"at_speed_tolerance": 2}, "at_speed_tolerance"),
                       ({"simulate": True, "host": "10.0.0.5"}, "host"), ({"rpm": 1}, "rpm")):
        with pytest.raises(ConfigError) as e:
            VfdOptions.from_dict(table, "service.toml: spindle")
        assert key in str(e.value)
    with pytest.raises(ConfigError):
        service_from_dict({"spindle": {"max_rpm": -1}})
    assert service_from_dict({"spindle": {"enabled": False}}).spindle is None


def test_job_speed_and_speed_changes():
    assert job_speed([0, 0, 8000, 8000, 0]) == 8000
    assert job_speed([0, -6000, -6000]) == -6000
    assert job_speed([0, 0]) == 0
    assert job_speed([0, 8000, 6000]) == 8000
    q = np.array([[0.0] * 5, [1.0] * 5, [1.0] * 5, [1.0] * 5, [1.0] * 5, [2.0] * 5, [3.0] * 5])
    # the change at sample 4 waits on the last sample of the old speed (3), at rest there (no joint
    # moves within two samples of it); the final M5 is no change
    assert speed_changes([8000, 8000, 8000, 8000, 6000, 6000, 0], q) == [(3, 6000.0, True)]
    assert speed_changes([8000] * 5 + [6000, 6000], q) == [(4, 6000.0, False)]
    assert speed_changes([0, 0, 8000, 8000, 8000, 8000], q) == []          # the start speed: no change
    assert speed_changes([8000, -8000, -8000, -8000], q, job_start=3) == [(3, -8000.0, True)]


def test_speed_change_mid_job_waits_on_the_path_until_at_speed(tmp_path):
    """S12000 and then M4 S9000 inside a job on the sim backend: the path stops at each change,
    the VFD gets the new speed, and no tick moves the target while the measured speed is off by
    more than 2 % from the speed of the move."""
    from pmctl.core.kinematics import ik
    from pmctl.task.planner import home_pose, load_job, plan
    job = tmp_path / "s.ngc"
    job.write_text(textwrap.dedent("""\
        G17 G21 G90 G94
        F600 S6000 M3
        G1 X2
        S12000
        G1 Y2
        M4 S9000
        G1 X0
        M5
        M2
        """))
    dt = 1e-3
    p = NCParams.from_machine(M, dt, kv=400.0)
    tip, axis = home_pose(M)
    c0 = counts_of(ik(tip, axis, M).q, p)
    st0 = initial_state(M, c0)
    traj = plan(load_job(job, M, start=(st0.tip, st0.axis)), M, dt, start=(st0.tip, st0.axis))
    tg = prepare(M, p, traj, dt, c0)
    be = hal.create("sim", M, dt, {})
    be.open(c0)
    sp = SpindleSession(VfdOptions.from_dict({"simulate": True, "port": 0, "poll_ms": 10.0,
                                              "sim_ramp_rpm_per_s": 40000.0}), log=lambda m: None).connect()
    try:
        sp.start(job_speed(traj.spindle_rpm))
        cfg = LoopConfig(rate_hz=1000, realtime=True, lock_memory=False, stall_timeout_s=5.0,
                         max_overruns_in_row=10**6)
        lp = ControlLoop(M, be, p, tg, cfg, st0, log=lambda m: None)
        ch = sp.follow(lp, tg, traj.spindle_rpm)
        sp.watch(lambda: lp.tick, lambda why: setattr(lp, "stop_request", why))
        res = lp.run()
        commands = sp.device.commands
    finally:
        sp.close()
    assert res.status == "done", res.reason
    assert [c[1] for c in ch.changes] == [12000.0, -9000.0] and all(c[2] for c in ch.changes)
    assert len(ch.held_ticks) == 2 and all(b > a for a, b in ch.held_ticks)
    # the VFD was told: set-point 12000 / 24000, then reverse at 9000
    assert [0x2000, 5000] in [list(c) for c in commands] and [0x1000, 2] in [list(c) for c in commands]
    rpm = sp.per_tick(res.ticks)
    k = np.arange(res.ticks)
    # the speed of the move a tick runs: that of the sample the target is heading for
    want = np.asarray(traj.spindle_rpm)[np.clip(np.ceil(res.path_s).astype(int) - tg.job_start, 0,
                                                len(traj.spindle_rpm) - 1)]
    # cutting: the target moves by more than the planned stop's creep (REST_STEP_MM a tick; the wait
    # may start up to LOOKAHEAD_SAMPLES short of the stop, and that last micrometre runs on release)
    moving = np.r_[np.linalg.norm(np.diff(res.target[:, :3], axis=0), axis=1) > REST_STEP_MM, False]
    # before the monitor's first poll the start speed was checked by the wait at speed
    first_poll = sp.monitor.samples[0][0]
    cut = moving & (want != 0) & (k >= max(tg.job_start, first_poll))
    assert cut.sum() > 500
    assert np.all(np.abs(rpm[cut] - want[cut]) <= 0.02 * np.abs(want[cut])), \
        np.flatnonzero(np.abs(rpm[cut] - want[cut]) > 0.02 * np.abs(want[cut]))[:5]
    # the recorded speed steps: 6000, then 12000, then -9000, each held while the path moves on it
    for level in (6000, 12000, -9000):
        assert np.any(cut & (np.abs(rpm - level) <= 0.02 * abs(level)))
    first = {lv: k[cut & (np.abs(rpm - lv) <= 0.02 * abs(lv))][0] for lv in (6000, 12000, -9000)}
    assert first[6000] < first[12000] < first[-9000]


def _paced_line_loop():
    """A 6 s line on the sim backend (open at the line's start) and its loop, paced in real time:
    back to back the compiled loop would finish the line before a device poll sees a fault.
    Returns (loop, backend, start counters)."""
    dt = 1e-3
    tr = line_traj([-30, -20, 0], [30, 20, 5], rp(0, 0), rp(2, -1), 10.0, dt)
    p = NCParams.from_machine(M, dt, kv=400.0)
    tg = prepare(M, p, tr, dt, None)
    c0 = counts_of(tg.q[0], p)
    be = hal.create("sim", M, dt, {})
    be.open(c0)
    cfg = LoopConfig(rate_hz=1000, realtime=True, lock_memory=False, stall_timeout_s=5.0, max_overruns_in_row=10**6)
    return ControlLoop(M, be, p, tg, cfg, initial_state(M, c0), log=lambda m: None), be, c0


def _spindle_run(inject, **extra):
    """A 6 s line on the sim backend with the spindle watched as pmctl run does; ``inject(dev, srv)``
    once the loop is under way."""
    lp, be, c0 = _paced_line_loop()
    sp = SpindleSession(VfdOptions.from_dict({"simulate": True, "port": 0, "poll_ms": 10.0,
                                              "sim_ramp_rpm_per_s": 40000.0, **extra}), log=lambda m: None).connect()
    sp.start(8000)
    sp.watch(lambda: lp.tick, lambda why: setattr(lp, "stop_request", why))

    def injector():
        while lp.tick < 500:
            time.sleep(0.001)
        inject(sp.device, sp.server)
    threading.Thread(target=injector, daemon=True).start()
    try:
        res = lp.run()
    finally:
        sp.close()
    return res, be, c0, sp


def test_vfd_fault_mid_job_is_a_controlled_stop():
    res, be, c0, sp = _spindle_run(lambda dev, srv: dev.fault(7))
    assert res.status == "stopped"                         # decelerated, not halted
    assert "spindle VFD" in res.reason and "fault code 7 in register 0x5000" in res.reason
    assert np.array_equal(c0 + res.pulses_sent, res.state.counts) and np.array_equal(be.counts, res.state.counts)
    assert res.ticks < len(res.target) + 10_000
    rpm = sp.per_tick(res.ticks)
    assert np.nanmax(rpm) >= 0.98 * 8000


def test_vfd_link_lost_mid_job_is_a_controlled_stop():
    res, be, c0, sp = _spindle_run(lambda dev, srv: srv.stop())
    assert res.status == "stopped"
    assert "spindle VFD" in res.reason and "link lost" in res.reason
    assert np.array_equal(c0 + res.pulses_sent, res.state.counts)


def test_vfd_over_rtu_fault_mid_job_is_a_controlled_stop():
    # Modbus RTU: the client on one end of a null modem (two ptys) of the device simulator, whose
    # RTU server is on the other end; the fault is injected into the simulator's VFD
    res, be, c0, sp = _spindle_run(lambda dev, srv: dev.fault(9), transport="rtu", serial_port="devsim",
                                   baud=115200)
    assert res.status == "stopped"
    assert "RTU 115200 N1 (unit 1): fault code 9 in register 0x5000" in res.reason
    assert np.array_equal(c0 + res.pulses_sent, res.state.counts)
    assert np.nanmax(sp.per_tick(res.ticks)) >= 0.98 * 8000


@pytest.mark.parametrize("table,key", [
    ({"transport": "can"}, "transport"), ({"transport": "rtu", "serial_port": "ttyUSB0"}, "serial_port"),
    ({"transport": "rtu", "serial_port": "/dev/ttyUSB0", "baud": 12345}, "baud"),
    ({"transport": "rtu", "serial_port": "/dev/ttyUSB0", "parity": "X"}, "parity"),
    ({"transport": "rtu", "serial_port": "/dev/ttyUSB0", "stop_bits": 3}, "stop_bits"),
    ({"transport": "rtu", "serial_port": "/dev/ttyUSB0", "device_id": 0}, "device_id"),
    ({"transport": "rtu", "simulate": True, "serial_port": "/dev/ttyUSB0"}, "serial_port"),
    ({"transport": "rtu", "simulate": True, "serial_port": "devsim", "parity": "E"}, "parity")])
def test_rtu_options_errors_name_the_field(table, key):
    with pytest.raises(ConfigError) as e:
        VfdOptions.from_dict(table, "service.toml: spindle")
    assert e.value.key == key and f"spindle: {key}: " in str(e.value)


def test_pmctl_run_canopen_with_a_spindle_job_records_spindle_rpm(tmp_path):
    job = tmp_path / "m4.ngc"
    job.write_text(textwrap.dedent("""\
        G17 G21 G90 G94
        F600 S6000 M4
        G0 X10 Y0 Z60
        G1 X4
        G1 Y3
        M5
        M2
        """))
    rec = tmp_path / "rec"
    # the shipped service config, except that a loaded CI host is no stall
    from pmctl.core.config import CONFIG_DIR
    svc = tmp_path / "service.toml"
    text = (CONFIG_DIR / "service.toml").read_text()
    assert "stall_timeout_ms = 50 " in text
    svc.write_text(text.replace("stall_timeout_ms = 50 ", "stall_timeout_ms = 5000 "))
    r = subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", "run", "--backend", "canopen", "--job", str(job),
                        "--record", str(rec), "--no-realtime", "--state", "", "--quiet", "--service", str(svc)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "spindle M4 S6000: at speed" in r.stderr
    meta = json.loads((rec / "recording.json").read_text())
    assert "spindle_rpm" in meta["channels"]
    d = np.genfromtxt(rec / "data.csv", delimiter=",", names=True)
    rpm = d["spindle_rpm"]
    cmd = np.column_stack([d[f"cmd_{a}"] for a in ("L1", "L2", "L3", "X", "Y")])
    moving = np.zeros(len(rpm), bool)
    moving[1:] = np.any(np.rint(np.diff(cmd, axis=0) * 2000) != 0, axis=1)
    assert moving.sum() > 100
    assert np.all(np.abs(rpm[moving] + 6000) <= 0.02 * 6000)      # M4: negative, at speed wherever a joint moves
    last_move = np.flatnonzero(moving)[-1]
    assert abs(rpm[-1]) < 60 and np.all(np.abs(rpm[last_move + 1:]) <= 6000 * 1.02)   # M5 before M2: stopped
    for a in ("L1", "L2", "L3", "X", "Y"):
        assert abs(d[f"enc_{a}"][-1] - d[f"cmd_{a}"][-1]) <= 1.0 / 2000 + 1e-9


# ---------------------------------------------------------------- strain DAQ

from pmctl.hal.modbus_daq import DaqOptions, DaqSession, StrainDAQ, chain_mode_hz, check_k_theta_source  # noqa: E402


@pytest.fixture
def daq():
    strain = [12.34, -5.67, 300.0]
    o = DaqOptions.from_dict({"simulate": True, "port": 0, "timeout_ms": 100.0, "poll_ms": 10.0,
                              "max_age_ms": 60.0, "sim_sample_hz": 200.0})
    ses = DaqSession(o, lambda: strain, log=lambda m: None).connect()
    yield ses, strain
    ses.close()


def test_daq_registers_by_hand_and_by_pymodbus(daq):
    ses, strain = daq
    # function 04: read input registers 0..3 -> three signed gauges in 0.01 ue, then the counter
    body = mbap_request(ses.opt.port, 1, struct.pack(">BHH", 4, 0x0000, 4))
    fc, nbytes, g1, g2, g3, n1 = struct.unpack(">BBhhhH", body)
    assert (fc, nbytes) == (4, 8) and (g1, g2, g3) == (1234, -567, 30000)
    time.sleep(0.05)
    n2 = struct.unpack(">BBhhhH", mbap_request(ses.opt.port, 1, struct.pack(">BHH", 4, 0x0000, 4)))[5]
    assert n2 != n1                                          # the DAQ samples on its own
    assert mbap_request(ses.opt.port, 1, struct.pack(">BHH", 4, 0x0004, 1)) == bytes([0x84, 0x02])
    t, n, s = ses.daq.poll()
    assert s == pytest.approx([12.34, -5.67, 300.0], abs=1e-9)


def test_daq_stale_data_and_timeout_name_device_and_register(daq):
    ses, strain = daq
    ses.device.freeze()
    with pytest.raises(HalError) as e:
        for _ in range(50):
            ses.daq.poll()
            time.sleep(0.01)
    assert f"strain DAQ 127.0.0.1:{ses.opt.port} (unit 1): stale data: input register 0x0003 (sample counter)" \
        in str(e.value)
    ses.device.frozen = False
    ses.device.delay_s = 0.3                                 # answers after the 100 ms timeout
    with pytest.raises(HalError) as e:
        ses.daq.poll()
    assert "input register 0x0000 (strain gauge 1)" in str(e.value)
    assert "timeout" in str(e.value)


class LateAnswerDAQ:
    """A DAQ model whose sample counter the test sets; it reads the counter, then answers
    ``delay_s`` later (a busy link or host: the sample is older than its arrival)."""

    def __init__(self):
        self.n, self.delay_s = 7, 0.0

    def read(self, addr):
        if not 0 <= addr <= 3:
            return None
        if addr < 3:
            return 0
        n = self.n
        time.sleep(self.delay_s)
        return n

    def write(self, addr, value):
        return False


def test_daq_a_late_answer_is_no_stale_data_but_a_stuck_counter_is():
    from pmctl.hal.modbus_sim import ModbusSimServer
    dev = LateAnswerDAQ()
    srv = ModbusSimServer(dev, port=0, input_registers=True).start()
    daq = StrainDAQ(DaqOptions.from_dict({"port": srv.port, "timeout_ms": 5000.0, "poll_ms": 10.0,
                                          "max_age_ms": 500.0})).connect()      # counter 7, at once
    try:
        # asked right after: the DAQ has not sampled again yet (7), its answer comes 1 s later,
        # within the timeout. Nothing says the counter stood still for 1 s: no stale data
        dev.delay_s = 1.0
        t, n, _ = daq.poll()
        assert n == 7
        # asked again (at once): 7 still, now read more than max_age after the first 7 arrived
        dev.delay_s = 0.0
        with pytest.raises(HalError) as e:
            daq.poll()
        assert "stale data" in str(e.value) and "(sample counter) stuck at 7 for" in str(e.value)
    finally:
        daq.close()
        srv.stop()


def test_k_theta_source_too_slow_for_the_chain_mode_is_refused():
    f = chain_mode_hz(M)
    assert 200 < f < 300                                     # 20 N/um, 25 kg / 3: 246 Hz
    slow = DaqOptions.from_dict({"port": 502, "k_theta_source": "daq", "poll_ms": 20.0})
    with pytest.raises(ConfigError) as e:
        check_k_theta_source(slow, (200.0,) * 3, M)
    assert "k_theta_source" in str(e.value) and "50 Hz" in str(e.value) and f"{f:.0f} Hz" in str(e.value)
    check_k_theta_source(slow, (0.0,) * 3, M)                # K_theta off: nothing to damp
    check_k_theta_source(DaqOptions.from_dict({"port": 502, "poll_ms": 20.0}), (200.0,) * 3, M)   # backend source
    fast = DaqOptions.from_dict({"port": 502, "k_theta_source": "daq", "poll_ms": 0.2, "max_age_ms": 1.0})
    check_k_theta_source(fast, (200.0,) * 3, M)              # 5 kHz > 2 x 246 Hz


def _daq_run(inject):
    """The paced 6 s line with the strain DAQ watched; ``inject(device)`` at tick 500."""
    lp, be, c0 = _paced_line_loop()
    ses = DaqSession(DaqOptions.from_dict({"simulate": True, "port": 0, "timeout_ms": 100.0, "poll_ms": 10.0,
                                           "max_age_ms": 60.0}), lambda: be._fb.strain.tolist(),
                     log=lambda m: None).connect()
    return run_with_daq(lp, ses, 500, inject), be, c0, ses


def run_with_daq(lp, ses, inject_at=None, inject=None):
    """Run the loop with the DAQ watched (a DAQ fault is a stop request), ``inject(device)`` at
    tick ``inject_at`` from another thread; the session is closed at the end."""
    ses.watch(lambda: lp.tick, lambda why: setattr(lp, "stop_request", why))
    if inject is not None:
        def injector():
            while lp.tick < inject_at and lp.mode == 0:
                time.sleep(0.001)
            inject(ses.device)
        threading.Thread(target=injector, daemon=True).start()
    try:
        return lp.run()
    finally:
        ses.close()


def test_daq_stale_mid_job_is_a_controlled_stop_and_samples_follow_the_plant():
    res, be, c0, ses = _daq_run(lambda dev: dev.freeze())
    assert res.status == "stopped" and "stale data" in res.reason and "strain DAQ" in res.reason
    assert np.array_equal(c0 + res.pulses_sent, res.state.counts)
    ds = ses.per_tick(res.ticks)
    k = [tk for tk, _, _ in ses.daq.samples]
    # a DAQ sample is the plant's gauge at about its tick (0.01 ue counts; the plant moves between)
    i = len(k) // 2
    assert np.all(np.isfinite(ds[k[i]:]))
    assert abs(ds[k[i], 0] - res.strain[k[i], 0]) < 5.0


def test_daq_timeout_mid_job_is_a_controlled_stop():
    def slow(dev):
        dev.delay_s = 0.3
    res, be, c0, ses = _daq_run(slow)
    assert res.status == "stopped" and "strain DAQ" in res.reason and "timeout" in res.reason
    assert np.array_equal(c0 + res.pulses_sent, res.state.counts)


def test_slow_deflection_is_the_static_chain_elongation_low_passed():
    from pmctl.hal.modbus_daq import SlowDeflection, chain_deflection_mm
    ue = np.array([100.0, -50.0, 0.0])
    d = chain_deflection_mm(ue, M)
    # tension = strain / gain; elongation = tension / axial stiffness
    np.testing.assert_allclose(d, ue / M.strain_gain / M.stiffness.chain_axial)
    f = SlowDeflection(M, tau_s=2.0)
    f.update(0.0, [0.0, 0.0, 0.0])
    for k in range(1, 201):                 # a strain step held for one time constant, 10 ms samples
        v = f.update(k * 0.01, ue)
    np.testing.assert_allclose(v, d * (1 - np.exp(-1.0)), rtol=1e-9)


def test_daq_session_keeps_the_slow_deflection_of_the_served_strain():
    ses = DaqSession(DaqOptions.from_dict({"simulate": True, "port": 0, "poll_ms": 10.0, "comp_tau_s": 0.05}),
                     lambda: (200.0, 100.0, -100.0), log=lambda m: None, machine=M).connect()
    try:
        ses.watch(lambda: 0, lambda why: None)
        t_end = time.monotonic() + 30.0
        while time.monotonic() < t_end and len(ses.daq.deflection) < 40:
            time.sleep(0.02)
    finally:
        ses.close()
    from pmctl.hal.modbus_daq import chain_deflection_mm
    want = chain_deflection_mm([200.0, 100.0, -100.0], M)
    np.testing.assert_allclose(ses.daq.deflection[-1][1], want, rtol=1e-3)
