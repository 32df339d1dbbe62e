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
from scipy.spatial import cKDTree

from grbl_sender import Sender, counters_clean_log, kill_supervisor_wait_rt, rt_pid_of, start_serve, stop_serve
from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.recording import read_recording
from pmctl.motion.state_store import load_counters
from pmctl.core.job import home_pose
from pmctl.task.planner import load_job, plan
import pytest

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

M = load_machine()
ROOT = Path(__file__).resolve().parents[2]
JOB = ROOT / "examples" / "jobs" / "cone.ngc"


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
        assert s.send(end, timeout=600) == "ok"                      # answered once the end is queued
        assert s.wait_for(lambda: "[MSG:Pgm End]" in s.pushed[n:], 600)   # said when the machine gets there
        done = s.wait_state(("Idle",), 600)
        assert done["state"] == "Idle"
        job = load_job(JOB, M, start=home_pose(M))
        assert np.allclose(done["pos"][:3], job.moves[-1].tip, atol=2e-3)
        final = done["pos"]
    finally:
        s.close()
        assert stop_serve(p) == 0
    counters_clean_log(tmp_path)
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
        kill_supervisor_wait_rt(p, rt_pid_of(p.pid))
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


def test_an_rt_restart_runs_the_settings_the_controller_started_with(tmp_path):
    """The settings are resolved once, in the supervisor; the rt process gets them as data over its
    spawn pipe and is given no config file. So when $X restarts it after its death, a service config
    edited meanwhile changes nothing: the restart goes ahead with the settings the supervisor runs,
    at the position where the machine was. (The edit applies when the service restarts.)"""
    svc = tmp_path / "service.toml"
    text = (Path(__file__).resolve().parents[2] / "config" / "service.toml").read_text()
    svc.write_text(text)
    p, link = start_serve(tmp_path, extra=("--service", str(svc)))
    s = Sender(link)
    try:
        s.reset()
        st = s.wait_state(("Idle",), 60)
        rt = rt_pid_of(p.pid)
        assert b"service.toml" not in Path(f"/proc/{rt}/cmdline").read_bytes()      # no file handed over
        n = len(s.pushed)
        os.kill(rt, signal.SIGKILL)
        assert s.wait_for(lambda: "ALARM:17" in s.pushed[n:], 30)
        svc.write_text("this is no TOML [[[")                    # edited meanwhile: not read again
        assert s.send("$X") == "ok"
        st2 = s.wait_state(("Idle",), 60)
        rt2 = rt_pid_of(p.pid)
        assert np.allclose(st2["pos"], st["pos"], atol=1.5e-3) and rt2 not in (None, rt)
        assert b"service.toml" not in Path(f"/proc/{rt2}/cmdline").read_bytes()
        assert s.send("G91 G1 X1 F600") == "ok" and s.send("G90") == "ok"     # and it moves
        assert s.wait_for(lambda: abs(s.status()["pos"][0] - st2["pos"][0] - 1.0) < 1e-3, 30)
    finally:
        s.close()
        stop_serve(p)


# ---------------------------------------------------------------- work offsets across a restart

WCS = ("G54", "G55", "G56", "G57", "G58", "G59")


def hash_report(s):
    """``$#`` as {name: 5 floats} (G54-G59, G28, G30, G92) plus the raw lines."""
    n = len(s.pushed)
    assert s.send("$#") == "ok"
    lines = [ln for ln in s.pushed[n:] if ln.startswith("[") and ":" in ln]
    out = {}
    for ln in lines:
        name, _, vals = ln[1:-1].partition(":")
        if name in WCS + ("G28", "G30", "G92"):
            out[name] = [float(x) for x in vals.split(",")]
    assert set(WCS + ("G92",)) <= set(out), lines
    return out, [ln for ln in lines if ln[1:4] in {w[:3] for w in WCS + ("G92",)} and not ln.startswith("[PRB")]


def active_wcs(s):
    import re
    n = len(s.pushed)
    assert s.send("$G") == "ok"
    gc = next(ln for ln in s.pushed[n:] if ln.startswith("[GC:"))
    return re.search(r"\bG5[4-9]\b", gc).group(0)


def wco_of(st):
    return np.array([float(x) for x in st["WCO"].split(",")])


