"""The twin's geometry findings become a calibrated config through the calibration machinery."""

import json
import subprocess
import sys

import numpy as np
import pytest

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.errors import InputError
from pmctl.tools.calibrate import model as Mo, twin_link
from pmctl.tools.twin import effects, synth

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

M = load_machine()


def report(*findings):
    return {"recording": "r", "verdict": "unmodelled physics found",
            "findings": [{"effect": "backlash", "axis": "X", "parameters": {"width_mm": 0.01}}, *findings]}


def test_findings_like_the_twin_reports_give_the_geometry_the_twin_simulates(tmp_path):
    """The synthesiser's true machine for geometry effects == the machine built from the findings."""
    effs = [synth.Effect("geometry", {"chain": 2}, {"length_offset_mm": 0.08}),
            synth.Effect("geometry", {"chain": 3}, {"base_joint_radial_mm": -0.12, "base_joint_z_mm": 0.05}),
            synth.Effect("geometry", {"chain": "tool"}, {"tool_length_mm": 0.15})]
    true_m = synth._true_machine(M, effs)
    rep = report(*({"effect": e.effect, "chain": e.locator["chain"], "parameters": e.parameters} for e in effs))
    m = twin_link.write_calibrated(M, rep, tmp_path / "twin.toml")
    for f in ("base_joints", "platform_joints", "length_offsets"):
        assert np.allclose(getattr(m.geometry, f), getattr(true_m.geometry, f), atol=1e-12, rtol=0)
    assert abs(m.geometry.tool_length - true_m.geometry.tool_length) < 1e-12
    # and IK through the written config puts the tool where it is wanted on that machine
    tips, axes = Mo.random_tool_poses(M, 20, np.random.default_rng(1))
    e_tip, e_ax = Mo.tool_errors(tips, axes, K.ik_batch(tips, axes, m).q, true_m.geometry)
    assert e_tip.max() < 1e-9 and e_ax.max() < 1e-12
    e0, _ = Mo.tool_errors(tips, axes, K.ik_batch(tips, axes, M).q, true_m.geometry)
    assert e0.max() > 0.05


def test_every_group_of_the_twin_effect_model_maps_with_its_sensitivity():
    """A small finding in each of the twin's parameter groups moves the tool as the twin's own
    sensitivity (effects.geometry_sensitivity) says, so the two parameterisations agree."""
    tips, axes = Mo.random_tool_poses(M, 5, np.random.default_rng(2))
    q = K.ik_batch(tips, axes, M).q
    pr = Mo.predict(q, M.geometry)
    sens = effects.geometry_sensitivity(pr.P, pr.R, M.geometry)
    h = 1e-4
    for group, S in sens.items():
        who, what = group.split(":")
        names = effects.Geometry.NAMES[what]
        k = S.shape[-1]
        for j in range(k):
            vec = np.zeros(k)
            vec[j] = h
            if len(names) == k:
                params = dict(zip(names, vec.tolist()))
            else:
                params = {names[0]: vec.tolist()}
            chain = int(who[5:]) if who.startswith("chain") else "tool"
            m = twin_link.apply_findings(M, [{"effect": "geometry", "chain": chain, "parameters": params}])
            moved = Mo.predict(q, m.geometry, (pr.P, pr.R))
            d = np.concatenate([moved.tip - pr.tip, moved.axis - pr.axis], 1) / h
            assert np.max(np.abs(d - S[..., j])) < 1e-4, (group, j)


def test_unknown_parameters_are_refused_and_nothing_is_written(tmp_path):
    with pytest.raises(InputError, match="unknown chain parameter"):
        twin_link.write_calibrated(M, report({"effect": "geometry", "chain": 1, "parameters": {"bogus_mm": 1}}),
                                   tmp_path / "x.toml")
    with pytest.raises(InputError, match="chain must be"):
        twin_link.geometry_dp(M, [{"effect": "geometry", "chain": 7, "parameters": {"length_offset_mm": 1}}])
    assert not (tmp_path / "x.toml").exists()


def test_from_twin_cli(tmp_path):
    rp = tmp_path / "report.json"
    rp.write_text(json.dumps(report({"effect": "geometry", "chain": 1, "parameters": {"length_offset_mm": 0.1}})))
    r = subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", "calibrate", "from-twin", str(rp),
                        "--out", str(tmp_path / "c.toml")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "1 geometry finding" in r.stdout
    assert load_machine(tmp_path / "c.toml").geometry.length_offsets.tolist() == [0.1, 0.0, 0.0]


def test_from_twin_leaves_out_a_geometry_finding_that_has_look_alikes(tmp_path):
    """A length offset the recording could not tell from a backlash (docs/diagnosis-report.md,
    "Look-alikes") is not applied: the written config keeps that leg's length, and says why."""
    alike = {"effect": "geometry", "chain": 2, "parameters": {"length_offset_mm": 0.011},
             "alternatives": [{"effect": "backlash", "axis": "L2", "parameters": {"width_mm": 0.022}, "weight": 2.0}],
             "separate_by": "a run that reverses the axis"}
    rp = tmp_path / "report.json"
    rp.write_text(json.dumps(report({"effect": "geometry", "chain": 1, "parameters": {"length_offset_mm": 0.1}},
                                    alike)))
    r = subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", "calibrate", "from-twin", str(rp),
                        "--out", str(tmp_path / "c.toml")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "applied 1 geometry finding" in r.stdout and "not applied: the geometry finding for chain 2" in r.stdout
    assert "backlash" in r.stdout and "reverses the axis" in r.stdout
    assert load_machine(tmp_path / "c.toml").geometry.length_offsets.tolist() == [0.1, 0.0, 0.0]
