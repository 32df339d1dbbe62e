"""The workspace limits pinned at their edges (pmctl.core.kinematics.limit_violations, behind IK, FK
with limits, the planner and the NC's preflight):

- each joint range (chains 150..570 mm, table X and Y -75..75 mm) and the tilt range (-20..20 deg):
  a joint or tilt exactly at its limit, or past it by float round-off (under 1e-9), is accepted;
  one a micrometre (a millionth of a degree) past it is refused, the message naming the joint, its
  value and its range;
- the spherical-joint swing: measured here from the joint positions and compared with the limit;
  with the limit a millionth of a degree above the swing of a pose the pose is accepted, below it
  refused with the swing's value;
- the platform above the base (z > 0);
- the first violated limit is the one reported, in the order tilt, chains, table, swing, height;
- batches keep their shape; and IK accepts a pose exactly when every limit, measured independently
  here, holds.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.job import home_pose

M = load_machine()
LIM = M.limits
HOME_TIP, HOME_AXIS = (np.asarray(x, float) for x in home_pose(M))
HOME = K.ik_batch(HOME_TIP, HOME_AXIS, M)
Q0 = np.asarray(HOME.q, float)                 # every joint well inside its range
EPS = 1e-6                                     # a micrometre (or a millionth of a degree) past a limit


def _with_limits(**kw):
    return dataclasses.replace(M, limits=dataclasses.replace(M.limits, **kw))


def _joints_only(q, m=M):
    """The check before FK: joint ranges only."""
    return K.limit_violations(np.asarray(q, float), None, None, None, m)


def _swing_deg(P, R, geom):
    """Largest angle between a chain (base joint A_i to spherical joint C_i) and the platform
    normal, from the joint positions (the test's own measure)."""
    C = P + (R @ np.asarray(geom.platform_joints, float).T).T
    u = C - np.asarray(geom.base_joints, float)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return float(np.degrees(np.arccos(np.clip(u @ R[:, 2], -1.0, 1.0))).max())


def _chain_text(i, v):
    return f"chain L{i + 1} = {v:.6f} mm outside [150, 570] mm"


def _table_text(name, v):
    return (f"table {name} = {v:.6f} mm outside [-75, 75] mm (the table carries the workpiece and moves "
            f"opposite to the tool: a tool tip near {name.lower()} = {-v:+.3f} mm in the workpiece frame "
            f"needs table {name} = {v:+.3f} mm)")


JOINTS = [(i, "chain", LIM.chain_length) for i in range(3)] + [(3, "X", LIM.table_x), (4, "Y", LIM.table_y)]


def test_the_prototypes_limits_are_the_ones_these_tests_pin():
    assert LIM.chain_length == (150.0, 570.0) and LIM.table_x == (-75.0, 75.0) == LIM.table_y
    assert LIM.theta2_deg == (-20.0, 20.0) and LIM.spherical_swing_deg == 45.0
    assert HOME.reason[()] == "" and _swing_deg(HOME.P, HOME.R, M.geometry) < 40.0


@pytest.mark.parametrize("j,name,rng", JOINTS, ids=["L1", "L2", "L3", "X", "Y"])
def test_a_joint_at_its_limit_is_accepted_and_a_micrometre_past_it_is_refused_naming_it(j, name, rng):
    lo, hi = rng
    at = np.array([Q0, Q0]), np.array([Q0, Q0])
    at[0][0, j], at[0][1, j] = lo, hi
    assert _joints_only(at[0]).tolist() == ["", ""]
    past = np.array([Q0, Q0])
    past[0, j], past[1, j] = lo - EPS, hi + EPS
    want = ([_chain_text(j, lo - EPS), _chain_text(j, hi + EPS)] if name == "chain"
            else [_table_text(name, lo - EPS), _table_text(name, hi + EPS)])
    assert _joints_only(past).tolist() == want
    # the same with the platform pose given (after FK): the joint range is checked the same way
    Ps, Rs, t2 = np.array([HOME.P] * 2), np.array([HOME.R] * 2), np.zeros(2)
    assert K.limit_violations(at[0], t2, Ps, Rs, M).tolist() == ["", ""]
    assert K.limit_violations(past, t2, Ps, Rs, M).tolist() == want


@pytest.mark.parametrize("j,name", [(3, "X"), (4, "Y")])
def test_a_table_past_its_limit_by_float_round_off_is_accepted(j, name):
    """Table targets are differences of tool and tip positions: a tip programmed at the edge may land
    a few ulps past it. Up to 1e-9 mm is round-off; 1e-8 mm is not."""
    q = np.array([Q0] * 4)
    q[0, j], q[1, j], q[2, j], q[3, j] = -75.0 - 5e-10, 75.0 + 5e-10, -75.0 - 1e-8, 75.0 + 1e-8
    assert _joints_only(q).tolist() == ["", "", _table_text(name, -75.0 - 1e-8), _table_text(name, 75.0 + 1e-8)]


@settings(max_examples=60, deadline=None)
@given(j=st.integers(0, 4), frac=st.floats(0.0, 1.0), past=st.floats(1e-6, 200.0), upper=st.booleans())
def test_any_joint_inside_its_range_is_accepted_and_any_past_it_refused(j, frac, past, upper):
    lo, hi = JOINTS[j][2]
    q = np.array([Q0, Q0])
    q[0, j] = lo + frac * (hi - lo)
    q[1, j] = hi + past if upper else lo - past
    r = _joints_only(q)
    assert r[0] == ""
    name = JOINTS[j][1]
    assert r[1] == (_chain_text(j, q[1, j]) if name == "chain" else _table_text(name, q[1, j]))


def test_tilt_at_its_limit_is_accepted_and_past_it_refused():
    t2 = np.radians([20.0, -20.0, 20.0 + EPS, -20.0 - EPS, 0.0])
    n = len(t2)
    r = K.limit_violations(np.array([Q0] * n), t2, np.array([HOME.P] * n), np.array([HOME.R] * n), M)
    assert r.tolist() == ["", "", "tilt theta2 = 20.000001 deg outside [-20, 20] deg",
                          "tilt theta2 = -20.000001 deg outside [-20, 20] deg", ""]


@settings(max_examples=40, deadline=None)
@given(theta1=st.floats(0.0, 2 * math.pi), tilt_deg=st.floats(0.0, 20.0), dz=st.floats(-120.0, 60.0))
def test_the_swing_limit_binds_exactly_at_the_measured_swing(theta1, tilt_deg, dz):
    """The swing of a real pose, measured from its joint positions: a limit a millionth of a degree
    above it accepts the pose, one a millionth below refuses it with the swing's value."""
    tip = HOME_TIP + [0.0, 0.0, dz]
    r = K.ik_batch(tip, K.tilt_to_axis(theta1, math.radians(tilt_deg)), M)
    s = _swing_deg(r.P, r.R, M.geometry)
    assert 0.0 < s < 45.0 and r.ok                    # (chains 164..557 mm here: within their range)
    above, below = _with_limits(spherical_swing_deg=s + EPS), _with_limits(spherical_swing_deg=s - EPS)
    assert K.limit_violations(r.q, r.theta2, r.P, r.R, above)[()] == ""
    assert K.limit_violations(r.q, r.theta2, r.P, r.R, below)[()] == \
        f"spherical joint swing {s:.2f} deg over {s - EPS:g} deg"
    # the joint-only check (before FK) does not judge the swing: there is no pose yet
    assert _joints_only(r.q, below)[()] == ""


def test_the_swing_is_the_largest_of_the_three_chains():
    """Tilted poses around the azimuth: the chain with the largest swing changes; each is judged by it."""
    t1 = np.radians([0.0, 60.0, 120.0, 180.0, 240.0, 300.0])
    tip = np.broadcast_to(HOME_TIP - [0.0, 0.0, 100.0], (len(t1), 3))
    r = K.ik_batch(tip, K.tilt_to_axis(t1, np.radians(15.0)), M, check_limits=False)
    C = K.joint_positions(r.P, r.R, M.geometry) - M.geometry.base_joints
    per_chain = np.degrees(np.arccos(np.einsum("nki,ni->nk", C / np.linalg.norm(C, axis=-1, keepdims=True),
                                               r.R[:, :, 2])))
    assert len(set(per_chain.argmax(1).tolist())) == 3        # each chain is the worst somewhere
    s = per_chain.max(1)
    assert np.allclose(s, [_swing_deg(P, R, M.geometry) for P, R in zip(r.P, r.R)], atol=1e-9)
    lim = float(np.median(s))
    out = K.limit_violations(r.q, r.theta2, r.P, r.R, _with_limits(spherical_swing_deg=lim))
    assert [bool(x) for x in out] == (s > lim).tolist() and 0 < (s > lim).sum() < len(s)


def test_the_platform_must_be_above_the_base():
    """With the swing out of the way (limit 180 deg): a platform at or below the base plane is refused,
    one a micrometre above it is not."""
    m = _with_limits(spherical_swing_deg=180.0)
    P = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -5.0], [0.0, 0.0, EPS], [0.0, 0.0, 393.0]])
    R = np.broadcast_to(np.eye(3), (4, 3, 3))
    r = K.limit_violations(np.array([Q0] * 4), np.zeros(4), P, R, m)
    assert r.tolist() == ["platform below the base", "platform below the base", "", ""]
    # with the machine's swing limit the low platform is refused by its swing first (the chains lie flat)
    r = K.limit_violations(np.array([Q0] * 2), np.zeros(2), P[:2], R[:2], M)
    assert r.tolist() == ["spherical joint swing 90.00 deg over 45 deg", "spherical joint swing 109.65 deg over 45 deg"]