def test_work_offsets_and_g92_come_back_after_sigterm_and_a_restart(tmp_path):
    """G10 L2 P2 (G55), G10 L20 P1 (G54 from the current position), G92, the active system and $10:
    after SIGTERM and a restart on the same --state, ``$#`` shows the same offsets, the status
    report the same WPos and WCO, and WPos = MPos - WCO with WCO = active system + G92."""
    state = tmp_path / "state.json"
    p, link = start_serve(tmp_path, state=state)
    s = Sender(link)
    try:
        s.reset()
        m0 = np.array(s.wait_state(("Idle",), 60)["pos"])            # $10=1 (default): MPos
        for line in ("G21 G90", "G10 L2 P2 X12.5 Y-7.25 Z3.125 A1.5 B-2", "G10 L20 P1 X1 Y2 Z-3",
                     "G55", "G92 X4 Y-5 Z6"):
            assert s.send(line) == "ok", line
        off, lines = hash_report(s)
        # the offsets are what the lines asked for (grbl's G10 L2 / L20 and G92 definitions)
        assert np.allclose(off["G55"], [12.5, -7.25, 3.125, 1.5, -2], atol=1e-9)
        assert np.allclose(off["G54"], [m0[0] - 1, m0[1] - 2, m0[2] + 3, 0, 0], atol=1.5e-3)
        assert np.allclose(off["G92"][:3], m0[:3] - off["G55"][:3] - [4, -5, 6], atol=1.5e-3)
        mpos = s.status()
        assert mpos["kind"] == "MPos" and np.allclose(mpos["pos"], m0, atol=1.5e-3)     # nothing moved
        assert np.allclose(wco_of(mpos), np.add(off["G55"], off["G92"]), atol=1.5e-3)
        assert s.send("$10=0") == "ok"
        # the last thing before the stop: back to G54 (a selection, no offset changes with it)
        assert s.send("G54") == "ok" and active_wcs(s) == "G54"
        wpos = s.status()
        assert wpos["kind"] == "WPos" and np.allclose(wco_of(wpos), np.add(off["G54"], off["G92"]), atol=1.5e-3)
        assert np.allclose(wpos["pos"], np.array(mpos["pos"]) - wco_of(wpos), atol=2e-3)
    finally:
        s.close()
        assert stop_serve(p) == 0                                  # SIGTERM
    assert load_counters(state, machine=M.name).clean
    p, link = start_serve(tmp_path, state=state)
    s = Sender(link)
    try:
        off2, lines2 = hash_report(s)
        assert lines2 == lines                                     # the same offsets, to the digit
        assert active_wcs(s) == "G54"                              # the system active at the stop
        w2 = s.status()
        assert w2["kind"] == "WPos"                                # $10 came back too
        assert np.allclose(w2["pos"], wpos["pos"], atol=1.5e-3) and w2["WCO"] == wpos["WCO"]
        assert s.send("$10=1") == "ok"
        m2 = s.status()
        assert m2["kind"] == "MPos" and np.allclose(m2["pos"], mpos["pos"], atol=1.5e-3)
        wco = wco_of(m2)
        assert np.allclose(wco, np.add(off2["G54"], off2["G92"]), atol=1.5e-3)
        assert np.allclose(np.array(m2["pos"]) - wco, w2["pos"], atol=2e-3)
        # G55 selected after the restart: its offset plus G92; the selection is journalled before the
        # ok, and a soft reset (grbl: back to G54, offsets kept) is journalled before the banner
        journal = Path(str(state) + ".journal")
        assert s.send("G55") == "ok"
        assert np.allclose(wco_of(s.status()), np.add(off2["G55"], off2["G92"]), atol=1.5e-3)
        assert json.loads(journal.read_text())["offsets"]["active"] == "G55"
        s.reset()
        assert active_wcs(s) == "G54" and json.loads(journal.read_text())["offsets"]["active"] == "G54"
        assert hash_report(s)[1] == lines
    finally:
        s.close()
        assert stop_serve(p) == 0


# ---------------------------------------------------------------- a killed session's recording

