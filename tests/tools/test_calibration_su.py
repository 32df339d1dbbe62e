"""SU-parameter (Sheth-Uicker) export of the machine and reading it back."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.errors import InputError
from pmctl.tools.calibrate import model as Mo, su

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

M = load_machine()


def rigid(rng, parallel=False):
    w = rng.normal(0, 1, 3)
    if parallel:
        w = np.array([0, 0, rng.choice([0.0, math.pi]) + rng.uniform(-0.0, 0.0)])
        T = np.eye(4)
        T[:3, :3] = K.expm_so3(np.array([0, 0, rng.uniform(-3, 3)]))
        if rng.random() < 0.5:
            T[:3, :3] = T[:3, :3] @ np.diag([1.0, -1.0, -1.0])
    else:
        T = np.eye(4)
        T[:3, :3] = K.expm_so3(w)
    T[:3, 3] = rng.normal(0, 100, 3)
    return T


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 2**31), st.booleans())
def test_su_parameters_represent_any_rigid_transform(seed, parallel):
    T = rigid(np.random.default_rng(seed), parallel)
    p = su.su_params(T)
    assert np.max(np.abs(su.su_matrix(p) - T)) < 1e-9


def test_su_matrix_is_the_published_product():
    p = {"a": 10.0, "alpha": 30.0, "b": -4.0, "beta": 12.0, "c": 7.0, "gamma": -50.0}
    r = math.radians
    T = su.A(3, 7.0) @ su.A(6, r(-50)) @ su.A(1, 10.0) @ su.A(4, r(30)) @ su.A(3, -4.0) @ su.A(6, r(12))
    assert np.allclose(su.su_matrix(p), T)
    assert np.allclose(su.A(5, 0.3)[:3, :3], K.rot_y(0.3)) and np.allclose(su.A(4, 0.3)[:3, :3], K.rot_x(0.3))


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**31))
def test_export_and_read_back_give_the_same_geometry(seed):
    from dataclasses import replace
    g = Mo.random_geometry(M.geometry, np.random.default_rng(seed))
    m = replace(M, geometry=g)
    doc = json.loads(json.dumps(su.export_machine(m)))
    g2 = su.geometry_from_su(doc, M)
    for f in ("base_joints", "platform_joints", "revolute_axes", "length_offsets"):
        assert np.max(np.abs(getattr(g2, f) - getattr(g, f))) < 1e-9, f
    assert abs(g2.tool_length - g.tool_length) < 1e-9 and abs(g2.z_table - g.z_table) < 1e-9
    assert np.allclose(g2.tool_tilt_deg, g.tool_tilt_deg, atol=1e-9)


def test_composing_a_chain_with_the_joint_values_of_a_pose_gives_that_pose():
    doc = su.export_machine(M)
    tip, axis = Mo.random_tool_poses(M, 1, np.random.default_rng(3))
    r = K.ik_batch(tip, axis, M)
    P, R = r.P[0], r.R[0]
    L = {lp["name"]: lp["links"] for lp in doc["loops"]}
    Tp = np.eye(4)
    Tp[:3, :3], Tp[:3, 3] = R, P
    for i in range(3):
        links = L[f"chain{i + 1}"]
        F1 = su.su_matrix(links[0]["su"])
        C = P + R @ M.geometry.platform_joints[i]
        d = np.linalg.inv(F1)[:3, :3] @ (C - M.geometry.base_joints[i])      # chain in the revolute frame
        phi = math.atan2(d[1], d[0])                                           # joint R value
        s = float(np.linalg.norm(d))                                           # joint P value
        F3 = F1 @ su.A(6, phi) @ su.su_matrix(links[1]["su"]) @ su.A(3, s) @ su.su_matrix(links[2]["su"])
        assert np.allclose(F3[:3, 3], C, atol=1e-9)
        assert abs(s - (r.q[0, i] + M.geometry.length_offsets[i])) < 1e-9
        T34 = su.su_matrix(links[3]["su"])
        Rs = F3[:3, :3].T @ R @ T34[:3, :3].T                                  # the spherical joint's turn
        S = np.eye(4)
        S[:3, :3] = Rs
        assert np.allclose(F3 @ S @ T34, Tp, atol=1e-9)
    # tool and table loops
    T_tool = Tp @ su.su_matrix(L["tool"][0]["su"])
    tl = L["table"]
    X, Y = r.q[0, 3], r.q[0, 4]
    W = su.su_matrix(tl[0]["su"]) @ su.A(3, Y) @ su.su_matrix(tl[1]["su"]) @ su.A(3, X) @ su.su_matrix(tl[2]["su"])
    assert np.allclose(np.linalg.inv(W)[:3, :3] @ T_tool[:3, 3] + np.linalg.inv(W)[:3, 3], tip[0], atol=1e-9)
    assert np.allclose(T_tool[:3, 2], axis[0], atol=1e-12)


def test_cli_export_import_round_trip_and_bad_input(tmp_path):
    cli = [sys.executable, "-m", "pmctl.interfaces.cli", "calibrate"]
    r = subprocess.run(cli + ["su-export", "--out", str(tmp_path / "m.json")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    r = subprocess.run(cli + ["su-import", str(tmp_path / "m.json"), "--out", str(tmp_path / "m.toml")],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    g = load_machine(tmp_path / "m.toml").geometry
    assert np.max(np.abs(g.base_joints - M.geometry.base_joints)) < 1e-9
    assert np.max(np.abs(g.platform_joints - M.geometry.platform_joints)) < 1e-9
    doc = json.loads((tmp_path / "m.json").read_text())
    doc["loops"][0]["links"][3]["su"]["a"] += 1.0
    with pytest.raises(InputError, match="does not close"):
        su.geometry_from_su(doc, M)
