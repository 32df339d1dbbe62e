"""The planner's last check on the samples pinned at its edges (pmctl.task.planner: ``_violations``,
``_check_samples``, ``_check_reachable``; the mutation group ``planner`` of
tools/mutation/run_mutmut.py):

- joint speed and acceleration and the tool tip's speed and acceleration measured on the samples by
  finite differences: a limit exceeded by twice the check's tolerance (VIOLATION_TOL, relative) is
  refused at exactly the offending samples, with the factor that brings each one 3 % under it; one
  exceeded by half the tolerance, or met, is accepted. The tip's speed of a pure reorientation move
  is not judged against its feed (which is the rotation's);
- reachability: an unreachable programmed pose and a path that leaves the workspace between two
  reachable ones are refused naming their line and the limit, or, for ``pmctl check``, listed once
  per line with what to do.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.errors import InputError
from pmctl.core.job import home_pose
from pmctl.task import planner as P
from pmctl.task.gcode import parse_gcode

M = load_machine()
DT = 1e-3
TOL = P.VIOLATION_TOL
TIP, AXIS = (np.asarray(x, float) for x in home_pose(M))
# joint limits 100 mm/s and 2000 mm/s^2 (every joint); the tip's: its feed, and accel_mm_s2
LIMITS = P.PlannerLimits(rapid_mm_s=200.0, accel_mm_s2=3000.0)
SLOW_TIP = P.PlannerLimits(rapid_mm_s=200.0, accel_mm_s2=1000.0)


def _path(text, limits):
    """The segments of a real job from the home pose: line 2 X-60 at F9000 (150 mm/s), line 3 a pure
    tilt at F600, line 4 X0 at F600 (10 mm/s), line 5 X-30 at F30 (0.5 mm/s)."""
    job = parse_gcode(text, "t.ngc", TIP, AXIS)
    return job, P._Path(job, (TIP, AXIS), limits, 1.0, DT)


JOB = "G21 G90\nG1 X-60 F9000\nG1 A5 F600\nG1 X0 F600\nG1 X-30 F30\n"


def _samples(x, direction, seg):
    """Samples of the tip at positions ``x`` (mm) along ``direction`` from the home tip, the tool
    vertical, all in segment ``seg``: (q, tip, v, s, seg) as the planner hands them to the check."""
    tip = TIP + np.outer(x, direction)
    q = K.ik_batch(tip, np.repeat(AXIS[None], len(x), 0), M).q
    v = np.abs(np.gradient(x, DT))
    return q, tip, v, 1000.0 + np.asarray(x, float), np.full(len(x), seg)


# what is measured -> (limits, segment, direction, the limit in mm/s or mm/s^2, speed or acceleration)
CASES = {
    "joint X speed": (LIMITS, 0, (1.0, 0.0, 0.0), 100.0, "v"),      # table X: 1 mm of tip X is 1 mm of X
    "joint Y speed": (LIMITS, 0, (0.0, 1.0, 0.0), 100.0, "v"),
    "joint X acceleration": (LIMITS, 0, (1.0, 0.0, 0.0), 2000.0, "a"),
    "tip speed": (LIMITS, 2, (0.0, 1.0, 0.0), 10.0, "v"),            # the feed of line 4
    "slow tip speed": (LIMITS, 3, (0.0, 1.0, 0.0), 0.5, "v"),        # line 5's F30: under 1 mm/s too
    "tip acceleration": (SLOW_TIP, 0, (0.0, 1.0, 0.0), 1000.0, "a"),
}


@pytest.mark.parametrize("case", sorted(CASES))
@settings(max_examples=10, deadline=None)
@given(over=st.booleans(), r=st.floats(0.5, 1.4), n=st.integers(4, 30))
def test_a_sample_beyond_a_limit_is_refused_there_and_one_within_the_tolerance_accepted(case, over, r, n):
    """n samples moving at a constant r x the limit (speeds), or accelerating from rest at r x it
    (accelerations). r between 1 + 2 tol and 1.4: every sample pair (speed) or triple (acceleration)
    is refused, at its first sample (its middle one), with the factor 0.97 / r and the samples'
    speed. r up to 1 + tol / 2: nothing is refused."""
    limits, seg, direction, lim, kind = CASES[case]
    job, path = _path(JOB, limits)
    r = (1.0 + 2 * TOL) + (r - 0.5) * (0.4 - 2 * TOL) / 0.9 if over else min(r, 1.0 + TOL / 2)
    i = np.arange(n)
    x = r * lim * DT * i if kind == "v" else 0.5 * r * lim * (DT * i) ** 2
    q, tip, v, s, sg = _samples(x, np.asarray(direction), seg)
    got = P._violations(q, tip, v, s, sg, path, M, limits, DT)
    if not over:
        assert got is None, (case, r)
        return
    assert got is not None, (case, r)
    s_bad, factor, v_bad = got
    at = slice(0, n - 1) if kind == "v" else slice(1, n - 1)
    assert s_bad.tolist() == s[at].tolist()
    assert factor == pytest.approx(np.full(len(s[at]), 0.97 / r), rel=1e-9)
    assert v_bad.tolist() == v[at].tolist()


def test_the_tip_speed_of_a_pure_reorientation_move_is_not_judged_against_its_feed():
    """Line 3 tilts the tool at F600: its feed is the rotation's (rotation_length_mm per radian), not
    the tip's. Samples of it with the tip at 3 x that feed (30 mm/s, joints at 30 % of theirs) pass;
    the same samples counted on line 4, a tip move at F600, are refused at every pair."""
    job, path = _path(JOB, LIMITS)
    assert path.rot.tolist() == [False, True, False, False]
    x = 30.0 * DT * np.arange(10)
    q, tip, v, s, _ = _samples(x, np.array([1.0, 0.0, 0.0]), 0)
    assert P._violations(q, tip, v, s, np.full(10, 1), path, M, LIMITS, DT) is None
    s_bad, factor, _ = P._violations(q, tip, v, s, np.full(10, 2), path, M, LIMITS, DT)
    assert s_bad.tolist() == s[:-1].tolist() and factor == pytest.approx(np.full(9, 0.97 / 3.0), rel=1e-9)


def test_each_sample_pair_is_judged_by_the_feed_of_the_segment_it_arrives_in():
    """Samples at 20 mm/s going from line 4 (F600, 10 mm/s) into line 2's segment (F9000): the pairs
    that end on line 4 are refused (factor 0.97 / 2), the pair that arrives in the faster segment and
    those after it are not."""
    job, path = _path(JOB, LIMITS)
    x = 20.0 * DT * np.arange(8)
    q, tip, v, s, _ = _samples(x, np.array([0.0, 1.0, 0.0]), 0)
    seg = np.array([2, 2, 2, 2, 0, 0, 0, 0])
    s_bad, factor, _ = P._violations(q, tip, v, s, seg, path, M, LIMITS, DT)
    assert s_bad.tolist() == s[:3].tolist()
    assert factor == pytest.approx(np.full(3, 0.97 / 2.0), rel=1e-9)


# ---------------------------------------------------------------- reachability

def _job(text):
    return parse_gcode(text, "reach.ngc", TIP, AXIS)


def test_an_unreachable_programmed_pose_is_refused_with_its_line_and_listed_once_for_check():
    """Table X travels +-75 mm: X-80 on line 4 is refused by plan and validate, naming line 4 and the
    table; ``pmctl check`` (validate with a problem list) lists each line once: the programmed poses
    of lines 4 and 7 (X-80, X90; the paths to them leave the workspace too, not listed again), then
    the paths of lines 5 and 8, which start at those poses; nothing for the other lines."""
    text = "G21 G90\nG1 X-60 F600\nG1 Y20\nG1 X-80\nG1 X0\nG1 Y0\nG1 X90\nG1 X0 Y10\n"
    for run in (lambda j: P.plan(j, M, DT), lambda j: P.validate(j, M, DT)):
        with pytest.raises(InputError) as e:
            run(_job(text))
        assert e.value.line == 4 and e.value.reason.startswith("pose unreachable: table X"), e.value.reason
        assert e.value.path == "reach.ngc"
    problems = []
    P.validate(_job(text), M, DT, problems=problems)
    assert [(p.line, p.kind) for p in problems] == [(4, "machine"), (7, "machine"), (5, "machine"), (8, "machine")]
    assert all(p.file == "reach.ngc" and p.column is None for p in problems)
    assert [p.message.split(":")[0] for p in problems] == ["the programmed pose is unreachable"] * 2 + [
        "the path between the programmed poses is unreachable"] * 2
    assert [p.message.split(": ")[1].split(" mm")[0] for p in problems] == [
        "table X = 80.000000", "table X = -90.000000", "table X = 80.000000", "table X = -90.000000"]
    assert all(p.message.endswith("move the program (or the part on the table) in X/Y so that the tool stays "
                                  "over the table's travel") for p in problems)


def test_a_path_that_leaves_the_workspace_between_reachable_poses_is_refused_with_its_line():
    """Both ends at table X = -60 mm, reachable; the arc of line 3 swings the table past -75 mm in
    between: refused on line 3 naming the table and a tip on the arc beyond the limit; listed once for
    ``pmctl check`` as the path between the programmed poses."""
    text = "G21 G90\nG0 X60 Y-30\nG3 X60 Y30 I0 J30 F600\nG1 X0 Y0\n"
    with pytest.raises(InputError) as e:
        P.plan(_job(text), M, DT)
    assert e.value.line == 3 and e.value.path == "reach.ngc"
    assert e.value.reason.startswith("the path leaves the workspace at tip [")
    assert "table X" in e.value.reason
    text_at = e.value.reason.split("[")[1].split("]")[0].split(",")
    assert all(len(t.strip().split(".")[1]) <= 4 for t in text_at)      # to 0.1 um
    where = [float(t) for t in text_at]
    assert math.hypot(where[0] - 60.0, where[1]) == pytest.approx(30.0, abs=1e-3) and where[0] > 75.0
    problems = []
    P.validate(_job(text), M, DT, problems=problems)
    assert [p.line for p in problems] == [3]
    assert problems[0].message.startswith("the path between the programmed poses is unreachable: table X")


def test_a_job_of_one_move_to_an_unreachable_pose_is_refused_at_that_pose():
    """The first and last programmed pose of a one-move job (X-80: table X +80 mm, over its 75) is
    checked as a pose: refused naming line 2 and the table (not as a path leaving the workspace);
    listed once for ``pmctl check`` though the path to it leaves the workspace too."""
    text = "G21 G90\nG1 X-80 F600\n"
    for run in (lambda j: P.plan(j, M, DT), lambda j: P.validate(j, M, DT)):
        with pytest.raises(InputError) as e:
            run(_job(text))
        assert e.value.line == 2 and e.value.reason.startswith("pose unreachable: table X = 80.000000 mm")
    problems = []
    P.validate(_job(text), M, DT, problems=problems)
    assert [(p.line, p.message.split(":")[0]) for p in problems] == [(2, "the programmed pose is unreachable")]
