"""Command sequences of two senders too heavy to install here, replayed byte for byte over the pty
of `pmctl serve` (sim), transcribed from their sources (no code copied):

- bCNC (github.com/vlachoudis/bCNC): its Stop button (bCNC/Sender.py ``stopRun``: feed hold, then
  ``purgeController`` in bCNC/controllers/_GenericController.py: ``!``, a second's wait, ctrl-X, GRBL1's
  ``purgeControllerExtra`` ``$X`` after a second, the G words of the last ``$G`` restored, ``G43.1Z`` with
  the tool length offset it holds (0.0), then ``$G`` and ``$#``); its probe button (bCNC/ProbePage.py
  ``probe``: ``prbcmd`` + the axis target + ``F``, no spaces; G38.3 chosen, so no alarm without a
  surface); its GRBL 1.1 jog (bCNC/controllers/GRBL1.py ``jog``: ``$J=G91 X1 F100000``).
- Universal G-code Sender (github.com/winder/Universal-G-Code-Sender): connecting
  (ugs-core/.../GrblControllerInitializer.java: ``?``, then ``$I``, ``$$``, ``$G``), a jog
  (GrblController.jogMachine with GcodeUtils.generateMoveCommand: ``$J=G21G91X1F1000``), pause and
  resume (``!``/``~``, GrblUtils), and cancel (GrblController.cancelSendBeforeEvent: ``!``; once the
  machine has stopped, the soft reset 0x18) followed by the initialisation again.
"""

import time

import numpy as np
import pytest

from grbl_sender import hold_still_resume, serve_session


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    yield from serve_session(tmp_path_factory, "replays")


def test_ugs_connect_jog_pause_resume_cancel(daemon):
    s, *_ = daemon

    def initialise():
        st = s.status()
        assert st is not None and st["state"] in ("Idle", "Alarm")
        n = len(s.pushed)
        assert [s.send(c) for c in ("$I", "$$", "$G")] == ["ok"] * 3
        assert any(x.startswith("[VER:1.1") for x in s.pushed[n:])
        assert any(x.startswith("$110=") for x in s.pushed[n:]) and any(x.startswith("[GC:") for x in s.pushed[n:])
    initialise()
    p0 = np.array(s.status()["pos"])
    assert s.send("$J=G21G91X1F1000") == "ok"
    assert s.wait_for(lambda: abs(s.status()["pos"][0] - p0[0] - 1.0) < 1e-3, 30)
    assert s.wait_state(("Idle",), 30)["state"] == "Idle"
    # a small program streamed, paused and resumed, then cancelled
    lines = ["G21 G90", "G91", "G1 X3 F300", "G1 Y3", "G1 X-3", "G1 Y-3", "G90"]
    s.stream(lines)
    assert s.wait_state(("Run",), 30)["state"] == "Run"
    hold_still_resume(s)
    assert s.wait_state(("Run",), 30)["state"] == "Run"
    s.realtime(b"!")                                      # cancel: pause, wait until still, soft reset
    assert s.wait_state(("Hold:0",), 30)["state"] == "Hold:0"
    n = len(s.pushed)
    s.realtime(b"\x18")
    s.wait_for(lambda: any(x.startswith("Grbl ") for x in s.pushed[n:]), 30)
    assert s.wait_state(("Idle",), 30)["state"] == "Idle"
    initialise()
    assert not [x for x in s.pushed if x.startswith("ALARM:")]


def test_bcnc_stop_probe_and_jog(daemon):
    s, *_ = daemon
    s.realtime(b"?")
    assert s.send("$G") == "ok"
    gc = [x for x in s.pushed if x.startswith("[GC:")][-1]
    g_words = " ".join(w for w in gc[4:-1].split() if w.startswith("G"))
    p0 = np.array(s.status()["pos"])
    # a job running, then Stop: feed hold, purge
    assert s.send("G21 G91 G1 X4 F300") == "ok" and s.send("G90") == "ok"
    assert s.wait_for(lambda: s.status()["pos"][0] - p0[0] > 0.2, 30)      # under way
    s.realtime(b"!")
    time.sleep(1.0)
    s.pending.clear()
    n = len(s.pushed)
    s.realtime(b"\x18")
    s.wait_for(lambda: any(x.startswith("Grbl ") for x in s.pushed[n:]), 30)
    time.sleep(1.0)
    answers = [s.send(line) for line in ("$X", g_words, "G43.1Z0.0", "$G", "$#")]
    assert answers == ["ok"] * 5, answers
    st = s.wait_state(("Idle",), 30)
    assert st["state"] == "Idle" and 0.05 < st["pos"][0] - p0[0] < 4.0       # stopped part-way, no alarm
    # probe (G38.3: no surface in the default sim, so no contact and no alarm)
    n = len(s.pushed)
    z = st["pos"][2]
    assert s.send(f"G38.3Z{z - 0.5:.3f}F100") == "ok"
    prb = [x for x in s.pushed[n:] if x.startswith("[PRB:")]
    assert prb and prb[0].endswith(":0]"), s.pushed[n:]
    # jog at bCNC's F100000: capped by the machine, it arrives
    p1 = np.array(s.status()["pos"])
    assert s.send("$J=G91 X1 F100000") == "ok"
    assert s.wait_for(lambda: abs(s.status()["pos"][0] - p1[0] - 1.0) < 1e-3, 30)
    assert s.wait_state(("Idle",), 30)["state"] == "Idle"
