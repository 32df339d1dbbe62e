"""Time-scaling in the loop (pmctl.motion.timescale): feed hold stops on the programmed path and
resumes it, overrides change the duration, joint accelerations stay within the limits through the
transitions, an empty queue decelerates along the path, and the loop's memory does not grow with
the job. All against the loopback sim with realtime=False."""

import tracemalloc

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pmctl import hal
from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.motion.loop import ControlLoop, prepare
from pmctl.motion.nc import NCParams, counts_of, initial_state
from pmctl.motion.recorder import REC_CAPACITY, REC_WIDTH, Recorder
from pmctl.motion.ring import Ring
from pmctl.motion.service_config import LoopConfig
from pmctl.motion.timescale import (FLAG_END, HELD, S_FLAGS, WIDTH, TimeScaler, backward_pass, iter_job_rows,
                                    make_follower)
from pmctl.task.gcode import parse_gcode
from pmctl.core.job import home_pose
from pmctl.task.planner import plan

M = load_machine()
DT = 1e-3
PROGRAM = """G21 G90
G1 F600 X10 Y0 Z{z}
G2 X0 Y10 I-10 J0
G1 X-8 Y4 Z{z2} A3
G3 X-2 Y-6 R7
"""


def planned(z=-30.0, feed=600):
    tip, axis = home_pose(M)
    text = PROGRAM.format(z=tip[2] - 6, z2=tip[2] - 4).replace("F600", f"F{feed}")
    job = parse_gcode(text, "t.ngc", tip, axis)
    return plan(job, M, DT, start=(tip, axis))


def run(traj, hook=None, keep=True):
    params = NCParams.from_machine(M, DT, kv=400.0)
    tg = prepare(M, params, traj, DT)
    c0 = counts_of(tg.q[0], params)
    be = hal.create("sim", M, DT, {})
    be.open(c0)
    ring = Ring(REC_CAPACITY, REC_WIDTH)
    lp = ControlLoop(M, be, params, tg, LoopConfig(realtime=False, stall_timeout_s=5.0), initial_state(M, c0),
                     log=lambda m: None, hook=hook, records=ring, recorder=Recorder(ring, keep=keep))
    return lp, lp.run(), be, c0, params


def dist_to_path(points, poly, near):
    """Distance of each point to the polyline ``poly`` (segments around index ``near``)."""
    out = np.empty(len(points))
    n = len(poly)
    for k, (p, i) in enumerate(zip(points, near)):
        lo, hi = max(0, int(i) - 5), min(n - 1, int(i) + 6)
        a, b = poly[lo:hi], poly[lo + 1:hi + 1]
        d = b - a
        L2 = np.maximum(np.sum(d * d, 1), 1e-30)
        u = np.clip(np.sum((p - a) * d, 1) / L2, 0, 1)
        out[k] = np.min(np.linalg.norm(a + u[:, None] * d - p, axis=1))
    return out


def truth_tip(res):
    return K.fk_batch(res.truth, M)[0].tip


def test_feed_hold_stops_on_the_path_and_resume_finishes_it():
    tr = planned()
    events = {}

    def hook(lp, k, st):
        f = lp.follower
        if k == 700:
            f.scaler.hold = True
        if f.scaler.hold and f.state == HELD and "held" not in events:
            events["held"] = k
        if "held" in events and k == events["held"] + 500:
            f.scaler.hold = False
        return st

    lp, res, be, c0, p = run(tr, hook)
    assert res.status == "done", res.reason
    held = events["held"]
    # sigma went to 0 and stayed there while held; the counters did not move while held
    assert res.sigma[held + 10:held + 400].max() == 0.0
    still = res.counts[held + 200:held + 480]
    assert np.abs(still - still[0]).max() <= 1          # at rest (the NC dithers by one pulse at most)
    # the tool (load side) stayed on the programmed path all the way, hold included
    d = dist_to_path(truth_tip(res), tr.tip, res.path_s)
    assert d.max() < 2e-3, d.max()
    # the whole path was run: the tool ends on the last programmed point
    assert np.linalg.norm(truth_tip(res)[-1] - tr.tip[-1]) < 1e-3
    assert abs(res.path_s[-1] - (len(tr) - 1)) < 1e-6
    assert res.ticks > len(tr) + 450          # the hold took time; nothing was skipped
    assert np.array_equal(c0 + res.pulses_sent, res.state.counts)
    assert np.array_equal(be.counts, res.state.counts)


def joint_accel_of_targets(res, params):
    q = K.ik_batch(res.target[:, :3], res.target[:, 3:6], M, check_limits=False).q
    return np.abs(np.diff(q, 2, axis=0)) / DT ** 2


def test_joint_accelerations_hold_through_hold_and_override_transitions():
    tr = planned(feed=1500)

    def hook(lp, k, st):
        sc = lp.follower.scaler
        if k == 400:
            sc.hold = True
        if k == 700:
            sc.hold = False
        if k == 900:
            sc.set_feed_override(2.0)
        if k == 1400:
            sc.set_feed_override(0.1)
        if k == 1700:
            sc.set_feed_override(1.0)
        return st

    lp, res, be, c0, p = run(tr, hook)
    assert res.status == "done", res.reason
    acc = joint_accel_of_targets(res, p)
    assert np.all(acc <= p.amax * 1.0 + 1.0), (acc.max(0), p.amax)
    d = dist_to_path(truth_tip(res), tr.tip, res.path_s)
    assert d.max() < 2e-3, d.max()


