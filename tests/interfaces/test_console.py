"""The grbl 1.1 console of `pmctl serve`, driven over a real pty as a sender does: banner, answers,
status reports, $ commands, work offsets, bad input (garbage, over-long lines, floods, binary,
a disconnect) that never disturbs the next valid line, check mode, jog and jog cancel; absolute jogs
(G90 in work, G53 in machine coordinates), A/B jogs that tilt about the tip, jogs queued behind a
running one and a cancel that drops them -- each judged by the final MPos."""

import json
import time

import numpy as np
import pytest

from grbl_sender import Sender, serve_session


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    yield from serve_session(tmp_path_factory, "console")


def test_reset_prints_the_banner_and_status_has_five_axes(daemon):
    s, *_ = daemon
    pushed = s.reset()
    assert "Grbl 1.1h ['$' for help]" in pushed
    st = s.status()
    assert st["state"] == "Idle" and st["kind"] == "MPos" and len(st["pos"]) == 5
    assert st["Ov"] == "100,100,100" and len(st["WCO"].split(",")) == 5 and "FS" in st


def test_system_commands(daemon):
    s, *_ = daemon
    n = len(s.pushed)
    assert s.send("$I") == "ok"
    assert any(x.startswith("[VER:1.1") for x in s.pushed[n:]) and any(x.endswith(",128]") for x in s.pushed[n:])
    n = len(s.pushed)
    assert s.send("$$") == "ok"
    assert "$10=1" in s.pushed[n:] and "$100=2000.000" in s.pushed[n:]
    n = len(s.pushed)
    assert s.send("$G") == "ok"
    assert s.pushed[n].startswith("[GC:G0 G54 G17 G21 G90 G94")
    n = len(s.pushed)
    assert s.send("$#") == "ok"
    assert s.pushed[n].startswith("[G54:") and len(s.pushed[n].split(",")) == 5
    assert s.send("$Q") == "error:3"


def test_bad_input_never_disturbs_the_next_valid_line(daemon):
    s, *_ = daemon
    cases = ["G1 X", "Q7", "hello world", "G1 X1 X2", "G1 F0 X1", "G2 X1", "G7.5", "%%%%", "X" + "9" * 300,
             "\x01\x02\x03\x04"]
    for bad in cases:
        a = s.send(bad)
        assert a.startswith("error:"), (bad, a)
        assert s.send("G21 G90") == "ok", bad          # the very next valid line is accepted
    # a flood with no line end at all, then a line end: one error:11, and the next line is fine
    n = len(s.answers)
    s.realtime(b"Z" * 20000)
    s.realtime(b"\n")
    s.wait_for(lambda: len(s.answers) > n)
    assert s.answers[n] == "error:11"
    assert s.send("G21") == "ok"
    assert s.status()["state"] == "Idle"


def test_a_disconnect_does_not_disturb_the_console(daemon):
    s, tmp, link = daemon
    s.close()
    time.sleep(0.3)
    s2 = Sender(link)
    try:
        assert s2.send("G21") == "ok"
        assert s2.status()["state"] == "Idle"
    finally:
        s2.close()
    s.__init__(link)


def test_work_offsets_g10_l20_g92_and_wpos_are_persisted(daemon):
    s, tmp, _ = daemon
    m = s.status()["pos"]
    assert s.send("G10 L20 P1 X0 Y0") == "ok"               # "zero X and Y" here
    st = s.status()
    wco = [float(v) for v in st["WCO"].split(",")]
    assert abs(wco[0] - m[0]) < 1e-3 and abs(wco[1] - m[1]) < 1e-3
    assert s.send("$10=0") == "ok"
    st = s.status()
    assert st["kind"] == "WPos" and abs(st["pos"][0]) < 1e-3 and abs(st["pos"][2] - (m[2] - wco[2])) < 1e-3
    assert s.send("G92 Z10") == "ok"
    st = s.status()
    assert abs(st["pos"][2] - 10.0) < 1e-3
    j = json.loads((tmp / "state.json.journal").read_text())
    assert abs(j["offsets"]["g92"][2] - (m[2] - 10.0)) < 1e-3 and j["settings"]["10"] == 0
    assert s.send("G92.1") == "ok" and s.send("G10 L2 P1 X0 Y0 Z0") == "ok" and s.send("$10=1") == "ok"
    assert s.status()["WCO"] == "0.000,0.000,0.000,0.000,0.000"


