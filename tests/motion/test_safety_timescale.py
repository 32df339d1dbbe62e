"""The time-scaling's limits (pmctl.motion.timescale) pinned at their boundaries: sigma's own rate and
jerk limits from the joint limits, the per-sample caps (joint speed, joint acceleration from the
path's curvature, tool-tip speed, SIGMA_MAX), the backward pass that lowers sigma ahead of a
tighter point, the feed override's range, and the follower's hold, starvation and job-end rules.

These functions are shared by both path followers (the compiled one takes its rows, caps and
limits from them), so the tick-for-tick comparison of tests/motion/test_follow.py cannot see a change in
them: each test here asserts the physical fact itself, and the follower's rules are checked in both
followers. All offline ticks, but the last test: jobs queued behind a job of one sample, through the
supervisor and its rt process on the sim (the follower once stepped over such a job's end uncounted,
and the supervisor, which retires its items by that count, kept the last one queued).
"""

import math
import time
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import assume, example, given, settings, strategies as st

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.job import home_pose
from pmctl.motion.nc import NCParams, counts_of
from pmctl.motion.ring import ArraySource, Ring
from pmctl.motion.timescale import (FEED_OVERRIDE_RANGE, FLAG_END, HELD, HOLDING, IDLE, JOINT_SHARE, MOVING,
                                    S_AXIS, S_CAP, S_FLAGS, S_LINE, S_QT, SIGMA_MAX, STARVED, WIDTH,
                                    CompiledFollower, TimeScaler, backward_pass, iter_job_rows, make_follower,
                                    sample_caps, scaling_limits)
from pmctl.task.gcode import parse_gcode
from pmctl.task.planner import plan
from pmctl.task.supervisor import Supervisor
from service_support import service_toml

M = load_machine()
DT = 1e-3
PARAMS = NCParams.from_machine(M, DT)

limits5 = st.lists(st.floats(1.0, 5000.0), min_size=5, max_size=5)


@settings(max_examples=60, deadline=None)
@given(vmax=limits5, amax=limits5)
@example(vmax=[100.0] * 5, amax=[2000.0] * 5)
def test_sigmas_rate_limit_accelerates_the_fastest_joint_at_045_of_its_limit(vmax, amax):
    """accel: at sigma' = accel, a joint at its speed limit accelerates at 45 % of its acceleration
    limit for the tightest joint (and at most that for the others); jerk: accel is reached in 50 ms."""
    p = replace(PARAMS, vmax=np.array(vmax), amax=np.array(amax))
    accel, jerk = scaling_limits(p)
    share = accel * np.array(vmax) / np.array(amax)
    assert np.all(share <= 0.45 * (1 + 1e-12)) and abs(share.max() - 0.45) < 1e-12
    assert abs(accel / jerk - 0.05) < 1e-15
    assert isinstance(accel, float)



@settings(max_examples=150, deadline=None)
@given(qt=st.lists(st.floats(-300, 300), min_size=5, max_size=5),
       qtt=st.lists(st.floats(-1e5, 1e5), min_size=5, max_size=5),
       tip=st.lists(st.floats(-300, 300), min_size=3, max_size=3),
       rapid=st.floats(0.01, 200.0), vmax=limits5, amax=limits5)
