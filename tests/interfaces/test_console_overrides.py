"""Overrides on the grbl console of `pmctl serve`, over a real pty, judged by the motion itself:
the rapid override bytes (0x95 100 %, 0x96 50 %, 0x97 25 %) scale the G0 speed in the session
recording and leave G1 alone, the feed override bytes leave G0 alone, and `Ov:` reports them; the
spindle override bytes (0x99-0x9D) and the control socket's spindle override set the frequency
set-point of a Modbus VFD (a simulated one, a pymodbus server run by the test) to the programmed S
times the override, within the VFD's maximum, and never start a stopped spindle."""

import time

import numpy as np

from grbl_sender import Sender, start_serve, stop_serve
from pmctl.core import kinematics as K
from pmctl.core.recording import read_recording
from pmctl.interfaces.commands.ctl import request
from pmctl.task.planner import PlannerLimits
import pytest

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

RAPID = PlannerLimits().rapid_mm_s          # the G0 tool-tip speed at 100 %, mm/s
JOINTS = ("L1", "L2", "L3", "X", "Y")
WINDOW = 10                                  # ticks a speed is measured over (1 pulse / 10 ticks: 0.05 mm/s)


def wait_ov(s, want, timeout=30.0):
    """The status report's Ov: once it says ``want`` (the rt side applied the override)."""
    t0 = time.time()
    st = s.status()
    while st["Ov"] != want and time.time() - t0 < timeout:
        time.sleep(0.02)
        st = s.status()
    return st["Ov"]


def move_speeds(rec):
    """Per console line that moved the tool: (line, peak tool-tip speed mm/s, ticks in motion), in
    order, from the recording's commanded pulse counters (FK) -- the motion the drives were given."""
    r = read_recording(rec)
    c = r.columns
    q = np.stack([c[f"cmd_{a}"] for a in JOINTS], 1)
    pose, ok = K.fk_batch(q, r.machine)
    assert ok.all()
    tip, t, line = pose.tip, c["t"], c["line"].astype(int)
    step = np.linalg.norm(np.diff(tip, axis=0), axis=1)
    v = np.linalg.norm(tip[WINDOW:] - tip[:-WINDOW], axis=1) / (t[WINDOW:] - t[:-WINDOW])
    out = []
    for ln in dict.fromkeys(line[1:][step > 0]):          # lines in the order they ran
        moving = (line[1:] == ln) & (step > 0)
        if moving.sum() < 50:
            continue
        idx = np.flatnonzero(line[:-WINDOW] == ln)
        out.append((int(ln), float(v[idx].max()), int(moving.sum())))
    return out


def test_rapid_override_scales_g0_only_and_feed_override_leaves_g0_alone(tmp_path):
    rec = tmp_path / "rec"
    p, link = start_serve(tmp_path, record=rec)
    s = Sender(link)
    plan = [  # realtime bytes before the move, the Ov: they give, the move
        (b"", "100,100,100", "G0 X20"),
        (b"\x97", "100,25,100", "G0 X-20"),
        (b"\x96", "100,50,100", "G0 X20"),
        (b"\x95" + b"\x92" * 5, "50,100,100", "G0 X-20"),        # feed 50 %: G0 unchanged
        (b"\x90" + b"\x97", "100,25,100", "G1 X20 F600"),       # rapid 25 %: G1 unchanged
        (b"\x95", "100,100,100", "G1 X-20 F600"),
    ]
    try:
        s.reset()
        p0 = np.array(s.status()["pos"])
        assert s.send("G21 G91") == "ok"
        for i, (rt, ov, line) in enumerate(plan):
            s.realtime(rt)
            assert wait_ov(s, ov) == ov, line
            assert s.send(line) == "ok" and s.send("G4 P0") == "ok"          # answered once it ran
            st = s.status()
            assert st["state"] == "Idle" and st["Ov"] == ov
            want = p0 + [20 if i % 2 == 0 else 0, 0, 0, 0, 0]
            assert np.allclose(st["pos"], want, atol=2e-3), (line, st)      # the whole move, and only it
        assert s.send("G90") == "ok"
    finally:
        s.close()
        stop_serve(p)
    moves = move_speeds(rec)
    assert len(moves) == len(plan), moves
    (_, v100, n100), (_, v25, n25), (_, v50, _), (_, v_f50, n_f50), (_, g1_r25, m25), (_, g1_r100, m100) = moves
    tol = 0.3                                                 # mm/s: pulse quantisation over the window
    assert abs(v100 - RAPID) <= tol, v100                     # G0 at the rapid speed
    assert abs(v25 - 0.25 * RAPID) <= tol, v25                # 25 %: a quarter of it, never more
    assert abs(v50 - 0.50 * RAPID) <= tol, v50
    assert 3.5 <= n25 / n100 <= 4.5, (n25, n100)              # ~4x the ticks for the same 20 mm
    assert abs(v_f50 - RAPID) <= tol and abs(n_f50 - n100) <= 0.02 * n100   # feed bytes: G0 unchanged
    assert abs(g1_r25 - 10.0) <= tol and abs(g1_r100 - 10.0) <= tol        # F600 = 10 mm/s either way
    assert abs(m25 - m100) <= 0.02 * m100                                   # rapid bytes: G1 unchanged


