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
from pmctl.hal.modbus_vfd import SpindleSession, SpindleVFD, VfdOptions, job_speed, simulated
from pmctl.motion.loop import ControlLoop, prepare
from pmctl.motion.nc import NCParams, counts_of, initial_state
from pmctl.motion.service_config import LoopConfig, service_from_dict

from test_loop import line_traj, rp

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


def test_job_speed():
    assert job_speed([0, 0, 8000, 8000, 0]) == 8000
    assert job_speed([0, -6000, -6000]) == -6000
    assert job_speed([0, 0]) == 0
    with pytest.raises(HalError):
        job_speed([0, 8000, 6000])


def _spindle_run(inject):
    """A 6 s line on the sim backend with the spindle watched as pmctl run does; ``inject(dev, srv)``
    once the loop is under way."""
    dt = 1e-3
    tr = line_traj([-30, -20, 0], [30, 20, 5], rp(0, 0), rp(2, -1), 10.0, dt)
    p = NCParams.from_machine(M, dt, kv=400.0)
    tg = prepare(M, p, tr, dt, None)
    c0 = counts_of(tg.q[0], p)
    be = hal.create("sim", M, dt, {})
    be.open(c0)
    sp = SpindleSession(VfdOptions.from_dict({"simulate": True, "port": 0, "poll_ms": 10.0,
                                              "sim_ramp_rpm_per_s": 40000.0}), log=lambda m: None).connect()
    sp.start(8000)
    lp = ControlLoop(M, be, p, tg, LoopConfig(rate_hz=1000, realtime=False, stall_timeout_s=5.0),
                     initial_state(M, c0), log=lambda m: None)
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
    r = subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", "run", "--backend", "canopen", "--job", str(job),
                        "--record", str(rec), "--no-realtime", "--state", "", "--quiet"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "spindle M4 S6000: at speed" in r.stderr
    meta = json.loads((rec / "recording.json").read_text())
    assert "spindle_rpm" in meta["channels"]
    d = np.genfromtxt(rec / "data.csv", delimiter=",", names=True)
    assert np.all(np.abs(d["spindle_rpm"] + 6000) <= 0.02 * 6000)       # M4: negative, at speed all along
    for a in ("L1", "L2", "L3", "X", "Y"):
        assert abs(d[f"enc_{a}"][-1] - d[f"cmd_{a}"][-1]) <= 1.0 / 2000 + 1e-9
