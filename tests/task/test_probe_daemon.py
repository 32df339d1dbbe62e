"""Probing through the daemon's machinery without the console: Supervisor.submit of a job with probing
moves (the contract `pmctl run` as a client relies on), and the pieces that carry a probe between the
supervisor and the rt process (the probe table row, the status block's result, the job's pieces)."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.motion import channel as C
from pmctl.motion.nc import counts_of
from pmctl.motion.probe import GRID, RESULT_WIDTH, SEGMENT_WIDTH, ProbeResult, ProbeSegment, split_at_probes
from pmctl.task.gcode import parse_gcode
from pmctl.core.job import home_pose
from pmctl.task.supervisor import Supervisor
import pytest

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

M = load_machine("prototype")
HOME_Z = float(home_pose(M)[0][2])
ZC = HOME_Z - 1.0
fin = st.floats(-1e3, 1e3, allow_nan=False)


@given(st.integers(1, 10**6), st.sampled_from([2, 3]), st.lists(fin, min_size=10, max_size=10),
       st.floats(0.01, 10), st.integers(2, GRID))
def test_a_probe_segment_survives_the_probe_table(line, mode, v, feed, n):
    seg = ProbeSegment(line, mode, np.array(v[:3]), np.array(v[3:6]), np.array(v[6:9]), feed,
                       list(np.linspace(0, abs(v[9]), n)), [[v[0] + i, v[1], v[2] - i] for i in range(n)])
    row = seg.to_row()
    assert len(row) == SEGMENT_WIDTH == C.PROBE_TABLE_WIDTH - 1
    back = ProbeSegment.from_row(np.array(row))
    assert (back.line, back.mode, back.feed) == (line, mode, feed)
    for a in ("start", "end", "axis"):
        assert np.array_equal(getattr(back, a), getattr(seg, a))
    assert back.grid_s == seg.grid_s and np.array_equal(back.grid_strain, seg.grid_strain)


@given(st.integers(1, 10**6), st.sampled_from([2, 3]), st.booleans(), st.lists(fin, min_size=12, max_size=12),
       st.integers(-1, 10**7), st.one_of(st.none(), st.tuples(*[st.integers(-2**40, 2**40)] * 5)))
def test_a_probe_result_survives_the_status_block(line, mode, contact, v, tick, counts):
    r = ProbeResult(line, mode, contact, np.array(v[:3]), (v[3], v[4]), np.array(v[5:8]), tick, v[8], v[9], v[10],
                    v[11], 0.5, "", counts)
    if mode == 2 and not contact:
        from pmctl.motion.probe import probe_fail_text
        r.error = probe_fail_text(line)
    row = r.to_row()
    assert len(row) == RESULT_WIDTH == C.PROBE_RESULT_WIDTH
    b = ProbeResult.from_row(np.array(row))
    assert b.as_dict() == r.as_dict() and b.prb() == r.prb()
    assert bool(b.error) == (mode == 2 and not contact)


def test_a_job_is_cut_into_pieces_at_each_probe():
    t, a = home_pose(M)
    job = parse_gcode(f"G21 G90\nG0 Z{HOME_Z - 0.5}\nG4 P0.1\nG38.2 Z{HOME_Z - 2} F60\nG38.3 Z{HOME_Z - 3} F60\n"
                      f"G0 Z{HOME_Z}\nG1 X1 F300\nG38.3 X2 F60\nG4 P0.2\n", "p.ngc", t, a)
    pieces = split_at_probes(job)
    lines = [[m.line for m in p.moves] for p, _ in pieces]
    assert lines == [[2, 3], [4], [5], [6, 7], [8], [9]]
    assert [pr.probe if pr is not None else 0 for _, pr in pieces] == [0, 2, 3, 0, 3, 0]
    assert [m for p, _ in pieces for m in p.moves] == list(job.moves)     # nothing lost, nothing twice
    assert len(split_at_probes(parse_gcode("G1 X1 F60\nG1 X2\n", "p.ngc", t, a))) == 1


def test_supervisor_submit_stops_on_contact_and_plans_the_rest_from_the_stop(tmp_path):
    svc = tmp_path / "service.toml"
    svc.write_text('[loop]\nrate_hz = 1000\nstall_timeout_ms = 5000\nmax_overruns_in_row = 100000\nstate_file = ""\n'
                   '[nc]\nk_theta_per_s = 200\n[hal]\nbackend = "sim"\n[hal.sim]\nflex = true\n'
                   f'strain_noise_ue = 0.01\ncontact_z_mm = {ZC}\ncontact_stiffness_N_per_mm = 2000\n')
    sup = Supervisor("prototype", service=str(svc), backend="sim")
    t, a = home_pose(M)
    c0 = counts_of(K.ik(t, a, M).q, sup.params)
    sup.start(c0)
    try:
        # G38.3 away from the surface (no contact: on to the next line), then G38.2 onto it, then away
        job = parse_gcode(f"G21 G90\nG38.3 Z{HOME_Z + 0.1:.4f} F120\nG0 Z{ZC + 0.12:.4f}\n"
                          f"G38.2 Z{ZC - 1:.4f} F60\nG0 Z{ZC + 1:.4f}\nG1 X0.5 F300\n", "p.ngc", t, a)
        it = sup.submit(job, name="p.ngc")
        after = sup.submit(parse_gcode(f"G0 X0 Z{HOME_Z:.4f}\n", "q.ngc", t, a), name="q.ngc")
        assert sup.wait_idle(300) and not sup.alarm, sup.alarm_msg
        assert it.parts == 4 and it.ends == 4 and it not in sup.items and after not in sup.items
        miss, hit = it.probe_results
        assert (miss.mode, miss.contact, miss.error, miss.line) == (3, False, "", 2)
        assert abs(miss.stop[2] - (HOME_Z + 0.1)) < 1e-9 and miss.prb().endswith(":0]")
        assert (hit.mode, hit.contact, hit.error, hit.line) == (2, True, "", 4)
        assert abs(hit.point[2] - ZC) < 3e-3 and 0 < hit.after_trigger_mm <= hit.bound_mm
        assert hit.overtravel_mm > 0 and hit.stop[2] < ZC and hit.prb().endswith(":1]")
        ppm = M.resolution.pulses_per_mm
        stop_q = np.asarray(hit.counts) / ppm                     # the counters at rest after the probe
        assert np.linalg.norm(K.fk(stop_q, M).tip - hit.stop) < 2e-3
        s = sup.raw()
        assert np.array_equal(s[C.ST_COUNTS:C.ST_COUNTS + 5], s[C.ST_COUNTS0:C.ST_COUNTS0 + 5] + s[C.ST_SENT:C.ST_SENT + 5])
        tip, _ = sup.pose()
        assert np.allclose(tip, [0.0, 0.0, HOME_Z], atol=2e-3)   # the queue after it ran to its end
    finally:
        sup.shutdown()
