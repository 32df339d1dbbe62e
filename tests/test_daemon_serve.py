"""`pmctl serve` end to end on the sim, driven over a real pty as a grbl sender does: stream a
bundled job by character counting with feed override, hold mid-job and resume, then SIGTERM and a
restart on the same state; SIGKILL of the rt process and of the supervisor; systemd notify.
Physical facts: the tool stays on the programmed path (recording vs the planned path), pulses
counted = pulses sent, position equal after a restart."""

import json
import os
import signal
import socket
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from grbl_sender import Sender, start_serve, stop_serve
from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.recording import read_recording
from pmctl.motion.state_store import load_counters
from pmctl.task.job import home_pose
from pmctl.task.planner import load_job, plan

M = load_machine()
ROOT = Path(__file__).resolve().parents[1]
JOB = ROOT / "examples" / "jobs" / "cone.ngc"


def rt_pid_of(pid):
    for t in os.listdir(f"/proc/{pid}/task"):
        kids = Path(f"/proc/{pid}/task/{t}/children").read_text().split()
        for k in kids:
            if "pmctl.motion.rtproc" in Path(f"/proc/{k}/cmdline").read_bytes().decode(errors="replace"):
                return int(k)
    return None


def dist_to_polyline(points, poly):
    tree = cKDTree(poly)
    _, idx = tree.query(points)
    best = np.full(len(points), np.inf)
    for off in range(-3, 3):
        a = poly[np.clip(idx + off, 0, len(poly) - 1)]
        b = poly[np.clip(idx + off + 1, 0, len(poly) - 1)]
        d = b - a
        L2 = np.maximum(np.sum(d * d, 1), 1e-30)
        u = np.clip(np.sum((points - a) * d, 1) / L2, 0, 1)
        best = np.minimum(best, np.linalg.norm(a + u[:, None] * d - points, axis=1))
    return best


def test_stream_a_bundled_job_hold_resume_override_then_sigterm_and_restart(tmp_path):
    rec = tmp_path / "rec"
    p, link = start_serve(tmp_path, record=rec)
    s = Sender(link)
    try:
        s.reset()
        for _ in range(10):
            s.realtime(b"\x91")                      # feed override +10 % x 10 = 200 %
        lines = [ln for ln in JOB.read_text().splitlines()]
        lines, end = lines[:-1], lines[-1]           # M30 waits for the job to run (grbl): sent after the hold
        assert end == "M30"
        answers = s.stream(lines)
        assert answers == ["ok"] * len(lines)
        st = s.wait_state(("Run",), 60)
        assert st["Ov"].startswith("200,")
        time.sleep(3.0)
        s.realtime(b"!")
        held = s.wait_state(("Hold:0",), 60)
        assert held["state"] == "Hold:0"
        time.sleep(1.0)
        again = s.status()
        assert again["state"] == "Hold:0" and np.allclose(again["pos"], held["pos"], atol=2e-3)
        s.realtime(b"~")
        n = len(s.pushed)
        assert s.send(end, timeout=600) == "ok" and "[MSG:Pgm End]" in s.pushed[n:]
        done = s.wait_state(("Idle",), 600)
        assert done["state"] == "Idle"
        job = load_job(JOB, M, start=home_pose(M))
        assert np.allclose(done["pos"][:3], job.moves[-1].tip, atol=2e-3)
        final = done["pos"]
    finally:
        s.close()
        assert stop_serve(p) == 0
    err = (tmp_path / "serve.err").read_text()
    assert "pulses sent = counter change: yes; device counters = counters: yes" in err
    # the recording: every recorded load-side tool tip lies on the programmed path
    r = read_recording(rec)
    tip = np.column_stack([r["tip_x"], r["tip_y"], r["tip_z"]])
    ok = np.all(np.isfinite(tip), axis=1)
    ref = plan(load_job(JOB, M, start=home_pose(M)), M, 1e-3, start=home_pose(M)).tip
    d = dist_to_polyline(tip[ok], ref)
    assert d.max() < 5e-3, d.max()
    sigma = r["sigma"]
    moving_before = np.nonzero(sigma > 0)[0]
    held_rows = np.nonzero((sigma == 0) & (np.arange(r.n) > moving_before[0]) & (np.arange(r.n) < moving_before[-1]))[0]
    assert len(held_rows) > 100                      # the hold is in the recording, on the path (d above)
    # restart on the same state: same position, trusted (clean stop)
    p, link = start_serve(tmp_path)
    s = Sender(link)
    try:
        st = s.status()
        assert st["state"] == "Idle"
        assert np.allclose(st["pos"], final, atol=1.5e-3)
    finally:
        s.close()
        stop_serve(p)