def test_check_mode_parses_without_moving(daemon):
    s, *_ = daemon
    p0 = s.status()["pos"]
    n = len(s.pushed)
    assert s.send("$C") == "ok" and "[MSG:Enabled]" in s.pushed[n:]
    assert s.status()["state"] == "Check"
    assert s.send("G1 F600 X3 Y3") == "ok"
    time.sleep(0.5)
    assert s.status()["pos"] == p0
    n = len(s.pushed)
    assert s.send("$C") == "ok"
    s.wait_for(lambda: any(x.startswith("Grbl") for x in s.pushed[n:]))
    assert "[MSG:Disabled]" in s.pushed[n:]
    assert s.status()["state"] == "Idle"


def test_unreachable_jog_is_refused_before_it_moves(daemon):
    s, *_ = daemon
    p0 = s.status()["pos"]
    assert s.send("$J=G91 X500 F600") == "error:15"
    assert s.send("$J=G91 X1 F600 M3") == "error:16"
    assert s.send("$J=G91 X1") == "error:22"
    time.sleep(0.3)
    st = s.status()
    assert st["state"] == "Idle" and st["pos"] == p0


def test_jog_and_jog_cancel_decelerate_on_the_line(daemon):
    s, *_ = daemon
    p0 = np.array(s.status()["pos"])
    assert s.send("$J=G91 X2 F600") == "ok"
    st = s.wait_state(("Idle",), 60)
    p1 = np.array(st["pos"])
    assert np.allclose(p1 - p0, [2, 0, 0, 0, 0], atol=1.5e-3)
    assert s.send("$J=G91 Y-20 F300") == "ok"
    assert s.wait_state(("Jog",), 30)["state"] == "Jog"
    assert s.wait_for(lambda: s.status()["pos"][1] - p1[1] < -0.3, 60)    # on its way (evidence, not a delay)
    s.realtime(b"\x85")
    st = s.wait_state(("Idle",), 30)
    p2 = np.array(st["pos"])
    assert -20 < p2[1] - p1[1] < -0.1                       # stopped part-way ...
    assert np.allclose(np.delete(p2 - p1, 1), 0, atol=1.5e-3)   # ... on the jog line
    time.sleep(0.3)
    assert np.allclose(s.status()["pos"], st["pos"], atol=2e-3)   # and stays there
    assert s.send("G21") == "ok"


def test_soft_reset_during_motion_stops_on_the_line_and_keeps_position(daemon):
    s, *_ = daemon
    p0 = np.array(s.status()["pos"])
    assert s.send("G21 G91 G1 F300 X-10") == "ok"
    assert s.send("G90") == "ok"
    assert s.wait_state(("Run",), 30)["state"] == "Run"
    assert s.wait_for(lambda: s.status()["pos"][0] - p0[0] < -0.3, 60)    # on its way (evidence, not a delay)
    pushed = s.reset()
    assert "Grbl 1.1h ['$' for help]" in pushed and not any(x.startswith("ALARM") for x in pushed)
    st = s.wait_state(("Idle",), 30)
    p1 = np.array(st["pos"])
    assert -10 < p1[0] - p0[0] < -0.05                       # stopped part-way ...
    assert np.allclose((p1 - p0)[1:], 0, atol=1.5e-3)        # ... on the line
    time.sleep(0.5)
    assert np.allclose(s.status()["pos"], p1, atol=2e-3)     # the queue is gone: nothing moves
    assert s.send("$G") == "ok" and any("G90" in x for x in s.pushed[-2:])


def _jog_to_rest(s, line, timeout=60):
    """Send a jog, expect ok, return the report once the machine is Idle again."""
    assert s.send(line) == "ok", line
    st = s.wait_state(("Idle",), timeout)
    assert st["state"] == "Idle", (line, st)
    return np.array(st["pos"])


