"""What a new user meets in the first hour, on real `pmctl` processes: a recording is never
overwritten by accident, SIGTERM is a controlled stop that saves a clean position and the
recording, a closed output pipe does not stop the machine, input errors come before anything is
said about the machine, and the messages say what the user typed."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from pmctl.core.errors import InputError
from pmctl.core.recording import read_recording
from service_support import sim_service as _service

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
JOBS = ROOT / "examples" / "jobs"
PMCTL = [sys.executable, "-m", "pmctl.interfaces.cli"]


def _run_args(tmp_path, job="hemisphere.cl", record="rec", extra=(), realtime=False, **svc):
    """realtime=True paces the ticks (27 s for hemisphere.cl), so that a signal sent a second in
    surely lands mid-run; back to back the compiled loop machines the job in well under a second."""
    return [*PMCTL, "run", "--job", str(JOBS / job), "--service", str(_service(tmp_path, **svc)),
            "--state", str(tmp_path / "state.json"), "--record", str(tmp_path / record),
            *([] if realtime else ["--no-realtime"]), *extra]


def _start_and_wait_for_loop(args, **kw):
    """Start `pmctl run`; return (process, stderr lines so far) once the loop is about to start
    (the line announcing the job streamed to the rt motion process)."""
    p = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT, **kw)
    seen = []
    t0 = time.monotonic()
    while time.monotonic() - t0 < 120:
        line = p.stderr.readline()
        if not line:
            break
        seen.append(line)
        if "streamed to the rt motion process" in line and "backend" in line:
            return p, seen
    p.kill()
    raise AssertionError("the loop never started: " + "".join(seen))


def test_sigterm_mid_run_is_a_controlled_stop_that_saves_a_clean_position(tmp_path):
    p, _ = _start_and_wait_for_loop(_run_args(tmp_path, extra=["--quiet"], realtime=True))
    time.sleep(1.0)
    p.send_signal(signal.SIGTERM)
    out, err = p.communicate(timeout=120)
    assert p.returncode == 3, out + err                      # controlled stop
    assert "SIGTERM" in out
    state = json.loads((tmp_path / "state.json").read_text())
    assert state["clean"] is True
    rec = read_recording(tmp_path / "rec")
    assert rec.meta["complete"] is True
    assert rec.meta["run"]["status"] == "stopped" and "SIGTERM" in rec.meta["run"]["reason"]
    assert 0 < rec.n < 27000                                  # stopped well before the job's end
    # the position saved is the last commanded one: counters = cmd of the last row (+ the last tick)
    q_last = np.array([rec[f"cmd_{a}"][-1] for a in ("L1", "L2", "L3", "X", "Y")])
    assert np.abs(np.array(state["counts"]) - np.rint(q_last * 2000)).max() <= 1
    # tracking is reported only over what was machined before the stop request
    tr = rec.meta["run"]
    if tr["tracking"]:
        assert tr["tracking"]["tip_max_um"] < 50 and "before the stop request" in tr["tracking_note"]
    else:
        assert "before it started" in tr["tracking_note"]
    # times are k / rate, printed shortest: 1.263, never 1.2630000000000001
    ts = [ln.split(",", 1)[0] for ln in (tmp_path / "rec" / "data.csv").read_text().splitlines()[1:]]
    assert ts[:3] == ["0.0", "0.001", "0.002"] and all(len(s) <= 6 for s in ts)


def test_ctrl_c_before_the_job_starts_reports_no_tracking_figures(tmp_path):
    p, _ = _start_and_wait_for_loop(_run_args(tmp_path, extra=["--quiet"], realtime=True))
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=120)
    assert p.returncode == 3, out + err
    line = next(ln for ln in out.splitlines() if "tool-tip error" in ln)
    # either nothing of the job was machined, or the figures cover only the machined part
    assert ("stopped before it started" in line) or ("before the stop request" in line and "RMS" in line)
    if "RMS" in line:
        rms_um = float(line.split("RMS ")[1].split(" ")[0])
        assert rms_um < 20                    # tracking, not the stopping ramp (1000 um before)


def test_closed_output_pipes_do_not_stop_the_machine(tmp_path):
    args = _run_args(tmp_path, job="cone.ngc", rate=250, kv=100, k_theta=50)
    p = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT)
    p.stdout.close()                          # like `pmctl run ... 2>&1 | head -0`
    p.stderr.close()
    assert p.wait(timeout=300) == 0
    rec = read_recording(tmp_path / "rec")
    assert rec.meta["run"]["status"] == "done" and rec.meta["complete"] is True
    assert json.loads((tmp_path / "state.json").read_text())["clean"] is True


def test_record_refuses_an_existing_recording_before_anything_moves(tmp_path):
    args = _run_args(tmp_path, job="cone.ngc", rate=250, kv=100, k_theta=50, extra=["--quiet"])
    first = subprocess.run(args, capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert first.returncode == 0, first.stderr
    before = (tmp_path / "rec" / "data.csv").read_bytes()
    state_before = (tmp_path / "state.json").read_text()
    again = subprocess.run(args, capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert again.returncode == 1
    assert "already there" in again.stderr and "--force" in again.stderr
    assert "position" not in again.stderr                  # refused before the machine is involved
    assert (tmp_path / "rec" / "data.csv").read_bytes() == before
    assert (tmp_path / "state.json").read_text() == state_before
    forced = subprocess.run(args + ["--force"], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert forced.returncode == 0, forced.stderr
    assert read_recording(tmp_path / "rec").meta["complete"] is True
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("rec")) == ["rec"]


@pytest.mark.parametrize("extra, says", [
    (["--backend", "foo"], "--backend 'foo': unknown backend"),
    (["--rate", "5"], "--rate must be within"),
    (["--feed-override", "0"], "--feed-override"),
])
def test_bad_input_is_reported_first_and_names_the_flag(tmp_path, extra, says):
    r = subprocess.run(_run_args(tmp_path, extra=extra), capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert r.returncode == 1
    assert says in r.stderr and "service config" not in r.stderr
    assert "position" not in r.stderr and not (tmp_path / "rec").exists()


def test_g1_x500_says_the_table_moves_opposite(tmp_path):
    job = tmp_path / "far.ngc"
    job.write_text("G21 G90\nG1 X500 F600\n")
    r = subprocess.run([*PMCTL, "run", "--job", str(job), "--state", "", "--no-realtime"],
                       capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert r.returncode == 1
    assert "far.ngc:2" in r.stderr and "table X = -500" in r.stderr
    assert "opposite" in r.stderr and "x = +500" in r.stderr
    assert "position" not in r.stderr


def test_unit_vector_tolerance_is_the_same_for_cl_data_and_kin(capsys):
    """A tool axis 0.8 tolerances off unit length is normalised by both; 3 tolerances off is
    refused by both (it used to be 0.001 for CL data and 0.01 for kin --axis)."""
    from pmctl.core.tolerances import AXIS_TOL
    from pmctl.interfaces.cli import main
    from pmctl.task import cldata
    assert cldata.AXIS_TOL == AXIS_TOL
    for norm, ok in ((1 + 0.8 * AXIS_TOL, True), (1 + 3 * AXIS_TOL, False), (1 - 3 * AXIS_TOL, False)):
        text = f"0,0,60,0,0,{norm!r},s\n5,0,60,0,0,{norm!r},w\n10,0,60,0,0,{norm!r},e\n"
        try:
            cldata.parse_cl(text, "t.cl")
            cl_ok = True
        except InputError:
            cl_ok = False
        kin_ok = main(["kin", "ik", "--tip", "0,0,60", "--axis", f"0,0,{norm!r}"]) == 0
        capsys.readouterr()
        assert (cl_ok, kin_ok) == (ok, ok), norm


def test_synth_refuses_existing_cases_unless_force(tmp_path):
    args = [*PMCTL, "twin", "synth", str(tmp_path / "o"), "--clean", "--duration", "2", "--rate", "50"]
    assert subprocess.run(args, capture_output=True, text=True, cwd=ROOT, timeout=300).returncode == 0
    r = subprocess.run(args, capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert r.returncode == 1 and "--force" in r.stderr
    assert subprocess.run(args + ["--force"], capture_output=True, text=True, cwd=ROOT,
                          timeout=300).returncode == 0


def test_diagnose_finds_the_recording_in_a_sub_folder_or_says_where(tmp_path):
    from pmctl.core.recording import CMD, write_recording
    from pmctl.tools.twin.diagnose import _display_name, find_recording
    cols = {"t": np.arange(5) / 100, **{c: np.zeros(5) for c in CMD}}
    write_recording(tmp_path / "case-000" / "recording", cols, sample_rate_hz=100)
    assert find_recording(tmp_path / "case-000") == tmp_path / "case-000" / "recording"
    assert find_recording(tmp_path) == tmp_path / "case-000" / "recording"      # two levels down
    assert _display_name(tmp_path / "case-000" / "recording") == "case-000/recording"
    write_recording(tmp_path / "case-001" / "recording", cols, sample_rate_hz=100)
    with pytest.raises(InputError, match="holds 2 recordings.*case-000.*case-001"):
        find_recording(tmp_path)
    (tmp_path / "run.partial").mkdir()
    with pytest.raises(InputError, match="run.partial.*did not finish"):
        find_recording(tmp_path / "run")


def test_a_resonance_at_the_simulated_chain_mode_is_said_to_be_the_simulation():
    from pmctl.tools.twin.diagnose import plant_notes
    report = {"findings": [
        {"effect": "resonance", "axis": "L2", "parameters": {"freq_hz": 246.5}, "evidence": "L2 rings."},
        {"effect": "resonance", "axis": "L1", "parameters": {"freq_hz": 120.0}, "evidence": "L1 rings."},
        {"effect": "backlash", "axis": "X", "parameters": {"width_mm": 0.01}, "evidence": "X flips."}]}
    meta = {"run": {"plant": {"chain_mode_hz": [246.6, 246.6, 246.6], "chain_mode_damping_ratio": [0.02] * 3}}}
    notes = plant_notes(report, meta)
    assert len(notes) == 1 and "L2" in notes[0]
    assert "simulated plant's chain-2 mode" in report["findings"][0]["evidence"]
    assert "simulated" not in report["findings"][1]["evidence"]       # 120 Hz is not the mode
    assert plant_notes(report, {}) == []                               # a real machine's recording


def test_tracking_window_covers_only_what_was_tracked():
    from types import SimpleNamespace

    from pmctl.interfaces.commands.run import tracking_window
    res = SimpleNamespace(job_start=500, ticks=3000, dt=0.001, status="stopped", reason="x")
    assert tracking_window(res, 200)[:2] == (500, 500)                  # before the job started
    assert "before it started" in tracking_window(res, 200)[2]
    assert tracking_window(res, 1500)[:2] == (500, 1500)
    assert tracking_window(res, None)[:2] == (500, 500)                 # the loop stopped itself
    done = SimpleNamespace(job_start=500, ticks=3000, dt=0.001, status="done", reason="")
    assert tracking_window(done, None) == (500, 3000, "")
