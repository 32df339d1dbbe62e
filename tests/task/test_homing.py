"""Homing ($H) and resuming an interrupted job.

- the joint move profile and the homing sequence (against a switch model, hypothesis: random
  switch positions, lost positions and stop overshoots): the counter ends within one latch tick's
  travel + 1 pulse of the switch-referenced truth; a missing switch is ALARM 9;
- `pmctl serve` on the sim over a real pty: an untrusted position that is off from the sim's true
  motor positions by a few mm -> Alarm; $H -> the counters equal the true switch-referenced
  positions within latch speed x tick + 1 pulse, the true tool tip matches the model pose, pulses
  counted = pulses sent; $H is refused while a move runs;
- a switch out of reach -> controlled stop, ALARM 9 (supervisor with the sim);
- SIGKILL of the supervisor mid-job, restart, home (`pmctl ctl home`), resume from the journal's
  line (`pmctl ctl resume-job`): the job completes and the resumed part of the tool path lies on the
  programmed path.
"""

import json
import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from grbl_sender import Sender, counters_clean_log, start_serve, stop_serve
from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.recording import read_recording
from pmctl.interfaces.commands.ctl import request
from pmctl.motion.service_config import HomingConfig
from pmctl.motion.state_store import save_counters
from pmctl.task.homing import HomingFailed, Sequence, joint_profile
from pmctl.core.alarms import ALARM_HOMING_APPROACH
from pmctl.task.job import load_job
from pmctl.core.job import home_pose

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

M = load_machine()
PPM = M.resolution.pulses_per_mm
ROOT = Path(__file__).resolve().parents[2]
DT = 1e-3
SWITCH = [400.0, 400.0, 400.0, 5.0, 5.0]
OFFSET = [-2.0, 1.5, 3.0, -2.5, 0.7]           # true motor - believed, mm (the lost position)
# the latch bound scales with the latch speed (speed x tick + 1 pulse): 4 mm/s keeps it at 9 pulses
# and the five latch approaches (~2 mm each) under a second each
FAST = {"seek_mm_s": 20.0, "latch_mm_s": 4.0, "pull_off_mm": 0.5}


@settings(max_examples=60, deadline=None)
@given(st.floats(-30, 30).filter(lambda d: abs(d) > 1e-6), st.floats(0.5, 50), st.floats(50, 2000))
def test_joint_profile_ends_exactly_and_keeps_speed_and_acceleration(dist, speed, accel):
    s = joint_profile(dist, speed, accel, DT)
    assert s[0] == 0.0 and s[-1] == dist
    v = np.diff(s) / DT
    assert np.all(v * np.sign(dist) >= -1e-12)                       # monotone
    assert np.max(np.abs(v)) <= speed * (1 + 1e-9) + 1e-9
    a = np.diff(v) / DT
    assert np.max(np.abs(a), initial=0.0) <= accel * (1 + 1e-6)
    assert abs(v[0]) * DT <= 0.5 * accel * DT ** 2 * 1.000001 + 1e-12                            # starts at rest


class SwitchModel:
    """One tick at a time: the counter moves by the commanded pulses, the true motor with it (plus the
    lost offset); the switch closes at true >= edge. A stop overshoots by ``overshoot`` mm."""

    def __init__(self, counts, offset_mm, edges, overshoot):
        self.c = np.array(counts, np.int64)
        self.off = np.rint(np.asarray(offset_mm) * PPM).astype(np.int64)
        self.edges = edges
        self.overshoot = overshoot

    def true(self, i):
        return (self.c[i] + self.off[i]) / PPM[i]

    def switch(self, i):
        return self.true(i) >= self.edges[i]

    def count(self, i):
        return int(self.c[i])

    def move(self, i, dist, speed, want=None):
        s = joint_profile(dist, speed, 0.25 * 2000, DT)
        c = self.c[i] + np.rint(s[1:] * PPM[i]).astype(np.int64)            # the counter tick by tick
        hit = np.nonzero(((c + self.off[i]) / PPM[i] >= self.edges[i]) == want)[0] if want is not None else []
        if len(hit) == 0:
            self.c[i] = c[-1]
            return None
        latched = int(c[hit[0]])
        self.c[i] = latched + int(round(np.sign(dist) * self.overshoot * PPM[i]))
        return latched

    def set_count(self, i, n):            # a re-reference: the motor stays where it is
        self.off[i] -= n - self.c[i]
        self.c[i] = n


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(-4, 4), min_size=5, max_size=5), st.lists(st.floats(-3, 8), min_size=5, max_size=5),
       st.floats(0.0, 1.5))