def test_the_first_violated_limit_is_reported_in_order():
    """tilt before chains before table before swing before height; the swing limit lowered to 1 deg
    makes the home pose violate it."""
    m = _with_limits(spherical_swing_deg=1.0)
    s = _swing_deg(HOME.P, HOME.R, M.geometry)
    bad_chain, bad_table = Q0.copy(), Q0.copy()
    bad_chain[1], bad_table[4] = 600.0, 80.0
    both = Q0.copy()
    both[1], both[4] = 600.0, 80.0
    low = HOME.P.copy()
    low[2] = -1.0
    cases = [  # (q, theta2 rad, P, expected)
        (both, math.radians(25.0), HOME.P, "tilt theta2 = 25.000000 deg outside [-20, 20] deg"),
        (both, 0.0, HOME.P, _chain_text(1, 600.0)),
        (bad_table, 0.0, HOME.P, _table_text("Y", 80.0)),
        (Q0, 0.0, HOME.P, f"spherical joint swing {s:.2f} deg over 1 deg"),
        (Q0, 0.0, low, f"spherical joint swing {_swing_deg(low, HOME.R, M.geometry):.2f} deg over 1 deg"),
    ]                              # (a platform below the base: its swing is reported first)
    q = np.array([c[0] for c in cases])
    P = np.array([c[2] for c in cases])
    R = np.array([HOME.R] * len(cases))
    out = K.limit_violations(q, np.array([c[1] for c in cases]), P, R, m)
    assert out.tolist() == [c[3] for c in cases]


