"""The stall policy: on the sim (a backend that can ride out a stall, Backend.stall_hold) a stall of
the rt process in the middle of a move -- SIGSTOP for 0.3 s, a computer too busy to schedule it --
is a feed hold on the path that resumes by itself once the ticks are on time again: no alarm, the
tool stays on the programmed line and arrives at its target. Backends that cannot (the step/dir
bridge, CSP drives) keep the controlled stop."""

import os
import signal
import time

import numpy as np

from grbl_sender import Sender, rt_pid_of, start_serve, stop_serve
from pmctl.hal.canopen_csp import CanopenCSP
from pmctl.hal.sim import SimBackend
from pmctl.hal.stepdir import StepDirBackend
import pytest

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow


def test_which_backends_ride_out_a_stall():
    assert SimBackend.stall_hold and not StepDirBackend.stall_hold and not CanopenCSP.stall_hold


def test_a_stall_mid_move_is_a_hold_on_the_path_then_it_goes_on(tmp_path):
    p, link = start_serve(tmp_path, realtime=True)
    s = Sender(link)
    try:
        p0 = np.array(s.status()["pos"])
        assert s.send("G21 G91 G1 X8 F300") == "ok" and s.send("G90") == "ok"
        assert s.wait_for(lambda: s.status()["pos"][0] - p0[0] > 1.0, 60)        # under way at 5 mm/s
        rt = rt_pid_of(p.pid)
        os.kill(rt, signal.SIGSTOP)
        time.sleep(0.3)
        os.kill(rt, signal.SIGCONT)
        seen = []
        t0 = time.time()
        while time.time() - t0 < 60:
            st = s.status()
            seen.append(st)
            if st["state"] == "Idle":
                break
            time.sleep(0.05)
        assert seen[-1]["state"] == "Idle", seen[-3:]
        assert not [x for x in s.pushed if x.startswith("ALARM:")], s.pushed[-5:]
        d = np.array([x["pos"] for x in seen]) - p0
        assert np.all(np.abs(d[:, 1:]) < 1e-3), d            # on the line: only X moved
        assert np.allclose(d[-1], [8, 0, 0, 0, 0], atol=2e-3), d[-1]
        err = (tmp_path / "serve.err").read_text()
        assert "loop stalled" in err and "feed hold on the path" in err and "resumed after the stall" in err, err[-2000:]
    finally:
        s.close()
        stop_serve(p)
