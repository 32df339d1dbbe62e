"""Kinematics facts: FK(IK(x)) = x, chain-plane constraints, representations agree, Jacobians."""

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine, machine_from_dict
from pmctl.core.errors import KinematicsError, UnreachablePose

M = load_machine()
G = M.geometry
R_OUT = G.platform_radius

# The workspace: tilt within the theta2 limit, table within travel, chains within their range.
theta1s = st.floats(min_value=1e-3, max_value=math.pi, allow_nan=False)
theta2s = st.floats(min_value=-math.radians(20), max_value=math.radians(20), allow_nan=False)
zs = st.floats(min_value=230.0, max_value=520.0)
txy = st.floats(min_value=-60.0, max_value=60.0)


def pose_from(z, t1, t2, x, y):
    """A reachable tool pose: platform height, tilt, table position -> tip in W and axis."""
    P, R = K.platform_pose(z, t1, t2, R_OUT)
    tip, axis = K.tool_of_platform(P, R, np.array([x, y]), G)
    return tip, axis


@settings(max_examples=300, deadline=None)
@given(zs, theta1s, theta2s, txy, txy)
def test_fk_of_ik_is_identity_to_1e9_mm(z, t1, t2, x, y):
    tip, axis = pose_from(z, t1, t2, x, y)
    r = K.ik_batch(tip, axis, M)
    assume(r.ok)                       # inside the workspace (chains 150-570 mm, swing)
    t = K.fk(r.q, M)
    assert np.max(np.abs(t.tip - tip)) < 1e-9
    assert np.max(np.abs(t.axis - axis)) < 1e-12
    assert np.allclose(r.q[3:], [x, y], atol=1e-9)


@settings(max_examples=300, deadline=None)
@given(zs, st.floats(-math.pi, math.pi), st.floats(-0.6, 0.6))
def test_chain_plane_constraints_hold_to_1e12_mm(z, t1, t2):
    P, R = K.platform_pose(z, t1, t2, R_OUT)
    C = K.joint_positions(P, R, G)
    assert np.max(np.abs(np.einsum("ki,ki->k", C - G.base_joints, G.revolute_axes))) < 1e-12


def test_home_chain_length_is_the_documented_393_249():
    P, R = K.platform_pose(G.z_home, 0.7, 0.0, R_OUT)
    assert np.allclose(K.chain_lengths(P, R, G), 393.249, atol=5e-4)
    # ... and FK of it comes back to the home pose.
    P2, R2 = K.forward_platform(K.chain_lengths(P, R, G), G)
    assert np.allclose(P2, [0, 0, 393.0], atol=1e-9) and np.allclose(R2, np.eye(3), atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5), st.floats(100, 600))
def test_roll_pitch_and_tilt_representations_agree(alpha, beta, z):
    """R = Rx(a) Ry(b) Rz(gamma_u) with the corrected gamma_u is the zero-torsion tilt rotation."""
    P1, R1 = K.roll_pitch_pose(alpha, beta, z, R_OUT)
    t1, t2 = K.roll_pitch_to_tilt(alpha, beta)
    P2, R2 = K.platform_pose(z, t1, t2, R_OUT)
    assert np.max(np.abs(R1 - R2)) < 1e-12
    assert np.max(np.abs(P1 - P2)) < 1e-9
    a2, b2 = K.tilt_to_roll_pitch(t1, t2)
    assert abs(a2 - alpha) < 1e-12 and abs(b2 - beta) < 1e-12


def test_seed_printed_gamma_without_minus_violates_the_constraints():
    """docs/machine.md §8 erratum: the seed's eq. 3.24 sign breaks the chain-plane constraints."""
    a, b = 0.2, 0.15
    g = -K.dependent_yaw(a, b)           # the seed's sign
    R = K.rot_x(a) @ K.rot_y(b) @ K.rot_z(g)
    xu = -R_OUT * math.cos(b) * math.sin(g)
    yu = 0.5 * R_OUT * (math.cos(b) * math.cos(g) - math.cos(a) * math.cos(g) + math.sin(a) * math.sin(b) * math.sin(g))
    C = K.joint_positions(np.array([xu, yu, 400.0]), R, G)
    assert np.max(np.abs(np.einsum("ki,ki->k", C, G.revolute_axes))) > 0.1


