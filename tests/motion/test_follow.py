"""The compiled path follower (pmctl.motion._follow via timescale.CompiledFollower) against the
Python reference (timescale.PathFollower), tick for tick.

Both followers get their own ring fed with the same rows at the same ticks and the same operator
requests; every tick the targets must be bit-identical and so must sigma, its rate, the path
clock, the line, the state, the reason, the job ends counted and the queue. Streams are drawn by
hypothesis: planned paths near home through the machine's IK (curvature and joint-speed caps, the
backward pass), rapids, several jobs back to back, short jobs passed at sigma > 1, feeds that lag
(starvation), holds and resumes, feed overrides 10-200 % (and out of range), rapid overrides,
soft resets, sigma set from outside, and a probe's raised accel/jerk."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.motion.nc import NCParams
from pmctl.motion.ring import ArraySource, Ring
from pmctl.motion.timescale import (FLAG_END, FLAG_RAPID, S_CAP, S_FLAGS, WIDTH, CompiledFollower,
                                    PathFollower, backward_pass, make_follower, make_rows, scaling_limits)
from pmctl.core.job import home_pose

M = load_machine()
DT = 1e-3
PARAMS = NCParams.from_machine(M, DT)
HOME_TIP, HOME_AXIS = (np.asarray(x, float) for x in home_pose(M))


def job_rows(rng, n_seg, dt_plan, *, short=False):
    """Rows of one job: segments between random points near home (smoothstep in time, so each
    segment starts and ends at rest), some of them rapids; the last row ends the job."""
    pts = [HOME_TIP + rng.uniform(-3, 3, 3)]
    axs = [HOME_AXIS]
    tips, axes, lines, rapid = [], [], [], []
    for s in range(n_seg):
        p = pts[-1] + rng.uniform(-8, 8, 3) * (0.05 if short else 1.0)
        a = HOME_AXIS + np.r_[rng.uniform(-0.05, 0.05, 2), 0.0]
        a /= np.linalg.norm(a)
        n = int(rng.integers(2, 6)) if short else int(rng.integers(40, 400))
        u = np.linspace(0, 1, n + 1)[1:]
        u = u * u * (3 - 2 * u)
        tips.append(pts[-1] + u[:, None] * (p - pts[-1]))
        ax = axs[-1] + u[:, None] * (a - axs[-1])
        axes.append(ax / np.linalg.norm(ax, axis=1, keepdims=True))
        lines.append(np.full(n, 10 * s + 1))
        rapid.append(np.full(n, bool(rng.random() < 0.3)))
        pts.append(p)
        axs.append(a)
    tip, axis = np.concatenate(tips), np.concatenate(axes)
    q = K.ik_batch(tip, axis, M, check_limits=False).q
    rows = make_rows(tip, axis, q, np.concatenate(lines), dt_plan, PARAMS, rapid=np.concatenate(rapid))
    rows[:, S_CAP] = backward_pass(rows[:, S_CAP], dt_plan, 0.5 * scaling_limits(PARAMS)[0])
    return rows


def raw_rows(rng, n):
    """Arbitrary rows (no planner behind them): random caps, joint rates and curvatures, flags."""
    rows = np.zeros((n, WIDTH))
    rows[:, :3] = HOME_TIP + np.cumsum(rng.normal(0, 0.01, (n, 3)), 0)
    ax = HOME_AXIS + rng.normal(0, 0.01, (n, 3))
    rows[:, 3:6] = ax / np.linalg.norm(ax, axis=1, keepdims=True)
    rows[:, 6:22] = rng.normal(0, 1, (n, 16)) * rng.choice([0.0, 1.0, 30.0, 3000.0], (n, 16))
    rows[:, S_CAP] = rng.choice([0.0, 0.05, 0.5, 1.0, 1.7, 2.0], n)
    rows[:, S_CAP + 1] = rng.integers(0, 50, n)
    rows[:, S_FLAGS] = rng.choice([0, FLAG_RAPID], n) + np.where(rng.random(n) < 0.01, FLAG_END, 0)
    rows[-1, S_FLAGS] = int(rows[-1, S_FLAGS]) | FLAG_END
    return rows


def stream(seed, kind, n_jobs, dt_plan):
    rng = np.random.default_rng(seed)
    jobs = []
    for j in range(n_jobs):
        if kind == "raw":
            jobs.append(raw_rows(rng, int(rng.integers(1, 300))))
        else:
            jobs.append(job_rows(rng, int(rng.integers(1, 4)), dt_plan, short=bool(j % 2)))
    return np.concatenate(jobs)


OPS = st.one_of(
    st.tuples(st.just("hold"), st.booleans()),
    st.tuples(st.just("feed"), st.one_of(st.floats(0.1, 2.0), st.sampled_from([0.0, 0.1, 2.0, 3.5]))),
    st.tuples(st.just("rapid"), st.sampled_from([0.25, 0.5, 1.0, 0.3, 2.0])),
    st.tuples(st.just("push"), st.integers(0, 400)),
    st.tuples(st.just("clear"), st.just(0)),
    st.tuples(st.just("sigma"), st.sampled_from([0.0, 1.0, 2.0])),
    st.tuples(st.just("probe"), st.floats(1.0, 4.0)),
)


def fields(f):
    sc = f.scaler
    return (sc.sigma, sc.dsigma, sc.hold, sc.feed_override, sc.rapid_override, sc.accel, sc.jerk, f.frac,
            f.line, f.state, f.s_total, f.ended_jobs, f.at_end, f.reason, f.src.count(), f._rest)


def apply(f, op, arg, rows, fed):
    sc = f.scaler
    if op == "hold":
        sc.hold = arg
    elif op == "feed":
        sc.set_feed_override(arg)
    elif op == "rapid":
        sc.set_rapid_override(arg)
    elif op == "push":
        return fed + f.src.push(rows[fed:fed + arg])
    elif op == "clear":
        f.clear()
    elif op == "sigma":
        sc.sigma = arg
    elif op == "probe":               # what ProbeMonitor does for a probing move
        sc.accel, sc.jerk = sc.accel * arg, sc.jerk * arg * 2
    return fed


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), kind=st.sampled_from(["planned", "planned", "raw"]),
       n_jobs=st.integers(1, 5), k_plan=st.sampled_from([1.0, 1.0, 0.5, 2.0]),
       capacity=st.sampled_from([16, 97, 1024, 8192]), first=st.integers(0, 3000),
       feed_every=st.integers(1, 40), feed_n=st.integers(0, 60),
       ops=st.lists(st.tuples(st.integers(0, 2500), OPS), max_size=25), ticks=st.integers(50, 2500))
def test_compiled_follower_equals_the_python_follower_tick_for_tick(
        seed, kind, n_jobs, k_plan, capacity, first, feed_every, feed_n, ops, ticks):
    dt_plan = DT * k_plan
    rows = stream(seed, kind, n_jobs, dt_plan)
    py = PathFollower(Ring(capacity, WIDTH), PARAMS, DT, dt_plan, pose=list(HOME_TIP) + list(HOME_AXIS))
    c = CompiledFollower(Ring(capacity, WIDTH), PARAMS, DT, dt_plan, pose=list(HOME_TIP) + list(HOME_AXIS))
    fed = [py.src.push(rows[:first]), c.src.push(rows[:first])]
    assert fed[0] == fed[1]
    at = {}
    for k, op in ops:
        at.setdefault(k, []).append(op)
    ends = int(np.sum(rows[:, S_FLAGS].astype(int) & FLAG_END != 0))
    for k in range(ticks):
        for op, arg in at.get(k, ()):
            fed = [apply(f, op, arg, rows, n) for f, n in zip((py, c), fed)]
        if k % feed_every == 0:
            fed = [n + f.src.push(rows[n:n + feed_n]) for f, n in zip((py, c), fed)]
        assert fed[0] == fed[1]
        a = py.next_target().copy()
        b = c.next_target()
        assert np.array_equal(a, b), f"tick {k}: targets differ by {np.max(np.abs(a - b))}"
        assert fields(py) == fields(c), f"tick {k}"
        assert c.ended_jobs <= ends


def test_a_job_end_is_never_stepped_over_at_sigma_above_one():
    """Jobs of 1-3 samples back to back, followed at 200 % feed (sigma up to 2 samples a tick):
    both followers stop on every job end and count it, and end on the last sample."""
    rng = np.random.default_rng(7)
    jobs = [job_rows(rng, 1, DT, short=True) for _ in range(30)]
    rows = np.concatenate(jobs)
    rows[:, S_CAP] = 2.0
    rows[:, 12:22] = 0.0            # no joint bound: sigma runs at its goal
    for impl in ("python", "compiled"):
        f = make_follower(ArraySource(rows.copy()), PARAMS, DT, implementation=impl)
        f.scaler.set_feed_override(2.0)
        f.scaler.sigma = 2.0
        for _ in range(2000):
            f.next_target()
        assert f.ended_jobs == len(jobs), impl
        assert np.array_equal(f.next_target()[:6], rows[-1, :6])


def test_the_loop_picks_the_compiled_follower_unless_python_is_selected():
    from dataclasses import replace
    rows = raw_rows(np.random.default_rng(1), 10)
    assert isinstance(make_follower(ArraySource(rows), PARAMS, DT), CompiledFollower)
    assert isinstance(make_follower(ArraySource(rows), replace(PARAMS, implementation="python"), DT), PathFollower)
    with pytest.raises(ValueError, match="implementation"):
        make_follower(ArraySource(rows), PARAMS, DT, implementation="fortran")


@settings(max_examples=40, deadline=None)
@given(st.floats(0.0, 2.0), st.lists(st.floats(0.0, 2.0), min_size=1, max_size=6),
       st.lists(st.floats(-50, 50), min_size=5, max_size=5), st.lists(st.floats(-2000, 2000), min_size=5, max_size=5))
def test_compiled_sigma_step_equals_the_time_scaler(s0, goals, qt, qtt):
    """TimeScaler.step and the compiled one, from the same sigma through the same goals."""
    from pmctl.motion.timescale import TimeScaler
    ref = TimeScaler(PARAMS, DT)
    c = CompiledFollower(ArraySource(np.zeros((0, WIDTH))), PARAMS, DT).scaler
    ref.sigma = c.sigma = s0
    for g in goals:
        for _ in range(300):
            assert ref.step(g, qt, qtt) == c.step(g, qt, qtt)
            assert (ref.sigma, ref.dsigma) == (c.sigma, c.dsigma)
