"""The Move fields of the full RS-274 reader in the planner: arcs in any plane, G93 durations, the
tool length offset (which moves the chains as the kinematic model says)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.job import ARC, Job, LINE, Move, RAPID, controlled_point
from pmctl.task.planner import PlannerLimits, plan, plan_stream
from pmctl.motion.trajectory import Trajectory

DT = 1e-3
UP = np.array([0.0, 0.0, 1.0])


@pytest.fixture(scope="module")
def machine():
    return load_machine()


def longer_tool(machine, d):
    """The same machine with a tool d mm longer than its reference tool."""
    g = machine.geometry
    return dataclasses.replace(machine, geometry=dataclasses.replace(g, tool_length=g.tool_length + d))


def unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


# ---------------------------------------------------------------- arcs in any plane

def arc_job(start, center, normal, sweep, dh=0.0, feed=20.0):
    """G0 to ``start``, then an arc about the axis through ``center`` along ``normal``."""
    n = unit(normal)
    w = start - center
    h = float(w @ n)
    d = w - h * n
    e1 = d / np.linalg.norm(d)
    e2 = np.cross(n, e1)
    r = np.linalg.norm(d)
    end = center + (h + dh) * n + r * (math.cos(sweep) * e1 + math.sin(sweep) * e2)
    moves = (Move(RAPID, start, UP, line=1),
             Move(ARC, end, UP, line=2, feed=feed, center=center, normal=normal, sweep=sweep))
    return Job(moves, "arc.ngc", np.array([start, end])), end, (center, n, r, h)


@pytest.mark.parametrize("normal,sweep", [((0, 1, 0), 2.5), ((0, 1, 0), -1.2), ((1, 0, 0), 4.0),
                                          ((0.3, -0.4, 0.866), 1.7), ((0, 0, 1), -3.0)])
def test_arcs_in_any_plane_stay_on_their_circle(machine, normal, sweep):
    center = np.array([5.0, -3.0, 60.0])
    n = unit(normal)
    start = center + 8.0 * unit(np.cross(n, [0.2, 0.9, 0.1]))        # a point of the circle of radius 8
    job, end, (c, n, r, h) = arc_job(start, center, normal, sweep)
    traj = plan(job, machine, DT)
    on = traj.line == 2
    w = traj.tip[on] - c
    hh = w @ n
    rr = np.linalg.norm(w - hh[:, None] * n, axis=1)
    assert np.abs(hh - h).max() < 1e-9 and np.abs(rr - r).max() < 1e-9        # in the plane, on the circle
    assert np.array_equal(traj.tip[-1], end)
    # the sense: counter-clockwise about the normal for a positive sweep (angular momentum along n)
    mom = np.cross(w[:-1], np.diff(traj.tip[on], axis=0)) @ n
    assert np.all(mom[np.abs(mom) > 1e-12] * sweep > 0)
    # the swept angle is the sweep, monotonically, from the start
    e1 = (start - c - h * n) / r
    dd = w - hh[:, None] * n
    ang = np.unwrap(np.arctan2(dd @ np.cross(n, e1), dd @ e1))
    assert ang[-1] == pytest.approx(sweep, abs=1e-9) and np.all(np.diff(ang) * sweep >= -1e-12)
    whole = Trajectory.join(plan_stream(job, machine, DT, window=1))
    assert np.abs(whole.tip - traj.tip).max() < 1e-9


def test_an_xy_arc_with_a_2d_centre_is_the_3d_one(machine):
    start = np.array([10.0, 0.0, 60.0])
    end = np.array([0.0, 10.0, 62.0])                    # a quarter turn, helical
    moves = lambda c: (Move(RAPID, start, UP, line=1),  # noqa: E731
                       Move(ARC, end, UP, line=2, feed=10.0, center=c, sweep=math.pi / 2))
    a = plan(Job(moves(np.array([0.0, 0.0])), "a.ngc"), machine, DT)
    b = plan(Job(moves(np.array([0.0, 0.0, 60.0])), "a.ngc"), machine, DT)
    c = plan(Job(moves(np.array([0.0, 0.0, -5.0])), "a.ngc"), machine, DT)
    assert len(a) == len(b) == len(c)
    assert np.abs(a.tip - b.tip).max() < 1e-12 and np.abs(a.tip - c.tip).max() < 1e-9
    on = a.line == 2
    assert np.abs(np.hypot(a.tip[on, 0], a.tip[on, 1]) - 10.0).max() < 1e-9
    # the height goes linearly with the angle (a helix)
    ang = np.unwrap(np.arctan2(a.tip[on, 1], a.tip[on, 0]))
    assert np.abs(a.tip[on, 2] - (60.0 + 2.0 * ang / (math.pi / 2))).max() < 1e-9


# ---------------------------------------------------------------- G93 inverse-time feed

@pytest.mark.parametrize("duration,length", [(4.0, 40.0), (10.0, 5.0), (0.05, 20.0)])
def test_a_g93_move_takes_its_duration_within_the_limits(machine, duration, length):
    start = np.array([-10.0, 0.0, 60.0])
    end = start + [length, 0.0, 0.0]
    job = Job((Move(RAPID, start, UP, line=1), Move(LINE, end, UP, line=2, duration=duration)), "g93.ngc")
    traj = plan(job, machine, DT)
    on = np.nonzero(traj.line == 2)[0]
    v = np.linalg.norm(np.diff(traj.tip[on[0] - 1:on[-1] + 1], axis=0), axis=1) / DT
    top = min(length / duration, PlannerLimits().rapid_mm_s)          # capped by the rapid speed
    assert v.max() <= top * (1 + 1e-6)
    assert v.max() >= 0.98 * top
    # the move itself, plus what the speed changes at its ends add (each takes at least a grid interval
    # of the limit grid at these low speeds, and the S-curve's filter time)
    t_move = len(on) * DT
    lim = PlannerLimits()
    assert length / top <= t_move <= (length + 4 * lim.grid_mm) / top + top / lim.tangential_accel + 0.3
    # the feed override scales it like a feed
    fast = plan(job, machine, DT, feed_override=2.0)
    vf = np.linalg.norm(np.diff(fast.tip[fast.line == 2], axis=0), axis=1).max() / DT
    assert vf == pytest.approx(min(2 * length / duration, PlannerLimits().rapid_mm_s), rel=0.02)


# ---------------------------------------------------------------- the tool length

@settings(max_examples=40, deadline=None)
@given(st.floats(-40, 40), st.floats(-40, 40), st.floats(30, 80), st.floats(-15, 15), st.floats(-15, 15),
       st.floats(-30, 60))
def test_a_longer_tool_is_the_reference_tool_further_up_its_axis(x, y, z, a_deg, b_deg, d):
    """IK of a tip with a tool longer by d (the model with tool_length + d) equals IK of the point d
    further up the tool axis with the reference tool; FK gives both points back to 1e-9 mm."""
    machine = load_machine()
    tip = np.array([x, y, z])
    axis = K.axis_from_roll_pitch(math.radians(a_deg), math.radians(b_deg))
    long = longer_tool(machine, d)
    r_long = K.ik_batch(tip, axis, long)
    r_ref = K.ik_batch(controlled_point(tip, axis, d), axis, machine)
    assert np.abs(r_long.q - r_ref.q).max() < 1e-9
    if abs(d) > 1e-3:                       # a longer tool sits higher: every chain differs
        assert np.abs(r_long.q[:3] - K.ik_batch(tip, axis, machine).q[:3]).min() > 0
    if not r_ref.ok:
        return
    assert np.abs(K.fk(r_ref.q, long).tip - tip).max() < 1e-9
    assert np.abs(K.fk(r_ref.q, machine).tip - controlled_point(tip, axis, d)).max() < 1e-9


def tilted_job(offset, line_at=3):
    """A 5-axis line whose tool axis tilts by 8 degrees while the tip goes straight, with a tool length
    offset in force."""
    a0 = unit([0.0, 0.0, 1.0])
    a1 = unit([math.sin(math.radians(8)), 0.0, math.cos(math.radians(8))])
    p0, p1 = np.array([-15.0, 5.0, 55.0]), np.array([15.0, -5.0, 50.0])
    moves = (Move(RAPID, p0, a0, line=1, tool_offset=offset),
             Move(LINE, p1, a1, line=line_at, feed=15.0, tool_offset=offset))
    return Job(moves, "tilt.ngc", np.array([p0, p1])), (p0, p1, a0, a1)


@pytest.mark.parametrize("d", [25.0, -10.0])
def test_a_tool_offset_moves_the_planned_chains_as_the_model_says(machine, d):
    job, (p0, p1, a0, a1) = tilted_job(d)
    traj = plan(job, machine, DT)
    ref, _ = tilted_job(0.0)
    t0 = plan(ref, machine, DT)
    long = longer_tool(machine, d)
    # the samples are of the reference tool's tip (the controlled point); the cutting tip, that point
    # less d along the axis, runs on the programmed straight line while the axis tilts
    cut = traj.tip - d * traj.axis
    on = traj.line == 3
    u = (cut[on] - p0) @ (p1 - p0) / ((p1 - p0) @ (p1 - p0))
    off_line = cut[on] - (p0 + u[:, None] * (p1 - p0))
    assert np.abs(off_line).max() < 1e-9
    # the programmed end: the controlled point exactly, and the joints IK of the tip with the longer tool
    assert np.array_equal(traj.tip[-1], controlled_point(p1, a1, d))
    q_end = K.ik_batch(traj.tip[-1], traj.axis[-1], machine).q
    assert np.abs(q_end - K.ik_batch(p1, a1, long).q).max() < 1e-9
    # every planned sample: FK with the longer tool of the planned joints is the cutting tip
    q = K.ik_batch(traj.tip, traj.axis, machine).q
    assert np.abs(K.fk_batch(q, long)[0].tip - cut).max() < 1e-9
    # and the chains differ from the reference tool's plan at the same programmed points by what the
    # longer tool needs: about d cos(tilt) on every chain
    q0_end = K.ik_batch(t0.tip[-1], t0.axis[-1], machine).q
    dq = q_end[:3] - q0_end[:3]
    assert np.all(np.sign(dq) == np.sign(d)) and np.abs(dq).min() > 0.8 * abs(d)
    # the same from the streaming planner
    joined = Trajectory.join(plan_stream(job, machine, DT, window=1))
    assert np.abs(joined.tip - traj.tip).max() < 1e-9


def test_a_change_of_tool_offset_is_taken_up_by_the_next_move(machine):
    p = np.array([0.0, 0.0, 60.0])
    moves = (Move(RAPID, p, UP, line=1),
             Move(RAPID, p, UP, line=2, tool_offset=12.0),         # G43: the same tip, a longer tool
             Move(LINE, p + [10.0, 0, 0], UP, line=3, feed=10.0, tool_offset=12.0))
    traj = plan(Job(moves, "g43.ngc"), machine, DT)
    on2 = traj.line == 2
    # the machine rises by 12 mm with the tip programmed in place: the controlled point goes up
    assert traj.tip[on2][-1] == pytest.approx(p + [0, 0, 12.0], abs=1e-12)
    assert np.abs(traj.tip[on2][:, :2]).max() < 1e-12
    assert np.array_equal(traj.tip[-1], p + [10.0, 0.0, 12.0])
