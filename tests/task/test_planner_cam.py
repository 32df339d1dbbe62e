"""The planner on CAM output: runs of micro-segments merged within the path tolerance (LinuxCNC's
naive-CAM detector) and passed through without a tick each; the fallback where re-planning does not
meet the limits; the whole job planned before anything moves."""

from __future__ import annotations

import contextlib
import io
import json
import math
import runpy
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import pmctl.task.planner as P
from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.interfaces.cli import main
from pmctl.task.gcode import parse_gcode
from pmctl.core.job import Job, LINE, Move
from pmctl.task.planner import PlannerLimits, PlanningError, home_pose, plan, plan_stream, validate
from pmctl.motion.trajectory import Trajectory

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
DT = 1e-3
UP = np.array([0.0, 0.0, 1.0])


@pytest.fixture(scope="module")
def machine():
    return load_machine()


def micro_program(n=3000, step_mm=(0.0002, 0.001), decimals=4, feed=1500, seed=0, extra=""):
    """A quarter of a circle of R 4 mm in Z-varying micro-steps, coordinates rounded as a post writes them."""
    rng = np.random.default_rng(seed)
    s = np.cumsum(rng.uniform(*step_mm, n))
    th = s / 4.0
    x, y, z = 4.0 * np.cos(th) - 4.0, 4.0 * np.sin(th), 60.0 - 0.2 * np.sin(3 * th)
    f = f"{{:.{decimals}f}}".format
    lines = ["G21 G90" + extra, "G0 X0 Y0 Z62", f"G1 Z{f(z[0])} F{feed}"]
    lines += [f"X{f(a)}Y{f(b)}Z{f(c)}" for a, b, c in zip(x, y, z)]
    lines.append("G0 Z65")
    return "\n".join(lines) + "\n", np.round(np.array([x, y, z]).T, decimals)


def dist_to_polyline(points, poly):
    """Distance of each point to the polyline through ``poly`` (to every segment of a short one; to
    the two segments at the nearest vertex of a dense one)."""
    if len(poly) < 50:
        a, d = poly[:-1], np.diff(poly, axis=0)
        w = points[:, None, :] - a[None]
        t = np.clip(np.einsum("nmk,mk->nm", w, d) / np.maximum(np.einsum("mk,mk->m", d, d), 1e-300), 0, 1)
        return np.linalg.norm(w - t[..., None] * d[None], axis=2).min(axis=1)
    from scipy.spatial import cKDTree
    _, k = cKDTree(poly).query(points)
    best = np.full(len(points), np.inf)
    for j0 in (k - 1, k):                            # the two segments at the nearest vertex
        j0 = np.clip(j0, 0, len(poly) - 2)
        a, d = poly[j0], poly[j0 + 1] - poly[j0]
        t = np.clip(np.einsum("ij,ij->i", points - a, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300), 0, 1)
        best = np.minimum(best, np.linalg.norm(points - a - t[:, None] * d, axis=1))
    return best


def check_limits(traj, machine):
    jl = machine.limits
    q = K.ik_batch(traj.tip, traj.axis, machine).q
    tol = 1 + P.VIOLATION_TOL
    assert np.all(np.abs(np.diff(q, axis=0)) / DT <= jl.joint_speed * tol)
    assert np.all(np.abs(np.diff(q, 2, axis=0)) / DT**2 <= jl.joint_accel * tol)
    a = np.linalg.norm(np.diff(traj.tip, 2, axis=0), axis=1) / DT**2
    assert a.max() <= PlannerLimits().accel_mm_s2 * tol


# ---------------------------------------------------------------- the merge's core: lines from kept point to kept point

@st.composite
def noisy_polylines(draw):
    n = draw(st.integers(3, 300))
    rng = np.random.default_rng(draw(st.integers(0, 2**31)))
    kind = draw(st.sampled_from(["curve", "zigzag", "back"]))
    t = np.cumsum(rng.uniform(1e-4, 2e-3, n))
    if kind == "curve":
        pts = np.array([np.cos(t * 3), np.sin(t * 3), 0.1 * t]).T * draw(st.floats(0.5, 20))
    elif kind == "zigzag":
        pts = np.array([t, 1e-3 * (np.arange(n) % 2), 0 * t]).T
    else:                                        # along a line, forth and back
        pts = np.array([np.abs(np.sin(t * 40)), 0 * t, 0 * t]).T
    pts = pts + rng.normal(0, draw(st.sampled_from([0.0, 1e-5, 1e-4])), pts.shape)
    return pts, draw(st.sampled_from([1e-4, 5e-4, 1e-3, 1e-2]))