@settings(max_examples=200, deadline=None)
@given(theta1s, theta2s)
def test_axis_tilt_convention(t1, t2):
    """theta1 in (0, 180 deg], theta2 signed; axis -> (theta1, theta2) -> axis is the identity."""
    v = K.tilt_to_axis(t1, t2)
    a1, a2 = K.axis_to_tilt(v)
    assert 0 < a1 <= math.pi
    assert np.allclose(K.tilt_to_axis(a1, a2), v, atol=1e-14)
    if abs(t2) > 1e-9 and t1 < math.pi - 1e-9:
        assert abs(a1 - t1) < 1e-9 and abs(a2 - t2) < 1e-9


def test_vertical_axis_gives_theta1_180():
    assert K.axis_to_tilt(np.array([0.0, 0.0, 1.0])) == (math.pi, 0.0)
    assert K.axis_to_tilt(np.array([-0.0, 0.0, 1.0]))[0] == math.pi


@settings(max_examples=60, deadline=None)
@given(zs, theta1s, theta2s, txy, txy)
def test_tool_jacobian_matches_finite_differences(z, t1, t2, x, y):
    tip, axis = pose_from(z, t1, t2, x, y)
    r = K.ik_batch(tip, axis, M)
    assume(r.ok)
    t = K.fk(r.q, M)
    J = K.jacobian_tool(t.P, t.R, G)
    h = 1e-5
    Jn = np.zeros((6, 5))
    for j in range(5):
        dq = np.zeros(5)
        dq[j] = h
        a, b = K.fk(r.q + dq, M, guess=(t.P, t.R)), K.fk(r.q - dq, M, guess=(t.P, t.R))
        Jn[:, j] = np.concatenate([a.tip - b.tip, a.axis - b.axis]) / (2 * h)
    assert np.max(np.abs(J - Jn)) < 1e-6


@settings(max_examples=100, deadline=None)
@given(st.floats(150, 550), st.floats(-math.pi, math.pi), st.floats(-0.5, 0.5))
def test_ztt_jacobian_matches_finite_differences(z, t1, t2):
    J = K.jacobian_ztt(z, t1, t2, R_OUT, G)
    x0 = np.array([z, t1, t2])
    Jn = np.zeros((3, 3))
    for j, h in enumerate((1e-5, 1e-7, 1e-7)):
        dx = np.zeros(3)
        dx[j] = h
        Jn[:, j] = (K.chain_lengths(*K.platform_pose(*(x0 + dx), R_OUT), G)
                    - K.chain_lengths(*K.platform_pose(*(x0 - dx), R_OUT), G)) / (2 * h)
    assert np.max(np.abs(J - Jn)) < 1e-5


def test_batch_equals_scalar():
    rng = np.random.default_rng(1)
    n = 2000
    t1 = rng.uniform(0.01, math.pi, n)
    t2 = rng.uniform(-0.3, 0.3, n)
    P, R = K.platform_pose(rng.uniform(250, 500, n), t1, t2, R_OUT)
    tip, axis = K.tool_of_platform(P, R, rng.uniform(-30, 30, (n, 2)), G)
    r = K.ik_batch(tip, axis, M)
    assert r.ok.mean() > 0.9, set(r.reason[~r.ok])
    tip, axis = tip[r.ok], axis[r.ok]
    r = K.ik_batch(tip, axis, M)
    n = len(tip)
    tp, ok = K.fk_batch(r.q, M)
    assert ok.all()
    assert np.max(np.abs(tp.tip - tip)) < 1e-9
    for k in (0, 17, n - 1):
        assert np.allclose(K.ik(tip[k], axis[k], M).q, r.q[k], atol=1e-12)


