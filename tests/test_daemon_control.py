"""The control socket of `pmctl serve` (JSON lines, owner/group only) and `pmctl ctl`: queue jobs
(the next planned while the current runs), list, hold/resume, override, status, subscribe, record
start/stop."""

import json
import os
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from grbl_sender import start_serve, stop_serve
from pmctl.interfaces.commands.ctl import request

ROOT = Path(__file__).resolve().parents[1]


def test_control_socket_queue_hold_resume_override_subscribe(tmp_path):
    sock = tmp_path / "pmctl.sock"
    a = tmp_path / "a.ngc"
    b = tmp_path / "b.ngc"
    a.write_text("G21 G91 G1 F600 X6\n")
    b.write_text("G21 G91 G1 F600 Y4\n")
    p, link = start_serve(tmp_path, extra=("--socket", str(sock)))
    try:
        assert stat.S_IMODE(os.stat(sock).st_mode) == 0o660
        st0 = request(sock, {"cmd": "status"})
        assert st0["ok"] and st0["state"] == "Idle" and len(st0["mpos"]) == 5
        assert request(sock, {"cmd": "queue", "add": str(a)})["ok"]
        assert request(sock, {"cmd": "queue", "add": str(b)})["ok"]          # planned while a runs
        items = request(sock, {"cmd": "queue", "list": True})["items"]
        assert [i["name"] for i in items] == ["a.ngc", "b.ngc"] or [i["name"] for i in items] == ["b.ngc"]
        bad = request(sock, {"cmd": "queue", "add": str(tmp_path / "missing.ngc")})
        assert not bad["ok"] and "missing.ngc" in bad["error"]
        assert request(sock, {"cmd": "override", "feed": 1.5})["ok"]
        assert not request(sock, {"cmd": "override", "feed": 5})["ok"]
        assert request(sock, {"cmd": "hold"})["ok"]
        t0 = time.time()
        while request(sock, {"cmd": "status"})["state"] != "Hold:0" and time.time() - t0 < 30:
            time.sleep(0.1)
        assert request(sock, {"cmd": "status"})["state"] == "Hold:0"
        # pmctl ctl, the CLI, on the same socket
        out = subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", "ctl", "--socket", str(sock), "resume"],
                             capture_output=True, text=True, cwd=ROOT)
        assert out.returncode == 0 and json.loads(out.stdout)["ok"]
        s, f = request(sock, {"cmd": "subscribe", "period_s": 0.1}, stream=True)
        lines = [json.loads(f.readline()) for _ in range(3)]
        s.close()
        assert all(x["ok"] for x in lines)
        t0 = time.time()
        while time.time() - t0 < 120:
            st = request(sock, {"cmd": "status"})
            if st["state"] == "Idle" and st["queued_items"] == 0:
                break
            time.sleep(0.2)
        assert np.allclose(np.subtract(st["mpos"], st0["mpos"])[:3], [6, 4, 0], atol=2e-3)   # both jobs ran
        # record start / stop: the recording holds the move made while it was on, finalised at stop
        rec = tmp_path / "rec"
        out = subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", "ctl", "--socket", str(sock), "record",
                              "start", str(rec)], capture_output=True, text=True, cwd=ROOT)
        assert out.returncode == 0 and json.loads(out.stdout)["folder"] == str(rec)
        again = request(sock, {"cmd": "record", "start": str(tmp_path / "other")})
        assert not again["ok"] and "already recording" in again["error"]
        c = tmp_path / "c.ngc"
        c.write_text("G21 G91 G1 F600 X-3\n")
        assert request(sock, {"cmd": "queue", "add": str(c)})["ok"]
        t0 = time.time()
        while time.time() - t0 < 120:
            st2 = request(sock, {"cmd": "status"})
            if abs(st2["mpos"][0] - (st["mpos"][0] - 3)) < 1e-3 and st2["sigma"] == 0:
                break
            time.sleep(0.2)
        time.sleep(0.2)
        assert request(sock, {"cmd": "record", "stop": True})["ok"]
        assert not request(sock, {"cmd": "record", "stop": True})["ok"]
    finally:
        stop_serve(p)
    from pmctl.core.recording import read_recording
    r = read_recording(rec)
    x = r["tip_x"][np.isfinite(r["tip_x"])]
    assert abs((x.max() - x.min()) - 3.0) < 2e-3 and abs(x[-1] - (st["mpos"][0] - 3)) < 2e-3