@settings(max_examples=60, deadline=None)
@given(noisy_polylines())
def test_every_dropped_point_is_within_the_tolerance_of_its_chord(data):
    pts, tol = data
    keep, last = P._simplify(pts, tol, 0.0)
    assert keep[0] and keep[-1] and keep[last]
    # each decision depends only on the points up to the one after it: the run cut anywhere (a job
    # whose blocks are still arriving) keeps the same points up to its last one kept
    cut = len(pts) // 2 + 1
    part, anchor = P._simplify(pts[:cut], tol, 0.0, open_end=True)
    assert np.array_equal(part[:anchor + 1], keep[:anchor + 1])
    k = np.nonzero(keep)[0]
    for a, b in zip(k[:-1], k[1:]):
        p, d = pts[a], pts[b] - pts[a]
        w = pts[a + 1:b] - p
        dd = d @ d
        t = np.clip(w @ d / dd, 0, 1) if dd > 0 else np.zeros(len(w))
        assert np.all(np.linalg.norm(w - t[:, None] * d, axis=1) <= tol * (1 + 1e-12))
        if dd > 0 and len(w):                   # and they go along it: no turn back by more than tol
            along = w @ d / math.sqrt(dd)
            assert np.all(np.maximum.accumulate(along) - along <= tol * (1 + 1e-12))


def test_a_run_that_turns_back_on_its_line_is_not_merged(machine):
    start = home_pose(machine)
    text = "G0 X-5 Y0 Z60\nF600\n" + "\n".join(f"G1 X{5 if i % 2 == 0 else -5}" for i in range(6))
    job = parse_gcode(text, "p.ngc", *start)
    traj = plan(job, machine, DT)
    # every reversal is a stop exactly on its point: the X samples turn six times
    xv = np.sign(np.round(np.diff(traj.tip[:, 0]), 12))
    turns = np.count_nonzero(np.diff(xv[xv != 0]) != 0)
    assert turns == 6
    assert traj.tip[:, 0].min() == -5.0 and traj.tip[:, 0].max() == 5.0


# ---------------------------------------------------------------- micro-segments

@pytest.mark.parametrize("decimals,extra,tol", [(4, "", 0.0005), (3, "", 0.001), (4, " G64 P0.01", 0.01)])
def test_micro_segments_plan_within_the_tolerance_and_the_limits(machine, decimals, extra, tol):
    """3000 steps of 0.2-1 um: planned (it faulted after 10 re-planning iterations), merged within
    the tolerance (the default: one pulse, or the resolution the coordinates are written at), every
    limit met, the same from the streaming planner, and the samples' lines go through the program."""
    text, pts = micro_program(decimals=decimals, extra=extra)
    job = parse_gcode(text, "m.ngc", *home_pose(machine))
    if extra:                                # until the RS-274 reader sets it: G64 P0.01 by hand
        job = Job(tuple(Move(m.kind, m.tip, m.axis, m.line, m.feed, m.spindle_rpm, m.center, m.sweep, m.dwell,
                             m.probe, tolerance=0.01 if m.kind == LINE else 0.0) for m in job.moves),
                  job.source, job.points)
    path = validate(job, machine, DT, full=True)
    assert path.n < 300 and len(path.mrg_seg) > 2700          # 3000 lines became a few hundred or fewer
    if not extra:       # every dropped point within the tolerance of the line that replaced it
        seg = path.mrg_seg
        by_line = {m.line: m.tip for m in job.moves}
        q = np.array([by_line[ln] for ln in path.mrg_line])
        d = path.p1[seg] - path.p0[seg]
        w = q - path.p0[seg]
        t = np.clip(np.einsum("ij,ij->i", w, d) / np.einsum("ij,ij->i", d, d), 0, 1)
        assert np.linalg.norm(w - t[:, None] * d, axis=1).max() <= tol * (1 + 1e-9)
    traj = plan(job, machine, DT)
    check_limits(traj, machine)
    assert traj.duration < 20.0
    # every programmed point within the tolerance of the path as planned (G64 P: merged within P, and
    # the corners left rounded within P: 2 P at most, as LinuxCNC's P and Q)
    assert dist_to_polyline(pts, traj.tip).max() <= (2 * tol if extra else tol) + 1e-6
    lines = traj.line[traj.line >= 4]
    assert np.all(np.diff(lines) >= 0) and len(np.unique(lines)) > 100      # the line goes through the program
    joined = Trajectory.join(plan_stream(job, machine, DT, path=path, window=16))
    assert len(joined) == len(traj) and np.abs(joined.tip - traj.tip).max() < 1e-6