def test_absolute_jogs_g90_in_work_and_g53_in_machine_coordinates(daemon):
    s, *_ = daemon
    p0 = np.array(s.status()["pos"])
    assert s.send("G10 L2 P1 X1 Y-2 Z170") == "ok"             # G54: W = M - (1, -2, 170)
    assert s.status()["WCO"] == "1.000,-2.000,170.000,0.000,0.000"
    p = _jog_to_rest(s, "$J=G90 X0 Y0 F600")                   # work zero of X and Y
    assert np.allclose(p, [1, -2, p0[2], p0[3], p0[4]], atol=2e-3), p
    p = _jog_to_rest(s, "$J=G90 Z2.5 F600")                     # Z alone; X Y stay
    assert np.allclose(p, [1, -2, 172.5, p0[3], p0[4]], atol=2e-3), p
    p = _jog_to_rest(s, "$J=G53 X-1.5 Y0.5 F600")               # machine coordinates, offsets ignored
    assert np.allclose(p, [-1.5, 0.5, 172.5, p0[3], p0[4]], atol=2e-3), p
    p = _jog_to_rest(s, "$J=G21 G53 G90 X0.25 F600")            # G90 with G53 is still machine
    assert np.allclose(p, [0.25, 0.5, 172.5, p0[3], p0[4]], atol=2e-3), p
    assert s.send("$G") == "ok" and "G90" in s.pushed[-1]       # the jog's modes were its own
    p = _jog_to_rest(s, f"$J=G53 X{p0[0]:.4f} Y{p0[1]:.4f} Z{p0[2]:.4f} F600")
    assert np.allclose(p, p0, atol=2e-3)
    assert s.send("G10 L2 P1 X0 Y0 Z0") == "ok"


def test_a_b_jogs_tilt_the_tool_about_its_tip(daemon):
    s, *_ = daemon
    p0 = np.array(s.status()["pos"])
    p = _jog_to_rest(s, "$J=G91 A3 F600")
    assert np.allclose(p[:3], p0[:3], atol=2e-3) and abs(p[3] - (p0[3] + 3)) <= 2e-3 and abs(p[4] - p0[4]) <= 2e-3, p
    p = _jog_to_rest(s, "$J=G90 B-2 F600")                      # absolute B (WCO B is 0)
    assert np.allclose(p[:3], p0[:3], atol=2e-3) and abs(p[3] - (p0[3] + 3)) <= 2e-3 and abs(p[4] + 2) <= 2e-3, p
    p = _jog_to_rest(s, "$J=G91 X1 A-3 B2 F600")                # tip and tilt together
    assert np.allclose(p, p0 + [1, 0, 0, 0, 0], atol=2e-3), p
    p = _jog_to_rest(s, "$J=G91 X-1 F600")
    assert np.allclose(p, p0, atol=2e-3)


def test_a_jog_sent_while_one_runs_is_queued_and_a_cancel_drops_the_queue(daemon):
    s, *_ = daemon
    p0 = np.array(s.status()["pos"])
    # queued: the second jog starts where the first ends (G91 from the end of the queued motion)
    assert s.send("$J=G91 X4 F300") == "ok"
    assert s.status()["state"] == "Jog"
    assert s.send("$J=G91 Y3 F300") == "ok"
    assert s.send("$J=G91 X-1 Y-1 F300") == "ok"
    st = s.wait_state(("Idle",), 60)
    p1 = np.array(st["pos"])
    assert np.allclose(p1 - p0, [3, 2, 0, 0, 0], atol=2e-3), p1 - p0
    # cancel during the first of two jogs: it stops on its own line, the second never runs
    assert s.send("$J=G91 X-10 F200") == "ok"
    assert s.send("$J=G91 Y-10 F300") == "ok"
    t0 = time.time()
    while s.status()["pos"][0] - p1[0] > -0.5 and time.time() - t0 < 60:    # moving along the first
        time.sleep(0.02)
    s.realtime(b"\x85")
    st = s.wait_state(("Idle",), 30)
    p2 = np.array(st["pos"])
    assert -10 < p2[0] - p1[0] < -0.5                            # part-way along X ...
    assert np.allclose((p2 - p1)[1:], 0, atol=2e-3), p2 - p1     # ... on its line; no Y at all
    assert s.send("G4 P0") == "ok"
    assert np.allclose(s.status()["pos"], p2, atol=2e-3)        # nothing queued is left to run
    p = _jog_to_rest(s, f"$J=G53 X{p0[0]:.4f} Y{p0[1]:.4f} F600")
    assert np.allclose(p, p0, atol=2e-3)
