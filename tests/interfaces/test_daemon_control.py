"""The control socket of `pmctl serve` (JSON lines, owner/group only) and `pmctl ctl`: queue jobs
(the next planned while the current runs), list, hold/resume, override, status, subscribe, record
start/stop; the rapid override (reported by the socket and the console's Ov:), an E-stop mid-job
(Alarm 10 with its reason, not a pulse more), unlock (Idle where it stopped), and stop mid-job (the
tool stays on the job's line, no alarm)."""

import json
import os
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from grbl_sender import Sender, start_serve, stop_serve
from pmctl.interfaces.commands.ctl import request
import pytest

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]


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
        # record start refused (a killed session's rec.partial is there): nothing changes, the next start works
        rec = tmp_path / "rec"
        (tmp_path / "rec.partial").mkdir()
        refused = request(sock, {"cmd": "record", "start": str(rec)})
        assert not refused["ok"] and "rec.partial exists" in refused["error"], refused
        assert not request(sock, {"cmd": "record", "stop": True})["ok"]          # not recording
        (tmp_path / "rec.partial").rmdir()
        # record start / stop: the recording holds the move made while it was on, finalised at stop
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


def _wait(pred, sock, timeout=60.0):
    """The first status (control socket) for which ``pred`` holds, or the last one after ``timeout``."""
    t0 = time.time()
    st = request(sock, {"cmd": "status"})
    while not pred(st) and time.time() - t0 < timeout:
        time.sleep(0.02)
        st = request(sock, {"cmd": "status"})
    return st


def _at_rest(sock, st, ticks=200):
    """A later status, ``ticks`` rt ticks after ``st`` (time passed for the machine, not the test)."""
    return _wait(lambda x: x["tick"] >= st["tick"] + ticks, sock)


def _ctl(sock, *args):
    out = subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", "ctl", "--socket", str(sock), *args],
                         capture_output=True, text=True, cwd=ROOT)
    return out.returncode, json.loads(out.stdout)


def test_control_socket_override_rapid_estop_unlock_and_stop(tmp_path):
    sock = tmp_path / "pmctl.sock"
    p, link = start_serve(tmp_path, extra=("--socket", str(sock)))
    s = Sender(link)
    try:
        s.reset()
        st0 = request(sock, {"cmd": "status"})
        assert st0["state"] == "Idle"
        # override rapid: the factor the rt side applies, and the console's Ov: says it too
        rc, ans = _ctl(sock, "override", "--rapid", "0.5")
        assert rc == 0 and ans["ok"]
        assert _wait(lambda x: x["rapid_override"] == 0.5, sock)["rapid_override"] == 0.5
        assert s.status()["Ov"] == "100,50,100"
        bad = request(sock, {"cmd": "override", "rapid": 0.3})
        assert not bad["ok"] and "0.25, 0.5 or 1.0" in bad["error"]
        assert request(sock, {"cmd": "status"})["rapid_override"] == 0.5          # a refused value changes nothing
        assert request(sock, {"cmd": "override", "rapid": 0.25})["ok"]
        assert _wait(lambda x: x["rapid_override"] == 0.25, sock)["rapid_override"] == 0.25
        assert s.status()["Ov"] == "100,25,100"
        assert request(sock, {"cmd": "override", "rapid": 1.0})["ok"]
        assert _wait(lambda x: x["rapid_override"] == 1.0, sock)["rapid_override"] == 1.0

        # estop mid-job: Alarm 10 with its reason, motion stops at once and stays stopped
        job = tmp_path / "x.ngc"
        job.write_text("G21 G91 G1 F300 X-10\n")
        assert request(sock, {"cmd": "queue", "add": str(job)})["ok"]
        _wait(lambda x: x["mpos"][0] - st0["mpos"][0] < -0.5, sock)
        n = len(s.pushed)
        rc, ans = _ctl(sock, "estop")
        assert rc == 0 and ans["ok"]
        st1 = _wait(lambda x: x["state"] == "Alarm", sock)
        assert st1["state"] == "Alarm" and st1["alarm"] == 10
        assert "E-stop from the control socket" in st1["alarm_msg"] and st1["queued_items"] == 0
        assert s.wait_for(lambda: "[MSG:E-stop from the control socket]" in s.pushed[n:], 30)
        assert s.pushed[s.pushed.index("[MSG:E-stop from the control socket]", n) - 1] == "ALARM:10"
        st2 = _at_rest(sock, st1)
        st3 = _at_rest(sock, st2)
        assert st2["counts"] == st3["counts"], (st2["counts"], st3["counts"])      # not a pulse more
        assert -10 < st3["mpos"][0] - st0["mpos"][0] < -0.5                        # part-way ...
        assert np.allclose(np.subtract(st3["mpos"], st0["mpos"])[1:], 0, atol=2e-3)   # ... on the X line
        refused = request(sock, {"cmd": "queue", "add": str(job)})
        assert not refused["ok"] and "alarm" in refused["error"]
        assert s.send("G1 X1 F300") == "error:9"
        # unlock: Idle at the same position, the dropped job does not come back
        rc, ans = _ctl(sock, "unlock")
        assert rc == 0 and ans["ok"]
        st4 = _wait(lambda x: x["state"] == "Idle", sock)
        assert st4["state"] == "Idle" and st4["alarm"] == 0 and st4["alarm_msg"] == "" and st4["queued_items"] == 0
        st5 = _at_rest(sock, st4)
        assert st5["state"] == "Idle" and np.abs(np.subtract(st5["counts"], st3["counts"])).max() <= 1   # where it stopped

        # stop mid-job: a soft reset, the job ends with the tool on its line, no alarm
        back = tmp_path / "back.ngc"
        back.write_text("G21 G91 G1 F300 X10\n")
        assert request(sock, {"cmd": "queue", "add": str(back)})["ok"]
        _wait(lambda x: x["mpos"][0] - st5["mpos"][0] > 0.5, sock)
        n = len(s.pushed)
        rc, ans = _ctl(sock, "stop")
        assert rc == 0 and ans["ok"]
        st6 = _wait(lambda x: x["state"] == "Idle" and x["queued_items"] == 0 and x["sigma"] == 0, sock)
        assert st6["state"] == "Idle" and st6["alarm"] == 0 and st6["queued_items"] == 0
        st7 = _at_rest(sock, st6)
        st8 = _at_rest(sock, st7)
        # stopped and staying: the NC goes on regulating at rest (a counter may dither by one pulse,
        # 0.5 um), unlike the halted NC of an E-stop above
        assert np.abs(np.subtract(st8["counts"], st6["counts"])).max() <= 1, (st6["counts"], st8["counts"])
        assert 0.5 < st7["mpos"][0] - st5["mpos"][0] < 10                           # part-way ...
        assert np.allclose(np.subtract(st7["mpos"], st5["mpos"])[1:], 0, atol=2e-3)   # ... on the X line
        s.status()
        assert not any(x.startswith("ALARM") for x in s.pushed[n:])
        # and the machine takes the next job as usual
        assert request(sock, {"cmd": "queue", "add": str(back)})["ok"]
        st9 = _wait(lambda x: x["state"] == "Idle" and x["queued_items"] == 0 and x["sigma"] == 0
                    and abs(x["mpos"][0] - (st7["mpos"][0] + 10)) < 2e-3, sock, 120)
        assert np.allclose(np.subtract(st9["mpos"], st7["mpos"]), [10, 0, 0, 0, 0], atol=2e-3)
    finally:
        s.close()
        stop_serve(p)
