"""The console of `pmctl serve` after a crash, over a real pty: the daemon comes back in Alarm 11
(the saved position is a periodic snapshot, not trusted; a job was interrupted) before the console
exists, and the console says so -- grbl's start-up message, ``[MSG:'$H'|'$X' to unlock]`` right
after it, then ``ALARM:11`` and ``[MSG:reason]`` with the position's age, that it is not trusted
and the interrupted job -- at start and again after each soft reset while the alarm lasts."""

import os
import termios
import tty

import numpy as np

from grbl_sender import Sender, power_cut_mid_move, start_serve, stop_serve
import pytest

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

BANNER = "Grbl 1.1h ['$' for help]"
UNLOCK = "[MSG:'$H'|'$X' to unlock]"


def open_keeping(link) -> Sender:
    """A sender that keeps what the daemon wrote before it opened the pty: ``tty.setraw``'s default
    (TCSAFLUSH) would discard the start-up message, so the line settings change at once instead."""
    s = Sender.__new__(Sender)
    s.fd = os.open(str(link), os.O_RDWR | os.O_NOCTTY)
    tty.setraw(s.fd, termios.TCSANOW)
    s.buf, s.pending, s.answers, s.pushed, s.reports = b"", [], [], [], []
    return s


def _alarm_block(pushed, start=0):
    """The start-up message at or after ``start`` and the lines after it: (index of the banner, the
    three lines that follow it)."""
    i = pushed.index(BANNER, start)
    return i, pushed[i + 1:i + 4]


def test_a_crash_comes_back_in_alarm_and_the_console_says_why(tmp_path):
    state = tmp_path / "state.json"
    p0 = power_cut_mid_move(tmp_path, state)
    p, link = start_serve(tmp_path, state=state)
    s = open_keeping(link)
    try:
        # the start-up message the daemon wrote before anyone listened, then the alarm and its reason
        assert s.wait_for(lambda: sum(x.startswith("[MSG:position") for x in s.pushed) >= 1, 60), s.pushed
        i, after = _alarm_block(s.pushed)
        assert after[0] == UNLOCK and after[1] == "ALARM:11", s.pushed
        reason = after[2]
        assert reason.startswith("[MSG:") and reason.endswith("]")
        assert "NOT trusted" in reason and " s old" in reason                     # age, not trusted
        assert "job console was interrupted at line" in reason                    # the interrupted job
        assert s.pushed.count("ALARM:11") == 1                                    # said once
        st = s.status()
        assert st["state"] == "Alarm"
        assert -12 < st["pos"][0] - p0[0] < -0.3                                  # stopped part-way ...
        assert np.allclose(np.array(st["pos"][1:]), p0[1:], atol=2e-3)            # ... on the X line
        # a soft reset in alarm: the start-up message again, and the alarm with it
        n = len(s.pushed)
        s.reset()
        s.wait_for(lambda: sum(x.startswith("[MSG:position") for x in s.pushed[n:]) >= 1, 30)
        i2, after2 = _alarm_block(s.pushed, n)
        assert after2 == [UNLOCK, "ALARM:11", reason], s.pushed[n:]
        assert s.send("G1 X1") == "error:9"                                       # still locked
        n = len(s.pushed)
        assert s.send("$X") == "ok" and "[MSG:Caution: Unlocked]" in s.pushed[n:]
        assert s.wait_state(("Idle",), 30)["state"] == "Idle"
        pushed = s.reset()                                                        # no alarm: the banner only
        assert BANNER in pushed and not any(x.startswith("ALARM") or x == UNLOCK for x in pushed), pushed
    finally:
        s.close()
        stop_serve(p)
