"""A soft reset (ctrl-X) while the console executes a line: grbl drops the line, and so must we.

CNCjs keeps streaming while it holds (it sends the next line on each ``ok`` while paused) and its
forced stop sends ctrl-X 500 ms after ``!``: the console's worker is then usually in the middle of a
line. Before the fix that line's motion was queued after the reset had dropped the queue: it was
neither planned nor dropped, and the machine reported Run at rest for ever (a sender waits for Idle:
it could not start again); queued after the reset's end, it would have moved the machine after the
reset. Its parser changes (G91 here) could also outlive the reset.

This test streams as CNCjs does, G91 lines through a hold, and resets at different points of the
stream; after each reset: Idle, nothing moves, the parser is the reset's (G90), no answer to the
dropped lines."""

import time
from pathlib import Path

import numpy as np
import pytest

from grbl_sender import Sender, start_serve, stop_serve

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
CNCJS_BUFFER = 120                      # CNCjs's character-counting buffer (grbl's 128 less 8)


class _Pushed(list):
    """The sender's pushed lines, noting how many answers had come when a banner came."""

    def __init__(self, s):
        super().__init__()
        self.s = s

    def append(self, x):
        if x.startswith("Grbl "):
            self.s.answers_at_banner = len(self.s.answers)
        super().append(x)


@pytest.fixture
def sender(tmp_path):
    p, link = start_serve(tmp_path)
    s = Sender(link)
    s.pushed = _Pushed(s)
    s.reset()
    try:
        yield s
    finally:
        s.close()
        stop_serve(p)


def _feed(s, lines, i):
    """CNCjs's sender: the next lines while they fit its buffer (it goes on while paused)."""
    while i < len(lines) and sum(s.pending) + len(lines[i]) + 1 <= CNCJS_BUFFER:
        s.send(lines[i], wait=False)
        i += 1
    return i


def _pump_feeding(s, lines, i, seconds):
    t0 = time.time()
    while time.time() - t0 < seconds:
        i = _feed(s, lines, i)
        s._pump(0.002)
    return i


def test_a_reset_while_a_line_executes_drops_it_and_the_machine_is_idle_where_it_stopped(sender):
    s = sender
    lines = ["G21 G90 G17", "G0 X19 Y0 Z65", "S12000 M3", "G1 Z62 F600"] + ["G91 G1 X-0.05 Y0.02 F1500"] * 300
    # (delay after the 4th ok before "!", delay in the hold before ctrl-X): the reset lands in the
    # rapid, at the spindle's hold point, in the feed moves, early and late in a complete hold
    timings = [(0.0, 0.0), (0.15, 0.1), (0.3, 0.25), (0.5, 0.05), (0.7, 0.4), (0.9, 0.15), (1.1, 0.5), (0.05, 0.3)]
    for k, (d_hold, d_reset) in enumerate(timings):
        assert s.send("G90 G0 X19 Y0 Z65") == "ok"
        assert s.wait_state(("Idle",), 60)["state"] == "Idle"
        n0, i = len(s.answers), 0
        while len(s.answers) - n0 < 4:
            i = _feed(s, lines, i)
            s._pump(0.002)
        i = _pump_feeding(s, lines, i, d_hold)
        s.realtime(b"!")
        t0 = time.time()
        while True:
            i = _feed(s, lines, i)
            st = s.status()
            if st and st["state"].startswith("Hold"):
                break
            assert time.time() - t0 < 60, f"reset {k}: no Hold after '!' ({st})"
        i = _pump_feeding(s, lines, i, d_reset)
        s.reset()
        st = s.wait_state(("Idle",), 30)
        assert st["state"] == "Idle", (f"reset {k} ({d_hold} s, {d_reset} s): {st['state']} at rest after "
                                       f"the reset, a dropped line still queued ({i} lines sent)")
        p = np.array(st["pos"])
        s.wait_for(lambda: False, 1.0)
        st2 = s.status()
        assert np.allclose(st2["pos"], p, atol=1e-3), f"reset {k}: moved after the reset {p} -> {st2['pos']}"
        assert st2["state"] == "Idle"
        # the dropped lines got no answer: nothing came after the reset's banner
        assert len(s.answers) == s.answers_at_banner, \
            f"reset {k}: answers to dropped lines {s.answers[s.answers_at_banner:]}"
        n_pushed = len(s.pushed)
        assert s.send("$G") == "ok"
        gc = [x for x in s.pushed[n_pushed:] if x.startswith("[GC:")]
        assert gc and "G90" in gc[-1].split(), f"reset {k}: the parser after the reset: {gc}"