def test_micro_segments_without_merging_are_passed_through_not_sampled(machine, monkeypatch):
    """With merging off (a tolerance of 1e-9 mm) the points of a micro-segment run are knots only
    every two ticks of top speed; the rest are passed through on the path: it still plans, every limit
    met, every sample on the programmed polyline."""
    text, pts = micro_program(n=800, decimals=6)
    job = parse_gcode(text, "m.ngc", *home_pose(machine))
    lim = PlannerLimits(naive_cam_mm=1e-9)
    monkeypatch.setattr(P, "MAX_QUANTUM_MM", 0.0)
    path = validate(job, machine, DT, limits=lim, full=True)
    traj = plan(job, machine, DT, limits=lim)
    assert path.n > 790 and len(path.pin_idx) < path.n / 5
    check_limits(traj, machine)
    # the samples of the run lie on the polyline: each within 1e-9 mm of one of its segments
    on = (traj.line > 3) & (traj.line < 3 + len(pts))
    poly = np.vstack([[0.0, 0.0, pts[0, 2]], pts])      # from the plunge's end
    assert dist_to_polyline(traj.tip[on], poly).max() < 1e-9


# ---------------------------------------------------------------- the fallback

def reversal_job(machine):
    text = ("G0 X0 Y1 Z50\nF600\nG1 X0 Y0 Z50\nG3 X5.103461 Y-13.624282 I-0.565898 J-7.979960\n"
            "G1 X1 Y0\nG1 X0 Y0\n")
    return parse_gcode(text, "f.ngc", *home_pose(machine))


def test_where_re_planning_fails_the_fallback_stops_and_slows_and_the_stream_follows(machine):
    job = reversal_job(machine)
    lim = PlannerLimits(max_iterations=1)            # re-planning gives up at once: the fallback does the work
    path = validate(job, machine, DT, limits=lim, full=True)
    assert path.fallbacks >= 1 and path.stop.all()
    pieces = list(plan_stream(job, machine, DT, limits=lim, path=path))
    traj = Trajectory.join(pieces)
    assert len(traj) == path.planned_samples
    check_limits(traj, machine)
    whole = plan(job, machine, DT, limits=lim)        # the batch planner falls back the same way
    assert len(whole) == len(traj) and np.abs(whole.tip - traj.tip).max() < 1e-6


def test_a_job_the_fallback_cannot_plan_is_refused_with_its_line(machine, monkeypatch):
    job = reversal_job(machine)
    orig = P._violations

    def never(q, tip, v, s, seg, path, *a):          # a limit no speed meets on the arc (line 4)
        w = orig(q, tip, v, s, seg, path, *a)
        on = path.line[seg] == 4
        if not np.any(on):
            return w
        return s[on], np.full(on.sum(), 0.97), np.abs(v[on])
    monkeypatch.setattr(P, "_violations", never)
    monkeypatch.setattr(P, "MAX_FALLBACKS", 2)          # (each round halves the speed: keep it short)
    with pytest.raises(PlanningError) as e:
        validate(job, machine, DT, full=True)
    assert e.value.line == 4 and e.value.path == "f.ngc" and "fallback" in str(e.value)
    assert "1/4 of the feed" in str(e.value)
    with pytest.raises(PlanningError) as e:            # unchecked, the stream names the line too
        list(plan_stream(job, machine, DT))
    assert e.value.line == 4


# ---------------------------------------------------------------- a V-carve program, generated

