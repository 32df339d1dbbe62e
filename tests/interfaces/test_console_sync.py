"""grbl 1.1 synchronisation and small protocol facts on the console of `pmctl serve`, over a real pty:
G4 (any P, also 0) and M2/M30 are answered once all queued motion has run, as grbl's
protocol_buffer_synchronize does, while realtime bytes keep working and a soft reset ends the wait;
Ln only for lines with an N word; grbl's error codes for a negative jog feed and a $ value that is
no number; a feed hold while idle; no ``-0.000``; Run as soon as a motion line is accepted."""

import time

import numpy as np
import pytest

from grbl_sender import serve_session


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    yield from serve_session(tmp_path_factory, "console_sync")


def test_a_dwell_of_zero_is_ok_and_motion_after_it_runs(daemon):
    s, *_ = daemon
    for dwell in ("G4 P0", "G4 P0.001", "N3 G4 P0"):
        p0 = np.array(s.status()["pos"])
        assert s.send(dwell) == "ok"
        assert s.send("G21 G91 G1 X1 F600") == "ok" and s.send("G90") == "ok"
        assert s.send("G4 P0.01") == "ok"
        st = s.status()
        assert st["state"] == "Idle", (dwell, st)
        assert np.allclose(np.array(st["pos"]) - p0, [1, 0, 0, 0, 0], atol=2e-3), (dwell, st)


def test_g4_answers_once_the_queued_motion_has_run_m30_once_the_end_is_queued(daemon):
    s, *_ = daemon
    p0 = np.array(s.status()["pos"])
    assert s.send("G21 G91 G1 X-6 F600") == "ok"
    assert s.send("G4 P0.01") == "ok"                   # the way interface.md detects an empty buffer
    st = s.status()
    assert st["state"] == "Idle" and np.allclose(np.array(st["pos"]) - p0, [-6, 0, 0, 0, 0], atol=2e-3)
    assert s.send("G1 X6 F600") == "ok"
    n = len(s.pushed)
    assert s.send("M30") == "ok"                         # the program's end is queued: answered then
    st = s.status()
    assert st["state"] == "Run" and st["pos"][0] < p0[0] - 1.0, st     # 6 mm at 10 mm/s: still on the way
    assert s.wait_for(lambda: "[MSG:Pgm End]" in s.pushed[n:], 60)    # said when the machine gets there
    st = s.status()
    assert st["state"] == "Idle" and np.allclose(st["pos"], p0, atol=2e-3)
    assert s.send("$G") == "ok" and "G90" in s.pushed[-1]          # M30 reset the modes (G91 -> G90)


def test_realtime_bytes_work_during_the_wait_and_a_reset_ends_it(daemon):
    s, *_ = daemon
    p0 = np.array(s.status()["pos"])
    assert s.send("G21 G91 G1 Y-8 F300") == "ok"
    n = len(s.answers)
    s.send("G4 P0.01", wait=False)
    assert s.wait_state(("Run",), 30)["state"] == "Run"   # '?' is answered while G4 waits
    s.realtime(b"!")
    assert s.wait_state(("Hold:0",), 30)["state"] == "Hold:0"
    time.sleep(0.3)
    assert len(s.answers) == n                           # held: the dwell line is not answered
    s.realtime(b"~")
    assert s.wait_state(("Run",), 30)["state"] == "Run"
    assert s.wait_for(lambda: s.status()["pos"][1] - p0[1] < -0.1, 60)    # on its way again
    pushed = s.reset()                                   # a soft reset ends the wait: no answer to G4
    assert "Grbl 1.1h ['$' for help]" in pushed
    st = s.wait_state(("Idle",), 30)
    assert -8 < st["pos"][1] - p0[1] < -0.05             # stopped part-way
    time.sleep(0.3)
    s._pump(0.2)
    assert len(s.answers) == n
    assert s.send("G90") == "ok"


def test_ln_only_for_lines_with_an_n_word(daemon):
    s, *_ = daemon
    seen = []
    s.stream(["G21 G91", "G1 X2 F300", "N15 G1 X-2 F300", "G90"])
    while True:
        st = s.status()
        seen.append(st)
        if st["state"] == "Idle" and len(seen) > 1:
            break
        time.sleep(0.05)
    run = [x for x in seen if x["state"] == "Run"]
    assert run and all(x.get("Ln") in (None, "15") for x in run)
    assert any(x.get("Ln") == "15" for x in run)


def test_grbl_error_codes_hold_while_idle_and_no_negative_zero(daemon):
    s, *_ = daemon
    assert s.send("$J=G91 X1 F-5") == "error:4"          # negative value
    assert s.send("$10=abc") == "error:2"                # bad number format
    assert s.send("$10=1") == "ok"
    s.realtime(b"!")
    assert s.wait_state(("Hold:0",), 10)["state"] == "Hold:0"
    s.realtime(b"~")
    assert s.wait_state(("Idle",), 10)["state"] == "Idle"
    n = len(s.pushed)
    assert s.send("$#") == "ok"
    assert not any("-0.000" in x for x in s.reports + s.pushed[n:]), [x for x in s.reports if "-0.000" in x][:3]


def test_run_as_soon_as_a_motion_line_is_accepted(daemon):
    s, *_ = daemon
    assert s.send("G21 G91 G1 Z-2 F600") == "ok"
    st = s.status()                                      # asked right after the ok
    assert st["state"] == "Run", st
    assert s.send("$J=G91 X1 F100") == "error:8"         # a jog only when idle: the Z move is queued
    assert s.send("G1 Z2 F600") == "ok" and s.send("G90") == "ok" and s.send("G4 P0") == "ok"
    assert s.status()["state"] == "Idle"
