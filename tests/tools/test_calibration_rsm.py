"""The report's response-surface method: the statistics, the 22-parameter machine, Table 6.2."""

import subprocess
import sys

import numpy as np
from hypothesis import given, settings, strategies as st

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.tools.calibrate import identify as I, model as Mo, rsm
import pytest

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

M = load_machine()


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**31))
def test_quadratic_surface_is_recovered_exactly_and_adjusted_r2_follows_eq_5_14(seed):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1, 1, (20, 3))
    beta = rng.normal(0, 1, 10)
    y = rsm.quad_design(x) @ beta
    f = rsm.fit_quadratic(x, y + rng.normal(0, 1e-3, 20), np.ones(10, bool))
    assert np.max(np.abs(f.b - beta)) < 0.05
    yn = y + rng.normal(0, 0.3, 20)
    f = rsm.fit_quadratic(x, yn, np.ones(10, bool))
    X = rsm.quad_design(x)
    sse = np.sum((yn - X @ f.b) ** 2)
    syy = np.sum((yn - yn.mean()) ** 2)
    assert abs(f.r2_adj - (1 - (sse / (20 - 9 - 1)) / (syy / 19))) < 1e-12


def test_t_test_drops_the_terms_that_are_not_there():
    rng = np.random.default_rng(4)
    x = rng.uniform(-1, 1, (40, 3))
    beta = np.array([1.0, 2.0, 0, 0, 0, 0, 0, 3.0, 0, 0])          # 1 + 2a + 3a^2
    y = rsm.quad_design(x) @ beta + rng.normal(0, 0.01, 40)
    keep = rsm.t_prune(rsm.fit_quadratic(x, y, np.ones(10, bool)), 40)
    assert keep[[0, 1, 7]].all() and keep.sum() <= 5


def test_d_optimal_design_beats_random_designs():
    rng = np.random.default_rng(5)
    cand = rsm.region_grid(((-1, 1), (-1, 1), (-1, 1)))
    idx, ld = rsm.d_optimal_design(cand, 20, np.ones(10, bool), rng)
    assert len(set(idx.tolist())) == 20
    X = rsm.quad_design(cand)
    for _ in range(20):
        r = rng.choice(len(cand), 20, replace=False)
        assert np.linalg.slogdet(X[r].T @ X[r])[1] < ld


def test_seed_machine_without_errors_is_the_nominal_machine_and_pmctl_model_covers_it():
    sm = rsm.SeedMachine(M, {})
    tip, axis, q = rsm.spatial_pose(M, [170.0, 200.0], [20.0, 120.0], [-3.0, 4.0])
    t, a = sm.tool(q)
    assert np.max(np.abs(t - tip)) < 1e-9 and np.max(np.abs(a - axis)) < 1e-12
    # without the normal offsets SL, CL the report's machine is exactly a pmctl geometry
    rng = np.random.default_rng(2)
    errs = {k: float(rng.uniform(-0.5, 0.5)) for k in rsm.SEED_PARAMS if not k.startswith(("SL", "CL"))}
    sm = rsm.SeedMachine(M, errs)
    tips, axes = Mo.random_tool_poses(M, 40, rng)
    q = K.ik_batch(tips, axes, M).q
    mt, ma = sm.tool(q)
    res = I.identify(q, mt, ma, M.geometry, max_sigma=1e9)
    assert res.tip_max_um < 1e-3
    # with SL + CL the joint distance is sqrt((L+BL)^2 + e^2): not in the 30-parameter model,
    # but within a micrometre of it
    sm2 = rsm.SeedMachine(M, {**errs, "SL1": 0.5, "CL1": 0.5, "SL2": -0.5})
    mt2, ma2 = sm2.tool(q)
    res2 = I.identify(q, mt2, ma2, M.geometry, max_sigma=1e9)
    assert 1e-3 < res2.tip_max_um < 1.0


def test_table_6_2_rsm_calibrates_and_identification_does_better_on_the_same_poses():
    sm = rsm.SeedMachine.random(M, np.random.default_rng(3))
    t = rsm.table_6_2(sm, np.random.default_rng(1), region=rsm.SMALL_REGION)
    e0 = np.abs(t["before"] - t["target"])
    e_rsm = np.abs(t["rsm"] - t["target"])
    e_id = np.abs(t["identification"] - t["target"])
    assert e0[1] > 0.5                          # theta1 off by degrees before
    assert np.all(e_rsm < 0.1 * e0)             # RSM: more than 10x better
    assert t["identification_axis_deg"] < 0.1 * t["rsm_axis_deg"]
    assert np.all(e_id[[0, 2]] <= e_rsm[[0, 2]] + 1e-6)


def test_rsm_cli_prints_the_tables():
    r = subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", "calibrate", "rsm"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "Table 5.2" in r.stdout and "Table 6.2" in r.stdout and "199.9795" in r.stdout
    assert r.stdout.count("\n     4 ") == 3                         # region 4: dx, dy, dz
