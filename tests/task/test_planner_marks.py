"""EVENT moves in the planner: an exact stop at that point, and a mark (sample, line, events) on the
stop's sample, in program order, the same from the batch and the streaming planner."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pmctl.core.config import load_machine
from pmctl.task.gcode import parse_gcode
from pmctl.core.job import DWELL, EVENT, Job, Move
from pmctl.task.planner import home_pose, plan, plan_stream
from pmctl.motion.trajectory import Trajectory

DT = 1e-3
UP = np.array([0.0, 0.0, 1.0])


@pytest.fixture(scope="module")
def machine():
    return load_machine()


def event(line, *events):
    return Move(EVENT, np.zeros(3), UP, line=line, events=tuple(events))


def with_events(job, at):
    """``job`` with an EVENT inserted before move index i for each (i, line, events) of ``at``."""
    moves = list(job.moves)
    for i, line, ev in sorted(at, key=lambda x: -x[0]):
        moves.insert(i, event(line, *ev))
    return Job(tuple(moves), job.source, job.points)


def programmed_pose_of_events(job, start):
    """Where the path is (tip, axis) when each EVENT is reached: the end of the last move before it."""
    tip, axis = start
    out = []
    for m in job.moves:
        if m.kind == EVENT:
            out.append((tip, axis))
        elif m.kind != DWELL:
            tip, axis = np.asarray(m.tip, float), np.asarray(m.axis, float) / np.linalg.norm(m.axis)
    return out


def assert_marks_at_rest_on_their_points(traj, job, start):
    evs = [m for m in job.moves if m.kind == EVENT]
    assert [ln for _, ln, _ in traj.marks] == [m.line for m in evs]          # one each, in program order
    assert [e for _, _, e in traj.marks] == [m.events for m in evs]
    idx = [i for i, _, _ in traj.marks]
    assert idx == sorted(idx)
    for (i, _, _), (tip, axis) in zip(traj.marks, programmed_pose_of_events(job, start)):
        assert np.array_equal(traj.tip[i], tip), (traj.tip[i], tip)        # the programmed point, bit for bit
        assert np.allclose(traj.axis[i], axis, atol=1e-15)
        assert not np.any(traj.tip_vel[i]) and not np.any(traj.axis_vel[i])
        # at rest: the neighbouring samples are within the jerk-limited creep of a stop (~j dt^3)
        for j in (i - 1, i + 1):
            if 0 <= j < len(traj):
                assert np.linalg.norm(traj.tip[j] - traj.tip[i]) < 1e-5


def test_events_stop_the_path_and_mark_the_stop(machine):
    start = home_pose(machine)
    g = parse_gcode("G0 X10 Y0 Z60\nF1200\nG1 X20\nG1 X30\nG1 Y5\nG4 P0.25\nG1 X0\nG1 Y10\n", "p.ngc", *start)
    # before the first move, between two feed lines (no stop there otherwise), before and after a
    # dwell at the same point, and at the end
    job = with_events(g, [(0, 90, [("message", "start")]), (2, 91, [("spindle", 6000.0)]),
                          (4, 92, [("coolant", "flood")]), (4, 93, [("coolant", "mist"), ("output", ("d", 1, 1))]),
                          (5, 94, [("coolant", "off")]), (7, 95, [("spindle", 0.0)])])
    traj = plan(job, machine, DT)
    assert_marks_at_rest_on_their_points(traj, job, start)
    i93, i94 = traj.marks[3][0], traj.marks[4][0]
    assert i94 - i93 == 250                      # the dwell lies between the marks around it
    assert np.all(traj.line[i93 + 1:i94] == 6)
    # without the events the path does not stop at X20 (a straight run): the event made that stop
    plain = plan(g, machine, DT)
    speed = np.linalg.norm(plain.tip_vel, axis=1)
    k = int(np.argmin(np.linalg.norm(plain.tip - [20.0, 0.0, 60.0], axis=1)))
    assert speed[k] > 10.0
    assert traj.duration > plain.duration


@pytest.mark.parametrize("window", [1, 2, 64])
def test_marks_are_the_same_from_the_streaming_planner(machine, monkeypatch, window):
    import pmctl.task.planner as P
    monkeypatch.setattr(P, "SAMPLE_CHUNK", 700)          # several pieces in a window, too
    monkeypatch.setattr(P, "STREAM_KEEP", 1000)
    start = home_pose(machine)
    lines = ["G0 X-20 Y0 Z60", "F2400"] + [f"G1 X{(-1) ** i * 20} Y{i * 1.5}" for i in range(12)]
    g = parse_gcode("\n".join(lines), "p.ngc", *start)
    job = with_events(g, [(i, 100 + i, [("user_m", (100 + i, 1.0, 0.0))]) for i in range(1, 14, 3)]
                      + [(14, 200, [("pause", "M0")])])
    whole = plan(job, machine, DT)
    pieces = list(plan_stream(job, machine, DT, window=window))
    assert max(len(p) for p in pieces) <= 700
    joined = Trajectory.join(pieces)
    assert joined.marks == whole.marks
    assert np.abs(joined.tip - whole.tip).max() < 1e-9
    for p in pieces:                     # each piece's marks index its own samples
        for i, _, _ in p.marks:
            assert 0 <= i < len(p) and not np.any(p.tip_vel[i])
    assert_marks_at_rest_on_their_points(joined, job, start)


def test_a_job_of_only_events_is_one_sample_at_the_start(machine):
    start = home_pose(machine)
    job = Job((event(1, ("spindle", 0.0)),), "console")
    for traj in (plan(job, machine, DT), Trajectory.join(plan_stream(job, machine, DT))):
        assert len(traj) == 1 and traj.marks == ((0, 1, (("spindle", 0.0),)),)
        assert np.array_equal(traj.tip[0], start[0])
    # with a dwell between two events: the second mark after the dwell
    job = Job((event(1, ("spindle", 3000.0)), Move(DWELL, np.zeros(3), UP, line=2, dwell=0.5),
               event(3, ("spindle", 0.0))), "console")
    a, b = plan(job, machine, DT), Trajectory.join(plan_stream(job, machine, DT))
    assert a.marks == b.marks == ((0, 1, (("spindle", 3000.0),)), (500, 3, (("spindle", 0.0),)))


@st.composite
def programs_with_events(draw):
    f = "{:.4f}".format
    lines = [f"G0 X{f(draw(st.floats(-20, 20)))} Y{f(draw(st.floats(-20, 20)))} Z60", "F1800"]
    for _ in range(draw(st.integers(2, 8))):
        kind = draw(st.sampled_from(["G1", "G1", "G0", "G4"]))
        if kind == "G4":
            lines.append(f"G4 P{draw(st.floats(0.001, 0.05)):.3f}")
        else:
            lines.append(f"{kind} X{f(draw(st.floats(-25, 25)))} Y{f(draw(st.floats(-25, 25)))} "
                         f"Z{f(draw(st.floats(50, 70)))} A{f(draw(st.floats(-5, 5)))}")
    n = len(lines)
    at = draw(st.lists(st.integers(0, n), min_size=1, max_size=5))
    return "\n".join(lines), [(i, 1000 + k, [("message", f"e{k}")]) for k, i in enumerate(at)], \
        draw(st.sampled_from([1, 2, 3]))


@settings(max_examples=10, deadline=None)
@given(programs_with_events())
def test_random_programs_with_events(machine, prog):
    text, at, window = prog
    start = home_pose(machine)
    g = parse_gcode(text, "p.ngc", *start)
    at = [(min(i, len(g.moves)), ln, ev) for i, ln, ev in at]
    # same-place events keep their program order: insert from the back, stable among equals
    job = with_events(g, [(i, ln, ev) for i, ln, ev in at])
    whole = plan(job, machine, DT)
    assert_marks_at_rest_on_their_points(whole, job, start)
    joined = Trajectory.join(plan_stream(job, machine, DT, window=window))
    assert joined.marks == whole.marks
