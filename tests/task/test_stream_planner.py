"""The streaming planner of a job that grows as blocks arrive (pmctl.task.stream_planner): fed block by
block as a sender streams a program, it hands out the samples ``plan`` gives for the whole program
(to rounding), and closed early it plans to rest exactly at the last block it has. Memory does not
grow with the stream."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pmctl.core.config import load_machine
from pmctl.core.errors import InputError
from pmctl.task.gcode import parse_gcode
from pmctl.task.job import load_job
from pmctl.task.planner import home_pose, plan
from pmctl.task.stream_planner import KEEP_BEHIND_MM, RUN_CUT_MM, StreamPlanner
from pmctl.motion.trajectory import Trajectory
from test_planner import long_programs

DT = 1e-3


@pytest.fixture(scope="module")
def machine():
    return load_machine()


def polygon(r=30.0, n=120, feed=600):
    """A polygon of ``n`` sides around a circle of radius ``r`` (1 mm sides at R 30, 0.1 s a block at
    F600), after a rapid down from the home pose."""
    lines = ["G21 G90 G17", f"G0 X{r:g} Y0 Z60", f"G1 F{feed}"]
    for k in range(1, n + 1):
        a = 2 * math.pi * k / n
        lines.append(f"G1 X{r * math.cos(a):.4f} Y{r * math.sin(a):.4f}")
    return "\n".join(lines) + "\n"


def streamed(job, machine, sizes, start=None, window=None, run_cut_mm=math.inf):
    """The job's moves fed to a StreamPlanner in chunks of ``sizes`` (cycled), the settled pieces taken
    after each, then closed: (joined Trajectory, blocks known beyond the last sample handed out after
    each chunk, the planner). A straight run of lines is not cut (``run_cut_mm``) unless asked."""
    sp = StreamPlanner(machine, DT, start=start or home_pose(machine), source=job.source, run_cut_mm=run_cut_mm,
                       **({"window": window} if window else {}))
    moves, pieces, ahead, i, k = list(job.moves), [], [], 0, 0
    while i < len(moves):
        n = sizes[k % len(sizes)]
        sp.extend(moves[i:i + n])
        pieces += list(sp.settled())
        i, k = i + n, k + 1
        ahead.append(sp.b.n + len(sp.pending) - sp.emitted)
    pieces += list(sp.close())
    return Trajectory.join(pieces), ahead, sp


def assert_same(a, b, tol_mm):
    assert len(a) == len(b)
    assert np.abs(a.tip - b.tip).max() <= tol_mm
    assert np.abs(a.axis - b.axis).max() <= tol_mm / 100
    assert np.array_equal(a.line, b.line) and a.marks == b.marks


@pytest.mark.parametrize("name,sizes", [("cone.ngc", [1, 2]), ("hemisphere.cl", [7, 3]), ("spiral.ngc", [9]),
                                        ("comb.ngc", [1])])
def test_a_program_fed_block_by_block_is_the_whole_program_planned(machine, name, sizes):
    job = load_job(f"examples/jobs/{name}", machine)
    whole = plan(job, machine, DT)
    got, _, _ = streamed(job, machine, sizes)
    assert_same(got, whole, 1e-9)


def test_the_polygon_settles_a_steady_look_ahead_and_is_the_whole_plan(machine):
    """1 mm blocks at F600: after the first window (a rapid before it: its reach), each block known
    settles the next; the samples are plan()'s."""
    job = parse_gcode(polygon(), "p.ngc", *home_pose(machine))
    got, ahead, _ = streamed(job, machine, [1])
    assert_same(got, plan(job, machine, DT), 1e-9)
    steady = ahead[40:]
    assert max(steady) <= 20, steady              # blocks waiting for their look-ahead (docs/console.md)
    assert max(ahead) <= 32                       # the first window too: within the console's queue


def test_closed_early_it_stops_at_the_last_block_and_what_it_handed_out_is_the_whole_plan(machine):
    job = parse_gcode(polygon(n=120), "p.ngc", *home_pose(machine))
    whole = plan(job, machine, DT)
    moves = list(job.moves)
    sp = StreamPlanner(machine, DT, start=home_pose(machine))
    out = []
    for m in moves[:70]:
        sp.extend([m])
        out += list(sp.settled())
    handed = sum(len(p) for p in out)
    assert handed > 0
    tail = Trajectory.join(list(sp.close()))
    got = Trajectory.join(out + [tail])
    # what was handed out before the close is the whole program's; the rest goes to rest at block 70
    assert np.abs(got.tip[:handed] - whole.tip[:handed]).max() <= 1e-9
    end = np.asarray(moves[69].tip, float)
    assert np.array_equal(got.tip[-1], end)                      # exactly the last block's point
    assert np.abs(got.tip - end).max() > 1.0                     # (it moved there)
    assert np.all(np.linalg.norm(got.tip_vel[-1], axis=-1) == 0.0)
    # never past it: the tip's distance along the polygon to the last block's point only shrinks near it
    d = np.linalg.norm(got.tip[handed:] - end, axis=1)
    assert np.all(np.diff(d[-200:]) <= 1e-12)
    # the blocks after it start a new stream from rest there
    sp2 = StreamPlanner(machine, DT, start=(got.tip[-1], got.axis[-1]))
    sp2.extend(moves[70:])
    rest = Trajectory.join(list(sp2.settled()) + list(sp2.close()))
    assert np.array_equal(rest.tip[0], end) and np.array_equal(rest.tip[-1], np.asarray(moves[-1].tip, float))