@example(qt=[0.0] * 5, qtt=[0.0] * 5, tip=[0.0] * 3, rapid=50.0, vmax=[100.0] * 5, amax=[2000.0] * 5)
@example(qt=[0.5, 0, 0, 0, 0], qtt=[0.0] * 5, tip=[0.3, 0, 0], rapid=0.5, vmax=[1.0] * 5, amax=[1.0] * 5)
@example(qt=[0.0] * 5, qtt=[0.0] * 5, tip=[0.0] * 3, rapid=1.0, vmax=[1.0] * 5, amax=[1.0] * 5)
@example(qt=[0.0] * 5, qtt=[0.5, 0, 0, 0, 0], tip=[0.0] * 3, rapid=50.0, vmax=[100.0] * 5, amax=[1.0] * 5)
def test_a_samples_cap_is_the_fastest_sigma_within_every_limit(qt, qtt, tip, rapid, vmax, amax):
    """The cap is the largest sigma <= SIGMA_MAX with every joint's speed sigma |q_tau| within 95 % of
    its limit, every joint's curvature acceleration sigma^2 |q_tautau| within 95 % of its limit, and
    the tip's speed sigma |tip_tau| within the rapid speed: all hold at the cap and one of them (or
    SIGMA_MAX) binds there."""
    p = replace(PARAMS, vmax=np.array(vmax), amax=np.array(amax))
    qt, qtt, tip = (np.array(x)[None] for x in (qt, qtt, tip))
    cap = sample_caps(qt, qtt, tip, p, rapid)
    assert cap.shape == (1,)
    c = float(cap[0])
    vm, am = JOINT_SHARE * np.array(vmax), JOINT_SHARE * np.array(amax)
    speed, curv, tipv = c * np.abs(qt[0]), c * c * np.abs(qtt[0]), c * np.linalg.norm(tip[0])
    eps = 1e-9
    assert 0.0 < c <= SIGMA_MAX
    assert np.all(speed <= vm * (1 + eps)) and np.all(curv <= am * (1 + eps)) and tipv <= rapid * (1 + eps)
    binds = (c == SIGMA_MAX or np.any(speed >= vm * (1 - eps)) or np.any(curv >= am * (1 - eps))
             or tipv >= rapid * (1 - eps))
    assert binds, (c, speed / vm, curv / am, tipv / rapid)


def test_sample_caps_of_many_samples_are_each_samples_own():
    """Caps of a stack of samples: each row's cap is that row's alone (the minimum is over the joints
    of a sample, never across samples)."""
    rng = np.random.default_rng(3)
    qt, qtt, tip = rng.normal(0, 60, (40, 5)), rng.normal(0, 3000, (40, 5)), rng.normal(0, 60, (40, 3))
    caps = sample_caps(qt, qtt, tip, PARAMS, 50.0)
    one = [sample_caps(qt[i:i + 1], qtt[i:i + 1], tip[i:i + 1], PARAMS, 50.0)[0] for i in range(40)]
    assert caps.shape == (40,) and np.array_equal(caps, one)
    assert len(set(caps.tolist())) > 30


@settings(max_examples=150, deadline=None)
@given(cap=st.lists(st.floats(0.0, 2.0), min_size=0, max_size=60), dt=st.sampled_from([1e-3, 5e-4, 2e-3, 0.05]),
       decel=st.floats(0.5, 50.0), end=st.one_of(st.just(SIGMA_MAX), st.floats(0.0, 2.0)))
@example(cap=[2.0] * 30 + [0.0], dt=1e-3, decel=4.5, end=SIGMA_MAX)
@example(cap=[2.0] * 30, dt=1e-3, decel=4.5, end=0.0)
@example(cap=[2.0], dt=1e-3, decel=4.5, end=0.0)
@example(cap=[0.0] * 10 + [1e-7], dt=0.05, decel=2.0, end=2.0)
def test_the_backward_pass_is_the_fastest_sigma_that_can_still_slow_down_in_time(cap, dt, decel, end):
    """allowed <= cap everywhere; sigma can come down from each allowed value to the next one (and
    past the last sample to ``end``) at sigma' >= -decel, i.e. allowed_i^2 <= allowed_{i+1}^2 + 2
    decel dt; and it is the fastest such: each allowed value is its own cap or exactly the speed that
    decelerates to the next one."""
    cap = np.array(cap, float)
    a = backward_pass(cap, dt, decel, end)
    assert a.shape == cap.shape
    if len(cap) == 0:
        return
    tol = 1e-12 * (SIGMA_MAX ** 2 + 2 * decel * dt * len(cap))    # the rounding of the closed form's squares
    a2, reach2 = a ** 2, np.r_[a[1:], end] ** 2 + 2 * decel * dt
    assert np.all(a >= 0.0) and np.all(a2 <= cap ** 2 + tol)
    assert np.all(a2 <= reach2 + tol)
    assert np.all(np.abs(a2 - np.minimum(cap ** 2, reach2)) <= tol), np.max(np.abs(a2 - np.minimum(cap ** 2, reach2)))


