"""The console's realtime bytes, with the console in this process: a GrblConsole on a real pty (the
daemon's ConsolePort), a real Supervisor with its rt motion process on the sim and its spindle on a
simulated Modbus VFD (on loopback), and a grbl sender on the pty's other side (tests/grbl_sender.py). The other console tests run `pmctl serve` in a child
process, where a mutation tool's switch does not reach; these pin the realtime handling itself:

- ``?`` answers a status report at once, also in the middle of a line, which goes on unharmed;
- ``!`` holds a running G0 on the line (Hold, the tool stops short of the target and stays), ``~``
  finishes it; ``!`` while idle is a hold too (Hold:0, grbl 1.1); ``!`` during a jog cancels the jog;
- 0x85 cancels a jog; 0x18 stops a G0 short, drops the half-received line and the queue, sets the
  overrides back to 100 % and greets again; a second 0x18 drops the line the worker holds unanswered;
- 0x9E, and no other byte, stops the spindle in Hold:0 and starts it back;
- the override bytes step and bound as grbl's do (feed and spindle 10-200 %, +-10, +-1, 100; rapid
  100/50/25 %), the feed and rapid ones as the rt process reports them applied;
- any byte from 0x80 up is a realtime byte, never part of a line; ``\\n`` and ``\\r`` end a line; a
  line longer than 256 bytes is dropped whole with error:11 and the next one runs.

Each test waits for evidence with generous bounds; no timing is asserted.
"""

import os
import time

import numpy as np
import pytest

from grbl_sender import Sender
from test_console_overrides import wait_ov as _ov
from pmctl.core import kinematics as K
from pmctl.interfaces.console.grbl import PLANNER_BLOCKS, GrblConsole
from pmctl.interfaces.console.port import ConsolePort
from pmctl.motion import channel as C
from pmctl.motion.nc import counts_of
from pmctl.task.jog import make_jogger
from pmctl.core.job import home_pose
from pmctl.task.journal import Journal
from pmctl.task.supervisor import Supervisor

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def vfd():
    """The spindle's VFD: a simulated Modbus inverter (a pymodbus server in this process, on loopback)
    spinning up at 200000 rpm/s; the console's supervisor connects to it at the first M3."""
    from pmctl.hal.modbus_vfd import VfdOptions, simulated
    opt = VfdOptions.from_dict({"simulate": True, "port": 0, "sim_ramp_rpm_per_s": 200000.0,
                                "max_rpm": 24000.0, "max_hz": 400.0})
    srv, dev = simulated(opt)
    try:
        yield opt, dev
    finally:
        srv.stop()


@pytest.fixture(scope="module")
def console(tmp_path_factory, vfd):
    tmp = tmp_path_factory.mktemp("console")
    svc = tmp / "service.toml"
    svc.write_text('[loop]\nrate_hz = 1000\nstall_timeout_ms = 5000\nmax_overruns_in_row = 100000\n'
                   'state_file = ""\n[hal]\nbackend = "sim"\n'
                   f'[spindle]\nhost = "127.0.0.1"\nport = {vfd[0].port}\nsimulate = false\npoll_ms = 20\n'
                   'max_rpm = 24000.0\nmax_hz = 400.0\n')
    sup = Supervisor(service=str(svc), log=lambda m: None)
    tip, axis = home_pose(sup.machine)
    sup.start(counts_of(K.ik(tip, axis, sup.machine).q, sup.params))
    port = ConsolePort(f"pty:{tmp / 'tty'}")
    con = GrblConsole(sup, port.fd, Journal(None, sup.machine.name).load(), jogger=make_jogger(sup),
                      present=port.client_present)
    con.start()
    s = Sender(tmp / "tty")
    try:
        yield s, sup, con
    finally:
        s.close()
        con.stop()
        port.close()
        sup.shutdown()


def _idle(s, timeout=60):
    st = s.wait_state(("Idle",), timeout)
    assert st["state"] == "Idle", st
    return st


def _moving(s, timeout=30):
    """The status once the tool has left where it was (a move under way)."""
    p0 = s.status()["pos"]
    t0 = time.time()
    while time.time() - t0 < timeout:
        st = s.status()
        if np.linalg.norm(np.subtract(st["pos"][:3], p0[:3])) > 0.5:
            return st
        time.sleep(0.01)
    raise AssertionError(f"no motion within {timeout} s: {st}")


