"""The supervisor's planner thread on items with nothing to move (an empty job, comments and M30,
a dwell of 0 s) and on a bug inside planning: an empty item retires at once, and an unexpected
exception stops motion with an alarm saying why -- never a dead planner thread with `ok`s that
never run. Also `pmctl run` of an empty job: an input error naming the file."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pmctl.core import kinematics as K
from pmctl.motion.nc import counts_of
from pmctl.task.gcode import parse_gcode
from pmctl.core.job import home_pose
from pmctl.task.supervisor import Supervisor
from pmctl.core.alarms import ALARM_ABORT

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]


class _Sup(Supervisor):
    """The real supervisor; an item named ``boom`` hits a planning bug, one named ``nothing``
    plans to no samples at all."""

    def _rows_of(self, job, start, it=None):
        if job.source == "boom":
            raise ZeroDivisionError("a bug in planning")
        if job.source == "nothing":
            return iter(())
        return super()._rows_of(job, start, it)


@pytest.fixture(scope="module")
def sup():
    s = _Sup("prototype", realtime=False)
    tip, ax = home_pose(s.machine)
    s.start(counts_of(K.ik(tip, ax, s.machine).q, s.params))
    yield s
    s.shutdown()


def _job(sup, text, name="t.ngc"):
    tip, ax = sup.end_pose()
    return parse_gcode(text, name, tip, ax)


def _move_runs(sup, dx):
    p0 = sup.pose()[0]
    sup.submit(_job(sup, f"G21 G91 G1 F1200 X{dx}"))
    assert sup.wait_idle(120) and not sup.alarm, sup.alarm_msg
    assert sup.state_name() == "Idle"
    assert np.allclose(sup.pose()[0] - p0, [dx, 0, 0], atol=2e-3)


@pytest.mark.parametrize("text", ["", "(only a comment)\nM30\n", "G4 P0\n", "G4 P0.001\n"])
def test_an_item_with_nothing_to_move_retires_and_motion_goes_on(sup, text):
    it = sup.submit(_job(sup, text))
    assert sup.wait_idle(60) and not sup.alarm, sup.alarm_msg
    assert it not in sup.items and not it.error and sup.state_name() == "Idle"
    _move_runs(sup, 1.0)


def test_an_item_planned_to_no_samples_retires_in_its_turn(sup):
    first = sup.submit(_job(sup, "G21 G91 G1 F600 X-1"))
    empty = sup.submit(_job(sup, "G4 P0.5", name="nothing"))
    assert sup.wait_idle(120) and not sup.alarm
    assert first not in sup.items and empty not in sup.items
    _move_runs(sup, 0.5)


def test_a_bug_in_planning_raises_an_alarm_and_stops_motion(sup):
    events = []
    sup.listeners.append(lambda ev, d: events.append((ev, d)))
    sup.submit(_job(sup, "G21 G91 G1 F300 X-4"))
    sup.submit(_job(sup, "G21 G91 G1 F300 X1", name="boom"), name="boom")
    sup.submit(_job(sup, "G21 G91 G1 F300 X1"))
    assert sup.wait_idle(120)
    assert sup.alarm == ALARM_ABORT and "ZeroDivisionError" in sup.alarm_msg and "boom" in sup.alarm_msg
    assert ("alarm", {"code": ALARM_ABORT, "msg": sup.alarm_msg}) in events
    assert not sup.items and sup.state_name() == "Alarm"
    sup.unlock()                              # the planner thread lives on: motion works after $X
    _move_runs(sup, 1.0)


def test_pmctl_run_of_an_empty_job_is_an_input_error(tmp_path):
    job = tmp_path / "empty.ngc"
    job.write_text("(nothing here)\nM30\n")
    r = subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", "run", "--job", str(job), "--state", "",
                        "--no-realtime"], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert r.returncode == 1, r.stderr
    assert f"{job}: no motion in the job" in r.stderr and "internal error" not in r.stderr
