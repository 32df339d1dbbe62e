"""`pmctl check` (every problem of a job, its kind and line, and a summary; exit 0/1) and `pmctl post`
(the job in actuator coordinates: FK of the written joints gives back the planned tips)."""

from __future__ import annotations

import contextlib
import csv
import io
import json
from pathlib import Path

import numpy as np
import pytest

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.errors import InputError
from pmctl.interfaces.cli import main
from pmctl.task import post
from pmctl.task.job import load_job
from pmctl.core.job import EVENT, Job, LINE, Move, RAPID
from pmctl.task.planner import home_pose, plan, plan_stream
from pmctl.motion.trajectory import Trajectory

JOBS = Path(__file__).resolve().parents[2] / "examples" / "jobs"
DT = 1e-3
UP = np.array([0.0, 0.0, 1.0])


@pytest.fixture(scope="module")
def machine():
    return load_machine()


def cli(*argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    return code, out.getvalue(), err.getvalue()


def check_json(path):
    code, out, _ = cli("check", str(path), "--json", "--state", "")
    return code, json.loads(out)


def test_check_lists_every_machine_problem_with_its_line(tmp_path):
    p = tmp_path / "bad.ngc"
    p.write_text("G0 X60 Y-30 Z60\nF600\n"
                 "G1 Z400\n"                       # 3: too high
                 "G1 Z60\n"
                 "G1 X200\n"                       # 5: beyond the table's travel
                 "G1 X60\n"
                 "G3 X60 Y30 I0 J30\n"             # 7: both ends reachable, the arc between is not
                 "G1 X0 Y0\n")
    code, rep = check_json(p)
    assert code == 1 and rep["ok"] is False
    probs = rep["problems"]
    # one problem per stretch of moves out of the same limit: 3-4 (too high, and the way back down),
    # 5-7 (beyond the table: the pose, the way back, and the arc between reachable ends)
    assert [q["line"] for q in probs] == [3, 5]
    assert all(q["kind"] == "machine" and q["file"] == str(p) and q["column"] is None for q in probs)
    assert "chain" in probs[0]["message"] and "move the program (or the part) in Z" in probs[0]["message"]
    assert "to line 4: 2 lines" in probs[0]["message"]
    assert "table X" in probs[1]["message"] and "X/Y" in probs[1]["message"]
    assert "to line 7: 3 lines" in probs[1]["message"]
    assert set(rep) == {"ok", "problems", "summary"} and rep["summary"]["moves"] == 7
    # the text form: one line per problem, then the verdict
    code, out, _ = cli("check", str(p), "--state", "")
    lines = out.strip().splitlines()
    assert code == 1 and lines[0].startswith(f"{p}:3: machine: ") and lines[-1] == "2 problems: the job cannot run"
    # an arc whose ends are reachable and whose middle is not: its own line, "between the poses"
    p.write_text("G0 X60 Y-30 Z60\nF600\nG3 X60 Y30 I0 J30\nG1 X0 Y0\nG1 X0 Y0 Z400\n")
    code, rep = check_json(p)
    assert [(q["line"], "between the programmed poses" in q["message"]) for q in rep["problems"]] == \
        [(3, True), (5, False)]


def test_a_program_placed_outside_the_workspace_is_one_problem(tmp_path):
    p = tmp_path / "far.ngc"
    p.write_text("G0 X100 Y0 Z60\nF600\n" + "\n".join(f"G1 X{100 + i % 2} Y{i * 0.1:.1f}" for i in range(500)) + "\n")
    code, rep = check_json(p)
    assert code == 1 and len(rep["problems"]) == 1
    q = rep["problems"][0]
    assert q["line"] == 1 and "table X" in q["message"] and "to line 502: 501 lines" in q["message"]


@pytest.mark.parametrize("text,line,column,kind", [
    ("G0 X1 Y1 Z60\nG1 X2 Y\n", 2, 7, "syntax"),
    ("G0 X1 Y1 Z60\nG5.2 X2 Y2\n", 2, 1, "unsupported"),      # NURBS (G5, the cubic spline, is supported)
])
def test_check_reports_the_readers_refusal_with_its_kind(tmp_path, text, line, column, kind):
    p = tmp_path / "r.ngc"
    p.write_text(text)
    code, rep = check_json(p)
    assert code == 1 and len(rep["problems"]) == 1
    q = rep["problems"][0]
    assert (q["line"], q["column"], q["kind"]) == (line, column, kind), q


def test_check_reports_a_planning_problem_with_its_line(tmp_path):
    p = tmp_path / "slow.ngc"
    p.write_text("G0 X0 Y0 Z70\nG1 F0.0000001 X10\n")
    code, rep = check_json(p)
    q = rep["problems"]
    assert code == 1 and len(q) == 1 and q[0]["kind"] == "planning" and q[0]["line"] == 2
    assert "at most 24 h" in q[0]["message"] and "F is per minute" in q[0]["message"]


def test_check_of_a_good_job_says_what_the_run_will_do(machine):
    code, rep = check_json(JOBS / "cone.ngc")
    assert code == 0 and rep["ok"] and rep["problems"] == []
    s = rep["summary"]
    job = load_job(JOBS / "cone.ngc", machine)
    traj = plan(job, machine, DT)
    assert s["moves"] == len(job.moves) and s["tools"] == []
    assert s["machining_time_s"] == pytest.approx(len(traj) * DT, abs=1e-9)   # what the planner plans
    tips = np.array([m.tip for m in job.moves if m.kind != EVENT])       # programmed points (S M3: an event)
    assert s["extents"]["z_mm"] == [tips[:, 2].min(), tips[:, 2].max()]
    seg_len = np.linalg.norm(np.diff(np.vstack([home_pose(machine)[0], tips]), axis=0), axis=1)
    assert s["length_mm"] >= seg_len.sum() - 1e-9           # (arcs are longer than their chords)
    assert cli("check", str(JOBS / "cone.ngc"), "--state", "")[1].strip().endswith("ok: the job can run")


def test_run_refuses_a_job_with_problems_before_anything_moves(tmp_path):
    p = tmp_path / "bad.ngc"
    p.write_text("G0 X0 Y0 Z60\nF600\nG1 Z400\nG1 Z60\nG1 X200\n")
    code, out, err = cli("run", "--job", str(p), "--backend", "sim", "--no-realtime", "--state", "", "--quiet")
    assert code == 1 and out == ""
    assert err.count("\n") == 1 and f"{p}:3: " in err and "(and 1 more problem: pmctl check lists them)" in err


def test_run_on_a_real_machine_refuses_a_tool_change_or_a_pause_it_cannot_perform():
    from pmctl.interfaces.commands.run import _refuse_operator_waits
    job = Job((Move(RAPID, np.array([0.0, 0.0, 60.0]), UP, line=1),
               Move(EVENT, np.zeros(3), UP, line=2, events=(("spindle", 0.0), ("tool_change", 3))),
               Move(LINE, np.array([5.0, 0.0, 60.0]), UP, line=3, feed=10.0),
               Move(EVENT, np.zeros(3), UP, line=4, events=(("pause", "M1"),))), "t.ngc")
    _refuse_operator_waits(job, 3)                          # tool 3 is loaded, M1 not taken: nothing to do
    for tool in (None, 2):
        with pytest.raises(InputError) as e:
            _refuse_operator_waits(job, tool)
        assert e.value.line == 2 and "T3" in e.value.reason and "--tool 3" in e.value.reason
    m0 = Job(job.moves[:1] + (Move(EVENT, np.zeros(3), UP, line=5, events=(("pause", "M0"),)),), "t.ngc")
    with pytest.raises(InputError) as e:
        _refuse_operator_waits(m0, None)
    assert e.value.line == 5 and "M0" in e.value.reason and "pmctl serve" in e.value.reason


def test_run_on_the_sim_changes_tools_and_goes_on_after_m0_to_done(tmp_path):
    """The simulation's stand-in operator: a CAM-style program with T2 M6, G43 H2 and M0 (which a real
    machine's pmctl run refuses) runs to done on the sim, each wait answered and said."""
    p = tmp_path / "tc.ngc"
    p.write_text("G21 G90 G17\nT2 M6\nG43 H2\nG0 X5 Y0 Z60\nM0\nG1 X10 F600\nG49\nM30\n")
    code, out, err = cli("run", "--job", str(p), "--backend", "sim", "--no-realtime", "--state", "", "--quiet")
    assert code == 0, err
    assert "tool change: load tool 2: done by the simulation's operator" in out + err
    assert "program paused (M0): done by the simulation's operator" in out + err


# ---------------------------------------------------------------- pmctl post

def read_csv(path):
    with open(path) as f:
        r = csv.reader(f)
        head = next(r)
        rows = np.array([[float(x) for x in row] for row in r])
    return head, rows


def test_post_per_move_gives_the_programmed_poses_back_through_fk(tmp_path, machine):
    out = tmp_path / "cone.csv"
    code, msg, _ = cli("post", str(JOBS / "cone.ngc"), "--out", str(out), "--state", "")
    assert code == 0 and "25 rows" in msg
    head, rows = read_csv(out)
    assert head == ["line", "L1", "L2", "L3", "X", "Y"]
    job = load_job(JOBS / "cone.ngc", machine)
    moves = [m for m in job.moves if m.kind != EVENT]            # a row per programmed pose (S M3: an event)
    tips = np.array([m.tip for m in moves])
    assert np.array_equal(rows[:, 0], [m.line for m in moves])
    fk, ok = K.fk_batch(rows[:, 1:], machine)
    assert ok.all() and np.abs(fk.tip - tips).max() < 1e-9


def test_post_per_time_step_gives_the_planned_tips_back_through_fk(tmp_path, machine):
    out = tmp_path / "h.csv"
    code, msg, _ = cli("post", str(JOBS / "spiral.ngc"), "--out", str(out), "--dt", "0.02", "--state", "")
    assert code == 0
    head, rows = read_csv(out)
    assert head == ["t", "line", "L1", "L2", "L3", "X", "Y"]
    job = load_job(JOBS / "spiral.ngc", machine)
    traj = Trajectory.join(plan_stream(job, machine, DT))
    k = np.round(rows[:, 0] / DT).astype(int)
    assert np.array_equal(k[:-1], np.arange(0, len(traj) - 1, 20)[:len(k) - 1]) and k[-1] == len(traj) - 1
    fk, ok = K.fk_batch(rows[:, 2:], machine)
    assert ok.all() and np.abs(fk.tip - traj.tip[k]).max() < 1e-9
    assert np.array_equal(rows[:, 1], traj.line[k])
    assert cli("post", str(JOBS / "spiral.ngc"), "--out", str(out), "--dt", "0.0015", "--state", "")[0] == 1


def test_post_with_a_tool_offset_gives_the_joints_of_the_longer_tool(machine):
    import dataclasses
    d = 30.0
    p = np.array([[0.0, 0.0, 55.0], [10.0, 5.0, 50.0]])
    ax = np.array([[0.0, 0.0, 1.0], [np.sin(0.1), 0.0, np.cos(0.1)]])
    job = Job(tuple(Move(LINE, p[i], ax[i], line=i + 1, feed=5.0, tool_offset=d) for i in range(2)), "o.ngc")
    lines, q = post.per_move(job, machine)
    g = machine.geometry
    long = dataclasses.replace(machine, geometry=dataclasses.replace(g, tool_length=g.tool_length + d))
    assert np.abs(K.fk_batch(q, long)[0].tip - p).max() < 1e-9