def _home_x(s):
    assert s.send("G90 G0 X0 Y0") == "ok"
    _idle(s)


def test_a_status_byte_inside_a_line_answers_at_once_and_the_line_runs(console):
    s, sup, con = console
    _home_x(s)
    n0 = len(s.reports)
    s.realtime(b"G1 F600 X")
    s.realtime(b"?")
    assert s.wait_for(lambda: len(s.reports) > n0, 10)
    assert s.reports[n0].startswith("<Idle|MPos:")
    assert s.send("2") == "ok"                     # the line "G1 F600 X2", the ? not in it
    _idle(s)
    assert s.status()["pos"][0] == pytest.approx(2.0, abs=2e-3)


def test_a_hold_stops_a_g0_on_the_line_and_cycle_start_finishes_it(console):
    s, sup, con = console
    _home_x(s)
    assert s.send("G0 X-40") == "ok"
    _moving(s)
    s.realtime(b"!")
    held = s.wait_state(("Hold:0",), 30)
    assert held["state"] == "Hold:0", held
    x = held["pos"][0]
    assert -40.0 + 1.0 < x < -0.5                  # stopped short of the target, on the line
    assert held["pos"][1] == pytest.approx(0.0, abs=2e-3)
    time.sleep(0.2)
    assert s.status()["pos"][0] == pytest.approx(x, abs=0.01)     # and it stays there (a pulse or two)
    s.realtime(b"~")
    st = _idle(s)
    assert st["pos"][0] == pytest.approx(-40.0, abs=2e-3)


def test_a_hold_while_idle_is_a_hold_and_cycle_start_releases_it(console):
    s, sup, con = console
    _idle(s)
    s.realtime(b"!")
    assert s.wait_state(("Hold:0",), 10)["state"] == "Hold:0"
    assert sup.operator_hold
    s.realtime(b"~")
    _idle(s)
    assert not sup.operator_hold


@pytest.mark.parametrize("byte", [b"!", b"\x85"])
def test_a_hold_or_a_jog_cancel_during_a_jog_cancels_it(console, byte):
    s, sup, con = console
    _home_x(s)
    assert s.send("$J=G91 X20 F300") == "ok"          # 4 s of jogging: still under way when the byte comes,
    st = _moving(s)                                    # however slowly a loaded machine polls
    assert st["state"] == "Jog"
    s.realtime(byte)
    st = _idle(s)                                   # a cancel, not a hold: Idle, nothing queued
    assert 0.5 < st["pos"][0] < 19.0, st
    assert not sup.operator_hold
    time.sleep(0.2)
    assert s.status()["pos"][0] == pytest.approx(st["pos"][0], abs=0.01)


def test_the_override_bytes_step_and_bound_as_grbls(console):
    """Feed (0x90 100 %, 0x91 +10, 0x92 -10, 0x93 +1, 0x94 -1, within 10..200 %), rapid (0x95 100 %,
    0x96 50 %, 0x97 25 %) and spindle (0x99..0x9D as the feed's): the feed and rapid values as the rt
    process reports them applied."""
    s, sup, con = console
    _idle(s)
    steps = [(b"\x91\x91\x91", "130,100,100"), (b"\x92", "120,100,100"), (b"\x93", "121,100,100"),
             (b"\x94\x94", "119,100,100"), (b"\x90", "100,100,100"), (b"\x91" * 12, "200,100,100"),
             (b"\x92", "190,100,100"), (b"\x92" * 25, "10,100,100"), (b"\x91", "20,100,100"),
             (b"\x90", "100,100,100"),
             (b"\x96", "100,50,100"), (b"\x97", "100,25,100"), (b"\x95", "100,100,100"),
             (b"\x9a\x9a", "100,100,120"), (b"\x9b", "100,100,110"), (b"\x9c", "100,100,111"),
             (b"\x9d\x9d", "100,100,109"), (b"\x9a" * 12, "100,100,200"), (b"\x9b", "100,100,190"),
             (b"\x9b" * 25, "100,100,10"), (b"\x9a", "100,100,20"),
             (b"\x99", "100,100,100")]
    for data, want in steps:
        s.realtime(data)
        assert _ov(s, want) == want, data
        assert sup.spindle_ov == int(want.split(",")[2]) / 100.0, data     # what the spindle is given
    assert sup.raw()[C.ST_FEED_OV] == 1.0 and sup.raw()[C.ST_RAPID_OV] == 1.0


