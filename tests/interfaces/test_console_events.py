"""M-codes take effect in program order where the stream gets to them, as grbl's planner sync does.

Over the pty of `pmctl serve` (sim, simulated Modbus VFD): a lone M3 S.. starts the spindle and a lone
M5 stops it while the machine is idle, and so do M4, an S change, M7, M8 and M9 (``FS:`` and ``A:``);
mid-stream, M5, an S change and the coolant words M8/M9 take effect at the stop between the moves
around them, never during the move before (judged by the position reported with the spindle speed
and the ``A:`` accessory field); G43.1 with a zero offset (bCNC's reset) and
G49 are accepted. Through the supervisor (EVENT moves as the RS-274 interpreter makes them): a tool
change M6 and M0 hold the path until cycle start and say why, M1 only with the optional stop on,
outputs and messages are recorded where the path reaches them."""

import time

import numpy as np
import pytest

from grbl_sender import serve_session
from pmctl.core import kinematics as K
from pmctl.motion.nc import counts_of
from pmctl.core.job import EVENT, Job, LINE, Move, home_pose
from pmctl.task.supervisor import Supervisor
from service_support import service_toml as _service

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    yield from serve_session(tmp_path_factory, "console_events")


def spindle(st):
    return float(st["FS"].split(",")[1])


def test_a_lone_m3_starts_and_a_lone_m5_stops_the_spindle_when_idle(daemon):
    s, *_ = daemon
    assert s.send("M3 S7000") == "ok"
    st = s.wait_for(lambda: spindle(s.status()) == 7000, 30) and s.status()
    assert st and "S" in st.get("A", ""), st
    assert s.wait_state(("Idle",), 30)["state"] == "Idle"        # the path waited for the speed, then idle
    assert s.send("M5") == "ok"
    assert s.wait_for(lambda: spindle(s.status()) == 0, 30)
    st = s.status()
    assert "S" not in st.get("A", "") and st["state"] in ("Idle", "Run")


def test_lone_m4_s_change_m7_m8_m9_take_effect_when_idle(daemon):
    s, *_ = daemon
    for line, rpm, acc in (("M4 S5000", 5000, "C"), ("S9000", 9000, "C"), ("M3", 9000, "S"), ("M7", 9000, "SM"),
                           ("M8", 9000, "SFM"), ("M9", 9000, "S"), ("M5", 0, "")):
        assert s.send(line) == "ok", line
        assert s.wait_for(lambda: (lambda st: spindle(st) == rpm and st.get("A", "") == acc)(s.status()), 30), \
            (line, s.status())
    assert s.wait_state(("Idle",), 30)["state"] == "Idle"


def test_mid_stream_m5_and_coolant_take_effect_between_the_moves(daemon):
    s, *_ = daemon
    assert s.send("M3 S6000") == "ok" and s.send("G4 P0") == "ok"
    assert spindle(s.status()) == 6000
    x0 = s.status()["pos"][0]
    seen = []
    lines = ["G21 G91 G1 X3 F300", "M5 M8", "G1 X-3 F300", "M9", "G90"]
    s.stream(lines, during=lambda i: None)
    # the stream was answered; the machine goes on: watch it to the end
    t0 = time.time()
    while time.time() - t0 < 60:
        st = s.status()
        seen.append((st["pos"][0] - x0, spindle(st), st.get("A", ""), st["state"]))
        if st["state"] == "Idle" and abs(st["pos"][0] - x0) < 1e-3 and len(seen) > 3:
            break
        time.sleep(0.02)
    out = [x for x in seen if 0.05 < x[0] < 2.95]
    # on the way out (x rising to 3, before the stop), the spindle turns and no coolant; on the way
    # back the spindle is off and flood is on; at the end the coolant is off again
    rising = True
    for dx, rpm, acc, _ in seen:
        if dx > 2.999:
            rising = False
        if 0.05 < dx < 2.95:
            if rising:
                assert rpm == 6000 and "F" not in acc, seen
            else:
                assert rpm == 0 and "F" in acc, seen
    assert out and not rising, seen
    assert seen[-1][2] == "", seen