def test_a_batch_keeps_its_shape_and_each_pose_gets_its_own_verdict():
    q = np.broadcast_to(Q0, (2, 3, 5)).copy()
    q[0, 1, 0] = 149.0
    q[1, 2, 3] = 76.0
    P = np.broadcast_to(HOME.P, (2, 3, 3))
    R = np.broadcast_to(HOME.R, (2, 3, 3, 3))
    t2 = np.zeros((2, 3))
    t2[1, 0] = math.radians(-21.0)
    want = [["", _chain_text(0, 149.0), ""], ["tilt theta2 = -21.000000 deg outside [-20, 20] deg", "",
                                               _table_text("X", 76.0)]]
    out = K.limit_violations(q, t2, P, R, M)
    assert out.shape == (2, 3) and out.tolist() == want
    j = _joints_only(q)
    assert j.shape == (2, 3) and j.tolist() == [["", _chain_text(0, 149.0), ""], ["", "", _table_text("X", 76.0)]]
    one = _joints_only(Q0)
    assert one.shape == () and one[()] == ""


def test_joints_that_are_not_numbers_are_refused_naming_the_joint():
    q = np.array([Q0] * 3)
    q[0, 2], q[1, 4], q[2, 0] = np.nan, np.inf, -np.inf
    assert _joints_only(q).tolist() == [_chain_text(2, np.nan), _table_text("Y", np.inf), _chain_text(0, -np.inf)]


@settings(max_examples=60, deadline=None)
@given(x=st.floats(-90.0, 90.0), y=st.floats(-90.0, 90.0), dz=st.floats(-200.0, 120.0),
       theta1=st.floats(0.0, 2 * math.pi), tilt_deg=st.floats(0.0, 24.0))
def test_ik_accepts_a_pose_exactly_when_every_limit_measured_independently_holds(x, y, dz, theta1, tilt_deg):
    tip = HOME_TIP + [x, y, dz]
    axis = K.tilt_to_axis(theta1, math.radians(tilt_deg))
    r = K.ik_batch(tip, axis, M)
    q = r.q
    swing = _swing_deg(r.P, r.R, M.geometry)
    margins = [min(q[i] - 150.0, 570.0 - q[i]) for i in range(3)] + [75.0 - abs(q[3]), 75.0 - abs(q[4]),
                                                                     20.0 - tilt_deg, 45.0 - swing]
    if min(abs(v) for v in margins) < 1e-6:       # on an edge to a micrometre: judged by the tests above
        return
    inside = min(margins) > 0 and r.P[2] > 0
    assert bool(r.ok) == inside, (margins, r.reason[()])