def test_sequence_references_each_counter_to_its_switch_within_one_latch_tick(offset, edge_from_start, overshoot):
    start = np.array([393.0, 393.0, 393.0, 0.0, 0.0])
    edges = [float(start[i] + offset[i] + edge_from_start[i]) for i in range(5)]    # true switch edges
    cfg = HomingConfig(reference_mm=tuple(edges), seek_mm_s=5.0, latch_mm_s=0.5, pull_off_mm=1.0, search_mm=15.0)
    mv = SwitchModel(np.rint(start * PPM), offset, edges, overshoot)
    Sequence(cfg, PPM).run(mv)
    for i in range(5):
        # the counter now reads the true motor position (the reference is the true edge), within one
        # tick of travel at the latch speed plus one pulse of rounding
        bound = cfg.latch_mm_s * DT + 1 / PPM[i]
        assert abs(mv.c[i] / PPM[i] - mv.true(i)) <= bound + 1e-12
        assert not mv.switch(i)                                   # left pulled off the switch


def test_sequence_switch_not_found_within_the_search_distance_is_alarm_9():
    cfg = HomingConfig(search_mm=5.0)
    mv = SwitchModel(np.rint(np.array([393.0, 393.0, 393.0, 0, 0]) * PPM), [0] * 5, [410.0] + SWITCH[1:], 0.1)
    with pytest.raises(HomingFailed) as e:
        Sequence(cfg, PPM).run(mv)
    assert e.value.code == ALARM_HOMING_APPROACH and "L1" in str(e.value)


def service_file(tmp_path, switch=SWITCH, offset=OFFSET, homing=FAST):
    base = (ROOT / "config" / "service.toml").read_text()
    assert "[hal.sim]\n" in base and "[homing]" in base
    text = base.replace("[hal.sim]\n", f"[hal.sim]\nmotor_offset_mm = {list(offset)}\n")
    for k, v in {"home_switch_mm": list(switch), **homing}.items():
        lines = [ln for ln in text.splitlines() if ln.startswith(f"{k} =")]
        text = text.replace(lines[0], f"{k} = {v}")
    p = tmp_path / "service.toml"
    p.write_text(text)
    return p


def test_serve_home_after_a_lost_position_then_counters_match_the_truth(tmp_path):
    svc = service_file(tmp_path)
    state = tmp_path / "state.json"
    tip, ax = home_pose(M)
    c0 = np.rint(K.ik(tip, ax, M).q * PPM).astype(np.int64)
    save_counters(state, c0, machine=M.name, clean=False)            # a periodic snapshot: not trusted
    sock = tmp_path / "ctl.sock"
    rec = tmp_path / "rec"
    p, link = start_serve(tmp_path, state=state, record=rec, extra=("--service", str(svc), "--socket", str(sock)))
    s = Sender(link)
    try:
        assert s.status()["state"] == "Alarm"
        assert s.send("G1 X1 F100") == "error:9"
        assert s.send("$H", timeout=300) == "ok"
        st_ = s.wait_state(("Idle",), 60)
        assert st_["state"] == "Idle"
        ans = request(sock, {"cmd": "status"})
        assert ans["homed"] and not ans["alarm"]
        counts = np.array(ans["counts"])
        true = c0 + np.rint(np.array(OFFSET) * PPM).astype(np.int64) + np.array(ans["sent"])   # the plant's motors
        bound = FAST["latch_mm_s"] * DT * PPM + 1      # latch speed x tick + 1 pulse, in pulses
        print(f"counters - true motor positions after $H: {(counts - true).tolist()} pulses (bound {bound.tolist()})")
        assert np.all(np.abs(counts - true) <= bound), counts - true
        # $H is refused while a move runs
        assert s.send("G21 G91 G1 F360 X-6") == "ok"
        s.wait_state(("Run",), 60)
        assert s.send("$H") == "error:8"
        s.wait_state(("Idle",), 120)
        mpos = s.status()["pos"]
    finally:
        s.close()
        assert stop_serve(p) == 0
    counters_clean_log(tmp_path)
    r = read_recording(rec)
    tip_true = np.column_stack([r["tip_x"], r["tip_y"], r["tip_z"]])[-1]
    print(f"true tool tip - model tip at rest: {np.linalg.norm(tip_true - np.array(mpos[:3])) * 1e3:.2f} um")
    assert np.linalg.norm(tip_true - np.array(mpos[:3])) < 5e-3          # the true tool tip is where the model is