# ---------------------------------------------------------------- unreachable poses and FK faults

def test_unreachable_poses_say_which_limit():
    with pytest.raises(UnreachablePose, match="theta2 = 25"):
        K.ik([0, 0, 150], K.tilt_to_axis(1.0, math.radians(25)), M)
    with pytest.raises(UnreachablePose, match="chain L"):
        K.ik([0, 0, 600], [0, 0, 1], M)
    with pytest.raises(UnreachablePose, match="table X"):
        K.ik([-100, 0, 150], [0, 0, 1], M)
    with pytest.raises(UnreachablePose, match="not a unit vector"):
        K.ik([0, 0, 150], [0, 0, 2], M)
    with pytest.raises(UnreachablePose, match="no upward component"):
        K.ik([0, 0, 150], [0, 0, -1], M)
    with pytest.raises(UnreachablePose, match="finite"):
        K.ik([0, float("nan"), 150], [0, 0, 1], M)


def test_batch_ik_marks_each_bad_pose():
    tips = np.array([[0, 0, 150], [200, 0, 150], [0, 0, 150.0]])
    axes = np.array([[0, 0, 1], [0, 0, 1], K.tilt_to_axis(0.5, 0.6)])
    r = K.ik_batch(tips, axes, M)
    assert r.ok.tolist() == [True, False, False]
    assert "table X" in r.reason[1] and "theta2" in r.reason[2]


def test_fk_failure_is_an_error_never_a_silent_answer():
    with pytest.raises(KinematicsError):
        K.fk([100.0, 900.0, 100.0, 0, 0], M)           # no assembly: chains incompatible
    with pytest.raises(KinematicsError):
        K.fk([float("nan"), 393, 393, 0, 0], M)
    sol = K.solve_platform(np.array([[393.249] * 3, [100.0, 900.0, 100.0]]), G)
    assert sol.ok.tolist() == [True, False]


def test_fk_iteration_cap_is_reported():
    sol = K.solve_platform(np.array([420.0, 380.0, 400.0]), G, max_iter=1)
    assert not sol.ok


# ---------------------------------------------------------------- calibrated (general) geometry

def _calibrated(**over):
    import tomllib
    from pmctl.core.config import CONFIG_DIR
    data = tomllib.loads((CONFIG_DIR / "prototype.toml").read_text())
    data["geometry"].update(over)
    return machine_from_dict(data, "<test>")


def _random_calibrated(rng, mm=0.5, deg=0.5):
    """A calibrated machine: every joint, axis, offset and tool parameter off by up to mm / deg."""
    u = lambda *shape: rng.uniform(-1, 1, shape)
    N = G.revolute_axes + np.radians(deg) * u(3, 3)         # ~0.5 deg tilt of each revolute axis
    return _calibrated(base_joints_mm=(G.base_joints + mm * u(3, 3)).tolist(),
                       platform_joints_mm=(G.platform_joints + mm * u(3, 3)).tolist(),
                       revolute_axes=N.tolist(), length_offsets_mm=(mm * u(3)).tolist(),
                       tool_tilt_deg=(deg * u(2)).tolist(), tool_length_mm=100.0 + mm * u()[()])


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31), zs, theta1s, st.floats(-0.3, 0.3), txy, txy)
def test_general_geometry_fk_of_ik(seed, z, t1, t2, x, y):
    """A calibrated geometry (+-0.5 mm / +-0.5 deg on every parameter): FK(IK(x)) = x to 1e-9 mm,
    the chain-plane constraints hold, and the closed form alone would be off by far more."""
    m = _random_calibrated(np.random.default_rng(seed))
    assert not m.geometry.nominal
    tip, axis = pose_from(z, t1, t2, x, y)
    r = K.ik_batch(tip, axis, m)
    assume(r.ok)
    t = K.fk(r.q, m)
    assert np.max(np.abs(t.tip - tip)) < 1e-9
    assert np.max(np.abs(t.axis - axis)) < 1e-12
    C_base = K.joint_positions(r.P, r.R, m.geometry)
    assert np.max(np.abs(np.einsum("ki,ki->k", C_base - m.geometry.base_joints, m.geometry.revolute_axes))) < 1e-9
    # the nominal IK on the calibrated machine misses: the calibration matters
    t_nom = K.fk(K.ik_batch(tip, axis, M, check_limits=False).q, m)
    assert np.max(np.abs(t_nom.tip - tip)) > 1e-3


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31), zs, theta1s, st.floats(-0.3, 0.3), txy, txy)
def test_general_geometry_ik_of_fk(seed, z, t1, t2, x, y):
    """IK(FK(q)) = q on a calibrated geometry (joints to 1e-9 mm)."""
    m = _random_calibrated(np.random.default_rng(seed))
    P, R = K.platform_pose(z, t1, t2, R_OUT)
    q = np.concatenate([K.chain_lengths(P, R, G), [x, y]])
    t, ok = K.fk_batch(q, m)
    assume(bool(ok))
    r = K.ik_batch(t.tip, t.axis, m)
    assume(r.ok)
    assert np.max(np.abs(r.q - q)) < 1e-9