def test_the_backward_pass_default_end_lets_sigma_run_on_and_a_zero_end_brakes_to_rest():
    """With no end value the last samples keep their caps (the next chunk may run at SIGMA_MAX); with
    end 0 sigma must reach 0 just after the last sample: the last allowed value is sqrt(2 decel dt)."""
    cap = np.full(50, 2.0)
    assert np.allclose(backward_pass(cap, DT, 4.5), cap, rtol=0, atol=1e-12)
    a = backward_pass(cap, DT, 4.5, 0.0)
    assert abs(a[-1] - math.sqrt(2 * 4.5 * DT)) < 1e-12 and abs(a[-2] - math.sqrt(4 * 4.5 * DT)) < 1e-12


@settings(max_examples=80, deadline=None)
@given(f=st.one_of(st.floats(-5.0, 5.0), st.sampled_from([0.1, 2.0, 0.0999999, 2.0000001, 1.0, -1.0])))
def test_the_feed_override_is_clamped_to_10_to_200_percent(f):
    """Any request gives the nearest value in [0.1, 2.0], stored and returned."""
    sc = TimeScaler(PARAMS, DT)
    lo, hi = FEED_OVERRIDE_RANGE
    assert (lo, hi) == (0.10, 2.00)
    got = sc.set_feed_override(f)
    want = min(hi, max(lo, f))
    assert got == want and sc.feed_override == want
    assert isinstance(got, float)


# ---------------------------------------------------------------- sigma's step (TimeScaler.step)

ZERO5 = [0.0] * 5


@pytest.mark.parametrize("impl", ["python", "compiled"])
@settings(max_examples=40, deadline=None)
@given(s0=st.floats(0.5, 2.0), frac=st.floats(0.05, 1.0))
def test_sigma_coming_down_through_its_goal_keeps_its_jerk_limit(impl, s0, frac):
    """sigma at its goal while still falling at up to the full rate (the goal raised just as sigma
    came down to it): sigma' changes by at most jerk x dt a tick, so sigma passes below the goal and
    comes back (landing on it from below, as any approach does), never snapping its rate to 0."""
    sc = _scaler(impl)
    A, J = sc.accel, sc.jerk
    sc.sigma, sc.dsigma = s0, -frac * A
    assume(frac * A > 2 * J * DT)
    prev, low = sc.dsigma, s0
    for _ in range(300):
        sc.step(s0, ZERO5, ZERO5)
        landed = sc.sigma == s0 and sc.dsigma == 0.0
        if not landed:
            assert abs(sc.dsigma - prev) <= J * DT * (1 + 1e-12) and abs(sc.dsigma) <= A * (1 + 1e-12)
        low = min(low, sc.sigma)
        prev = sc.dsigma
    # below the goal by sigma'^2 / 2 jerk, less a tick's step: the rate came down at the jerk limit
    ds0 = frac * A
    assert low < s0 - 0.5 * ds0 ** 2 / J + ds0 * DT, (low, s0)
    assert sc.sigma == s0 and sc.dsigma == 0.0


@pytest.mark.parametrize("impl", ["python", "compiled"])
@settings(max_examples=40, deadline=None)
@given(s0=st.floats(0.1, 2.0), frac=st.floats(0.05, 1.0))
def test_sigma_at_its_goal_while_still_rising_never_passes_it(impl, s0, frac):
    """At the curvature cap a sigma past its goal is a joint past its acceleration limit: sigma that
    reaches its goal while still rising lands on it and rests there."""
    sc = _scaler(impl)
    sc.sigma, sc.dsigma = s0, frac * sc.accel
    for _ in range(50):
        assert sc.step(s0, ZERO5, ZERO5) <= s0 and sc.sigma <= s0
    assert sc.sigma == s0 and sc.dsigma == 0.0


@pytest.mark.parametrize("impl", ["python", "compiled"])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_rate_above_a_lowered_limit_is_brought_within_it_on_the_next_tick(impl, sign):
    """sigma' at three times its limit when the limit comes down (a probe's raised stop limits put
    back by ProbeMonitor.cancel): the next tick's sigma' is at the limit, in the same direction."""
    sc = _scaler(impl)
    A = sc.accel
    sc.sigma, sc.dsigma = 1.0, sign * 3.0 * A
    s = sc.step(2.0 if sign > 0 else 0.0, ZERO5, ZERO5)
    assert sc.dsigma == sign * A and abs(s - (1.0 + sign * A * DT)) < 1e-12


