"""The state journal and position across a power cut: offsets/settings/job round-trip, a damaged
journal is an error naming the file, and after both processes die at once (a power cut) the
daemon comes back in Alarm at the last periodic snapshot, saying its age and that it is not
trusted, until the operator confirms."""

import json
import os
import signal
import time

import numpy as np
import pytest

from grbl_sender import Sender, start_serve, stop_serve
from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.errors import InputError
from pmctl.motion.state_store import load_counters
from pmctl.task.journal import Journal

M = load_machine()


def test_journal_round_trip_and_damaged_file(tmp_path):
    p = tmp_path / "c.json.journal"
    j = Journal(p, M.name)
    off = {"wcs": {"G54": [1, 2, 3, 4, 5]}, "g92": [0, 0, 1, 0, 0], "active": "G55"}
    j.save(offsets=off, settings={"10": 0}, running=True, job="x.ngc", line=12)
    k = Journal(p, M.name).load()
    assert k.loaded and k.data["offsets"] == off and k.data["line"] == 12 and k.data["running"]
    p.write_text("{not json")
    with pytest.raises(InputError) as e:
        Journal(p, M.name).load()
    assert str(p) in str(e.value)
    p.write_text(json.dumps({"format": "pmctl-journal/1", "machine": M.name, "offsets": {"g92": [1, 2]}}))
    with pytest.raises(InputError) as e:
        Journal(p, M.name).load()
    assert "offsets.g92" in str(e.value)
    for key, bad in (("line", -1), ("line", "7"), ("job_start", [1, 2, 3]), ("job", 5), ("homed", "yes")):
        p.write_text(json.dumps({"format": "pmctl-journal/1", "machine": M.name, key: bad}))
        with pytest.raises(InputError) as e:
            Journal(p, M.name).load()
        assert key in str(e.value)
    j.save(job="/jobs/a.ngc", line=7, job_start=[0, 0, 173, 0, 0, 1], homed=True)
    k = Journal(p, M.name).load()
    assert k.data["job_start"] == [0, 0, 173, 0, 0, 1] and k.data["homed"] is True
    p.write_text(json.dumps({"format": "pmctl-journal/1", "machine": "other"}))
    with pytest.raises(InputError):
        Journal(p, M.name).load()


def rt_pid_of(pid):
    from pathlib import Path
    for t in os.listdir(f"/proc/{pid}/task"):
        for k in Path(f"/proc/{pid}/task/{t}/children").read_text().split():
            if b"pmctl.motion.rtproc" in Path(f"/proc/{k}/cmdline").read_bytes():
                return int(k)
    return None


def test_power_cut_comes_back_in_alarm_at_the_last_snapshot_not_trusted(tmp_path):
    state = tmp_path / "state.json"
    p, link = start_serve(tmp_path, state=state)
    s = Sender(link)
    try:
        s.reset()
        p0 = np.array(s.status()["pos"])
        assert s.send("G21 G91 G1 F300 X-12") == "ok"
        s.wait_state(("Run",), 60)
        t0 = time.time()                 # moving (the first plan can take a second on a loaded machine) ...
        while s.status()["pos"][0] - p0[0] > -0.5 and time.time() - t0 < 60:
            time.sleep(0.05)
        time.sleep(0.3)                  # ... and past a periodic snapshot
        rt = rt_pid_of(p.pid)
        os.kill(rt, signal.SIGKILL)                 # both at once: nobody can save anything
        p.send_signal(signal.SIGKILL)
        p.wait(10)
    finally:
        s.close()
    saved = load_counters(state, machine=M.name)
    assert not saved.clean                          # a periodic snapshot
    tip = K.fk_batch((saved.counts / M.resolution.pulses_per_mm)[None], M)[0].tip[0]
    assert -12 < tip[0] - p0[0] < 0 and np.allclose(tip[1:], p0[1:3], atol=2e-3)   # on the programmed line
    p, link = start_serve(tmp_path, state=state)
    s = Sender(link)
    try:
        st = s.status()
        assert st["state"] == "Alarm"
        assert np.allclose(st["pos"][:3], tip, atol=1.5e-3)
        assert s.send("G1 X1") == "error:9"
        assert s.send("$X") == "ok"
        assert s.wait_state(("Idle",), 30)["state"] == "Idle"
    finally:
        s.close()
        stop_serve(p)
    err = (tmp_path / "serve.err").read_text()
    assert "NOT trusted" in err and " s old" in err