def _chain_along_the_normal(sign):
    """A platform pose (tilted, from IK's rotation) placed so that chain 1 runs exactly along the
    platform normal (``sign`` +1: swing 0) or against it (-1: swing 180 deg), 250 mm long, and whose
    cosine of that angle rounds past +-1 (the first such tilt of a fixed list)."""
    g = M.geometry
    for i in range(400):
        axis = K.tilt_to_axis(0.0123 * i, math.radians(1 + i % 19))
        R = K.ik_batch(np.array([0.0, 0.0, 100.0]), axis, M, check_limits=False).R
        P = g.base_joints[0] + sign * 250.0 * R[:, 2] - R @ g.platform_joints[0]
        d = K.joint_positions(P, R, g)[0] - g.base_joints[0]
        if sign * float(d / np.linalg.norm(d) @ R[:, 2]) > 1.0:
            return P, R
    raise AssertionError("no pose in the list rounds past 1")


def test_a_chain_exactly_along_the_platform_normal_does_not_hide_the_others_swing():
    """Round-off can put the cosine of a chain at 0 (or 180) deg a hair past 1: that chain's swing is
    still a number, 0 (180) deg, and the pose is judged by its largest swing."""
    P, R = _chain_along_the_normal(+1)
    s = _swing_deg(P, R, M.geometry)                   # the other two chains lean a few degrees
    assert 1.0 < s < 10.0
    r = K.limit_violations(Q0, 0.0, P, R, _with_limits(spherical_swing_deg=1.0))
    assert r[()] == f"spherical joint swing {s:.2f} deg over 1 deg"
    assert K.limit_violations(Q0, 0.0, P, R, _with_limits(spherical_swing_deg=s + EPS))[()] == ""
    # against the normal: the platform hangs below the base, and the swing (180 deg) is the first reason
    P, R = _chain_along_the_normal(-1)
    assert P[2] < 0
    assert K.limit_violations(Q0, 0.0, P, R, M)[()] == "spherical joint swing 180.00 deg over 45 deg"


def test_the_edge_of_the_round_off_allowance_is_still_accepted():
    """A table position or tilt exactly 1e-9 past its limit (the allowance's edge) is accepted."""
    q = np.array([Q0] * 4)
    q[0, 3], q[1, 3], q[2, 4], q[3, 4] = -75.0 - 1e-9, 75.0 + 1e-9, -75.0 - 1e-9, 75.0 + 1e-9
    assert _joints_only(q).tolist() == [""] * 4
    t2 = np.radians([20.0 + 1e-9, -20.0 - 1e-9])
    assert np.degrees(t2).tolist() == [20.0 + 1e-9, -20.0 - 1e-9]          # the same floats, round trip
    r = K.limit_violations(np.array([Q0] * 2), t2, np.array([HOME.P] * 2), np.array([HOME.R] * 2), M)
    assert r.tolist() == ["", ""]


def test_a_pose_at_its_joint_and_tilt_limits_is_judged_by_the_limit_it_does_violate():
    """Every joint and the tilt exactly at a limit (accepted), and the swing over a lowered limit:
    the reason is the swing, not an edge that holds."""
    m = _with_limits(spherical_swing_deg=1.0)
    s = _swing_deg(HOME.P, HOME.R, M.geometry)
    want = f"spherical joint swing {s:.2f} deg over 1 deg"
    rows, t2 = [], []
    for lo_hi in (0, 1):
        for j, _, rng in JOINTS:
            q = Q0.copy()
            q[j] = rng[lo_hi] + (0.0 if j < 3 else (-1e-9 if lo_hi == 0 else 1e-9))
            rows.append(q)
            t2.append(0.0)
        for edge in (20.0, 20.0 + 1e-9):
            rows.append(Q0.copy())
            t2.append(math.radians(edge) * (1 if lo_hi else -1))
    n = len(rows)
    out = K.limit_violations(np.array(rows), np.array(t2), np.array([HOME.P] * n), np.array([HOME.R] * n), m)
    assert out.tolist() == [want] * n


def test_one_pose_that_is_not_a_number_leaves_the_others_of_its_batch_alone():
    q = np.array([Q0] * 3)
    q[1, 0] = np.nan
    assert _joints_only(q).tolist() == ["", _chain_text(0, np.nan), ""]
    r = K.limit_violations(q, np.zeros(3), np.array([HOME.P] * 3), np.array([HOME.R] * 3), M)
    assert r.tolist() == ["", _chain_text(0, np.nan), ""]