def _scaler(impl):
    if impl == "python":
        return TimeScaler(PARAMS, DT)
    return CompiledFollower(ArraySource(np.zeros((0, WIDTH))), PARAMS, DT).scaler


# ---------------------------------------------------------------- the follower's rules (PathFollower.next_target)

AXIS = [0.0, 0.0, 1.0]


def _line(n, x0=0.0, step=0.01, cap=2.0, end=True, line=1):
    """Rows of ``n`` samples along X from ``x0``, ``step`` mm apart, caps ``cap``; the last one a job
    end (``end``). No joint rates: sigma is bound only by its goal, its caps and its own limits."""
    r = np.zeros((n, WIDTH))
    r[:, 0] = x0 + step * np.arange(n)
    r[:, S_AXIS:S_AXIS + 3] = AXIS
    r[:, S_CAP] = cap
    r[:, S_LINE] = line
    if end:
        r[-1, S_FLAGS] = FLAG_END
    return r


IMPLS = ["python", "compiled"]


@pytest.mark.parametrize("impl", IMPLS)
def test_with_nothing_queued_and_no_pose_the_target_is_a_valid_pose_at_rest(impl):
    """A follower made without a rest pose, nothing queued: the target is the origin with the unit
    axis (0, 0, 1), at rest; IDLE, and HELD under a hold."""
    fol = make_follower(Ring(16, WIDTH), PARAMS, DT, implementation=impl)
    for hold, state in ((False, IDLE), (True, HELD)):
        fol.scaler.hold = hold
        assert np.array_equal(fol.next_target(), [0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0]) and fol.state == state


@pytest.mark.parametrize("impl", IMPLS)
@settings(max_examples=25, deadline=None)
@given(lengths=st.lists(st.integers(1, 40), min_size=2, max_size=6), feed=st.floats(0.1, 2.0),
       sigma=st.sampled_from([0.0, 0.5, 1.0, 2.0]), per_tick=st.sampled_from([1, 1, 2, 3]))
@example(lengths=[50, 1, 50], feed=1.0, sigma=1.0, per_tick=1)
@example(lengths=[30, 1, 1, 30], feed=0.5, sigma=0.5, per_tick=1)
@example(lengths=[7, 1], feed=1.4375, sigma=0.0, per_tick=1)
@example(lengths=[9, 2, 9], feed=2.0, sigma=2.0, per_tick=3)
@example(lengths=[30, 1, 1, 30], feed=1.0, sigma=1.0, per_tick=2)
def test_every_job_end_is_counted_even_a_job_of_one_sample(impl, lengths, feed, sigma, per_tick):
    """Jobs back to back, all queued (a job of one sample: a line that plans to a single sample, as
    `M3 S1000` or a move to where the tool is), planned at ``per_tick`` samples a tick: the follower
    stops on each job's last sample, counts every job once, and ends on the last one at rest; a whole
    next job queued, it never reports STARVED."""
    rows, x = [], 0.0
    for i, n in enumerate(lengths):
        rows.append(_line(n, x, line=i + 1))
        x = rows[-1][-1, 0]
    rows = np.concatenate(rows)
    ends = np.nonzero(rows[:, S_FLAGS] == FLAG_END)[0]
    fol = make_follower(ArraySource(rows), PARAMS, DT, DT / per_tick, implementation=impl)
    fol.scaler.set_feed_override(feed)
    fol.scaler.sigma = sigma
    counted = []
    for _ in range(5000):
        tg = fol.next_target()
        assert fol.state != STARVED and fol.reason == ""
        counted.append(fol.ended_jobs)
        if fol.at_end and fol.src.count() == 1:
            break
    assert fol.ended_jobs == len(lengths) == len(ends), (fol.ended_jobs, lengths)
    assert sorted(set(counted)) == list(range(len(lengths) + 1))[1 if lengths[0] == 1 else 0:]
    assert np.array_equal(tg[:6], rows[-1, :6]) and not np.any(tg[6:]) and fol.sigma == 0.0


