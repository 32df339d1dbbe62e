"""`pmctl run` is a one-shot client of the daemon's machinery: a Supervisor starts the rt motion
process (its own process: loop, NC, backend), the job is planned window by window and streamed
into the sample ring, the records stream back into the recording. Real processes, real signals."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np

from pmctl.core.recording import read_recording
from service_support import sim_service as _service
import pytest

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
JOBS = ROOT / "examples" / "jobs"
PMCTL = [sys.executable, "-m", "pmctl.interfaces.cli"]
AXES = ("L1", "L2", "L3", "X", "Y")


def _short_job(path: Path) -> Path:
    path.write_text("G17 G21 G90 G94\nG0 X5 Y0 Z65\nG1 X-5 F600\nG1 Y4\nG1 X5 Y0\nM2\n")
    return path


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:                                  # a zombie is gone for our purpose
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


def test_sigterm_stops_the_rt_process_on_the_path_with_clean_counters(tmp_path):
    """Real time: the job is machined by a separate rt process (its pid is not the client's and is
    named in the recording); SIGTERM mid-run is a controlled stop: exit 3, the counters saved clean
    where the last commanded tick left them, the recording complete, the rt process gone."""
    state = tmp_path / "state.json"
    args = [*PMCTL, "run", "--job", str(JOBS / "hemisphere.cl"), "--service", str(_service(tmp_path)),
            "--state", str(state), "--record", str(tmp_path / "rec"), "--quiet"]
    p = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    rt_pid = None
    try:
        t0 = time.monotonic()
        while time.monotonic() - t0 < 120:
            line = p.stderr.readline()
            if not line or "streamed to the rt motion process" in line:
                break
        rt_pid = int(line.split("(pid ")[1].split(")")[0])
        assert rt_pid != p.pid and _alive(rt_pid)
        data = tmp_path / "rec.partial" / "data.csv"
        t0 = time.monotonic()
        while time.monotonic() - t0 < 120 and p.poll() is None:
            if data.exists() and data.read_bytes().count(b"\n") > 3000:
                break
            time.sleep(0.05)
        assert p.poll() is None, "the run ended before the signal"
        p.send_signal(signal.SIGTERM)
        out, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    assert p.returncode == 3, out + err
    assert "result: stopped (stop requested (SIGTERM" in out and "(clean stop)" in out
    assert "pulses sent = pulse counters: yes" in out
    assert not _alive(rt_pid)
    saved = json.loads(state.read_text())
    assert saved["clean"] is True
    rec = read_recording(tmp_path / "rec")
    run = rec.meta["run"]
    assert rec.meta["complete"] is True and run["status"] == "stopped" and run["rt_pid"] == rt_pid
    assert 3000 <= rec.n < 27000 and run["timing"]["ticks"] == min(rec.n, 1 << 16)
    q_last = np.array([rec[f"cmd_{a}"][-1] for a in AXES])
    assert np.abs(np.array(saved["counts"]) - np.rint(q_last * 2000)).max() <= 1
    # the stop decelerated along the path: the commands never jump
    for a in AXES:
        assert np.abs(np.diff(rec[f"cmd_{a}"])).max() < 0.1


def _run(tmp_path, name, job, realtime, rate=1000, extra=""):
    state = tmp_path / f"{name}.json"
    args = [*PMCTL, "run", "--job", str(job), "--service", str(_service(tmp_path, rate, extra)), "--state",
            str(state), "--record", str(tmp_path / name), "--quiet", *([] if realtime else ["--no-realtime"])]
    r = subprocess.run(args, capture_output=True, text=True, cwd=ROOT, timeout=300)
    return r, json.loads(state.read_text()), read_recording(tmp_path / name)


def test_an_offline_run_is_the_realtime_run_faster(tmp_path):
    """--no-realtime runs the same path (rt process, streamed samples), ticks back to back: it ends
    on the same counters as a paced run (within the pulse the servo dithers by at rest) with the
    same tracking, and never decelerates for an empty queue."""
    job = _short_job(tmp_path / "short.ngc")
    r_rt, s_rt, rec_rt = _run(tmp_path, "rt", job, True)
    r_off, s_off, rec_off = _run(tmp_path, "off", job, False)
    for r in (r_rt, r_off):
        assert r.returncode == 0 and "result: done" in r.stdout, r.stdout + r.stderr
        assert "pulses sent = pulse counters: yes" in r.stdout
    assert np.abs(np.array(s_rt["counts"]) - np.array(s_off["counts"])).max() <= 1
    assert s_rt["clean"] and s_off["clean"]
    t_rt, t_off = rec_rt.meta["run"]["tracking"], rec_off.meta["run"]["tracking"]
    assert abs(t_rt["tip_rms_um"] - t_off["tip_rms_um"]) <= 0.1 * t_rt["tip_rms_um"]
    assert abs(t_rt["samples"] - t_off["samples"]) < 2000      # the same job, its tail at rest aside
    assert "lateness n/a (--no-realtime)" in r_off.stdout and "lateness p99" in r_rt.stdout


def test_a_job_longer_than_the_batch_planner_holds_is_streamed(tmp_path, monkeypatch, capsys):
    """The planner's whole-trajectory bound (MAX_SAMPLES) no longer limits `pmctl run`: with the bound
    at 3000 ticks, a 30 s job runs to its end, planned window by window (neither the batch planner
    nor a join of the pieces is called) and streamed through the bounded sample ring."""
    import pmctl.task.planner as P
    import pmctl.task.supervisor as S
    from pmctl.interfaces.cli import main
    from pmctl.motion import channel as C
    from pmctl.motion.trajectory import Trajectory

    def refuse(*a, **k):
        raise AssertionError("the job was planned whole")
    monkeypatch.setattr(P, "MAX_SAMPLES", 3000)
    monkeypatch.setattr(P, "plan", refuse)
    monkeypatch.setattr(S, "plan", refuse)              # the supervisor's own name for it
    monkeypatch.setattr(Trajectory, "join", classmethod(refuse))
    job = tmp_path / "long.ngc"
    lines = ["G17 G21 G90 G94", "G0 X5 Y0 Z60", "F120"] + ["G1 X-5" if i % 2 == 0 else "G1 X5" for i in range(6)]
    job.write_text("\n".join(lines) + "\n")
    rc = main(["run", "--job", str(job), "--service", str(_service(tmp_path, rate=1000)), "--state", "",
               "--record", str(tmp_path / "rec"), "--no-realtime", "--quiet"])
    out = capsys.readouterr().out
    assert rc == 0 and "result: done" in out, out
    rec = read_recording(tmp_path / "rec")
    assert rec.n > 30_000 > 3000 and rec.meta["complete"] is True
    assert C.SAMPLE_CAPACITY < rec.n                    # more samples than the ring ever held at once
    # the table went back and forth 6 times over 10 mm: it ends where the job ends (X5)
    assert rec.meta["run"]["tracking"]["tip_rms_um"] < 5


def test_a_speed_change_inside_the_job_holds_the_path_until_at_speed(tmp_path):
    """S16000, then M4 S6000 inside a job (pmctl run through the supervisor, simulated VFD on the
    loopback): wherever the commanded path moves, the spindle turns within 2 % of one of the job's
    speeds -- the path waits at each change (C_HOLD_AT in the rt process) until the new speed is
    reached -- and the three speeds come in the job's order."""
    job = tmp_path / "s.ngc"
    job.write_text(textwrap.dedent("""\
        G17 G21 G90 G94
        F900 S8000 M3
        G1 X3
        S16000
        G1 Y-2
        M4 S6000
        G1 X0 Y0
        M5
        M2
        """))
    spindle = ('[spindle]\nsimulate = true\nport = 0\npoll_ms = 10\nsim_ramp_rpm_per_s = 40000\n'
               'spinup_timeout_s = 20\n')
    r, saved, rec = _run(tmp_path, "rec", job, False, extra=spindle)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "spindle M3 S8000: at speed" in r.stderr
    rpm = rec["spindle_rpm"]
    q = np.stack([rec[f"cmd_{a}"] for a in AXES], -1)
    moving = np.r_[np.abs(np.diff(q, axis=0)).max(axis=1) > 1e-3, False]
    assert moving.sum() > 500
    levels = np.array([8000.0, 16000.0, -6000.0])
    # the path goes on once the VFD reads within 2 % (at_speed_tolerance); a row records the last
    # speed polled before its tick, which lags by up to two polls of the ramp under load (800 rpm);
    # a path that did not wait would show the old speed (8000 rpm while S16000 spins up)
    lag = 2 * 0.010 * 40000
    near = np.abs(rpm[moving][:, None] - levels[None]) <= 0.02 * np.abs(levels)[None] + lag
    assert near.any(axis=1).all(), rpm[moving][~near.any(axis=1)][:5]
    first = [int(np.flatnonzero(near[:, i])[0]) for i in range(3)]
    assert first[0] < first[1] < first[2]