def test_mid_stream_speed_change_takes_effect_at_the_stop(daemon):
    s, *_ = daemon
    assert s.send("M3 S6000") == "ok" and s.send("G4 P0") == "ok"
    x0 = s.status()["pos"][0]
    s.stream(["G21 G91 G1 X3 F300", "S9000", "G1 X-3 F300", "M5", "G90"])
    seen = []
    t0 = time.time()
    while time.time() - t0 < 60:
        st = s.status()
        seen.append((st["pos"][0] - x0, spindle(st)))
        if st["state"] == "Idle" and len(seen) > 3:
            break
        time.sleep(0.02)
    back = False
    for dx, rpm in seen:
        back = back or dx > 2.999
        if 0.05 < dx < 2.95:
            assert rpm == (9000 if back else 6000), seen
    assert back and seen[-1][1] == 0, seen


def test_g43_1_with_a_zero_offset_and_g49_are_accepted(daemon):
    s, *_ = daemon
    for line in ("G43.1Z0.000", "G43.1 Z0", "G49"):
        assert s.send(line) == "ok", line


def test_tool_change_pause_output_and_message_over_the_pty(daemon):
    s, *_ = daemon
    x0 = s.status()["pos"][0]
    n = len(s.pushed)
    for line in ("G21 G91 G1 X2 F600", "T2 M6", "G1 X-2", "M0", "M62 P1", "(MSG, check the part)", "G90"):
        assert s.send(line) == "ok", line
    for what, x in (("tool change: load tool 2", 2.0), ("program paused (M0)", 0.0)):
        st = s.wait_state(("Hold:0",), 60)
        assert abs(st["pos"][0] - x0 - x) < 1e-3, (what, st)           # held where the program says it
        assert s.wait_for(lambda: any(what in m for m in s.pushed[n:]), 10), s.pushed[n:]
        s.realtime(b"~")
        assert s.wait_state(("Run", "Idle"), 30)["state"] in ("Run", "Idle")
    assert s.wait_for(lambda: "[MSG:check the part]" in s.pushed[n:], 30)
    assert s.wait_state(("Idle",), 60)["state"] == "Idle"


def test_tool_change_and_pauses_hold_until_cycle_start_outputs_are_recorded(tmp_path):
    sup = Supervisor(service=str(_service(tmp_path)), log=lambda m: None)
    tip, axis = home_pose(sup.machine)
    events = []
    sup.listeners.append(lambda ev, d: events.append((ev, d)))
    sup.start(counts_of(K.ik(tip, axis, sup.machine).q, sup.params))
    try:
        a, b = tip + [2.0, 0, 0], tip + [2.0, 2.0, 0]
        moves = (Move(LINE, a, axis, line=1, feed=5.0),
                 Move(EVENT, a, axis, line=2, events=(("output", ("digital", 3, 1)), ("message", "check the part"),
                                                      ("tool_change", 2))),
                 Move(LINE, b, axis, line=3, feed=5.0),
                 Move(EVENT, b, axis, line=4, events=(("pause", "M1"),)),
                 Move(EVENT, b, axis, line=5, events=(("pause", "M0"),)),
                 Move(LINE, tip, axis, line=6, feed=5.0))
        it = sup.submit(Job(moves, "events"))
        t0 = time.monotonic()
        while not sup.paused and time.monotonic() - t0 < 60:
            time.sleep(0.01)
        assert "tool change: load tool 2" in sup.paused
        assert sup.state_name() == "Hold:0"
        assert np.allclose(sup.pose()[0], a, atol=1e-3)           # held where the M6 is, after line 1
        assert sup.outputs == {"digital 3": 1}
        assert ("message", {"msg": "check the part"}) in events
        time.sleep(0.3)
        assert sup.paused and np.allclose(sup.pose()[0], a, atol=1e-3)     # it waits for the operator
        sup.resume()
        t0 = time.monotonic()                  # M1 is skipped (optional stop off); M0 holds at b
        while not sup.paused and time.monotonic() - t0 < 60:
            time.sleep(0.01)
        assert "program paused (M0)" in sup.paused and np.allclose(sup.pose()[0], b, atol=1e-3)
        assert [d["msg"] for ev, d in events if ev == "pause"][-1] == sup.paused
        sup.resume()
        assert sup.wait_idle(60) and sup.retired(it)
        assert np.allclose(sup.pose()[0], tip, atol=1e-3)
        sup.optional_stop = True               # with the switch on, M1 pauses
        sup.submit(Job((Move(EVENT, tip, axis, line=1, events=(("pause", "M1"),)),), "m1"))
        t0 = time.monotonic()
        while not sup.paused and time.monotonic() - t0 < 60:
            time.sleep(0.01)
        assert "M1" in sup.paused
        sup.resume()
        assert sup.wait_idle(60)
    finally:
        sup.shutdown()
