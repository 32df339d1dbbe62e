"""Workspace and planning limits pinned where they bind:

- the spherical-joint swing limit (45 deg, SRJ012C), which on the prototype's nominal geometry never
  binds inside the 20 deg tilt range: on a mechanism with a 200 mm platform working 160 mm below
  its home height (the chains lean 29 deg with the tool vertical) it does. Just under it a pose is reachable, just over it IK, FK with limits and the
  planner refuse it naming the swing; the swing is measured here from the joint positions;
- the planner's last check on the samples: a limit grid allowed 130 % of the joint speed and
  acceleration (``joint_fraction`` 1.3), the samples exceed the machine's limits, and the check must
  lower the caps and plan again until they hold (batch and streaming planner alike).
"""

import math
from pathlib import Path

import numpy as np
import pytest

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.errors import InputError, UnreachablePose
from pmctl.task.gcode import parse_gcode
from pmctl.core.job import home_pose
from pmctl.task.planner import PlannerLimits, plan, plan_stream, validate

ROOT = Path(__file__).resolve().parents[2]
M = load_machine()
DT = 1e-3


@pytest.fixture(scope="module")
def small_platform(tmp_path_factory):
    text = (ROOT / "config" / "prototype.toml").read_text()
    assert "platform_radius_mm = 316.0" in text
    p = tmp_path_factory.mktemp("swing") / "small-platform.toml"
    p.write_text(text.replace("platform_radius_mm = 316.0", "platform_radius_mm = 200.0"))
    return load_machine(p)


def _low_tip(m):
    """The tool tip 160 mm below the home pose's (the platform low: the chains lean most)."""
    tip, _ = home_pose(m)
    return np.asarray(tip, float) - [0.0, 0.0, 160.0]


def _swing_deg(P, R, geom):
    """The largest angle between a chain (base joint A_i to spherical joint C_i) and the platform
    normal, measured from the joint positions."""
    C = P + (R @ np.asarray(geom.platform_joints, float).T).T
    u = C - np.asarray(geom.base_joints, float)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return float(np.degrees(np.arccos(np.clip(u @ R[:, 2], -1.0, 1.0))).max())


def _pose_at_swing(m, tip, theta1, want_deg):
    """The tool axis of azimuth theta1 whose tilt gives swing ``want_deg`` (bisection on the tilt)."""
    lo, hi = 0.0, math.radians(20.0)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        r = K.ik_batch(tip, K.tilt_to_axis(theta1, mid), m, check_limits=False)
        if _swing_deg(r.P, r.R, m.geometry) < want_deg:
            lo = mid
        else:
            hi = mid
    return K.tilt_to_axis(theta1, 0.5 * (lo + hi))


def test_the_swing_limit_does_not_bind_on_the_nominal_geometry_but_does_on_a_small_platform(small_platform):
    tip, _ = home_pose(M)
    worst = max(_swing_deg(*(lambda r: (r.P, r.R))(K.ik_batch(tip, K.tilt_to_axis(t1, math.radians(20.0)), M,
                                                                 check_limits=False)), M.geometry)
                for t1 in np.linspace(0, 2 * np.pi, 13))
    assert worst < M.limits.spherical_swing_deg - 5.0
    r = K.ik_batch(_low_tip(small_platform), np.array([0.0, 0.0, 1.0]), small_platform)
    assert r.ok and _swing_deg(r.P, r.R, small_platform.geometry) > 28.0


@pytest.mark.parametrize("theta1_deg", [0.0, 90.0, 150.0])
def test_a_pose_just_under_the_swing_limit_is_reachable_and_just_over_it_is_refused(small_platform, theta1_deg):
    m = small_platform
    lim = m.limits.spherical_swing_deg
    tip = _low_tip(m)
    t1 = math.radians(theta1_deg)
    under = _pose_at_swing(m, tip, t1, lim - 0.1)
    over = _pose_at_swing(m, tip, t1, lim + 0.1)
    r = K.ik_batch(np.array([tip, tip]), np.array([under, over]), m)
    assert r.ok[0], r.reason[0]
    assert not r.ok[1] and r.reason[1].startswith("spherical joint swing 45.10 deg over 45 deg"), r.reason[1]
    # (the tilt is checked first: it is inside its own limit, the swing refuses the pose)
    assert abs(math.degrees(r.theta2[1])) < m.limits.theta2_deg[1]
    K.ik(tip, under, m)
    with pytest.raises(UnreachablePose, match="spherical joint swing"):
        K.ik(tip, over, m)
    # forward kinematics with the limits checked says the same for the joints of both poses
    K.fk(r.q[0], m, check_limits=True)
    with pytest.raises(UnreachablePose, match="spherical joint swing"):
        K.fk(r.q[1], m, check_limits=True)


def test_the_planner_refuses_a_job_over_the_swing_limit_naming_its_line(small_platform, tmp_path):
    m = small_platform
    tip, axis = _low_tip(m), np.array([0.0, 0.0, 1.0])
    over = _pose_at_swing(m, tip, 0.0, m.limits.spherical_swing_deg + 0.5)
    a, b = (math.degrees(float(x)) for x in K.roll_pitch_from_axis(over))
    job = parse_gcode(f"G21 G90\nG1 A{a / 2:.4f} B{b / 2:.4f} F600\nG1 A{a:.4f} B{b:.4f}\n", "tilt.ngc", tip, axis)
    with pytest.raises(InputError, match="spherical joint swing") as e:
        validate(job, m, DT, start=(tip, axis))
    assert e.value.line == 3


LIMITS_130 = PlannerLimits(rapid_mm_s=200.0, accel_mm_s2=3000.0, jerk_mm_s3=60000.0, joint_fraction=1.3)


def _joint_peaks(tip, axis):
    q = K.ik_batch(tip, axis, M).q
    return np.abs(np.diff(q, axis=0)).max(0) / DT, np.abs(np.diff(q, 2, axis=0)).max(0) / DT ** 2


@pytest.mark.parametrize("stream", [False, True])
def test_the_planners_last_check_holds_the_joint_limits_that_the_grid_let_through(stream):
    """X across the table at F9000 with a limit grid that allows 130 % of the joint limits: the
    samples of the first plan reach 130 mm/s; the last check finds that, lowers the caps and plans
    again, and what comes out keeps the table within 100 mm/s and 2000 mm/s^2 (to the planner's
    1e-6), while still using most of it (the check lowers only where it must)."""
    tip, axis = home_pose(M)
    job = parse_gcode("G21 G90\nG1 X-60 F9000\nG1 X60\n", "fast.ngc", tip, axis)
    if stream:
        parts = list(plan_stream(job, M, DT, start=(tip, axis), limits=LIMITS_130))
        tips, axes = np.concatenate([p.tip for p in parts]), np.concatenate([p.axis for p in parts])
    else:
        tr = plan(job, M, DT, start=(tip, axis), limits=LIMITS_130)
        tips, axes = tr.tip, tr.axis
    v, a = _joint_peaks(tips, axes)
    jl = M.limits
    assert np.all(v <= jl.joint_speed * (1 + 1e-6)), v
    assert np.all(a <= jl.joint_accel * (1 + 1e-6)), a
    assert v[3] > 0.9 * jl.joint_speed[3]
