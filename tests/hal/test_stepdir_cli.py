"""`pmctl run --backend stepdir` end to end: the CLI starts the bridge's host build on a pty itself
(port = "host-pty", as in the shipped service config), machines a short job, writes the recording,
and the bridge's edge log holds exactly the commanded steps."""

import subprocess
import sys
import tomllib

import numpy as np

from pmctl.core.config import CONFIG_DIR
from pmctl.core.recording import read_recording
from pmctl.hal import bridge_protocol as bp
import pytest

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

JOB = """(short stepdir test job)
G17 G21 G90 G94
F600
G0 X5 Y0 Z65 A0 B0
G1 Z60
G1 X-5 Y3
G1 X0 Y-4 Z62
G0 Z65
"""


def _toml(d: dict) -> str:
    out = []
    for name, table in d.items():
        out.append(f"[{name}]")
        for k, v in table.items():
            if isinstance(v, dict):
                continue
            out.append(f"{k} = {_val(v)}")
        for k, v in table.items():
            if isinstance(v, dict):
                out.append(f"[{name}.{k}]")
                out += [f"{kk} = {_val(vv)}" for kk, vv in v.items()]
    return "\n".join(out) + "\n"


def _val(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_val(x) for x in v) + "]"
    return repr(v)


def test_pmctl_run_backend_stepdir_records_a_job_and_the_bridge_executes_every_step(tmp_path):
    job = tmp_path / "short.ngc"
    job.write_text(JOB)
    # the shipped service config, with the step-edge log switched on and timeouts sized for a
    # shared test machine (the job is run back to back, paced by the bridge)
    svc = tomllib.loads((CONFIG_DIR / "service.toml").read_text())
    edges = tmp_path / "edges.bin"
    svc["hal"]["stepdir"].update(edge_log=str(edges), read_timeout_ms=500.0, link_timeout_ms=1000.0,
                                 watchdog_ms=2000.0)
    (tmp_path / "service.toml").write_text(_toml(svc))
    rec = tmp_path / "rec"
    r = subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", "run", "--backend", "stepdir",
                        "--service", str(tmp_path / "service.toml"), "--job", str(job), "--record", str(rec),
                        "--state", "", "--no-realtime", "--quiet"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "result: done" in r.stdout and "pulses sent = pulse counters: yes" in r.stdout
    data = read_recording(rec)
    cmd = np.stack([np.asarray(data.columns[f"cmd_{a}"]) for a in ("L1", "L2", "L3", "X", "Y")], -1)
    assert "stepdir" in data.meta["description"]
    # the commanded motion (counters at the first and the last tick start; the last ticks hold still)
    commanded = np.rint((cmd[-1] - cmd[0]) * 2000.0).astype(np.int64)
    executed = bp.executed_steps(bp.read_edge_log(edges))
    assert np.array_equal(executed, commanded)
    assert np.abs(commanded).sum() > 1000