def test_general_geometry_batch_equals_single_and_nonconvergence_is_reported():
    rng = np.random.default_rng(5)
    m = _random_calibrated(rng)
    n = 500
    P, R = K.platform_pose(rng.uniform(280, 480, n), rng.uniform(0.01, math.pi, n), rng.uniform(-0.3, 0.3, n), R_OUT)
    tip, axis = K.tool_of_platform(P, R, rng.uniform(-30, 30, (n, 2)), G)
    r = K.ik_batch(tip, axis, m)
    assert r.ok.mean() > 0.9
    t, ok = K.fk_batch(r.q[r.ok], m)
    assert ok.all() and np.max(np.abs(t.tip - tip[r.ok])) < 1e-9
    for k in np.nonzero(r.ok)[0][:3]:
        assert np.allclose(K.ik(tip[k], axis[k], m).q, r.q[k], atol=1e-12)
    P1, R1, conv = K._ik_platform(tip[:4], axis[:4], m.geometry, max_iter=1)
    assert not conv.any()               # one Newton step is not enough: reported, not hidden
    r1 = K.ik_batch(tip[:4], axis[:4], m)
    assert r1.ok[r.ok[:4]].all()


# ---------------------------------------------------------------- the loop's single-pose FK (pmctl.core.model_fk.ModelFK)

@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31))
def test_loop_fk_follows_a_path_like_the_batch_solver(seed):
    """Tick after tick, with the predictor warm start, the loop's FK lands on the batch solution."""
    from pmctl.core.model_fk import ModelFK
    rng = np.random.default_rng(seed)
    n = 60
    z = 393 + np.cumsum(rng.normal(0, 0.5, n))
    t1 = 1.0 + np.cumsum(rng.normal(0, 0.01, n))
    t2 = np.clip(np.cumsum(rng.normal(0, 0.005, n)), -0.3, 0.3)
    P, R = K.platform_pose(z, t1, t2, R_OUT)
    L = K.chain_lengths(P, R, G)
    q = np.concatenate([L, np.zeros((n, 2))], 1)
    model = ModelFK(M)
    Pk, Rk = K.forward_platform(L[0], G)
    pred = None
    for k in range(n):
        Pk, Rk, tip, axis, J = model.solve(q[k], Pk, Rk, pred)
        assert np.max(np.abs(Pk - P[k])) < 1e-9 and np.max(np.abs(Rk - R[k])) < 1e-12
        assert np.max(np.abs(K.loop_residual(Pk, Rk, L[k], G))) < K.FK_TOL_MM
        if k + 1 < n:
            pred = (L[k + 1] - L[k], model.last_T)
    _, _, _, _, J = model.solve(q[-1], Pk, Rk)
    assert np.max(np.abs(J - K.jacobian_tool(Pk, Rk, G))) < 1e-12