# ---------------------------------------------------------------- spindle override on a Modbus VFD

def _vfd_service(tmp, port):
    p = tmp / "service.toml"
    p.write_text('[loop]\nrate_hz = 1000\nstall_timeout_ms = 5000\nmax_overruns_in_row = 100000\nstate_file = ""\n'
                 '[hal]\nbackend = "sim"\n'
                 f'[spindle]\nhost = "127.0.0.1"\nport = {port}\nsimulate = false\npoll_ms = 20\n'
                 f'max_rpm = {MAX_RPM}\nmax_hz = {MAX_HZ}\n')
    return p


MAX_RPM, MAX_HZ = 24000.0, 400.0


def setpoint_of(rpm):
    """The frequency set-point register for ``rpm`` (0 .. 10000 of the maximum frequency)."""
    return int(round(rpm / MAX_RPM * 10000))


def test_spindle_override_sets_the_vfd_frequency(tmp_path):
    from pymodbus.client import ModbusTcpClient

    from pmctl.hal.modbus_vfd import VfdOptions, simulated
    opt = VfdOptions.from_dict({"simulate": True, "port": 0, "sim_ramp_rpm_per_s": 200000.0,
                                "max_rpm": MAX_RPM, "max_hz": MAX_HZ})
    srv, dev = simulated(opt)                 # the VFD: a pymodbus server in this process
    reg = opt.registers
    client = ModbusTcpClient("127.0.0.1", port=opt.port, timeout=2.0)
    assert client.connect()

    def read(addr):
        rr = client.read_holding_registers(addr, count=1, device_id=opt.device_id)
        assert not rr.isError(), rr
        return rr.registers[0]

    def wait_setpoint(want, timeout=30.0):
        t0 = time.time()
        while read(reg.setpoint) != want and time.time() - t0 < timeout:
            time.sleep(0.02)
        return read(reg.setpoint)

    sock = tmp_path / "pmctl.sock"
    p, link = start_serve(tmp_path, extra=("--service", str(_vfd_service(tmp_path, opt.port)), "--socket", str(sock)))
    s = Sender(link)
    try:
        s.reset()
        assert s.send("G21 G91 M3 S6000") == "ok"
        assert s.send("G1 X1 F600") == "ok" and s.send("G4 P0", timeout=120) == "ok"   # at speed, then moved
        assert read(reg.setpoint) == setpoint_of(6000) and read(reg.command) == reg.run_forward
        st = s.status()
        assert st["Ov"] == "100,100,100" and st["FS"].endswith(",6000")
        # grbl's spindle override: +10 / -10 / +1 / -1 %, 0x99 back to 100 %, limits 10 and 200 %
        for rt, ov, rpm in ((b"\x9a\x9a", 120, 7200), (b"\x9d", 119, 7140), (b"\x9b" * 20, 10, 600),
                            (b"\x9c", 11, 660), (b"\x99", 100, 6000), (b"\x9a" * 15, 200, 12000)):
            s.realtime(rt)
            assert wait_setpoint(setpoint_of(rpm)) == setpoint_of(rpm), (rt, ov)
            assert read(reg.command) == reg.run_forward
            assert wait_ov(s, f"100,100,{ov}") == f"100,100,{ov}"
            assert s.wait_for(lambda: s.status()["FS"].endswith(f",{rpm}"), 10)
            assert abs(read(reg.setpoint) / 10000 * MAX_HZ - rpm / MAX_RPM * MAX_HZ) <= MAX_HZ / 10000   # Hz
        # the control socket's spindle override: the same set-point; the console's steps go on from it
        assert request(sock, {"cmd": "override", "spindle": 0.75})["ok"]
        assert wait_setpoint(setpoint_of(4500)) == setpoint_of(4500)
        st = request(sock, {"cmd": "status"})
        assert st["spindle_override"] == 0.75 and st["spindle_rpm"] == 4500
        assert s.status()["Ov"] == "100,100,75"
        s.realtime(b"\x9a")
        assert wait_setpoint(setpoint_of(5100)) == setpoint_of(5100)
        bad = request(sock, {"cmd": "override", "spindle": 2.5})
        assert not bad["ok"] and "0.1 .. 2.0" in bad["error"]
        assert request(sock, {"cmd": "override", "spindle": 2.0})["ok"]
        assert wait_setpoint(setpoint_of(12000)) == setpoint_of(12000)
        # 200 % of S20000 is beyond the VFD's maximum: the set-point stops at it
        assert s.send("S20000") == "ok" and s.send("G1 X-1 F600") == "ok" and s.send("G4 P0", timeout=120) == "ok"
        assert read(reg.setpoint) == 10000
        s.realtime(b"\x99")
        assert wait_setpoint(setpoint_of(20000)) == setpoint_of(20000)
        # M5: stopped; an override then changes nothing at the VFD until the next M3, which uses it
        assert s.send("M5") == "ok" and s.send("G1 X1 F600") == "ok" and s.send("G4 P0", timeout=120) == "ok"
        t0 = time.time()
        while read(reg.command) != reg.stop and time.time() - t0 < 30:
            time.sleep(0.02)
        assert read(reg.command) == reg.stop
        n = len(dev.commands)
        s.realtime(b"\x9a")                                   # 110 %
        assert wait_ov(s, "100,100,110") == "100,100,110" and s.status()["FS"].endswith(",0")
        assert s.send("M3 S6000") == "ok" and s.send("G1 X-1 F600") == "ok"
        assert s.send("G4 P0", timeout=120) == "ok"
        assert dev.commands[n:] == [(reg.setpoint, setpoint_of(6600)), (reg.command, reg.run_forward)]
        # a soft reset stops the spindle and sets the override back to 100 %
        s.reset()
        assert wait_ov(s, "100,100,100") == "100,100,100"
        t0 = time.time()
        while read(reg.command) != reg.stop and time.time() - t0 < 30:
            time.sleep(0.02)
        assert read(reg.command) == reg.stop and read(reg.setpoint) == setpoint_of(6600)
        assert s.send("G90") == "ok"
    finally:
        s.close()
        stop_serve(p)
        client.close()
        srv.stop()