def test_the_generated_v_carve_program_checks_and_runs_to_done(tmp_path):
    """benchmarks/make_microsegments.py's V-carve program (steps of 1 um down to 1 micro-inch), a small
    one: pmctl check plans it, pmctl run machines it to done on the simulation."""
    mm = runpy.run_path(str(ROOT / "benchmarks" / "make_microsegments.py"))
    text, st = mm["program"](3, 120_000)
    assert st["steps"] > 2000 and st["step_um"][2] <= 1.0 + 2e-3
    out = tmp_path / "v.ngc"
    out.write_text(text)
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["check", str(out), "--json", "--state", ""])
    rep = json.loads(buf.getvalue())
    assert code == 0 and rep["ok"] and rep["problems"] == []
    assert rep["summary"]["moves"] > 2000 and rep["summary"]["planner"]["merged_moves"] > 1500
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["run", "--job", str(out), "--backend", "sim", "--no-realtime", "--state", "", "--quiet"])
    report = buf.getvalue()
    assert code == 0 and "result: done" in report, report
    # the job, the plant settling after it, and the hold at the M5 before M30 (an event: the path
    # waits there until the spindle stands, about 1 s of ramp-down on the simulated VFD)
    ticks = int(report.split("ticks ")[1].split()[0])
    assert 0 <= ticks * DT - rep["summary"]["machining_time_s"] < 2.5


# ---------------------------------------------------------------- corners rounded within G64 P

def with_tolerance(job, tol):
    """``job`` with G64 P``tol`` on its feed lines (until the RS-274 reader sets Move.tolerance)."""
    return Job(tuple(Move(m.kind, m.tip, m.axis, m.line, m.feed, m.spindle_rpm, m.center, m.sweep, m.dwell,
                          m.probe, tolerance=tol if m.kind == LINE else 0.0) for m in job.moves), job.source, job.points)


def test_g64_p_rounds_corners_within_its_tolerance(machine):
    text = "G0 X0 Y0 Z60\nF1500\nG1 X10\nG1 Y10\nG1 X0 Y10.5\nG1 X10 Y10.6\nG1 X20 Y20\n"
    exact = parse_gcode(text, "s.ngc", *home_pose(machine))
    job = with_tolerance(exact, 0.05)
    a, b = plan(exact, machine, DT), plan(job, machine, DT)
    check_limits(b, machine)
    corners = np.array([[10, 0, 60], [10, 10, 60], [0, 10.5, 60], [10, 10.6, 60]], float)
    poly = np.vstack([[0.0, 0.0, 60.0], corners, [20, 20, 60]])
    on = b.line >= 3
    assert dist_to_polyline(b.tip[on], poly).max() <= 0.05 + 1e-9      # within P of the program
    near = [np.linalg.norm(b.tip - c, axis=1).min() for c in corners]
    assert all(0.0499 < near[k] < 0.051 for k in (0, 1, 3)), near      # corners rounded, by P (+ sampling)
    assert near[2] == 0.0                                     # nearly a reversal (> 170 deg): exact
    assert b.duration < a.duration
    joined = Trajectory.join(plan_stream(job, machine, DT, window=1))
    assert len(joined) == len(b) and np.abs(joined.tip - b.tip).max() < 1e-9


def test_g64_p_lets_a_polygon_run_at_its_feed(machine):
    th = np.linspace(0, 2 * np.pi, 201)
    text = "G0 X5 Y0 Z60\nF1500\n" + "\n".join(f"G1 X{5 * np.cos(t):.4f} Y{5 * np.sin(t):.4f}" for t in th[1:])
    exact = parse_gcode(text, "c.ngc", *home_pose(machine))
    a, b = plan(exact, machine, DT), plan(with_tolerance(exact, 0.001), machine, DT)
    check_limits(b, machine)
    va = np.median(np.linalg.norm(a.tip_vel[a.line > 3], axis=1))
    vb = np.median(np.linalg.norm(b.tip_vel[b.line > 3], axis=1))
    assert vb > 0.95 * 25.0 > 1.5 * va                      # the feed (25 mm/s), not the corners' crawl
    pts = np.array([m.tip for m in exact.moves[1:]])
    assert dist_to_polyline(b.tip[b.line > 3], np.vstack([[5.0, 0, 60], pts])).max() <= 0.001 + 1e-9
