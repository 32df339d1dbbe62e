"""The two processes of the daemon: the rt motion process (loop + NC + sim backend) and the
supervisor, joined by shared memory. Motion runs through the channel; each process survives the
other's death (rt dead -> alarm, motion refused until unlock; supervisor dead -> the rt process
holds on the path, saves its counters and exits). Sim backend, no real-time priority."""

import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from grbl_sender import kill_supervisor_wait_rt
from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.motion import channel as C
from pmctl.motion.nc import counts_of
from pmctl.motion.state_store import load_counters
from pmctl.task.gcode import parse_gcode
from pmctl.core.job import home_pose
from pmctl.task.supervisor import Supervisor
from pmctl.core.errors import MotionRefused
from pmctl.core.alarms import ALARM_MOTOR_FAULT

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

M = load_machine()


@pytest.fixture
def sup(tmp_path):
    s = Supervisor("prototype", realtime=False, state_file=str(tmp_path / "counters.json"))
    tip, ax = home_pose(s.machine)
    s.start(counts_of(K.ik(tip, ax, s.machine).q, s.params))
    yield s
    s.shutdown()


def job_from(sup, text):
    tip, ax = sup.end_pose()
    return parse_gcode(text.format(z=tip[2] - 5), "t.ngc", tip, ax)


def test_a_job_runs_through_the_rt_process_and_every_pulse_is_counted(sup):
    job = job_from(sup, "G21 G90 G1 F1500 X8 Y-3 Z{z}\nG2 X0 Y-3 I-4 J0\nG0 X1 Y1\n")
    sup.submit(job)
    assert sup.wait_idle(120) and not sup.alarm
    s = sup.raw()
    counts = s[C.ST_COUNTS:C.ST_COUNTS + 5]
    assert np.array_equal(counts, s[C.ST_DEV_COUNTS:C.ST_DEV_COUNTS + 5])           # the drive side counted them
    assert np.array_equal(counts, s[C.ST_COUNTS0:C.ST_COUNTS0 + 5] + s[C.ST_SENT:C.ST_SENT + 5])
    tip, axis = sup.pose()
    assert np.linalg.norm(tip - job.moves[-1].tip) < 2e-3                           # at the last programmed point
    assert sup.state_name() == "Idle"
    # a normal shutdown: the rt side saves and exits as asked - no "rt motion process died" alarm
    events = []
    sup.listeners.append(lambda ev, detail: events.append(ev))
    sup.shutdown()                          # joins the monitor thread, which watched the rt side exit
    assert not sup.alarm and not sup.rt_dead and "rt_dead" not in events, (sup.alarm_msg, events)


def test_rt_process_killed_raises_an_alarm_refuses_motion_and_unlock_restarts_it(sup):
    job = job_from(sup, "G21 G90 G1 F600 X20 Y0 Z{z}\n")
    sup.submit(job)
    time.sleep(1.0)
    before = sup.counts()
    os.kill(sup.rt_pid, signal.SIGKILL)
    t0 = time.time()
    while not sup.rt_dead and time.time() - t0 < 10:
        time.sleep(0.02)
    assert sup.rt_dead and sup.alarm == ALARM_MOTOR_FAULT and sup.state_name() == "Alarm"
    assert "rt motion process died" in sup.alarm_msg
    kept = sup.counts()
    assert np.all(np.abs(kept - before) < 2000 * 2)          # the last reported counters are kept
    with pytest.raises(MotionRefused):
        sup.submit(job_from(sup, "G21 G90 G1 F600 X0 Y0\n"))
    sup.unlock()                                             # restarts the rt process at the kept counters
    assert not sup.rt_dead and sup.state_name() == "Idle"
    assert np.array_equal(sup.raw()[C.ST_COUNTS0:C.ST_COUNTS0 + 5], kept)
    back = job_from(sup, "G21 G90 G1 F1500 X0 Y0\n")
    sup.submit(back)
    assert sup.wait_idle(120) and not sup.alarm
    assert np.linalg.norm(sup.pose()[0][:2]) < 2e-3


SUPERVISOR_SCRIPT = textwrap.dedent("""
    import sys, time
    from pmctl.core import kinematics as K
    from pmctl.motion.nc import counts_of
    from pmctl.task.gcode import parse_gcode
    from pmctl.core.job import home_pose
    from pmctl.task.supervisor import Supervisor
    s = Supervisor("prototype", realtime=False, state_file={state!r})
    tip, ax = home_pose(s.machine)
    s.start(counts_of(K.ik(tip, ax, s.machine).q, s.params))
    s.submit(parse_gcode("G21 G90 G1 F600 X20 Y0 Z%r\\n" % float(tip[2] - 5), "t.ngc", tip, ax))
    from pmctl.motion import channel as C
    while s.raw()[C.ST_SIGMA] == 0 or s.raw()[C.ST_FOLLOW] != 1:     # wait until it moves
        time.sleep(0.01)
    time.sleep(0.5)
    print(s.rt_pid, flush=True)
    time.sleep(600)
""")


