"""What an operator reads: a successful run says it finished and leaves no lock file; a mistyped
option of a subcommand prints that subcommand's usage and exits 2; `pmctl ctl status` is a table
(positions to the micrometre, never -0.000); the run's progress estimate comes from the moves'
nominal times (a share that only grows, 1 at the last line)."""

import subprocess
import sys
from pathlib import Path

from pmctl.core.config import load_machine
from pmctl.interfaces.commands.ctl import status_table
from pmctl.interfaces.commands.run import _nominal_shares
from pmctl.task.planner import load_job
import pytest

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]


def pmctl(*args, **kw):
    return subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", *args], capture_output=True, text=True,
                          cwd=ROOT, **kw)


def test_a_successful_run_says_it_finished_and_leaves_no_lock(tmp_path):
    job = tmp_path / "j.ngc"
    job.write_text("G21 G91 G1 X2 F600\nG1 X-2\nM2\n")
    state = tmp_path / "state.json"
    out = pmctl("run", "--backend", "sim", "--job", str(job), "--state", str(state), "--no-realtime", "--quiet")
    assert out.returncode == 0, out.stderr
    assert "result: done" in out.stdout
    assert "pmctl rt: finished: the job ran to its end" in out.stderr
    assert "stopped by the supervisor" not in out.stderr
    assert state.exists() and not Path(str(state) + ".lock").exists()


def test_a_mistyped_subcommand_option_prints_its_usage_and_exits_2():
    out = pmctl("serve", "--consle", "pty:/tmp/x")
    assert out.returncode == 2
    assert out.stderr.startswith("usage: pmctl serve") and "unrecognized arguments: --consle" in out.stderr


def test_status_table_is_readable():
    st = {"ok": True, "state": "Idle", "mpos": [173.00021533104797, -0.0, -1e-9, 0.0, 2.5], "line": 0,
          "feed_override": 1.0, "rapid_override": 0.5, "spindle_override": 1.0, "spindle_rpm": 6000.0,
          "coolant": ["flood"], "queued_items": 0, "homed": True, "rt_alive": True, "counts": [1, 2, 3, 4, 5],
          "alarm": 0, "paused": ""}
    t = status_table(st)
    assert "X 173.000  Y 0.000  Z 0.000 mm   A 0.000  B 2.500 deg" in t
    assert "-0.000" not in t and "rapid 50 %" in t and "spindle 6000 rpm, flood" in t
    assert t.splitlines()[0].split() == ["state", "Idle"]


def test_progress_share_grows_to_one():
    m = load_machine("prototype")
    lines, share = _nominal_shares(load_job(ROOT / "examples/jobs/cone.ngc", m))
    assert all(b > a for a, b in zip(lines, lines[1:]))
    assert all(b >= a for a, b in zip(share, share[1:])) and abs(share[-1] - 1.0) < 1e-12