def test_switch_out_of_reach_stops_with_alarm_9(tmp_path):
    from pmctl.motion.nc import counts_of
    from pmctl.task.supervisor import Supervisor
    svc = service_file(tmp_path, switch=[430.0] + SWITCH[1:], offset=[0.0] * 5)
    s = Supervisor("prototype", service=str(svc), realtime=False)
    tip, ax = home_pose(M)
    s.start(counts_of(K.ik(tip, ax, M).q, s.params))
    try:
        ok, msg = s.home()
        assert not ok and s.alarm == 9 and "switch not found" in s.alarm_msg and "L1" in s.alarm_msg
        assert s.state_name() == "Alarm" and not s.homed
        moved = s.counts()[0] / PPM[0] - K.ik(tip, ax, M).q[0]
        assert 15.0 <= moved < 16.0                                  # the whole search, then a stop
    finally:
        s.shutdown()


JOB = """G21 G90
G0 X0 Y0 Z170
G1 F900 X6 Y0 Z168
G1 X6 Y6
G1 X-6 Y6
G1 X-6 Y-6
G1 X6 Y-6
G1 X6 Y0
G1 X0 Y0 Z170
"""


def ctl(sock, *args):
    import subprocess
    import sys
    out = subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", "ctl", "--socket", str(sock), *args],
                         capture_output=True, text=True, cwd=ROOT)
    return json.loads(out.stdout) if out.stdout.strip() else {"ok": False, "error": out.stderr}


def test_sigkill_mid_job_restart_home_and_resume_from_the_line(tmp_path):
    job = tmp_path / "square.ngc"
    job.write_text(JOB)
    state = tmp_path / "state.json"
    sock = tmp_path / "ctl.sock"
    p, link = start_serve(tmp_path, state=state, extra=("--socket", str(sock)))
    try:
        assert request(sock, {"cmd": "queue", "add": str(job)})["ok"]
        journal = tmp_path / "state.json.journal"
        t0 = time.time()
        while time.time() - t0 < 120:
            j = json.loads(journal.read_text())
            if j.get("running") and j.get("line", 0) >= 5:
                break
            time.sleep(0.05)
        assert j["job"] == str(job) and j["line"] >= 5
        from grbl_sender import rt_pid_of
        rt = rt_pid_of(p.pid)
        p.send_signal(signal.SIGKILL)                 # the supervisor dies: the rt side holds on the path
        p.wait(10)
        t0 = time.time()                              # ... saves its counters and exits
        while rt is not None and time.time() - t0 < 30:
            try:
                os.kill(rt, 0)
            except ProcessLookupError:
                break
            time.sleep(0.05)
        else:
            time.sleep(3.0)
    finally:
        stop_serve(p)
    line = json.loads(journal.read_text())["line"]
    rec = tmp_path / "rec2"
    # homing L1 and X only (the [homing] order; the other axes are covered by the tests above)
    svc = service_file(tmp_path, offset=[0.0] * 5, homing={**FAST, "order": ["L1", "X"]})
    p, link = start_serve(tmp_path, state=state, record=rec, extra=("--socket", str(sock), "--service", str(svc)))
    s = Sender(link)
    try:
        assert s.status()["state"] == "Alarm"
        ans = ctl(sock, "resume-job")
        assert not ans["ok"] and "alarm" in ans["error"]          # confirm or home first
        ans = ctl(sock, "home")
        assert ans["ok"] and "homed" in ans["msg"], ans
        assert s.status()["state"] == "Idle"
        ans = ctl(sock, "resume-job")
        assert ans["ok"], ans
        done = s.wait_state(("Idle",), 300)
        assert done["state"] == "Idle"
        assert np.allclose(done["pos"][:3], [0, 0, 170], atol=2e-3)    # the job's last point
    finally:
        s.close()
        assert stop_serve(p) == 0
    r = read_recording(rec)
    tip = np.column_stack([r["tip_x"], r["tip_y"], r["tip_z"]])
    resumed = (r["line"] >= line) & np.all(np.isfinite(tip), axis=1)
    assert resumed.sum() > 500 and (r["line"] == 0).sum() > 50          # the approach, then the job
    prog = load_job(job, M, start=home_pose(M))
    pts = np.array([m.tip for m in prog.moves])
    lines = np.array([m.line for m in prog.moves])
    k = int(np.argmax(lines >= line))
    poly = pts[k - 1:]                                                   # the programmed path from that line
    from test_daemon_serve import dist_to_polyline
    dense = np.concatenate([np.linspace(a, b, 200) for a, b in zip(poly[:-1], poly[1:])])
    d = dist_to_polyline(tip[resumed], dense)
    print(f"resumed from line {line}: {resumed.sum()} recorded ticks, max distance to the programmed path "
          f"{d.max() * 1e3:.2f} um")
    assert d.max() < 5e-3, d.max()