def test_sigkill_of_serve_leaves_a_readable_partial_recording_that_ends_at_the_saved_counters(tmp_path):
    """``pmctl serve --record DIR`` killed by SIGKILL after a move: DIR.partial reads as an incomplete
    recording with every drained tick (time monotonic, one tick apart), the move on its programmed
    line, and a last row whose pulse counters are the ones the rt process saved (clean) once it
    found the supervisor gone: the machine was at rest, so not a pulse differs."""
    state, rec = tmp_path / "state.json", tmp_path / "rec"
    data = tmp_path / "rec.partial" / "data.csv"
    p, link = start_serve(tmp_path, state=state, record=rec)
    s = Sender(link)
    rt = None
    try:
        s.reset()
        p0 = np.array(s.wait_state(("Idle",), 60)["pos"])
        assert s.send("G21 G91 G1 F600 X-8") == "ok"
        t0 = time.time()                 # the move has run (planning can take a while on a loaded machine)
        st = s.status()
        while not (st["state"] == "Idle" and st["pos"][0] < p0[0] - 7.99) and time.time() - t0 < 120:
            time.sleep(0.05)
            st = s.status()
        assert st["state"] == "Idle" and np.allclose(st["pos"][:3], p0[:3] - [8, 0, 0], atol=1.5e-3)
        # evidence, not a sleep: 300 ticks of rest after the move are on disk
        n_idle = data.read_bytes().count(b"\n")
        t0 = time.time()
        while data.read_bytes().count(b"\n") < n_idle + 300 and time.time() - t0 < 120:
            time.sleep(0.05)
        rt = rt_pid_of(p.pid)
        assert rt is not None
        kill_supervisor_wait_rt(p, rt)  # the rt process holds, saves its counters and exits
    finally:
        s.close()
        stop_serve(p)
    # nothing under the name, not even an empty folder: the rows are in DIR.partial
    assert not rec.exists()
    r = read_recording(tmp_path / "rec.partial")
    assert r.meta["complete"] is False
    assert {"line", "sigma", "tip_x", "enc_L1"} <= set(r.columns)
    dt = 1.0 / r.sample_rate_hz
    t = r["t"]
    assert r.n > 1000 and np.all(np.diff(t) > 0)
    np.testing.assert_allclose(np.diff(t), dt, rtol=1e-9)      # no tick lost between drained chunks
    ppm = M.resolution.pulses_per_mm
    cmd = np.column_stack([r[f"cmd_{a}"] for a in ("L1", "L2", "L3", "X", "Y")])
    assert np.all(np.isfinite(cmd))
    counts = np.rint(cmd * ppm).astype(np.int64)              # cmd_* = pulse counter / resolution
    assert np.abs(np.diff(cmd, axis=0)).max() < 0.1           # continuous: < 100 mm/s on any joint
    # the move is in the recording, every tool tip on its programmed line
    tip = np.column_stack([r["tip_x"], r["tip_y"], r["tip_z"]])
    assert np.all(np.isfinite(tip))
    assert np.abs(tip[:, 1:] - p0[1:3]).max() < 2e-3
    assert tip[:, 0].min() > p0[0] - 8 - 2e-3 and tip[:, 0].max() < p0[0] + 2e-3
    assert abs(tip[0, 0] - p0[0]) < 2e-3 and abs(tip[-1, 0] - (p0[0] - 8)) < 2e-3
    # the counters: the rt side saved them (clean) after the recording's last row; at rest, equal
    saved = load_counters(state, machine=M.name, pulses_per_mm=ppm)
    assert saved.clean and saved.pulses_per_mm.tolist() == ppm.tolist()
    assert np.array_equal(counts[-1], saved.counts), (counts[-1], saved.counts)
    assert np.all(counts[-300:] == counts[-1])                # the tail is the rest after the move
    assert json.loads((tmp_path / "state.json.journal").read_text())["running"] is False


# ---------------------------------------------------------------- the watchdog follows the rt side

