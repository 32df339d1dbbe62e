"""Nominal twin facts: it reproduces its own recordings, static strain obeys virtual work, loads."""

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pmctl.core import kinematics as K
from pmctl.core import statics as S
from pmctl.core.config import load_machine
from pmctl.core.recording import read_recording, write_recording
from pmctl.tools.twin import nominal as N

M = load_machine()
G = M.geometry
MG = M.mass.platform_kg * M.mass.gravity


def _trajectory(n=3000, rate=1000.0):
    t = np.arange(n) / rate
    tip = np.stack([40 * np.sin(1.1 * t), 30 * np.cos(0.7 * t), 10 + 5 * np.sin(0.5 * t)], -1)
    axis = K.tilt_to_axis(np.pi / 2 + 0.8 * np.sin(0.3 * t), np.radians(15) * np.sin(0.9 * t))
    r = K.ik_batch(tip, axis, M)
    assert r.ok.all()
    return t, r.q, tip, axis


def test_twin_reproduces_a_recording_it_generated(tmp_path):
    t, q, tip, axis = _trajectory()
    cols = {"t": t}
    for j, a in enumerate(("L1", "L2", "L3", "X", "Y")):
        cols[f"cmd_{a}"] = q[:, j]
        cols[f"enc_{a}"] = q[:, j]
    rng = np.random.default_rng(1)
    load = rng.normal(0, 50, (len(t), 3))
    for j, c in enumerate(("load_fx", "load_fy", "load_fz")):
        cols[c] = load[:, j]
    pred = N.predict_columns(cols, M, channels="all")
    assert np.allclose(pred["tip_x"], tip[:, 0], atol=1e-9)
    assert np.allclose(np.stack([pred["tool_i"], pred["tool_j"], pred["tool_k"]], -1), axis, atol=1e-12)
    cols.update(pred)
    tracker = np.arange(len(t)) % 10 != 0          # a 100 Hz tracker in a 1 kHz log
    for c in ("tip_x", "tip_y", "tip_z", "tool_i", "tool_j", "tool_k"):
        cols[c] = np.where(tracker, np.nan, cols[c])
    write_recording(tmp_path / "r", cols, sample_rate_hz=1000, exact=True)
    rec = read_recording(tmp_path / "r")
    res = N.residuals(rec)
    assert set(res) == set(N.PREDICTABLE)
    for c, r in res.items():
        assert np.nanmax(np.abs(r)) < 1e-9, c
        assert np.array_equal(np.isnan(r), np.isnan(rec[c])), c


def test_home_strain_is_weight_over_three_chains():
    P, R = K.platform_pose(G.z_home, np.pi, 0.0, G.platform_radius)
    C = K.joint_positions(P, R, G)
    u = (C - G.base_joints) / np.linalg.norm(C - G.base_joints, axis=-1, keepdims=True)
    f = S.chain_forces(P, R, M)
    expect = MG / 3 / u[:, 2]                      # ≈ 81.8 N compression each
    assert np.allclose(f.axial, expect, rtol=1e-12)
    assert np.allclose(f.lateral, 0.0, atol=1e-9)
    eps = S.static_strain(P, R, M)
    assert np.allclose(eps, -0.5 * expect) and np.all(eps < -40.0)


def test_downward_tip_load_adds_compression_upward_relieves():
    P, R = K.platform_pose(G.z_home, np.pi, 0.0, G.platform_radius)
    e0 = S.static_strain(P, R, M)
    down = S.static_strain(P, R, M, tip_force=[0, 0, -100.0])
    up = S.static_strain(P, R, M, tip_force=[0, 0, +100.0])
    assert np.all(down < e0) and np.all(up > e0)
    assert np.allclose(down - e0, e0 - up)                  # linear in the load
    assert np.allclose(down - e0, -0.5 * 100 / 3 / np.cos(np.arctan(14 / 393.0)), rtol=1e-3)
    # a sideways push along +x at the tip, 100 mm below P: the chains share it unequally,
    # and the total still balances
    side = S.chain_forces(P, R, M, tip_force=[100.0, 0, 0])
    assert np.ptp(side.axial) > 1.0