def test_reset_during_homing_aborts_with_alarm_6(tmp_path):
    import threading
    from pmctl.motion.nc import counts_of
    from pmctl.task.supervisor import Supervisor
    svc = service_file(tmp_path, offset=[0.0] * 5, homing={"seek_mm_s": 2.0, "latch_mm_s": 1.0, "pull_off_mm": 0.5})
    s = Supervisor("prototype", service=str(svc), realtime=False)
    tip, ax = home_pose(M)
    s.start(counts_of(K.ik(tip, ax, M).q, s.params))
    try:
        out = []
        t = threading.Thread(target=lambda: out.append(s.home()))
        t.start()
        t0 = time.time()
        while s.state_name() != "Home" and time.time() - t0 < 30:
            time.sleep(0.01)
        time.sleep(0.5)
        assert s.state_name() == "Home"
        s.resume()                                   # cycle start does not interfere with the cycle's stops
        s.soft_reset()
        t.join(60)
        assert out and not out[0][0] and s.alarm == 6 and s.state_name() == "Alarm"
        from pmctl.motion import channel as C
        r = s.raw()
        assert r[C.ST_SIGMA] == 0 and r[C.ST_QUEUED] == 0          # stopped, nothing left queued
    finally:
        s.shutdown()


JOB_TEXT_LINES = JOB.strip().splitlines()


@settings(max_examples=20, deadline=None)
@given(st.integers(1, len(JOB_TEXT_LINES) + 1), st.floats(0.5, 10.0),
       st.lists(st.floats(-8, 8), min_size=2, max_size=2), st.floats(165.0, 172.0))
def test_resume_plan_approaches_the_line_start_and_keeps_the_rest_of_the_job(tmp_path_factory, line, clearance, xy, z):
    from pmctl.motion.service_config import load_service_config
    from pmctl.task.resume import ResumeRefused, resume_job
    d = tmp_path_factory.mktemp("job")
    (d / "j.ngc").write_text(JOB)
    job = load_job(d / "j.ngc", M, start=home_pose(M))
    params = load_service_config().nc.params(M, DT)
    tip, axis = np.array([xy[0], xy[1], z]), np.array([0.0, 0.0, 1.0])
    try:
        r = resume_job(job, line, tip, axis, M, params, clearance)
    except ResumeRefused as e:
        assert line > max(m.line for m in job.moves) and "no motion" in str(e)
        return
    k = next(n for n, m in enumerate(job.moves) if m.line >= line)
    rest = job.moves[k:] if k > 0 else job.moves[1:]
    start = job.moves[k - 1].tip if k > 0 else job.moves[0].tip
    assert r.moves[3:] == tuple(rest)                                           # the job itself, unchanged
    assert np.allclose(r.moves[0].tip, tip + clearance * axis)                  # retract along the tool axis
    assert np.allclose(r.moves[1].tip, start + clearance * r.moves[2].axis)     # over the start point
    assert r.moves[1].kind == "rapid" and r.moves[2].kind == "line"
    assert np.allclose(r.moves[2].tip, start)                                   # plunge to it
    assert all(m.line == 0 for m in r.moves[:3])


@pytest.mark.parametrize("table, key", [
    ({"order": ["L1", "Z"]}, "homing.order"),
    ({"order": ["L1", "L1"]}, "homing.order"),
    ({"order": []}, "homing.order"),
    ({"seek_mm_s": "5"}, "homing.seek_mm_s"),
    ({"latch_mm_s": 6.0}, "homing.latch_mm_s"),
    ({"pull_off_mm": 0}, "homing.pull_off_mm"),
    ({"reference_mm": [400, 400, 400, 5]}, "homing.reference_mm"),
    ({"serch_mm": 5}, "serch_mm"),
])
def test_homing_table_is_strictly_validated(table, key):
    from pmctl.core.errors import ConfigError
    from pmctl.motion.service_config import service_from_dict
    with pytest.raises(ConfigError) as e:
        service_from_dict({"homing": table}, "svc.toml")
    assert key in str(e.value) and "svc.toml" in str(e.value)


def test_homing_references_outside_the_joint_travel_are_refused_at_start():
    from pmctl.core.errors import ConfigError
    from pmctl.motion.service_config import service_from_dict
    svc = service_from_dict({"homing": {"reference_mm": [600.0, 400.0, 400.0, 5.0, 5.0]}}, "svc.toml")
    params = svc.nc.params(M, DT)
    with pytest.raises(ConfigError) as e:
        svc.homing.check(params, "svc.toml")
    assert "reference_mm" in str(e.value) and "L1" in str(e.value)