@pytest.mark.parametrize("impl", IMPLS)
@settings(max_examples=25, deadline=None)
@given(first=st.integers(1, 30), ticks=st.integers(0, 80), after=st.lists(st.integers(1, 20), min_size=1, max_size=4))
@example(first=5, ticks=80, after=[1])
@example(first=1, ticks=3, after=[1, 1])
def test_after_a_soft_reset_the_next_jobs_end_is_counted_even_a_job_of_one_sample(impl, first, ticks, after):
    """A job run for ``ticks`` ticks (to its end and resting there, or stopped short), then a soft
    reset (``clear``: the queue dropped), then jobs queued from where it stopped: every one of their
    ends is counted, a job of one sample too (a move to where the tool already is). The follower once
    kept "resting on a job's end" through the reset and took the next lone end for the one it had
    counted: the supervisor kept that job queued for ever, the console said Run at rest."""
    ring = Ring(256, WIDTH)
    ring.push(_line(first))
    fol = make_follower(ring, PARAMS, DT, implementation=impl)
    for _ in range(ticks):
        fol.next_target()
    ended = fol.ended_jobs
    fol.clear()
    x = fol.next_target()[0]
    assert fol.state == IDLE and fol.ended_jobs == ended
    for i, n in enumerate(after):
        ring.push(_line(n, x, line=10 + i))
        x = x + 0.01 * (n - 1)
    for _ in range(3000):
        tg = fol.next_target()
        if fol.at_end and ring.count() == 1:
            break
    assert fol.ended_jobs == ended + len(after), (fol.ended_jobs, ended, after)
    assert abs(tg[0] - x) < 1e-12 and fol.sigma == 0.0


@pytest.mark.parametrize("impl", IMPLS)
def test_a_lone_sample_with_no_job_end_is_waited_on_at_rest(impl):
    """One sample queued and no job end (the planner behind): the follower stays on it at rest and
    says it is starved; the sample after it arriving with the job's end, it runs to that end."""
    ring = Ring(16, WIDTH)
    rows = _line(2)
    ring.push(rows[:1])
    fol = make_follower(ring, PARAMS, DT, implementation=impl)
    for _ in range(5):
        tg = fol.next_target()
        assert fol.state == STARVED and fol.sigma == 0.0
        assert np.array_equal(tg, np.r_[rows[0, :6], np.zeros(6)])
    ring.push(rows[1:])
    for _ in range(50):
        tg = fol.next_target()
    assert fol.at_end and fol.ended_jobs == 1 and np.array_equal(tg[:6], rows[1, :6])


@pytest.mark.parametrize("impl", IMPLS)
def test_sigma_keeps_to_the_cap_of_the_sample_ahead(impl):
    """A job of two samples, the second capped at 0.1: leaving the first, sigma is held to 0.1 (the
    tighter of the two caps), not the feed's 1."""
    rows = _line(2)
    rows[1, S_CAP] = 0.1
    fol = make_follower(ArraySource(rows), PARAMS, DT, implementation=impl)
    fol.next_target()
    assert 0.0 < fol.sigma <= 0.1 and abs(fol.frac - 0.1) < 1e-12


@pytest.mark.parametrize("impl", IMPLS)
def test_leaving_a_rest_point_steps_sigma_only_within_half_a_ticks_acceleration(impl):
    """From rest (IDLE, sigma 0) sigma steps straight to its goal when every joint's speed step
    |q_tau| x goal is within 0.5 x amax x dt (the boundary included), else it ramps up."""
    sc0 = TimeScaler(PARAMS, DT)
    edge = 0.5 * sc0.amax[2] * DT
    for qt, jumps in ((edge, True), (float(np.nextafter(edge, 1.0)), False), (0.0, True)):
        rows = _line(50)
        rows[:, S_QT + 2] = qt
        fol = make_follower(ArraySource(rows), PARAMS, DT, implementation=impl)
        fol.next_target()
        assert (fol.sigma == 1.0) == jumps, (qt, fol.sigma)
        assert fol.sigma > 0.0