def test_sigkill_of_the_rt_process_and_of_the_supervisor(tmp_path):
    state = tmp_path / "state.json"
    p, link = start_serve(tmp_path, state=state)
    s = Sender(link)
    try:
        s.reset()
        assert s.send("G21 G91 G1 F300 X-15") == "ok"
        s.wait_state(("Run",), 60)
        t0 = time.time()                 # moving (planning can take a while on a loaded machine)
        while s.status()["pos"][0] > -0.5 and time.time() - t0 < 60:
            time.sleep(0.05)
        rt = rt_pid_of(p.pid)
        n = len(s.pushed)
        os.kill(rt, signal.SIGKILL)
        assert s.wait_for(lambda: "ALARM:17" in s.pushed[n:], 30)
        st = s.status()
        assert st["state"] == "Alarm"
        assert s.send("G1 X1") == "error:9"             # motion refused until unlocked
        assert s.send("$X") == "ok"
        st2 = s.wait_state(("Idle",), 60)
        assert np.allclose(st2["pos"], st["pos"], atol=1.5e-3)    # the kept position
        assert -15 < st["pos"][0] < -0.1
        # now kill the supervisor mid-move: the rt process holds on the path, saves, exits
        assert s.send("G1 Y8") == "ok"
        s.wait_state(("Run",), 60)
        journal = tmp_path / "state.json.journal"
        t0 = time.time()                 # the journal has recorded the running job (an fsync on a busy disk)
        while not json.loads(journal.read_text()).get("running") and time.time() - t0 < 20:
            time.sleep(0.05)
        t0 = time.time()                 # and it moves
        while s.status()["pos"][1] - st2["pos"][1] < 0.1 and time.time() - t0 < 60:
            time.sleep(0.05)
        rt = rt_pid_of(p.pid)
        p.send_signal(signal.SIGKILL)
        p.wait(10)
        t0 = time.time()
        while time.time() - t0 < 60:
            try:
                os.kill(rt, 0)
            except ProcessLookupError:
                break
            time.sleep(0.05)
        else:
            os.kill(rt, signal.SIGKILL)
            pytest.fail("rt process kept running after the supervisor died")
    finally:
        s.close()
        stop_serve(p)
    saved = load_counters(state, machine=M.name)
    assert saved.clean
    pose, _ = K.fk_batch((saved.counts / M.resolution.pulses_per_mm)[None], M)
    tip = pose.tip[0]
    assert np.allclose(tip[[0, 2]], np.array(st2["pos"])[[0, 2]], atol=2e-3)     # on the Y line ...
    assert 0.05 < tip[1] - st2["pos"][1] < 8                                  # ... part-way
    p, link = start_serve(tmp_path, state=state)
    s = Sender(link)
    try:
        st3 = s.status()
        assert np.allclose(st3["pos"][:3], tip, atol=1.5e-3)
        assert st3["state"] == "Alarm"                 # the journal says a job was interrupted: confirm first
        assert s.send("$X") == "ok"
        assert s.wait_state(("Idle",), 30)["state"] == "Idle"
    finally:
        s.close()
        stop_serve(p)


def test_sd_notify_ready_and_watchdog(tmp_path):
    path = str(tmp_path / "notify.sock")
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    srv.bind(path)
    srv.settimeout(1.0)
    p, link = start_serve(tmp_path, env={"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "400000"})
    got = []
    try:
        t0 = time.time()
        while time.time() - t0 < 60 and not ("READY=1" in "".join(got) and "".join(got).count("WATCHDOG=1") >= 3):
            try:
                got.append(srv.recv(4096).decode())
            except socket.timeout:
                pass
    finally:
        stop_serve(p)
        srv.close()
    text = "\n".join(got)
    assert "READY=1" in text and text.count("WATCHDOG=1") >= 3
    assert "STATUS=" in text
    assert text.index("READY=1") < text.index("WATCHDOG=1")