def test_supervisor_killed_the_rt_process_holds_on_the_path_saves_counters_and_exits(tmp_path):
    state = tmp_path / "counters.json"
    p = subprocess.Popen([sys.executable, "-c", SUPERVISOR_SCRIPT.format(state=str(state))],
                         stdout=subprocess.PIPE, text=True)
    try:
        rt_pid = int(p.stdout.readline())
        kill_supervisor_wait_rt(p, rt_pid, timeout=20)
    finally:
        if p.poll() is None:
            p.kill()
    saved = load_counters(state, machine=M.name)
    assert saved.clean                                    # a controlled stop: the counters are exact
    q = saved.counts / M.resolution.pulses_per_mm
    pose, ok = K.fk_batch(q[None], M)
    tip = pose.tip[0]
    h_tip, _ = home_pose(M)
    # it stopped part-way, on the programmed line from (0, 0, z0) to (20, 0, z0 - 5)
    a, b = h_tip, np.array([20.0, 0.0, h_tip[2] - 5])
    u = np.dot(tip - a, b - a) / np.dot(b - a, b - a)
    assert 0.0 < u < 1.0
    assert np.linalg.norm(a + u * (b - a) - tip) < 2e-3


def test_estop_input_latches_alarm_10_until_it_clears_and_unlock(tmp_path):
    from pathlib import Path
    from pmctl.core.alarms import ALARM_ESTOP
    svc = tmp_path / "service.toml"
    base = (Path(__file__).resolve().parents[2] / "config" / "service.toml").read_text()
    assert "[hal.sim]\n" in base
    svc.write_text(base.replace("[hal.sim]\n", "[hal.sim]\nestop_from_tick = 400\nestop_to_tick = 2500\n"))
    s = Supervisor("prototype", service=str(svc), realtime=False)
    tip, ax = home_pose(s.machine)
    s.start(counts_of(K.ik(tip, ax, s.machine).q, s.params))
    try:
        t0 = time.time()
        while s.alarm != ALARM_ESTOP and time.time() - t0 < 60:
            time.sleep(0.02)
        assert s.alarm == ALARM_ESTOP and "E-stop input" in s.alarm_msg and s.state_name() == "Alarm"
        if s.raw()[C.ST_TICK] < 2300:
            with pytest.raises(MotionRefused):
                s.unlock()                          # latched while the input is pressed
            assert s.alarm == ALARM_ESTOP
        while s.raw()[C.ST_TICK] < 2600:
            time.sleep(0.05)
        s.unlock()
        assert s.state_name() == "Idle"
        s.submit(job_from(s, "G21 G91 G1 F1200 X1\n"))
        assert s.wait_idle(60) and not s.alarm
    finally:
        s.shutdown()


def test_a_shaped_job_through_the_daemon_ends_on_its_last_point_with_every_pulse_counted(tmp_path):
    """With [nc] shaper set, the planner thread shapes the time law of the whole item (not streamed):
    the machine still follows the programmed path to its last point and the rt side counts every
    pulse."""
    from pathlib import Path
    svc = tmp_path / "service.toml"
    base = (Path(__file__).resolve().parents[2] / "config" / "service.toml").read_text()
    assert 'shaper = "none"' in base
    svc.write_text(base.replace('shaper = "none"', 'shaper = "ZVD"\nshaper_hz = 40.0', 1))
    s = Supervisor("prototype", service=str(svc), realtime=False)
    assert s.nc_setup.shaper is not None and s.nc_setup.shaper.name == "ZVD"
    tip, ax = home_pose(s.machine)
    s.start(counts_of(K.ik(tip, ax, s.machine).q, s.params))
    try:
        job = job_from(s, "G21 G90 G1 F1500 X8 Y-3 Z{z}\nX0 Y4\n")
        s.submit(job)
        assert s.wait_idle(120) and not s.alarm
        r = s.raw()
        counts = r[C.ST_COUNTS:C.ST_COUNTS + 5]
        assert np.array_equal(counts, r[C.ST_COUNTS0:C.ST_COUNTS0 + 5] + r[C.ST_SENT:C.ST_SENT + 5])
        tip1, _ = s.pose()
        assert np.linalg.norm(tip1 - job.moves[-1].tip) < 2e-3
    finally:
        s.shutdown()