def test_a_soft_reset_stops_a_g0_drops_the_half_line_and_resets_the_overrides(console):
    s, sup, con = console
    _home_x(s)
    s.realtime(b"\x91\x91\x96\x9a")
    assert _ov(s, "120,50,110") == "120,50,110"
    assert s.wait_for(lambda: (sup.raw()[C.ST_FEED_OV], sup.raw()[C.ST_RAPID_OV]) == (1.2, 0.5), 10)
    assert s.send("G0 X-40") == "ok"
    _moving(s)
    s.realtime(b"G0 Y30")                           # half a line, then the reset
    greet = s.reset()
    assert any(g.startswith("Grbl ") for g in greet)
    st = _idle(s)
    x = st["pos"][0]
    assert -40.0 + 1.0 < x < -0.5 and st["pos"][1] == pytest.approx(0.0, abs=2e-3)
    assert _ov(s, "100,100,100") == "100,100,100"
    # the overrides as the rt process applies them and as the spindle gets them: back to 100 %
    assert s.wait_for(lambda: (sup.raw()[C.ST_FEED_OV], sup.raw()[C.ST_RAPID_OV]) == (1.0, 1.0), 10)
    assert sup.spindle_ov == 1.0
    # grbl clears its RX buffer: Bf (status mask $10=3) says the planner's blocks and the 128
    # bytes free, before and after the next line
    assert s.send("$10=3") == "ok"
    try:
        assert s.status()["Bf"] == f"{PLANNER_BLOCKS},128"
        assert s.send("") == "ok"                   # the rest of the dropped line ends nothing
        assert s.status()["Bf"] == f"{PLANNER_BLOCKS},128"
    finally:
        assert s.send("$10=1") == "ok"
    time.sleep(0.2)
    st = _idle(s)
    assert st["pos"][0] == pytest.approx(x, abs=0.01) and st["pos"][1] == pytest.approx(0.0, abs=2e-3)


def test_bytes_from_0x80_up_are_never_part_of_a_line_and_both_line_ends_count(console):
    """0x80, 0x98, 0x9E (spindle stop: only in a hold), 0x9F and 0xA0 (no command here) inside a line
    are dropped from it and change nothing; a line ends at \\n or at
    \\r (a bare \\r on an empty line is nothing); a line of more than 256 bytes (257) is refused whole
    with error:11, one of 256 runs, and so does the next line."""
    s, sup, con = console
    _home_x(s)
    n0 = len(s.answers)
    s.pending.append(12)
    s.realtime(b"G1 F600\x80 X\x98\x9e1\x9f\xa0\r")
    assert s.wait_for(lambda: len(s.answers) > n0, 30) and s.answers[n0] == "ok"
    st = _idle(s)
    assert st["pos"][0] == pytest.approx(1.0, abs=2e-3) and st["Ov"] == "100,100,100"
    s.realtime(b"\r")
    assert s.send("G1 X3") == "ok" and len(s.answers) == n0 + 2
    assert s.send("(" + "a" * 300 + ")") == "error:11"
    assert s.send("(" + "a" * 254 + ")") == "ok"                   # 256 bytes: the longest line
    assert s.send("(" + "a" * 255 + ")") == "error:11"             # 257
    assert s.send("G1 X2") == "ok"
    assert _idle(s)["pos"][0] == pytest.approx(2.0, abs=2e-3)