@pytest.mark.parametrize("impl", IMPLS)
def test_a_dwell_in_a_job_is_moving_not_idle(impl):
    """A dwell inside a job (G4: samples on one pose) is run at sigma > 0 with no motion: the state
    says MOVING all through it (IDLE would tell the console the job had ended), until the job's end."""
    tip, axis = home_pose(M)
    text = "G21 G91\nG1 X-2 F600\nG4 P0.2\nG1 X-2\n"
    tr = plan(parse_gcode(text, "t.ngc", tip, axis), M, DT, start=(tip, axis))
    rows = np.concatenate(list(iter_job_rows(tr, M, PARAMS)))
    fol = make_follower(ArraySource(rows), PARAMS, DT, implementation=impl)
    still = 0
    for _ in range(3 * len(rows)):
        tg = fol.next_target()
        if fol.at_end:
            break
        assert fol.state == MOVING, fol.state
        still += not np.any(tg[6:])
    assert fol.at_end and still > 150          # the dwell's 0.2 s at rest on the path


@pytest.mark.parametrize("impl", IMPLS)
def test_a_queue_that_runs_dry_stops_on_its_last_sample_and_says_so(impl):
    """Seven samples queued, no job end among them, four samples planned a tick, the feed override at
    10 % (the queue is enough for that: not starved) but sigma at 2 (set from outside): sigma cannot
    come down in time; the follower stops on the last queued sample (never past it), at rest, and
    says the sample queue ran dry."""
    rows = _line(7, end=False)
    fol = make_follower(ArraySource(rows), PARAMS, DT, DT / 4, implementation=impl)
    fol.scaler.set_feed_override(0.1)
    fol.scaler.sigma = 2.0
    fol.next_target()
    assert fol.reason == "sample queue ran dry" and fol.state == MOVING
    assert fol.sigma == 0.0 and fol.src.count() == 1
    tg = fol.next_target()
    assert np.array_equal(tg, np.r_[rows[-1, :6], np.zeros(6)]) and fol.state == STARVED


@pytest.mark.parametrize("impl", IMPLS)
def test_a_hold_says_holding_until_at_rest_then_held(impl):
    """A hold in the middle of a line: the state is HOLDING while sigma comes down, HELD from the tick
    the path is at rest on, and back to MOVING on resume."""
    fol = make_follower(ArraySource(_line(3000)), PARAMS, DT, implementation=impl)
    for _ in range(200):
        fol.next_target()
    assert fol.state == MOVING and fol.sigma == 1.0
    fol.scaler.hold = True
    states = []
    for _ in range(400):
        fol.next_target()
        states.append((fol.state, fol.sigma))
    moving = [st for st, s in states if s > 0.0]
    assert len(moving) > 50 and set(moving) == {HOLDING}
    assert states[-1] == (HELD, 0.0)
    fol.scaler.hold = False
    fol.next_target()
    assert fol.state == MOVING


@pytest.mark.slow
def test_jobs_queued_behind_a_job_of_one_sample_all_finish(tmp_path):
    """Through the supervisor and its rt process (sim): a move, a `G4 P0` (a job that plans to one
    sample) and a move back, queued at once. Every item is retired (the rt side counted each job's
    end) and the tool is back where it started; before the follower stopped on a one-sample job's
    end, the last item stayed queued for good."""
    sup = Supervisor(service=str(service_toml(tmp_path)), log=lambda m: None)
    tip, axis = home_pose(sup.machine)
    sup.start(counts_of(K.ik(tip, axis, sup.machine).q, sup.params))
    try:
        t1 = tip + np.array([-20.0, 0.0, 0.0])
        for text, start, name in (("G21 G91\nG1 X-20 F1200\n", tip, "a"), ("G21 G90\nG4 P0\n", t1, "b"),
                                  ("G21 G91\nG1 X20 F1200\n", t1, "c")):
            sup.submit(parse_gcode(text, f"{name}.ngc", start, axis), name=name)
        t0 = time.monotonic()
        while sup.queued_items() and time.monotonic() - t0 < 120:
            time.sleep(0.05)
        assert sup.queued_items() == 0
        q = K.ik(tip, axis, sup.machine).q
        while not np.array_equal(sup.status().counts, counts_of(q, sup.params)) and time.monotonic() - t0 < 120:
            time.sleep(0.05)
        assert np.array_equal(sup.status().counts, counts_of(q, sup.params))
    finally:
        sup.shutdown()
