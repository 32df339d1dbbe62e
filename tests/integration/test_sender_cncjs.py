"""CNCjs 1.11.5 (npm, pinned in tests/peers/npm/cncjs, installed by tests/peers/install) drives
`pmctl serve` on the sim over its console pty, through CNCjs's socket.io API as its web UI does
(tests/cncjs_driver.js): open the port as a Grbl controller, load and start the bundled spiral job
(longer than the console's planner queue),
feed override +100 %, hold (gcode:pause) and resume, to the end with no error and no alarm; a jog as
the Axes widget sends it (G91, G0 X.., G90); pause and a forced stop mid-job (gcode:stop sends ctrl-X
once the machine holds), after which the machine is Idle where it stopped, without an alarm."""

import json
import os
import queue
import socket
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from grbl_sender import start_serve, stop_serve

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
CNCJS = ROOT / "tests" / "peers" / "npm" / "cncjs" / "node_modules" / ".bin" / "cncjs"
DRIVER = ROOT / "tests" / "cncjs_driver.js"


class CncJs:
    """A CNCjs server and the driver script connected to it."""

    def __init__(self, tmp):
        assert CNCJS.exists(), "CNCjs is not installed: run tests/peers/install"
        s = socket.socket()
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
        s.close()
        rc = tmp / "cncrc"
        rc.write_text(json.dumps({"secret": "pmctl-test-secret", "watchDirectory": "", "mountPoints": []}))
        env = dict(os.environ, HOME=str(tmp))
        self.server = subprocess.Popen([str(CNCJS), "-H", "127.0.0.1", "-p", str(port), "-c", str(rc)],
                                       stdout=open(tmp / "cncjs.out", "w"), stderr=subprocess.STDOUT, env=env)
        t0 = time.time()
        while "Starting the server" not in (tmp / "cncjs.out").read_text():
            assert self.server.poll() is None and time.time() - t0 < 60, (tmp / "cncjs.out").read_text()[-2000:]
            time.sleep(0.1)
        self.driver = subprocess.Popen(["node", str(DRIVER), f"http://127.0.0.1:{port}", "pmctl-test-secret"],
                                       stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)
        self.events = queue.Queue()
        self.log = []
        self.state = {}
        self.sender = {}
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.driver.stdout:
            ev = json.loads(line)
            self.log.append(ev)
            if ev["ev"] == "controller:state":
                self.state = ev["data"][1]
            elif ev["ev"] == "sender:status":
                self.sender = ev["data"][0]
            self.events.put(ev)

    def emit(self, *args):
        self.driver.stdin.write(json.dumps({"emit": list(args)}) + "\n")
        self.driver.stdin.flush()

    def wait(self, pred, timeout=60.0, what=""):
        t0 = time.time()
        while time.time() - t0 < timeout:
            if pred():
                return True
            time.sleep(0.02)
        raise AssertionError(f"CNCjs: no {what} within {timeout:g} s; state {self.state}, sender {self.sender}")

    def workflow(self):
        ws = [e["data"][0] for e in self.log if e["ev"] == "workflow:state"]
        return ws[-1] if ws else ""

    def active(self):
        return self.state.get("status", {}).get("activeState", "")

    def pos(self):
        m = self.state.get("status", {}).get("mpos", {})
        return np.array([float(m.get(k, "nan")) for k in ("x", "y", "z")])

    def read_lines(self):
        return [e["data"][0] for e in self.log if e["ev"] == "serialport:read"]

    def close(self):
        for p in (self.driver, self.server):
            stop_serve(p, timeout=10)             # SIGTERM, then SIGKILL after 10 s


@pytest.fixture
def rig(tmp_path):
    p, link = start_serve(tmp_path)
    try:
        c = CncJs(tmp_path)
    except BaseException:                                 # CNCjs missing or broken: no serve left behind
        stop_serve(p)
        raise
    try:
        c.wait(lambda: any(e["ev"] == "connect" for e in c.log), 60, "socket.io connection")
        c.emit("open", str(link), {"controllerType": "Grbl", "baudrate": 115200})
        c.wait(lambda: any(e["ev"] == "serialport:open" for e in c.log), 60, "port open")
        c.wait(lambda: c.active() == "Idle", 60, "Idle status")
        yield c, link
    finally:
        c.close()
        stop_serve(p)


