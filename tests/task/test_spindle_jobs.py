"""The spindle between jobs, through the supervisor and the rt process with a simulated Modbus VFD
(a pymodbus server on 127.0.0.1): a job that ends with M5 is followed by another one queued just
after it at the same speed. The first job's M5 is written from a thread of its own; the second job
must not take the spindle for running while that M5 is still on its way, or it would cut with the
spindle stopping under it. The jobs carry their speed per move (as CL data does): G-code's M3/M5 are
EVENT moves, which take effect where the path gets to them (tests/interfaces/test_console_events.py)."""

import dataclasses
import threading
import time

import numpy as np

from pmctl.core import kinematics as K
from pmctl.hal import modbus_vfd
from pmctl.motion import channel as C
from pmctl.motion.nc import counts_of
from pmctl.core.job import EVENT, home_pose
from pmctl.task.planner import load_job as load_with_events
from pmctl.task.supervisor import Supervisor
from service_support import service_toml
import pytest

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

RPM = 6000.0


def load_job(path, machine, start):
    """The job with its speed per move only (its spindle EVENT moves left out)."""
    job = load_with_events(path, machine, start=start)
    return dataclasses.replace(job, moves=tuple(m for m in job.moves if m.kind != EVENT))


def _service(tmp_path):
    return service_toml(tmp_path, extra="[spindle]\nsimulate = true\nport = 0\nsim_ramp_rpm_per_s = 20000\n")


def test_a_job_queued_while_the_last_jobs_m5_is_on_its_way_starts_the_spindle_and_cuts_at_speed(
        tmp_path, monkeypatch):
    release = threading.Event()          # the M5 write waits for it
    real_stop = modbus_vfd.SpindleVFD.stop

    def late_stop(self):                  # the M5 write is held back until the test lets it go
        release.wait(30)
        real_stop(self)
    monkeypatch.setattr(modbus_vfd.SpindleVFD, "stop", late_stop)
    a, b = tmp_path / "a.ngc", tmp_path / "b.ngc"
    a.write_text(f"G17 G21 G90 G94\nS{RPM:g} M3\nG0 X5 Y0 Z65\nG1 X-5 F600\nM5\nG0 Z66\nM2\n")   # M5, retract
    b.write_text(f"G17 G21 G90 G94\nS{RPM:g} M3\nG1 X5 F300\nG1 Y5\nG1 X-5\nG1 Y0\nM5\nM2\n")
    sup = Supervisor(service=str(_service(tmp_path)), log=lambda m: None)
    tip, axis = home_pose(sup.machine)
    sup.start(counts_of(K.ik(tip, axis, sup.machine).q, sup.params))
    done = threading.Event()
    sup.listeners.append(lambda ev, d: done.set() if ev == "item_done" else None)
    try:
        ia = sup.submit(load_job(a, sup.machine, start=sup.pose()))
        assert done.wait(120) and sup.retired(ia)
        t0 = time.monotonic()             # a ended with the spindle off: its M5 is on its way (held back)
        while not any(t.name == "pmctl-m5" for t in threading.enumerate()) and time.monotonic() - t0 < 10:
            time.sleep(0.001)
        assert sup.spindle.vfd.rpm_cmd == RPM
        sup.submit(load_job(b, sup.machine, start=sup.pose()))
        t0 = time.monotonic()             # b moving (it skipped its M3), or 1 s (it waits for the M5)
        while sup.raw()[C.ST_SIGMA] == 0 and time.monotonic() - t0 < 1.0:
            time.sleep(0.002)
        release.set()
        speeds = []
        t0 = time.monotonic()
        while sup.busy() and time.monotonic() - t0 < 120:
            if sup.raw()[C.ST_SIGMA] > 0:
                speeds.append(sup.spindle.monitor.samples[-1][1])
            time.sleep(0.01)
        assert not sup.busy() and not sup.alarm, sup.alarm_msg
    finally:
        release.set()
        sup.shutdown()
    speeds = np.abs(np.array(speeds))
    assert len(speeds) > 100                                   # b cut for seconds, watched all along
    assert speeds.min() >= 0.98 * RPM, speeds.min()            # ... and always at speed (2 %)
