"""A CANopen drive fault mid-job through the whole stack: `pmctl run --backend canopen` (supervisor +
rt motion process + canopen master) against five CiA 402 drives that the test hosts itself in a
device simulator (pmctl.hal.devsim), reached as an slcan adapter on a loopback TCP port
(`simulate = false`, `channel = "socket://127.0.0.1:PORT"`): to the controller they are real drives
on a USB-CAN adapter, and the test keeps the handle to make one of them fault and to read where the
drives are afterwards.

Asserted: once the job moves, drive X (node 4) faults (continuous over-current: state Fault and
EMCY 0x2310, as a drive's own protection would); the run stops with the node, its axis and the code
in the rt process's stop line; the counters saved are the pulses sent (counter change = pulses
sent), marked not a clean stop; every drive is out of Operation enabled (X in Fault, the others
quick-stopped and disabled). The drives lag their targets (first-order lag, a CAN cycle), so after
such a stop the counters are ahead of the drives' positions by the travel of that lag: the next
start refuses them, naming the drive and both positions, and enables nothing (no drive moves)."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.hal import cia402 as C
from pmctl.hal.devsim import DeviceSimulator
from pmctl.motion.state_store import load_counters
from pmctl.core.job import home_pose
import pytest

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
JOB = ROOT / "examples" / "jobs" / "cone.ngc"
NODES = [1, 2, 3, 4, 5]
EMCY_CURRENT = 0x2310


def _service(tmp_path, port):
    """The shipped service config, its drives on an slcan adapter at the test's simulator; no
    spindle or DAQ (not what this test is about)."""
    text = (ROOT / "config" / "service.toml").read_text()
    head, sec, body = text.partition("[hal.canopen]")
    assert 'channel = "devsim"' in body and "\nsimulate = true " in body
    body = body.replace('channel = "devsim"', f'channel = "socket://127.0.0.1:{port}"', 1)
    body = body.replace("\nsimulate = true ", "\nsimulate = false ", 1)
    text = head + sec + body
    for s in ("[spindle]", "[daq]"):
        h, _, b = text.partition(s)
        assert "\nenabled = true" in b
        text = h + s + b.replace("\nenabled = true", "\nenabled = false", 1)
    p = tmp_path / "service.toml"
    p.write_text(text)
    return p


def _pmctl_run(svc, state):
    return [sys.executable, "-m", "pmctl.interfaces.cli", "run", "--backend", "canopen", "--job", str(JOB),
            "--service", str(svc), "--state", str(state), "--quiet"]


def test_drive_fault_mid_job_through_pmctl_run_is_a_controlled_stop_naming_node_and_code(tmp_path):
    m = load_machine("prototype")
    ppm = np.asarray(m.resolution.pulses_per_mm, float)
    tip, axis = home_pose(m)
    c0 = np.rint(K.ik(tip, axis, m).q * ppm).astype(np.int64)     # where pmctl run starts without counters
    sim = DeviceSimulator({"can": {"node_ids": NODES, "positions": c0.tolist(), "lag_s": 1e-3, "tcp": True,
                                   "ptys": 0}, "rt_priority": 52}, "the test's CiA 402 drives").start()
    # (real-time priority as the shipped config gives its simulator, sim_rt_priority: real drives
    # answer in hardware; a starved simulator on a loaded machine would answer SYNCs late)
    try:
        svc = _service(tmp_path, sim.info["can_tcp_port"])
        state = tmp_path / "counters.json"
        p = subprocess.Popen(_pmctl_run(svc, state), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             cwd=ROOT)
        try:
            # mid-job: once the drives have moved 1 mm on some axis (and the job is not over)
            t_end = time.monotonic() + 120
            while time.monotonic() < t_end and p.poll() is None:
                if np.abs(np.array(sim.call("drives", "positions")) - c0).max() > ppm[0]:
                    break
                time.sleep(0.02)
            assert p.poll() is None, "the run ended before the drives moved"
            sim.call("drive:4", "fault", EMCY_CURRENT, True)          # X: state Fault + EMCY 0x2310
            out, err = p.communicate(timeout=120)
        finally:
            if p.poll() is None:
                p.kill()
                p.communicate()
        assert p.returncode == 4, out + err                          # pmctl run: a fault
        stop = [ln for ln in err.splitlines() if "pmctl rt: stopped:" in ln]
        assert len(stop) == 1, err
        assert "backend fault: canopen node 4 (X): EMCY 0x2310 (current)" in stop[0]
        assert "pulses sent = counter change: yes" in stop[0] and "pulses sent = pulse counters: yes" in out
        # the drives hold no counters: their last positions against the counters, short of them here
        assert re.search(r"drive positions = counters: NO \((L1|L2|L3|X|Y) [-+]\d+ pulses", stop[0]), stop[0]

        counters = [int(x) for x in re.search(r"counters \[([-\d, ]+)\] saved", stop[0]).group(1).split(",")]
        saved = load_counters(state, machine=m.name)
        assert saved is not None and not saved.clean
        assert saved.counts.tolist() == counters
        assert np.abs(np.array(counters) - c0).max() > ppm[0]         # it stopped mid-job, after moving

        states = [sim.get(f"drive:{n}", "state") for n in NODES]
        assert states[3] == C.FAULT and all(s != C.OPERATION_ENABLED for s in states), states
        held = np.array(sim.call("drives", "positions"))

        # a restart on those counters: refused before anything is enabled, naming the drive
        r = subprocess.run(_pmctl_run(svc, state), capture_output=True, text=True, cwd=ROOT, timeout=120)
        assert r.returncode != 0 and "re-home; nothing enabled" in r.stderr, r.stdout + r.stderr
        assert re.search(r"canopen node \d \((L1|L2|L3|X|Y)\): drive at -?[\d.]+ mm but the controller's counters "
                         r"say -?[\d.]+ mm", r.stderr), r.stderr
        assert np.array_equal(np.array(sim.call("drives", "positions")), held)
        assert sim.get("drive:4", "state") == C.FAULT
        assert load_counters(state, machine=m.name).counts.tolist() == counters
    finally:
        sim.stop()

    # the run's result line gives the same reason (the rt process's exit after the fault is not it)
    result = next(ln for ln in out.splitlines() if ln.startswith("result:"))
    assert "node 4 (X): EMCY 0x2310" in result, result