def test_cncjs_streams_the_spiral_with_override_hold_resume_then_jogs_and_stops(rig):
    c, link = rig
    gcode = (ROOT / "examples" / "jobs" / "spiral.ngc").read_text()     # 370 lines: more than the queue
    c.emit("command", str(link), "gcode:load", "spiral.ngc", gcode, {})
    c.wait(lambda: any(e["ev"] == "gcode:load" for e in c.log), 30, "gcode:load")
    total = c.sender.get("total") or len([ln for ln in gcode.splitlines() if ln.strip()])
    c.emit("command", str(link), "gcode:start")
    c.wait(lambda: c.active() == "Run", 60, "Run")
    for _ in range(10):                                   # feed override +100 % (ten +10 % steps)
        c.emit("command", str(link), "feedOverride", 10)
    c.wait(lambda: c.state.get("status", {}).get("ov", [0])[0] == 200, 30, "feed override 200 %")
    c.wait(lambda: c.sender.get("received", 0) >= 8, 120, "8 lines acknowledged")
    c.emit("command", str(link), "gcode:pause")
    c.wait(lambda: c.active() == "Hold", 60, "Hold")

    def still():                                          # ("Hold" is grbl's Hold:1 too: still stopping)
        p = c.pos()
        time.sleep(0.5)
        return np.allclose(c.pos(), p, atol=1e-4)
    c.wait(still, 60, "the hold to come to rest")
    p_hold = c.pos()
    time.sleep(1.0)
    assert np.allclose(c.pos(), p_hold, atol=1e-3)        # held: nothing moves
    # the oks are paced by the motion: CNCjs has not had every line acknowledged while held mid-job
    assert c.sender.get("received", 0) < total, c.sender
    c.emit("command", str(link), "gcode:resume")
    c.wait(lambda: c.active() == "Run", 30, "Run after resume")
    c.wait(lambda: c.sender.get("received", 0) >= total and c.active() == "Idle", 300, "the job's end")
    lines = c.read_lines()
    assert not [x for x in lines if x.startswith(("error:", "ALARM:"))], [x for x in lines if "error" in x][:5]
    assert any("Pgm End" in x for x in lines) or c.sender.get("received") == total
    c.emit("command", str(link), "gcode:stop")            # the UI's stop after the end: rewind the program
    c.wait(lambda: c.workflow() == "idle", 30, "workflow idle")
    # jog, as the Axes widget sends it
    p0 = c.pos()
    for line in ("G91", "G0 X1", "G90"):
        c.emit("command", str(link), "gcode", line)
    c.wait(lambda: abs(c.pos()[0] - p0[0] - 1.0) < 1e-3 and c.active() == "Idle", 60, "the jog")
    # a forced stop mid-job: feed hold, then ctrl-X
    c.emit("command", str(link), "gcode:start")
    c.wait(lambda: c.active() == "Run", 60, "Run again")
    c.wait(lambda: c.sender.get("received", 0) >= 4, 60, "4 lines acknowledged")
    c.emit("command", str(link), "gcode:pause")           # pause, then stop: CNCjs's forced stop sends ctrl-X
    c.wait(lambda: c.active() == "Hold", 60, "Hold")      # only if its next status (500 ms on) says Hold
    n = len(c.read_lines())
    c.emit("command", str(link), "gcode:stop", {"force": True})
    c.wait(lambda: any(x.startswith("Grbl ") for x in c.read_lines()[n:]), 60, "the banner after the reset")
    c.wait(lambda: c.active() == "Idle", 60, "Idle after the stop")
    p_stop = c.pos()
    time.sleep(0.5)
    assert np.allclose(c.pos(), p_stop, atol=1e-3)
    assert not [x for x in c.read_lines() if x.startswith("ALARM:")]