def _proc_state(pid):
    """The kernel's one-letter state of ``pid`` (R, S, T stopped, ...), None once it is gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return None
    return stat[stat.rindex(")") + 2]


def test_watchdog_pings_stop_while_the_rt_process_is_stopped_and_resume_after(tmp_path):
    """systemd's watchdog is fed only while the rt side is on time: with the rt process stopped
    (SIGSTOP: alive, but no tick), WATCHDOG=1 stops for many watchdog intervals while the supervisor
    still answers on the console; after SIGCONT the pings come back."""
    path = str(tmp_path / "notify.sock")
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    srv.bind(path)
    usec = 200_000                                   # WatchdogSec=0.2: a ping every 0.1 s while healthy
    interval = usec / 1e6
    p, link = start_serve(tmp_path, env={"NOTIFY_SOCKET": path, "WATCHDOG_USEC": str(usec)})
    s = Sender(link)
    rt, stopped = None, False

    def pings(n, timeout=60.0):
        """Wait for ``n`` WATCHDOG=1 (and READY=1 before them); the messages received."""
        got, t0 = [], time.time()
        srv.settimeout(1.0)
        while time.time() - t0 < timeout and "".join(got).count("WATCHDOG=1") < n:
            try:
                got.append(srv.recv(4096).decode())
            except socket.timeout:
                pass
        return "".join(got)

    try:
        first = pings(3)
        assert "READY=1" in first and first.count("WATCHDOG=1") >= 3          # healthy: fed
        rt = rt_pid_of(p.pid)
        assert rt is not None
        srv.setblocking(False)                       # what was sent so far is not "after the stop"
        try:
            while True:
                srv.recv(4096)
        except BlockingIOError:
            pass
        os.kill(rt, signal.SIGSTOP)
        stopped = True
        t0 = time.time()
        while _proc_state(rt) != "T" and time.time() - t0 < 30:                 # the stop is evident
            time.sleep(0.01)
        assert _proc_state(rt) == "T"
        # the pings stop: a silence of 8 watchdog intervals must come (within a generous minute); the
        # pings before it are only those of the status block's freshness window (0.5 s after the rt
        # side's last tick, or the ping period when that is shorter: here 0.1 s; at most one per half
        # interval), none for a stopped rt process after that
        gap = 8 * interval
        srv.settimeout(gap)
        after, silent, t0 = 0, False, time.time()
        while time.time() - t0 < 60:
            try:
                after += srv.recv(4096).decode().count("WATCHDOG=1")
            except socket.timeout:
                silent = True
                break
        assert silent, f"WATCHDOG=1 kept coming while the rt process was stopped ({after} pings)"
        assert after <= int(min(0.5, interval / 2) / (interval / 2)) + 2, after
        assert _proc_state(rt) == "T" and p.poll() is None
        st = s.status()                              # the supervisor is up: it is the rt side that is late
        assert st is not None
        os.kill(rt, signal.SIGCONT)
        stopped = False
        srv.setblocking(True)
        again = pings(3)
        assert again.count("WATCHDOG=1") >= 3, again                              # fed again
        assert rt_pid_of(p.pid) == rt                                              # the same rt process
    finally:
        if stopped and rt is not None:
            os.kill(rt, signal.SIGCONT)
        s.close()
        stop_serve(p)
        srv.close()


def test_sigterm_during_the_start_up_is_a_clean_stop(tmp_path):
    """A SIGTERM while the daemon is still starting (its position note is out, the rt process and the
    console are coming up) is a stop like any other once it has started: exit 0, the counters saved
    as a clean stop, not a process killed unsaved by the signal's default action."""
    import subprocess
    import sys
    state, err = tmp_path / "state.json", tmp_path / "serve.err"
    cmd = [sys.executable, "-m", "pmctl.interfaces.cli", "serve", "--config", "config/prototype.toml",
           "--backend", "sim", "--console", f"pty:{tmp_path / 'tty'}", "--state", str(state), "--no-realtime"]
    with open(err, "wb") as e:
        p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=e, cwd=Path(__file__).resolve().parents[2])
    t0 = time.time()                             # the daemon has said where it starts: start-up under way
    while "starting at the home pose" not in err.read_text() and time.time() - t0 < 120 and p.poll() is None:
        time.sleep(0.002)
    p.send_signal(signal.SIGTERM)
    assert p.wait(120) == 0, err.read_text()[-2000:]
    saved = load_counters(state, machine=M.name)
    assert saved is not None and saved.clean
    assert "stopping (SIGTERM)" in err.read_text()
