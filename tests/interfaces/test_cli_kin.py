"""`pmctl kin` from the outside: JSON on stdout, one clear line on stderr for errors."""

import json
import subprocess
import sys

import numpy as np

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
import pytest

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow


def pmctl(*args):
    return subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", *args], capture_output=True, text=True)


def test_ik_then_fk_round_trip_through_the_cli():
    v = K.tilt_to_axis(2.0, 0.2)
    r = pmctl("kin", "ik", "--tip", "5,-7,160", "--axis", ",".join(repr(float(x)) for x in v), "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert set(out) == {"L", "table", "Z", "theta1_deg", "theta2_deg"}
    assert abs(out["theta1_deg"] - np.degrees(2.0)) < 1e-9 and abs(out["theta2_deg"] - np.degrees(0.2)) < 1e-9
    joints = ",".join(repr(x) for x in out["L"] + out["table"])
    f = json.loads(pmctl("kin", "fk", "--joints", joints, "--json").stdout)
    assert np.allclose(f["tip"], [5, -7, 160], atol=1e-9) and np.allclose(f["axis"], v, atol=1e-12)
    assert abs(f["Z"] - out["Z"]) < 1e-9


def test_home_pose():
    f = json.loads(pmctl("kin", "ik", "--tip", "0,0,173", "--axis", "0,0,1", "--json").stdout)
    m = load_machine()
    assert np.allclose(f["L"], K.chain_lengths(*K.platform_pose(393.0, 1.0, 0.0, 316.0), m.geometry), atol=1e-9)
    assert f["table"] == [0.0, 0.0] and f["theta1_deg"] == 180.0 and f["theta2_deg"] == 0.0


def test_errors_are_one_line_and_nonzero():
    for args in (["kin", "ik", "--tip", "0,0", "--axis", "0,0,1"],
                 ["kin", "ik", "--tip", "0,0,900", "--axis", "0,0,1"],
                 ["kin", "fk", "--joints", "100,900,100,0,0"],
                 ["kin", "ik", "--tip", "0,0,150", "--axis", "0,0,1", "--config", "/nonexistent.toml"]):
        r = pmctl(*args)
        assert r.returncode != 0 and r.stdout == ""
        assert len(r.stderr.strip().splitlines()) == 1 and r.stderr.startswith("pmctl: error:"), r.stderr


def test_negative_values_after_a_space_are_values_not_options():
    a = json.loads(pmctl("kin", "ik", "--tip", "-5,0,173", "--axis", "-0.1,0.2,0.97468", "--json").stdout)
    b = json.loads(pmctl("kin", "ik", "--tip=-5,0,173", "--axis=-0.1,0.2,0.97468", "--json").stdout)
    assert a == b and a["table"][0] > 0


def test_fk_applies_the_same_limits_as_ik():
    """A pose IK refuses must not come back from FK as if it were fine."""
    for joints, limit in (("303.853239,303.853239,483.534067,-22.478303,12.977854", "theta2 = 22.0"),
                          ("62.6,208.5,208.5,0,0", "chain L1 = 62.6"),
                          ("393.249,393.249,393.249,80,0", "table X = 80")):
        r = pmctl("kin", "fk", "--joints", joints)
        assert r.returncode == 1 and limit in r.stderr, r.stderr


def test_rounded_axis_is_normalised():
    r = json.loads(pmctl("kin", "ik", "--tip", "1,2,150", "--axis", "0.1,0.2,0.975", "--json").stdout)
    f = json.loads(pmctl("kin", "fk", "--joints", ",".join(map(repr, r["L"] + r["table"])), "--json").stdout)
    v = np.array([0.1, 0.2, 0.975])
    assert np.allclose(f["axis"], v / np.linalg.norm(v), atol=1e-12)