def test_spindle_stop_in_a_hold_and_cycle_start_waits_for_the_spindle(tmp_path):
    """grbl's 0x9E: ignored while moving; in Hold:0 it stops the spindle (the VFD's run command goes
    to stop), again starts it; cycle start brings it back and the path goes on only once the spindle
    is at its speed (2 %), read from the simulated VFD itself when the tool starts to move again."""
    from pymodbus.client import ModbusTcpClient

    from pmctl.hal.modbus_vfd import VfdOptions, simulated
    opt = VfdOptions.from_dict({"simulate": True, "port": 0, "sim_ramp_rpm_per_s": 4000.0,
                                "max_rpm": MAX_RPM, "max_hz": MAX_HZ})
    srv, dev = simulated(opt)                 # spin-up from rest to 6000 rpm: 1.5 s
    reg = opt.registers
    client = ModbusTcpClient("127.0.0.1", port=opt.port, timeout=2.0)
    assert client.connect()

    def command():
        rr = client.read_holding_registers(reg.command, count=1, device_id=opt.device_id)
        assert not rr.isError(), rr
        return rr.registers[0]

    def wait_command(want, timeout=30.0):
        t0 = time.time()
        while command() != want and time.time() - t0 < timeout:
            time.sleep(0.02)
        return command()

    p, link = start_serve(tmp_path, extra=("--service", str(_vfd_service(tmp_path, opt.port)),))
    s = Sender(link)
    try:
        s.reset()
        assert s.send("G21 G91 M3 S6000") == "ok"
        assert s.send("G1 X12 F300") == "ok"
        t0 = time.time()                      # at speed and cutting
        while s.status()["pos"][0] < 0.5 and time.time() - t0 < 120:
            time.sleep(0.02)
        s.realtime(b"\x9e")                   # moving: ignored
        time.sleep(0.3)
        assert command() == reg.run_forward and s.status()["state"] == "Run"
        s.realtime(b"!")
        held = s.wait_state(("Hold:0",), 60)
        s.realtime(b"\x9e")                   # in the hold: the spindle stops
        assert wait_command(reg.stop) == reg.stop
        assert s.wait_for(lambda: s.status()["FS"].endswith(",0"), 10)   # the status follows the register
        s.realtime(b"\x9e")                   # again: it starts back
        assert wait_command(reg.run_forward) == reg.run_forward
        s.realtime(b"\x9e")                   # and stops again
        assert wait_command(reg.stop) == reg.stop
        t0 = time.time()
        while dev.rpm > 100 and time.time() - t0 < 30:      # let it run down
            time.sleep(0.05)
        assert dev.rpm <= 100
        s.realtime(b"~")                      # cycle start: spindle first, then the path
        t0 = time.time()
        st = s.status()
        while np.allclose(st["pos"], held["pos"], atol=1e-3) and time.time() - t0 < 60:
            st = s.status()
        rpm_when_moving = dev.rpm
        assert not np.allclose(st["pos"], held["pos"], atol=1e-3), "the path never went on"
        assert rpm_when_moving >= 0.98 * 6000, rpm_when_moving
        assert command() == reg.run_forward
        assert s.send("G4 P0", timeout=120) == "ok"
        done = s.status()
        assert abs(done["pos"][0] - 12.0) < 2e-3 and done["FS"].endswith(",6000")
    finally:
        s.close()
        stop_serve(p)
        client.close()
        srv.stop()