poses = st.tuples(st.floats(280, 480), st.floats(0.05, math.pi), st.floats(-0.33, 0.33))
forces = st.lists(st.floats(-500, 500), min_size=3, max_size=3)


@settings(max_examples=60, deadline=None)
@given(poses, forces)
def test_chain_forces_obey_virtual_work(pose, fl):
    """Σ a_i δL_i + F_g·δ(com) + F_load·δ(tip) = 0 for any motion of the mechanism (FK only)."""
    P, R = K.platform_pose(*pose, G.platform_radius)
    L = K.chain_lengths(P, R, G)
    f = S.chain_forces(P, R, M, tip_force=fl)
    fg = np.array([0, 0, -MG])
    h = 1e-4
    for k in range(3):
        dL = np.zeros(3)
        dL[k] = h
        Pp, Rp = K.forward_platform(L + dL, G, guess=(P, R))
        Pm, Rm = K.forward_platform(L - dL, G, guess=(P, R))
        dcom = (Pp + Rp @ M.mass.com_offset - Pm - Rm @ M.mass.com_offset) / (2 * h)
        dtip = (Pp + Rp @ G.tool_tip_p - Pm - Rm @ G.tool_tip_p) / (2 * h)
        work = f.axial[k] + fg @ dcom + np.asarray(fl) @ dtip
        assert abs(work) < 1e-5 * (MG + np.abs(fl).sum()), (k, work)


def test_enc_overrides_cmd_cell_by_cell_and_nan_propagates():
    t, q, tip, axis = _trajectory(200)
    cols = {"t": t, **{f"cmd_{a}": q[:, j].copy() for j, a in enumerate(("L1", "L2", "L3", "X", "Y"))}}
    enc_x = q[:, 3] + 0.01
    enc_x[::2] = np.nan
    cols["enc_X"] = enc_x
    cols["cmd_L2"][50] = np.nan
    cols["tip_x"] = np.zeros(len(t))
    pred = N.predict_columns(cols, M)
    assert set(pred) == {"enc_X", "tip_x"}
    assert np.array_equal(pred["enc_X"], q[:, 3])
    # table at enc_X where sampled: the tip in W moves by -0.01 mm there
    d = pred["tip_x"] - tip[:, 0]
    odd, even = np.arange(1, len(t), 2), np.arange(0, len(t), 2)
    even = even[even != 50]
    assert np.allclose(d[odd], -0.01, atol=1e-9)
    assert np.allclose(d[even], 0.0, atol=1e-9)
    assert np.isnan(pred["tip_x"][50]) and np.sum(np.isnan(pred["tip_x"])) == 1


@pytest.mark.parametrize("load", [None, [30.0, -20.0, -150.0]])
def test_strain_prediction_matches_statics_along_a_path(load):
    t, q, tip, axis = _trajectory(500)
    cols = {"t": t, **{f"cmd_{a}": q[:, j] for j, a in enumerate(("L1", "L2", "L3", "X", "Y"))},
            "strain_1": np.zeros(len(t)), "strain_2": np.zeros(len(t)), "strain_3": np.zeros(len(t))}
    if load is not None:
        for c, v in zip(("load_fx", "load_fy", "load_fz"), load):
            col = np.full(len(t), np.nan)
            col[::50] = v                             # sampled slowly: held between samples
            cols[c] = col
    st_ = N.nominal_state(cols, M)
    pred = N.predict_columns(cols, M, state=st_)
    eps = S.static_strain(st_.P, st_.R, M, tip_force=load)
    assert np.allclose(np.stack([pred[f"strain_{i}"] for i in (1, 2, 3)], -1), eps, atol=1e-9)
    # vertical force balance: Σ a_i u_iz + b_i n_iz = m g - F_z
    C = K.joint_positions(st_.P, st_.R, G)
    u = (C - G.base_joints) / np.linalg.norm(C - G.base_joints, axis=-1, keepdims=True)
    fz = 0.0 if load is None else load[2]
    assert np.allclose((st_.axial * u[..., 2]).sum(-1), MG - fz, rtol=1e-9)