def test_bf_counts_the_bytes_of_the_lines_not_yet_answered(console):
    """grbl's character counting: held (Hold:0) with the planner's PLANNER_BLOCKS blocks full, the
    next lines wait unanswered in the RX buffer, and Bf's second field is 128 less their bytes (line
    ends counted), as the sender counts them; once released, all are answered and Bf is back to
    PLANNER_BLOCKS,128."""
    s, sup, con = console
    _home_x(s)
    assert s.send("$10=3") == "ok"
    try:
        s.realtime(b"!")
        assert s.wait_state(("Hold:0",), 10)["state"] == "Hold:0"
        n0 = len(s.answers)
        lines = [f"G1 X{0.001 * (i + 1):.3f} F600" for i in range(PLANNER_BLOCKS)] + ["G1 X0.5", "G1 Y0.25\r"]
        for ln in lines:
            data = (ln if ln.endswith("\r") else ln + "\n").encode()
            s.pending.append(len(data))
            os.write(s.fd, data)
        assert s.wait_for(lambda: len(s.answers) - n0 >= PLANNER_BLOCKS, 30)
        st = s.status()
        assert st["state"] == "Hold:0" and len(s.answers) - n0 == PLANNER_BLOCKS
        waiting = len("G1 X0.5") + 1 + len("G1 Y0.25") + 1         # the two lines past the full planner
        assert st["Bf"] == f"0,{128 - waiting}" and sum(s.pending) == waiting
        s.realtime(b"~")
        assert s.wait_for(lambda: len(s.answers) - n0 == len(lines), 60)
        assert all(a == "ok" for a in s.answers[n0:])
        st = _idle(s)
        assert st["pos"][0] == pytest.approx(0.5, abs=2e-3) and st["pos"][1] == pytest.approx(0.25, abs=2e-3)
        assert s.status()["Bf"] == f"{PLANNER_BLOCKS},128"
    finally:
        assert s.send("$10=1") == "ok"


def test_a_second_soft_reset_drops_the_line_in_the_workers_hands_unanswered(console):
    """Two resets: after the first, a probing line sent in a hold waits in the worker's hands (grbl
    answers a probe once it has ended); Bf's RX field counts exactly its bytes, line end included (the
    half line before the reset counted for nothing). The second reset drops it: it is never answered
    (a character-counting sender counts its bytes free again from the greeting), and the tool has not
    moved."""
    s, sup, con = console
    _home_x(s)
    assert s.send("$10=3") == "ok"
    try:
        s.realtime(b"G0 Y3")                        # half a line, dropped by the first reset
        s.reset()
        p0 = _idle(s)["pos"]
        s.realtime(b"!")
        assert s.wait_state(("Hold:0",), 10)["state"] == "Hold:0"
        n0 = len(s.answers)
        line = "G91 G38.3 Z-1 F60"
        s.send(line, wait=False)
        assert s.wait_for(lambda: sup.queued_items() >= 1, 30)        # the probe queued, held
        st = s.status()
        assert st["state"] == "Hold:0" and st["Bf"] == f"{PLANNER_BLOCKS},{128 - len(line) - 1}", st
        s.reset()
        st = _idle(s)
        assert st["Bf"] == f"{PLANNER_BLOCKS},128"
        assert s.send("G90") == "ok" and s.answers[n0:] == ["ok"]       # the probe line: no answer
        assert np.allclose(s.status()["pos"], p0, atol=1e-3)
    finally:
        s.reset()                                   # (a failed check may leave the probe held)
        assert s.send("$10=1") == "ok"


def test_the_spindle_stop_in_a_hold_is_byte_0x9e_alone(console, vfd):
    """In Hold:0 with the spindle running (the fixture's simulated VFD): 0x9F, the byte after it,
    leaves the spindle running; 0x9E stops it (the VFD's run command goes to stop), 0x9E again
    starts it back; cycle start finishes the move with the spindle at its speed."""
    s, sup, con = console
    _, dev = vfd
    _home_x(s)
    try:
        assert s.send("M3 S6000") == "ok" and s.send("G1 X-8 F600") == "ok"
        _moving(s)
        assert dev.run == 1 and dev.rpm > 5000
        s.realtime(b"!")
        assert s.wait_state(("Hold:0",), 30)["state"] == "Hold:0"
        s.realtime(b"\x9f")
        assert s.status()["FS"].endswith(",6000")          # (the report follows the byte: it was read)
        sup._spindle._m5_written()
        assert not sup._spindle.stopped_in_hold and dev.run == 1
        s.realtime(b"\x9e")
        assert s.wait_for(lambda: dev.run == 0, 10) and s.wait_for(lambda: dev.rpm == 0.0, 10)
        assert s.status()["FS"].endswith(",0") and s.status()["state"] == "Hold:0"
        s.realtime(b"\x9e")
        assert s.wait_for(lambda: dev.run == 1, 10)
        s.realtime(b"~")
        st = _idle(s)
        assert st["pos"][0] == pytest.approx(-8.0, abs=2e-3) and st["FS"].endswith(",6000")
        assert dev.rpm >= 0.98 * 6000
    finally:
        s.send("M5")
    assert s.wait_for(lambda: dev.run == 0, 10)
