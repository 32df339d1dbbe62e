"""CL data (seed 000 Fig. 7.10): parsing, checks with file:line, post-processing to actuator targets."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pmctl.core import kinematics as K
from pmctl.task.cldata import AXIS_TOL, cl_actuators, cl_job, parse_cl, read_cl, read_cl_job
from pmctl.core.config import load_machine
from pmctl.core.errors import InputError
from pmctl.task.job import load_job
from pmctl.core.job import LINE, RAPID

JOBS = Path(__file__).resolve().parents[2] / "examples" / "jobs"
GOOD = """Px,Py,Pz,Vx,Vy,Vz,flag
# a comment
0,0,50,0,0,1,s
5,0,50,0,0,1,w

10 0 50 0.1736481777 0 0.984807753 w
10,5,50,0,0,1,e
"""


@pytest.fixture(scope="module")
def machine():
    return load_machine()


def write(tmp_path, text, name="t.cl"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_bundled_hemisphere(machine):
    cl = read_cl(JOBS / "hemisphere.cl", machine)
    assert len(cl) > 300
    assert set(cl.flag.tolist()) == {"s", "w", "e"}
    assert np.count_nonzero(cl.flag == "s") == np.count_nonzero(cl.flag == "e") == 2
    assert cl.line[0] == 5                                  # after 3 comments and the header
    assert np.allclose(np.linalg.norm(cl.axis, axis=1), 1.0, atol=1e-12)
    tilt = np.degrees(np.arccos(cl.axis[:, 2]))
    assert tilt.max() <= 20.0 and tilt.max() > 10.0         # a real 5-axis job, inside the limit
    # the tool leans toward the bowl's centre line (the surface normal side)
    radial = cl.tip[:, :2] / np.linalg.norm(cl.tip[:, :2], axis=1, keepdims=True)
    assert np.all(np.sum(radial * cl.axis[:, :2], axis=1) < 0)


def test_post_processor_gives_actuator_targets_that_fk_maps_back(machine):
    cl = read_cl(JOBS / "hemisphere.cl", machine)
    q = cl_actuators(cl, machine)
    assert q.shape == (len(cl), 5)
    lo, hi = machine.limits.joint_lower, machine.limits.joint_upper
    assert np.all(q >= lo) and np.all(q <= hi)
    pose, ok = K.fk_batch(q[::37], machine)
    assert np.all(ok)
    assert np.allclose(pose.tip, cl.tip[::37], atol=1e-9)
    assert np.allclose(pose.axis, cl.axis[::37], atol=1e-12)


def test_parse_header_comments_blanks_and_separators():
    cl = parse_cl(GOOD, "g.cl")
    assert cl.line.tolist() == [3, 4, 6, 7]
    assert cl.flag.tolist() == ["s", "w", "w", "e"]
    assert np.allclose(cl.tip[2], [10, 0, 50])


def test_near_unit_vectors_are_normalised():
    cl = parse_cl("0,0,50,0,0,1.0005,s\n1,0,50,0,0,0.9995,e\n")
    assert np.allclose(np.linalg.norm(cl.axis, axis=1), 1.0, atol=1e-15)


def test_job_from_cl_passes(machine):
    cl = parse_cl(GOOD, "g.cl")
    job = cl_job(cl, machine, feed_mm_min=300, clearance_mm=4)
    kinds = [m.kind for m in job.moves]
    # approach above 's' (rapid), plunge, three cutting moves, retract after 'e'
    assert kinds == [RAPID, LINE, LINE, LINE, LINE, LINE]
    assert np.allclose(job.moves[0].tip, [0, 0, 54])
    assert np.allclose(job.moves[-1].tip, [10, 5, 54])
    assert all(m.feed == pytest.approx(5.0) for m in job.moves[1:])
    assert np.array_equal(job.points, cl.tip)
    assert [m.line for m in job.moves] == [3, 3, 4, 6, 7, 7]


@pytest.mark.parametrize("text,line,words", [
    ("0,0,50,0,0,1,s\n0,0,50,0,0,1\n", 2, "expected 7 fields"),
    ("0,0,50,0,0,1,s\n0,x,50,0,0,1,e\n", 2, "field 2 (Py)"),
    ("0,0,50,0,0,1,s\n0,0,nan,0,0,1,e\n", 2, "field 3 (Pz)"),
    ("0,0,50,0,0,1,s\n0,0,50,0,0,1,q\n", 2, "flag"),
    ("0,0,50,0,0,1.01,s\n", 1, "not a unit vector"),
    ("0,0,50,0,0,-1,s\n", 1, "points downward"),
    ("0,0,50,0,0,1,w\n", 1, "outside a pass"),
    ("0,0,50,0,0,1,s\n0,0,50,0,0,1,s\n", 2, "inside the pass"),
    ("\n0,0,50,0,0,1,s\n0,0,50,0,0,1,w\n", 2, "never ended"),
    ("Px,Py,Pz,Vx,Vy,Vz,flag\nPx,Py,Pz,Vx,Vy,Vz,flag\n", 2, "field 1"),
])
def test_malformed_lines_are_reported_with_their_line(tmp_path, machine, text, line, words):
    p = write(tmp_path, text)
    with pytest.raises(InputError) as e:
        read_cl(p, machine)
    assert e.value.line == line and e.value.path == str(p)
    assert words in e.value.reason, e.value.reason
    assert f"{p}:{line}" in str(e.value)


def test_empty_file_is_an_error(tmp_path, machine):
    with pytest.raises(InputError, match="no CL points"):
        read_cl(write(tmp_path, "# nothing\n"), machine)


def test_tilt_beyond_the_limit_and_unreachable_poses(tmp_path, machine):
    s25 = np.sin(np.radians(25))
    c25 = np.cos(np.radians(25))
    p = write(tmp_path, GOOD + f"0,0,50,{s25},0,{c25},s\n0,1,50,0,0,1,e\n")
    with pytest.raises(InputError) as e:
        read_cl_job(p, machine)
    assert e.value.line == 8 and "beyond the machine's theta2 limit 20" in e.value.reason
    p = write(tmp_path, GOOD + "0,0,50,0,0,1,s\n200,0,50,0,0,1,e\n")
    with pytest.raises(InputError) as e:
        read_cl_job(p, machine)
    assert e.value.line == 9 and "unreachable" in e.value.reason and "table X" in e.value.reason
    p = write(tmp_path, GOOD + "0,0,50,0,0,1,s\n0,0,400,0,0,1,e\n")
    with pytest.raises(InputError) as e:
        load_job(p, machine)
    assert e.value.line == 9 and "chain" in e.value.reason


def test_nothing_is_produced_from_a_file_with_one_bad_line_at_the_end(tmp_path, machine):
    text = (JOBS / "hemisphere.cl").read_text()
    n = text.count("\n")
    p = write(tmp_path, text + "1,2,3,0,0,1,x\n")
    with pytest.raises(InputError) as e:
        load_job(p, machine)
    assert e.value.line == n + 1


def test_approach_poses_are_checked_too(machine):
    # the 's' point is reachable, the approach point 'clearance' above it along the axis is not
    cl = parse_cl("0,0,50,0,0,1,s\n1,0,50,0,0,1,e\n", "c.cl")
    with pytest.raises(InputError) as e:
        cl_job(cl, machine, clearance_mm=2000.0)
    assert e.value.line == 1 and "unreachable" in e.value.reason


# Seed 000 Fig. 7.10, with its header and its data lines (the pass start added with the same rounding).
SEED_FIG_7_10 = """Px Py Pz Vx Vy Vz [s,w,e]
15,-26.04722665,60.27883705,0,-0.173648178,-0.984807753,s
15,-13.07336141,58.57079529,0,-0.087155743,-0.996194698,w
15,0,58,0,0,-1,w
15,13.07336141,58.57079529,0,0.087155743,-0.996194698,w
15,26.04722665,60.27883705,0,0.173648178,-0.984807753,w
15,38.82285677,63.11112606,0,0.258819045,-0.965925826,w
15,51.3030215,67.04610688,0,0.342020143,-0.939692621,e
"""


def test_seed_fig_7_10_data_reads_with_the_normal_convention(tmp_path, machine):
    p = write(tmp_path, SEED_FIG_7_10)
    with pytest.raises(InputError) as e:             # as a tool axis it points down
        read_cl(p, machine)
    assert e.value.line == 2 and "points downward" in e.value.reason
    cl = read_cl(p, machine, vector="normal")
    assert len(cl) == 7 and cl.line.tolist() == list(range(2, 9))
    assert np.allclose(cl.axis[2], [0, 0, 1]) and np.all(cl.axis[:, 2] > 0)
    # the points lie on a sphere (R 150 about (15, 0, 208)) and V is its radius direction
    centre = cl.tip + 150.0 * cl.axis
    assert np.allclose(centre, [15.0, 0.0, 208.0], atol=1e-6)
    # the last point's tilt (20 deg) is the machine's limit: still reachable, and post-processed
    q = cl_actuators(cl, machine)
    assert q.shape == (7, 5)
    assert load_job(p, machine, vector="normal").moves[0].kind == RAPID
    with pytest.raises(InputError, match="'axis' or 'normal'"):
        parse_cl(SEED_FIG_7_10, vector="down")


def test_unknown_suffix(tmp_path, machine):
    with pytest.raises(InputError, match="unknown job format"):
        load_job(write(tmp_path, GOOD, "t.xyz"), machine)


# ---------------------------------------------------------------- hypothesis

@st.composite
def cl_texts(draw):
    n = draw(st.integers(2, 12))
    rows = []
    for k in range(n):
        p = [draw(st.floats(-50, 50)), draw(st.floats(-50, 50)), draw(st.floats(0, 120))]
        tilt = np.radians(draw(st.floats(0, 19.9)))
        az = np.radians(draw(st.floats(0, 360)))
        v = [np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)]
        flag = "s" if k == 0 else ("e" if k == n - 1 else "w")
        rows.append((p, v, flag))
    sep = draw(st.sampled_from([",", " ", ", ", "\t"]))
    text = "\n".join(sep.join(repr(float(x)) for x in (*p, *v)) + sep + f for p, v, f in rows)
    return text, rows


@settings(max_examples=60, deadline=None)
@given(cl_texts())
def test_round_trip_of_generated_cl(data):
    text, rows = data
    cl = parse_cl(text)
    assert np.allclose(cl.tip, [r[0] for r in rows], rtol=0, atol=0)
    assert np.allclose(cl.axis, [r[1] for r in rows], atol=1e-15)
    assert cl.flag.tolist() == [r[2] for r in rows]
    assert cl.line.tolist() == list(range(1, len(rows) + 1))


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.text(max_size=120), st.text(alphabet="0123456789.,-+eswSWE \n\tnaifPx#", max_size=120)))
def test_junk_raises_only_input_error(text):
    try:
        cl = parse_cl(text, "j.cl")
    except InputError as e:
        assert e.path == "j.cl" and (e.line is None or 1 <= e.line <= text.count("\n") + 1)
    else:
        assert np.all(np.isfinite(cl.tip)) and np.allclose(np.linalg.norm(cl.axis, axis=1), 1.0)
        assert np.all(cl.axis[:, 2] > 0) and abs(np.linalg.norm(cl.axis[0]) - 1) <= AXIS_TOL