def square(feed, side, r=30.0):
    """A square of 2 r around the origin in lines of ``side`` mm at ``feed``, after a rapid to a corner."""
    n = int(round(2 * r / side))
    lines = ["G21 G90 G17", f"G0 X{-r:g} Y{-r:g} Z60", f"G1 F{feed:g}"]
    corners = [(-r, -r), (r, -r), (r, r), (-r, r), (-r, -r)]
    for (x0, y0), (x1, y1) in zip(corners, corners[1:]):
        lines += [f"G1 X{x0 + (x1 - x0) * k / n:.4f} Y{y0 + (y1 - y0) * k / n:.4f}" for k in range(1, n + 1)]
    return "\n".join(lines) + "\n"


def test_a_straight_run_of_short_lines_waits_at_most_run_cut_mm_and_keeps_its_speed(machine):
    """A straight run of 1 mm lines is merged into one line that the next line may continue: fed line
    by line it would wait for the side's end (60 blocks, more than the console's queue holds at the
    top feed beside the samples queued). Cut every RUN_CUT_MM, the blocks waiting stay few; the path
    is the square's (a knot at a programmed point), and the speed along a side is plan()'s: the
    feed, no dip at the knots; the duration within 0.2 % of plan()'s."""
    job = parse_gcode(square(3000, 1.0), "sq.ngc", *home_pose(machine))
    whole = plan(job, machine, DT)
    got, ahead, _ = streamed(job, machine, [1], run_cut_mm=RUN_CUT_MM)
    uncut, ahead_uncut, _ = streamed(job, machine, [1])
    assert max(ahead_uncut) >= 60 and max(ahead) <= 20, (max(ahead_uncut), max(ahead))
    assert_same(uncut, whole, 1e-9)
    assert abs(len(got) - len(whole)) <= 0.002 * len(whole), (len(got), len(whole))
    tip = got.tip
    on_side = np.minimum(np.abs(np.abs(tip[:, 0]) - 30.0), np.abs(np.abs(tip[:, 1]) - 30.0))
    moving = np.nonzero(got.line >= 4)[0]
    assert on_side[moving].max() <= 1e-9                       # on the square's sides
    v = np.linalg.norm(np.diff(tip, axis=0), axis=1) / DT
    mid = (np.abs(tip[1:, 0]) < 20.0) | (np.abs(tip[1:, 1]) < 20.0)    # 10 mm and more from a corner
    mid &= got.line[1:] >= 4
    assert v[mid].min() >= 0.99 * 50.0, v[mid].min()           # F3000: 50 mm/s, the knots at full speed
    assert np.array_equal(tip[-1], np.array([-30.0, -30.0, 60.0]))


def test_memory_does_not_grow_with_the_stream(machine):
    """Four turns of the 188-sided polygon at F1500, fed block by block and planned in whole windows of
    16 blocks: the segments held stay bounded (the path behind the windows is let go: at most twice
    KEEP_BEHIND_MM, 200 segments of 1 mm, and the windows ahead)."""
    text = polygon(n=188, feed=1500)
    turns = [ln for ln in text.splitlines() if ln.startswith("G1 X")]
    job = parse_gcode(text + "\n".join(turns * 3), "z.ngc", *home_pose(machine))
    sp = StreamPlanner(machine, DT, start=home_pose(machine), window=16)
    held = []
    for m in job.moves:
        sp.extend([m])
        for _ in sp.settled(eager=False):
            pass
        held.append(sp.b.n - sp.b.base)
    bound = 2 * KEEP_BEHIND_MM / 1.0 + 64
    assert sp.b.base > 300 and max(held) < bound, (sp.b.base, max(held))
    for _ in sp.close():
        pass


def test_a_block_whose_path_leaves_the_workspace_is_named(machine):
    sp = StreamPlanner(machine, DT, start=home_pose(machine), source="console")
    job = parse_gcode("G0 X0 Y0 Z60\nG1 F600 X10\nG1 X400\n", "c", *home_pose(machine))
    with pytest.raises(InputError) as e:
        sp.extend(list(job.moves))
        list(sp.close())
    assert e.value.line == 3


@settings(max_examples=12, deadline=None)
@given(long_programs(runs=True), st.lists(st.integers(1, 6), min_size=1, max_size=4))
def test_random_programs_fed_in_random_chunks_are_the_whole_plan(machine, text, sizes):
    job = parse_gcode(text, "r.ngc", *home_pose(machine))
    try:
        whole = plan(job, machine, DT)
    except InputError as e:
        if "batch planner holds at most" in str(e):
            return
        with pytest.raises(InputError) as e2:      # out of the workspace: refused, the same line named
            streamed(job, machine, sizes)
        assert e2.value.line == e.line
        return
    got, _, _ = streamed(job, machine, sizes)
    # as plan_stream's windows (tests/task/test_planner.py): up to a few 1e-8 mm where a knot is passed at a
    # near-zero speed; 1e-6 mm is 1/500 of a pulse
    assert_same(got, whole, 1e-6)
