"""The NC's rest deadband (pmctl.motion.nc, docs/machine.md §6) through the real loop on the sim:
while the target stands still (a dwell, a feed hold, a job's end) a joint within half a pulse of
its target gets no correction, so no pulse is sent (before, each chain flipped by one pulse at
~76 Hz: a quantisation limit cycle of the V-F residue); the held position is within half a pulse
of the target on every joint; motion, however slow, is tracked exactly as without the deadband;
a disturbance at rest (a new target, a chain-length offset, a strain reading) is acted on at once.
The compiled and the Python NC are compared tick for tick on rest cases in tests/motion/test_ncore.py."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from pmctl import hal
from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.kinematics import FK_TOL_MM
from pmctl.motion.loop import ControlLoop, prepare
from pmctl.motion.nc import NCParams, counts_of, initial_state
from pmctl.motion.ncore import make_nc
from pmctl.motion.service_config import LoopConfig
from pmctl.motion.timescale import HELD
from pmctl.task.gcode import parse_gcode
from pmctl.core.job import home_pose
from pmctl.task.planner import plan

M = load_machine()
DT = 1e-3
DWELL_LINE = 3
SETTLE_S = 0.25        # the stop's own transient (the loop's lag, a chain mode ringing under K_theta)


def dwell_job(d, ab, feed, dwell_s):
    """A move from home by d (mm; at least 10 um) to the tilt ab (A, B in degrees), a dwell there
    (line 3), a move back."""
    tip, axis = home_pose(M)
    d = np.asarray(d, float)
    n = float(np.linalg.norm(d))
    if n < 0.01:
        d = d + [0.0, 0.0, 0.01] if n == 0.0 else d * (0.01 / n)
    x, y, z = tip + d
    text = (f"G21 G90 G94\nG1 X{x:.4f} Y{y:.4f} Z{z:.4f} A{ab[0]:.3f} B{ab[1]:.3f} F{feed:g}\n"
            f"G4 P{dwell_s:g}\nG1 X{tip[0]:.4f} Y{tip[1]:.4f} Z{tip[2]:.4f} A0 B0\nM2\n")
    return plan(parse_gcode(text, "dwell.ngc", tip, axis), M, DT, start=(tip, axis))


def run_loop(traj, params, sim, hook=None):
    tg = prepare(M, params, traj, DT)
    c0 = counts_of(tg.q[0], params)
    be = hal.create("sim", M, DT, sim)
    be.open(c0)
    lp = ControlLoop(M, be, params, tg, LoopConfig(realtime=False, stall_timeout_s=5.0), initial_state(M, c0),
                     log=lambda m: None, hook=hook)
    res = lp.run()
    assert res.status == "done", res.reason
    assert np.array_equal(c0 + res.pulses_sent, res.state.counts)      # pulses sent = pulse counters
    assert np.array_equal(be.counts, res.state.counts)
    return res


def flips(counts):
    """Counter changes per axis over a stretch of ticks."""
    return np.sum(np.diff(counts, axis=0) != 0, axis=0)


def dwell_span(res):
    idx = np.nonzero(res.line == DWELL_LINE)[0]
    assert len(idx) > 0.5 / DT
    return int(idx[0]), int(idx[-1])


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(d=st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3),
       ab=st.lists(st.floats(-2.0, 2.0), min_size=2, max_size=2),
       feed=st.floats(30.0, 900.0), k_theta=st.sampled_from([0.0, 200.0]),
       impl=st.sampled_from(["compiled", "python"]), flex=st.booleans(), noise=st.booleans(),
       seed=st.integers(0, 1000))
def test_no_pulse_during_a_dwell_and_the_position_is_held_within_half_a_pulse(d, ab, feed, k_theta, impl, flex,
                                                                               noise, seed):
    params = NCParams.from_machine(M, DT, kv=400.0, k_theta=k_theta, implementation=impl)
    sim = {"flex": flex, "strain_noise_ue": 0.01 if noise else 0.0, "enc_noise_mm": 1e-5 if noise else 0.0,
           "seed": seed}
    res = run_loop(dwell_job(d, ab, feed, 0.8), params, sim)
    i0, i1 = dwell_span(res)
    held = res.counts[i0 + int(SETTLE_S / DT):i1 + 2]        # counters at the start of each tick (+ the next)
    assert not np.any(flips(held)), f"pulses during the dwell: {flips(held)}"
    # the held counters: within half a pulse of the dwell target's joints (IK), on every joint
    ik = K.ik_batch(res.target[i1, :3], res.target[i1, 3:6], M)
    assert bool(ik.ok)
    err = np.abs(held[-1] - ik.q * params.pulses_per_mm)           # pulses
    tol = 0.5 + 1e3 * FK_TOL_MM * params.pulses_per_mm              # the model's FK tolerance (and J+'s first order)
    if k_theta and noise:           # the strain term moves the held point by K_theta/kv x the gauge noise
        tol = tol + k_theta / params.kv * 6 * 0.01 * np.r_[params.deflection_per_ue, 0, 0] * params.pulses_per_mm
    assert np.all(err <= tol), err
    # and the job went on after the dwell: back home within a pulse or two
    home = counts_of(K.ik_batch(*home_pose(M), M).q, params)
    assert np.all(np.abs(res.state.counts - home) <= 2)


def test_the_dwell_of_the_report_no_longer_dithers():
    """The reported case (a move, then a 5 s dwell; K_theta 200 on the default flexible, noisy plant):
    with the deadband switched off every chain flips ~600 times in the dwell's last 4 s; with it,
    none does."""
    n = {}
    for band in (0.0, 0.5):
        params = NCParams.from_machine(M, DT, kv=400.0, k_theta=200.0, rest_deadband_pulses=band)
        res = run_loop(dwell_job([3.3, -1.7, 1.2], [0.0, 0.0], 600.0, 5.0), params,
                       {"flex": True, "strain_noise_ue": 0.01, "seed": 1})
        i0, i1 = dwell_span(res)
        n[band] = flips(res.counts[i1 - 4000:i1 + 2])
    assert np.all(n[0.0][:3] > 100), n[0.0]
    assert not np.any(n[0.5]), n[0.5]


def test_a_feed_hold_sends_no_pulses_once_held():
    tip, axis = home_pose(M)
    traj = plan(parse_gcode(f"G21 G90\nG1 X{tip[0] + 8:.4f} Y{tip[1] - 3:.4f} Z{tip[2] - 2:.4f} F300\n", "h.ngc",
                            tip, axis), M, DT, start=(tip, axis))
    seen = {}

    def hook(lp, k, st):
        f = lp.follower
        if k == 600:
            f.scaler.hold = True
        if f.scaler.hold and f.state == HELD and "held" not in seen:
            seen["held"] = k
        if "held" in seen and k == seen["held"] + 600:
            f.scaler.hold = False
        return st

    res = run_loop(traj, NCParams.from_machine(M, DT, kv=400.0, k_theta=200.0), {"flex": True, "seed": 2}, hook)
    h = seen["held"]
    assert res.sigma[h + 10:h + 590].max() == 0.0
    assert not np.any(flips(res.counts[h + int(SETTLE_S / DT):h + 590]))


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(speed=st.sampled_from([0.01, 0.5, 3.0, 60.0, 600.0]),
       direction=st.lists(st.floats(-1.0, 1.0), min_size=5, max_size=5),
       k_theta=st.sampled_from([0.0, 200.0]), impl=st.sampled_from(["compiled", "python"]),
       multi=st.booleans(), seed=st.integers(0, 1000))
def test_motion_is_never_taken_for_rest_and_is_tracked_as_without_the_deadband(speed, direction, k_theta, impl,
                                                                                multi, seed):
    """However slow the feed (down to 0.01 mm/min, a pulse every 6 s), a moving target has a
    non-zero feed-forward on every tick, so the deadband never acts: the same pulses, tick for
    tick, as the NC without it (on the flexible, noisy plant, with or without K_theta)."""
    params = [NCParams.from_machine(M, DT, kv=400.0, k_theta=k_theta, implementation=impl,
                                    max_pulses_per_tick=None if multi else 1, rest_deadband_pulses=band)
              for band in (0.5, 0.0)]
    u = np.asarray(direction, float)
    u = u / np.abs(u).max() if np.abs(u).max() > 1e-3 else np.ones(5)
    v = u * min(speed / 60.0, 0.2 * float(np.min(params[0].vmax)))      # joint rates, mm/s (mm/min / 60)
    n = 1500
    q = np.array([M.geometry.z_home] * 3 + [0.0, 0.0]) + np.arange(n + 1)[:, None] * DT * v[None, :]
    pose, ok = K.fk_batch(q, M)
    assert np.all(ok)
    rows = np.zeros((n, 12))
    rows[:, :3], rows[:, 3:6] = pose.tip[:-1], pose.axis[:-1]
    rows[:, 6:9] = np.diff(pose.tip, axis=0) / DT
    rows[:, 9:12] = np.diff(pose.axis, axis=0) / DT
    assert np.all(np.any(rows[:, 6:] != 0.0, axis=1))        # the target moves on every tick
    c0 = counts_of(q[0], params[0])
    out = []
    for p in params:
        nc = make_nc(M, p)
        s = nc.load(initial_state(M, c0))
        be = hal.create("sim", M, DT, {"flex": True, "strain_noise_ue": 0.01, "seed": seed})
        be.open(c0)
        pulses = []
        for k in range(n):
            pl, s = nc.step(s, rows[k], be.read())
            pl = np.array(pl)
            be.write_pulses(pl)
            pulses.append(pl)
        out.append(np.array(pulses))
    assert np.array_equal(out[0], out[1])
    moved = np.abs(out[0].sum(0))
    assert np.all(moved[np.abs(v) * n * DT * params[0].pulses_per_mm > 3] > 0)     # the joints did move


@pytest.mark.parametrize("impl", ["compiled", "python"])
def test_a_disturbance_at_rest_is_acted_on_at_once(impl):
    """Held in the deadband and silent, the NC acts again as soon as a joint leaves the band: a
    target step (no feed-forward) of 4 pulses on X, a chain-length offset of 1.5 um on L2, a strain
    reading that K_theta turns into 3 pulses of L3; each time the pulses start within a few ticks,
    the joint settles within half a pulse of its new equilibrium, and silence returns."""
    params = NCParams.from_machine(M, DT, kv=400.0, k_theta=200.0, implementation=impl,
                                   chain_offset_rate_mm_s=1.0)
    nc = make_nc(M, params)
    tip, axis = home_pose(M)
    tip = tip + np.array([0.31e-3, -0.77e-3, 0.123])          # a pose between pulses
    q = K.ik_batch(tip, axis, M).q
    c0 = counts_of(q, params)
    st0 = nc.load(initial_state(M, c0))
    be = hal.create("sim", M, DT, {})
    be.open(c0)
    target = np.r_[tip, axis, np.zeros(6)]
    ppm = params.pulses_per_mm
    dpu = params.deflection_per_ue
    ue_per_pulse = params.kv / params.k_theta[2] / dpu[2] / ppm[2]        # strain worth one pulse of L3 under K_theta
    events = {300: "target", 600: "offset", 900: "strain"}
    counts, qdots = [], []
    s, off, strain_add = st0, np.zeros(3), 0.0
    for k in range(1200):
        if events.get(k) == "target":
            target = target.copy()
            target[0] += 4 / ppm[3]          # the table's X moves the tip by -X: a 4-pulse step on X
        elif events.get(k) == "offset":
            off = np.array([0.0, 1.5e-3, 0.0])
        elif events.get(k) == "strain":
            strain_add = -3 * ue_per_pulse     # defl = -strain x dpu: 3 pulses' worth of K_theta defl on L3
        fb = be.read()
        fb.strain[2] += strain_add
        pl, s = nc.step(s, target, fb, off)
        be.write_pulses(np.array(pl))
        counts.append(np.array(s.counts).copy())
        qdots.append(np.array(s.qdot).copy())
    counts, qdots = np.array(counts), np.array(qdots)
    for k0, axis_i in ((300, 3), (600, 1), (900, 2)):
        before = counts[k0 - 200:k0]
        assert not np.any(flips(before)), (k0, flips(before))       # silent at rest before the event
        assert qdots[k0, axis_i] != 0.0                              # acted on at once
        moved = np.nonzero(counts[k0:k0 + 300, axis_i] != counts[k0 - 1, axis_i])[0]
        assert len(moved) and moved[0] <= 10, (k0, moved[:3])        # the first pulse within a few ticks
        assert not np.any(flips(counts[k0 + 100:k0 + 300])), (k0, flips(counts[k0 + 100:k0 + 300]))
    # the equilibria: the new target on X, target + offset on L2, target + K_theta's 3 pulses on L3
    q1 = K.ik_batch(target[:3], target[3:6], M).q
    want = q1 * ppm + np.r_[0.0, off[1] * ppm[1], 0.0, 0.0, 0.0]
    want[2] -= 3.0          # K_theta's equilibrium: kv (q* - q) = K_theta defl
    assert np.all(np.abs(counts[-1] - want) <= 0.5 + 1e-3), counts[-1] - want
    assert abs(round(counts[-1][3] - counts[299][3])) == 4 and abs(counts[-1][2] - counts[899][2]) == 3


def test_the_band_is_half_a_pulse_to_a_pulse_or_off():
    """Below half a pulse a target could sit where neither neighbouring pulse is in the band (the
    joint would go back and forth between them), so such a band is refused; 0 switches it off."""
    for ok in (0.0, 0.5, 0.75, 1.0):
        p = NCParams.from_machine(M, DT, kv=400.0, rest_deadband_pulses=ok)
        # (an exact half pulse is inside: the band's edge is 1e-9 pulse beyond, pmctl.core.vf.TIE)
        assert p._rest_band == [400.0 * (ok + 1e-9 if ok else 0.0) / x for x in p.pulses_per_mm]
    for bad in (0.25, 0.49, 1.5, -0.5, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="rest_deadband_pulses"):
            NCParams.from_machine(M, DT, rest_deadband_pulses=bad)