def test_a_stale_daq_mid_job_stops_the_supervisor_on_the_path(tmp_path):
    """The strain DAQ is polled by the supervisor (for pmctl run and serve alike): stale data mid-job
    is a controlled stop on the path with the reason (ALARM 3), the counters what was sent."""
    from pmctl.motion import channel as C
    from pmctl.motion.nc import counts_of
    from pmctl.core import kinematics as K
    from pmctl.core.job import home_pose
    from pmctl.task.planner import load_job
    from pmctl.task.supervisor import Supervisor
    from pmctl.core.alarms import ALARM_ABORT
    svc = _service(tmp_path, extra='[daq]\nsimulate = true\nport = 0\ntimeout_ms = 200\npoll_ms = 10\n'
                                   'max_age_ms = 60\nsim_sample_hz = 200\n')
    sup = Supervisor(service=str(svc), log=lambda m: None)
    tip, axis = home_pose(sup.machine)
    c0 = counts_of(K.ik(tip, axis, sup.machine).q, sup.params)
    sup.start(c0)
    try:
        assert sup.daq is not None
        job = tmp_path / "long.ngc"                    # about 10 s: longer than a simulated device's
        job.write_text("G17 G21 G90 G94\nG0 X5 Y0 Z65\n"  # patience without real-time priority (3 s)
                       + "G1 X-5 F600\nG1 Y4\nG1 X5 Y0\n" * 4 + "M2\n")
        sup.submit(load_job(job, sup.machine, start=sup.pose()))
        t0 = time.monotonic()
        while time.monotonic() - t0 < 60 and sup.raw()[C.ST_SIGMA] == 0:
            time.sleep(0.005)
        assert sup.raw()[C.ST_SIGMA] > 0, "the job never moved"
        sup.daq.device.freeze()
        t0 = time.monotonic()
        while time.monotonic() - t0 < 60 and not (sup.device_fault and not sup.busy()):
            time.sleep(0.01)
        assert "stale data" in sup.device_fault and "strain DAQ" in sup.device_fault
        assert sup.alarm == ALARM_ABORT and sup.device_fault in sup.alarm_msg
        assert sup.raw()[C.ST_ENDED] == 0                 # stopped before the job's end
    finally:
        counts = sup.shutdown()
    r = sup.rt_result
    assert r["sent_ok"] and r["clean"]
    assert np.array_equal(np.asarray(c0) + np.asarray(r["sent"]), counts)


def test_an_unreachable_line_is_refused_before_the_rt_process_starts(tmp_path):
    """The whole job is checked in the client before anything moves: exit 1, the file and the line
    named, no motion process started, no recording and no counters left."""
    job = tmp_path / "bad.ngc"
    job.write_text("G17 G21 G90 G94\nG0 X5 Y0 Z65\nG1 X-5 F600\nG1 X400\nM2\n")
    state = tmp_path / "state.json"
    args = [*PMCTL, "run", "--job", str(job), "--service", str(_service(tmp_path)), "--state", str(state),
            "--record", str(tmp_path / "rec"), "--no-realtime", "--quiet"]
    r = subprocess.run(args, capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert r.returncode == 1, r.stdout + r.stderr
    assert "bad.ngc:4:" in r.stderr
    assert "rt motion process" not in r.stderr and "result:" not in r.stdout
    assert not (tmp_path / "rec").exists() and not (tmp_path / "rec.partial").exists()
    assert not state.exists()
