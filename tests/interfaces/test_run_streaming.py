"""`pmctl run --record` streams: the recording is written while the machine runs, chunk by chunk from
the loop's bounded record ring, so memory does not grow with the job and a killed run leaves a
readable ``<DIR>.partial``; a run that ends writes the same recording and figures as before."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from pmctl.core.recording import read_recording
from service_support import sim_service as _service

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
JOBS = ROOT / "examples" / "jobs"
PMCTL = [sys.executable, "-m", "pmctl.interfaces.cli"]
AXES = ("L1", "L2", "L3", "X", "Y")


def long_job(path: Path, minutes: float) -> Path:
    """A G-code job of back-and-forth X moves at 1 mm/s (10 s each) lasting about ``minutes``."""
    lines = ["(test job: back and forth)", "G17 G21 G90 G94", "G0 X5 Y0 Z65 A-4.5088 B8.9351", "G0 Z60", "F60"]
    for i in range(int(round(minutes * 6))):
        lines.append("G1 X-5" if i % 2 == 0 else "G1 X5")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_sigkill_leaves_a_readable_partial_recording(tmp_path):
    rec_dir = tmp_path / "rec"
    args = [*PMCTL, "run", "--job", str(JOBS / "hemisphere.cl"), "--service", str(_service(tmp_path)),
            "--state", "", "--record", str(rec_dir), "--quiet"]        # real time: 27 s of ticks
    p = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        t0 = time.monotonic()
        while time.monotonic() - t0 < 120:                      # the loop has started
            line = p.stderr.readline()
            if not line or ("streamed to the rt motion process" in line and "backend" in line):
                break
        data = tmp_path / "rec.partial" / "data.csv"
        t0 = time.monotonic()                                   # ~2 s of ticks drained to disk (not a fixed
        while time.monotonic() - t0 < 120 and p.poll() is None:  # sleep: a loaded machine starts late)
            if data.exists() and data.read_bytes().count(b"\n") > 2000:
                break
            time.sleep(0.05)
        assert p.poll() is None, "the run ended before it could be killed"
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    assert not rec_dir.exists()                                  # nothing whole under the name
    part = tmp_path / "rec.partial"
    assert part.is_dir()
    rec = read_recording(part)
    assert rec.meta["complete"] is False
    assert rec.meta["run"]["status"] == "running" and rec.meta["run"]["backend"] == "sim"
    assert rec.n > 500                                           # ~2 s at 1 kHz, less a drain period
    t = rec["t"]
    assert np.all(np.diff(t) > 0)
    np.testing.assert_allclose(np.diff(t), 1e-3, rtol=1e-9)      # no row lost between chunks
    for a in AXES:                                               # commands continuous: <= vmax per tick
        q = rec[f"cmd_{a}"]
        assert np.all(np.isfinite(q))
        assert np.abs(np.diff(q)).max() < 0.1
    assert {"tip_x", "tool_k", "strain_1", "enc_L1"} <= set(rec.columns)


def _prepare_run(job, rate=1000):
    from pmctl import hal
    from pmctl.core import kinematics as K
    from pmctl.core.config import load_machine
    from pmctl.motion.loop import prepare
    from pmctl.motion.nc import counts_of, initial_state
    from pmctl.motion.service_config import ServiceConfig
    from pmctl.task.planner import home_pose, load_job, plan
    M = load_machine("prototype")
    svc = ServiceConfig()
    cfg = svc.loop
    cfg.rate_hz, cfg.realtime, cfg.state_file = float(rate), False, ""
    params = svc.nc.params(M, cfg.dt)
    c0 = counts_of(K.ik(*home_pose(M), M).q, params)
    st = initial_state(M, c0)
    j = load_job(job, M, start=(st.tip, st.axis))
    traj = plan(j, M, cfg.dt, start=(st.tip, st.axis))
    targets = prepare(M, params, traj, cfg.dt, c0)
    be = hal.create("sim", M, cfg.dt, {"flex": True})
    be.open(c0)
    return M, cfg, params, st, targets, be


def test_streamed_recording_equals_the_whole_run_arrays(tmp_path):
    """One run, its rows both kept in memory (the old way) and streamed through RunSink: the
    recording's channels are the whole-run conversion and the tracking figures are
    tracking_stats of the whole run."""
    from dataclasses import replace

    from pmctl.core import kinematics as K
    from pmctl.core.recording import RecordingWriter
    from pmctl.task.run_sink import RunSink
    from pmctl.motion.loop import ControlLoop, tracking_stats
    from pmctl.motion.recorder import REC_WIDTH, Recorder
    from pmctl.motion.ring import Ring
    M, cfg, params, st, targets, be = _prepare_run(JOBS / "cone.ngc", rate=1000)
    sink = RunSink(M, params.pulses_per_mm, cfg.rate_hz, True, targets.job_start, len(targets.rows))
    names, notes = sink.channels()
    ring = Ring(64, REC_WIDTH)                      # small: many chunks, drained inline when full
    w = RecordingWriter(tmp_path / "rec", names, sample_rate_hz=cfg.rate_hz, channel_notes=notes).__enter__()
    sink.writer = w
    lp = ControlLoop(M, be, params, targets, cfg, st, records=ring, recorder=Recorder(ring, keep=True, sink=sink))
    res = lp.run()
    be.close()
    w.finish(extra_meta={"run": {"status": res.status}})
    assert res.status == "done" and res.dropped == 0 and sink.chunks > 100 and sink.rows == res.ticks
    rec = read_recording(tmp_path / "rec")
    assert rec.n == res.ticks and rec.meta["complete"] is True and rec.meta["run"]["status"] == "done"
    np.testing.assert_allclose(rec["t"], np.arange(res.ticks) / cfg.rate_hz, rtol=1e-12)
    q_cmd = res.counts / params.pulses_per_mm
    pose, ok = K.fk_batch(res.truth, M)
    assert ok.all()
    for i, a in enumerate(AXES):
        np.testing.assert_allclose(rec[f"cmd_{a}"], q_cmd[:, i], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(rec[f"enc_{a}"], res.enc[:, i], rtol=1e-9, atol=1e-9)
    for i, c in enumerate(("tip_x", "tip_y", "tip_z")):
        np.testing.assert_allclose(rec[c], pose.tip[:, i], rtol=1e-9, atol=1e-9)
    for i in range(3):
        np.testing.assert_allclose(rec[f"strain_{i + 1}"], res.strain[:, i], rtol=1e-9, atol=1e-9)
    # the tracking figures: over the job, and over a window that ends early (a stop request)
    for i0, i1 in ((targets.job_start, res.ticks), (targets.job_start, targets.job_start + 700)):
        want = tracking_stats(replace(res, truth=res.truth[:i1], target=res.target[:i1]), M, from_tick=i0)
        got = sink.track.stats(i0, i1)
        assert got["samples"] == want["samples"] == i1 - i0 and got["fk_failures"] == want["fk_failures"] == 0
        for k in ("tip_rms_um", "tip_max_um", "tip_p99_um", "axis_rms_urad", "axis_max_urad"):
            assert got[k] == pytest.approx(want[k], rel=1e-5, abs=1e-6), k      # float32 per tick
    assert sink.track.stats(targets.job_start, targets.job_start) == {}


def test_a_normal_run_records_every_tick_with_its_figures(tmp_path):
    args = [*PMCTL, "run", "--job", str(JOBS / "cone.ngc"), "--service", str(_service(tmp_path, rate=1000)),
            "--state", "", "--record", str(tmp_path / "rec"), "--quiet", "--no-realtime"]
    r = subprocess.run(args, capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "pulses sent = pulse counters: yes" in r.stdout and "records dropped" not in r.stdout
    ticks = int(r.stdout.split("ticks ", 1)[1].split()[0])
    assert not (tmp_path / "rec.partial").exists()
    rec = read_recording(tmp_path / "rec")
    assert rec.n == ticks and f"({ticks} rows)" in r.stdout
    assert rec.meta["complete"] is True
    assert rec.columns.keys() >= {"t", *(f"cmd_{a}" for a in AXES), *(f"enc_{a}" for a in AXES),
                                  "tip_x", "tip_y", "tip_z", "tool_i", "tool_j", "tool_k",
                                  "strain_1", "strain_2", "strain_3"}
    run = rec.meta["run"]
    assert run["status"] == "done" and run["reason"] == "" and run["backend"] == "sim"
    assert run["job_start_row"] >= 0 and "dropped_rows" not in run
    assert run["tracking"]["samples"] == ticks - run["job_start_row"]
    assert 0 < run["tracking"]["tip_rms_um"] <= run["tracking"]["tip_p99_um"] <= run["tracking"]["tip_max_um"]
    assert f"RMS {run['tracking']['tip_rms_um']:.3f} um" in r.stdout
    assert run["timing"]["ticks"] == min(ticks, 1 << 16)
    assert "running" not in rec.meta["description"] and "done" in rec.meta["description"]
    assert json.loads((tmp_path / "rec" / "recording.json").read_text())["complete"] is True


def test_record_memory_does_not_grow_with_the_job(tmp_path):
    """A 2-minute job back to back: the recorder keeps no rows, the ring stays its fixed size, and
    the only per-tick memory is the tracking accumulator's 8 bytes a tick."""
    from pmctl.core.recording import RecordingWriter
    from pmctl.task.run_sink import RunSink
    from pmctl.motion.loop import ControlLoop
    from pmctl.motion.recorder import REC_CAPACITY, REC_WIDTH, Recorder
    from pmctl.motion.ring import Ring
    M, cfg, params, st, targets, be = _prepare_run(long_job(tmp_path / "long.ngc", 2.0), rate=500)
    sink = RunSink(M, params.pulses_per_mm, cfg.rate_hz, True, targets.job_start, len(targets.rows))
    names, notes = sink.channels()
    ring = Ring(REC_CAPACITY, REC_WIDTH)
    biggest = [0]

    def watch(rows):                                       # the largest chunk handed to the sink
        biggest[0] = max(biggest[0], len(rows))
        sink(rows)
    with RecordingWriter(tmp_path / "rec", names, sample_rate_hz=cfg.rate_hz, channel_notes=notes) as w:
        sink.writer = w
        rc = Recorder(ring, keep=False, sink=watch)
        lp = ControlLoop(M, be, params, targets, cfg, st, records=ring, recorder=rc)
        res = lp.run()
        be.close()
    assert res.status == "done" and res.ticks > 60_000 and res.dropped == 0
    assert rc.chunks == [] and rc.rows == res.ticks and rc.error == ""
    assert len(res.counts) == 0                            # the LoopResult holds no per-tick rows
    assert biggest[0] <= REC_CAPACITY and ring.nbytes < 2_000_000
    n_track = res.ticks - targets.job_start
    assert sink.track.nbytes <= 2 * 4 * 2 * n_track         # two float32 a tick (x2 growth slack)
    assert sink.track.n == n_track
    assert read_recording(tmp_path / "rec").n == res.ticks