def test_feed_override_changes_the_duration():
    tr = planned(feed=300)
    ticks = {}
    for ov in (0.5, 1.0, 1.5):
        def hook(lp, k, st, ov=ov):
            if k == 1:
                lp.follower.scaler.set_feed_override(ov)
            return st
        lp, res, *_ = run(tr, hook)
        assert res.status == "done", res.reason
        ticks[ov] = res.ticks
    assert ticks[0.5] > 1.8 * ticks[1.0] - 200
    assert ticks[1.5] < 0.75 * ticks[1.0] + 200


@pytest.mark.parametrize("impl", ["compiled", "python"])
def test_an_empty_queue_decelerates_along_the_path_and_continues_when_fed(impl):
    tr = planned()
    params = NCParams.from_machine(M, DT, kv=400.0)
    rows = np.concatenate(list(iter_job_rows(tr, M, params, chunk=500)))
    assert int(rows[-1, S_FLAGS]) & FLAG_END
    ring = Ring(4000, WIDTH)
    fol = make_follower(ring, params, DT, implementation=impl)
    ring.push(rows[:900])
    poses, state, fed = [], [], 900
    for k in range(20000):
        if k == 2500:               # the planner catches up
            fed += ring.push(rows[fed:fed + 3000])
        if k > 2500 and fed < len(rows):
            fed += ring.push(rows[fed:fed + 50])
        tg = fol.next_target().copy()
        poses.append(tg)
        state.append(fol.state)
        if fol.at_end:
            break
    poses = np.array(poses)
    assert "starved" in fol.reason or "queue" in fol.reason
    q = K.ik_batch(poses[:, :3], poses[:, 3:6], M, check_limits=False).q
    assert np.all(np.abs(np.diff(q, 2, axis=0)) / DT ** 2 <= params.amax + 1.0)
    # every target lies on the programmed path (the starved wait included)
    idx = np.array([np.argmin(np.linalg.norm(tr.tip - p, axis=1)) for p in poses[::50, :3]])
    d = dist_to_path(poses[::50, :3], tr.tip, idx)
    assert d.max() < 1e-6
    assert np.allclose(poses[-1, :3], tr.tip[-1], atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(st.floats(0.0, 1.0), st.floats(0.0, 1.0), st.lists(st.floats(-50, 50), min_size=5, max_size=5),
       st.lists(st.floats(-2000, 2000), min_size=5, max_size=5))
def test_scaler_respects_rate_and_joint_acceleration_limits(f0, fgoal, qt, qtt):
    """From any sigma within the curvature cap (sigma^2 |q_tautau| <= amax) towards any goal within
    it, sigma reaches the goal with sigma' within its limit, and every joint's acceleration stays
    within its limit - except while sigma slows down from the cap itself (e.g. a feed hold at the
    cap, where any deceleration adds to the curvature term): then by no more than the tangential
    part |sigma' q_tau| at sigma's own limit."""
    params = NCParams.from_machine(M, DT)
    sc = TimeScaler(params, DT)
    amax = np.array(sc.amax)
    cap = min(2.0, float(np.sqrt(np.min(amax / np.maximum(np.abs(qtt), 1e-12)))))
    sc.sigma = f0 * cap
    goal = fgoal * cap
    prev = sc.sigma
    for _ in range(1500):
        s = sc.step(goal, qt, qtt)
        assert s >= 0.0
        ds = (s - prev) / DT
        assert abs(ds) <= sc.accel * (1 + 1e-9) + 1e-9
        if s > 0:
            acc = np.abs(ds * np.array(qt) + prev ** 2 * np.array(qtt))
            slowing = s < prev
            bound = amax + (sc.accel * np.abs(qt) if slowing else 0.0)
            # + the final snap onto the goal (|sigma - goal| < 1e-9 in one tick: sigma' <= 1e-6 /s)
            assert np.all(acc <= bound * (1 + 1e-9) + 1e-6 * (1 + np.abs(qt))), (acc, amax, slowing)
        prev = s
    assert abs(sc.sigma - goal) < 1e-6


def test_backward_pass_lets_sigma_come_down_in_time():
    cap = np.full(1000, 2.0)
    cap[700] = 0.3
    a = backward_pass(cap, DT, 5.0)
    assert abs(a[700] - 0.3) < 1e-12 and np.all(a <= cap + 1e-12)
    # d(sigma^2)/dtau >= -2 decel everywhere
    assert np.all(np.diff(a ** 2) / DT >= -2 * 5.0 - 1e-6)


def test_loop_memory_does_not_grow_with_the_job():
    """Records go through a fixed ring; the run's peak memory (records not kept) is the same for a
    job 5x longer."""
    tip, axis = home_pose(M)
    peaks = {}
    for n_loops in (1, 5):
        text = "G21 G90 G1 F1500\n" + "".join(f"X{10 * (i % 2)} Y{3 * (i % 3)}\n" for i in range(4 * n_loops))
        tr = plan(parse_gcode(text, "t.ngc", tip, axis), M, DT, start=(tip, axis))
        params = NCParams.from_machine(M, DT, kv=400.0)
        tg = prepare(M, params, tr, DT)
        c0 = counts_of(tg.q[0], params)
        be = hal.create("sim", M, DT, {})
        be.open(c0)
        ring = Ring(REC_CAPACITY, REC_WIDTH)
        lp = ControlLoop(M, be, params, tg, LoopConfig(realtime=False, stall_timeout_s=5.0),
                         initial_state(M, c0), log=lambda m: None, records=ring, recorder=Recorder(ring, keep=False))
        tracemalloc.start()
        res = lp.run()
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert res.status == "done", res.reason
        peaks[n_loops] = (peak, res.ticks, ring.nbytes)
    (p1, t1, b1), (p5, t5, b5) = peaks[1], peaks[5]
    assert t5 > 3 * t1
    assert b1 == b5                                   # ring size independent of the job
    assert p5 < 1.3 * p1 + 200_000, peaks            # no per-tick growth (360 B/tick would be +MBs)
