"""Stop on contact pinned at its edges (pmctl.motion.probe), tick by tick:

the real path follower (``make_follower`` on the planned samples of a G38 line, as ``pmctl run``
builds it) and the real ProbeMonitor; the gauges read the gravity model of the commanded pose
(pmctl.core.statics, computed here per tick) plus a chosen axial force on one chain. So the force the
monitor sees is known exactly, and with it:

- a force of 0.95 x the threshold never stops the move, 1.05 x does;
- ``debounce_ticks - 1`` ticks over the threshold do not stop it, ``debounce_ticks`` ticks do;
- a constant gauge offset is tared off (no contact); a force already growing during the tare stops it;
- once stopped: sigma at rest, the tool past the first over-threshold tick by at most ``bound_mm``,
  the rest of the move dropped, the job counted as ended, the scaler's rate limits and hold back;
- ``cancel`` during the stop gives the rate limits back; the probing rows' feed cap.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from pmctl.core import kinematics as K
from pmctl.core import statics
from pmctl.core.config import load_machine
from pmctl.motion.loop import prepare, target_samples
from pmctl.motion.probe import (ARMED, IDLE, STOPPING, TARE, TARE_GUARD, ProbeConfig, ProbeMonitor, mark_probe_rows,
                                probe_segments)
from pmctl.motion.ring import ArraySource
from pmctl.motion.service_config import NCConfig
from pmctl.motion.timescale import FLAG_PROBE, JOINT_SHARE, S_CAP, S_FLAGS, make_follower
from pmctl.task.gcode import parse_gcode
from pmctl.core.job import home_pose
from pmctl.task.planner import plan

M = load_machine("prototype")
DT = 1e-3
PARAMS = NCConfig().params(M, DT)
TIP0, AXIS0 = (np.asarray(x, float) for x in home_pose(M))
GAIN = float(M.strain_gain)
# a tilted tool axis, off the table's centre: the three chains carry different gravity loads, which
# change along a probing line by different amounts (7 to 13 mN over 6 mm; at home all three are alike)
TILTED = (TIP0 + np.array([25.0, -15.0, 0.0]), K.axis_from_roll_pitch(math.radians(8.0), math.radians(-12.0)))


class Bench:
    """One G38 move from home, 2 mm down at F60 (1 mm/s), followed tick by tick."""

    def __init__(self, cfg=ProbeConfig(), text="G21 G90\nG38.2 Z{z:.4f} F60\n", params=PARAMS, chain=0,
                 fetch=False, start=(TIP0, AXIS0)):
        tip0, axis0 = (np.asarray(x, float) for x in start)
        job = parse_gcode(text.format(z=tip0[2] - 2.0), "p.ngc", tip0, axis0)
        traj = plan(job, M, DT, start=(tip0, axis0))
        tg = prepare(M, PARAMS, traj, DT)
        self.fol = make_follower(ArraySource(target_samples(tg, DT, PARAMS)), PARAMS, DT)
        self.fol.scaler.sigma = 1.0
        self.segs = probe_segments(job, M, tip0)
        if fetch:                # the daemon's way: the segment handed over once the follower is on it
            left = list(self.segs)
            self.mon = ProbeMonitor(M, [], cfg, DT, params,
                                    fetch=lambda fol: left.pop(0) if left and fol.line == left[0].line else None)
        else:
            self.mon = ProbeMonitor(M, self.segs, cfg, DT, params)
        self.cfg = cfg
        # the force's share on each chain: one chain, or a 3-vector (a tip force loads them all)
        self.share = np.eye(3)[chain] if np.ndim(chain) == 0 else np.asarray(chain, float)
        self.k = 0
        self.trace = []          # (tick, travel along the move mm, sigma, monitor state)

    def gauges(self, tg, force_N):
        """The three strains at this target: the gravity statics of its pose, plus ``force_N`` of
        axial force on ``self.chain`` (compression lowers the strain)."""
        r = K.ik_batch(tg[:3], tg[3:6], M, check_limits=False)
        s = statics.static_strain(r.P, r.R, M).reshape(3) - GAIN * force_N * self.share
        return [float(x) for x in s]

    def run(self, force, ticks=4000, results=1):
        """``force(k, travel_mm)`` N on the chosen chain per tick (travel along the first probing
        move), until the monitor has ``results`` results."""
        seg = self.segs[0]
        for _ in range(ticks):
            tg = self.fol.next_target()
            s = float(np.dot(tg[:3] - seg.start, seg.direction))
            self.mon.tick(self.fol, tg, self.gauges(tg, force(self.k, s)), self.k)
            self.trace.append((self.k, s, self.fol.scaler.sigma, self.mon.state))
            self.k += 1
            if len(self.mon.results) >= results:
                return self.mon.results[results - 1]
        raise AssertionError("no probe result")


@pytest.mark.parametrize("chain", [0, 1, 2, (1.0, -1.0, 0.5), (-0.5, 0.25, 1.0)])
def test_a_force_just_under_the_threshold_never_stops_the_move_and_just_over_it_does(chain):
    """On one chain, or shared by all three with mixed signs (a tip force compresses some chains and
    pulls others): the largest chain's share sets the trip."""
    cfg = ProbeConfig()
    b = Bench(cfg, chain=chain)
    r = b.run(lambda k, s: 0.95 * cfg.threshold_N if s > 0.3 else 0.0)
    assert not r.contact and r.error.startswith("probe fail") and "line 2" in r.error
    assert abs(r.stop[2] - (TIP0[2] - 2.0)) < 1e-6               # the move ran to its programmed end
    assert r.speed_mm_s == 0.0 and r.tick == -1 and r.bound_mm == 0.0
    b = Bench(cfg, chain=chain)
    r = b.run(lambda k, s: -1.05 * cfg.threshold_N if s > 0.3 else 0.0)     # (either sign)
    assert r.contact and r.error == ""
    # the first over-threshold tick is where the averaged force crossed, filter_ticks after the step
    first = next(k for k, s, *_ in b.trace if s > 0.3)
    assert r.tick - first >= cfg.filter_ticks - 1


@pytest.mark.parametrize("debounce", [2, 4])
def test_debounce_minus_one_ticks_over_the_threshold_do_not_stop_it_debounce_ticks_do(debounce):
    """A force pulse long enough that its moving average stays over the threshold for n ticks."""
    cfg = ProbeConfig(debounce_ticks=debounce, filter_ticks=1)
    for n, stops in ((debounce - 1, False), (debounce, True)):
        b = Bench(cfg)
        start = []

        def force(k, s, n=n):
            if s > 0.3 and not start:
                start.append(k)
            return 3.0 * cfg.threshold_N if start and k < start[0] + n else 0.0
        r = b.run(force)
        assert r.contact == stops, (n, r)
        if stops:
            assert r.tick == start[0] + n - 1
            # the travel past the trigger is counted from the first over-threshold tick (what bound_mm bounds)
            s_at = {k: s for k, s, *_ in b.trace}
            assert r.after_trigger_mm == pytest.approx(b.trace[-1][1] - s_at[start[0]], abs=1e-9)


@pytest.mark.parametrize("share", [(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (1.0, -0.6, 0.3)])
def test_a_constant_gauge_offset_is_tared_off_and_the_noise_is_reported(share):
    cfg = ProbeConfig()
    rng = np.random.default_rng(7)
    noise = rng.normal(0.0, 0.2, 5000)
    b = Bench(cfg, chain=share)
    r = b.run(lambda k, s: 40.0 + noise[k])            # 8 x the threshold, from the start: an offset
    assert not r.contact and r.error.startswith("probe fail")
    # the reference: filter_ticks - 1 ticks fill the moving average, then tare_ticks reference ticks at
    # feed, the last of which arms the monitor (the trace holds the state after each tick)
    assert sum(1 for *_, st in b.trace if st == TARE) == (cfg.filter_ticks - 1) + (cfg.tare_ticks - 1)
    assert b.trace[cfg.filter_ticks + cfg.tare_ticks][3] == ARMED
    if share != (1.0, 0.0, 0.0) and share != (0.0, 1.0, 0.0) and share != (0.0, 0.0, 1.0):
        return
    # the reference ticks' spread of the averaged force: 0.2 N / sqrt(filter_ticks) per chain, one
    # chain of three noisy: sqrt(1/3) of it
    want = 0.2 / math.sqrt(cfg.filter_ticks) / math.sqrt(3.0)
    assert 0.6 * want < r.noise_N < 1.4 * want, (r.noise_N, want)


@pytest.mark.parametrize("chain", [0, 1, 2])
def test_a_force_growing_during_the_tare_stops_the_move(chain):
    """Contact before the reference is complete: a force rising at 10 N/mm from the start is seen
    against the running reference (twice the threshold) once TARE_GUARD reference ticks are in."""
    cfg = ProbeConfig(tare_ticks=400)
    b = Bench(cfg, chain=chain)
    r = b.run(lambda k, s: 200.0 * max(s, 0.0))
    assert r.contact
    armed_at = next(k for k, _, _, st in b.trace if st in (ARMED, STOPPING))
    tare_ticks = sum(1 for _, _, _, st in b.trace if st == TARE)
    assert tare_ticks < cfg.tare_ticks and armed_at == r.tick


@pytest.mark.parametrize("feed", [60, 300])
def test_the_stop_on_contact_comes_to_rest_within_its_bound_and_gives_the_limits_back(feed):
    cfg = ProbeConfig()
    b = Bench(cfg, text="G21 G90\nG38.3 Z{z:.4f} F%d\n" % feed)
    sc = b.fol.scaler
    a0, j0 = sc.accel, sc.jerk
    b.fol.ended_jobs = ended0 = 5          # the daemon's follower has passed other jobs' ends before
    r = b.run(lambda k, s: 10.0 * cfg.threshold_N if s > 0.4 else 0.0)
    v = feed / 60.0
    assert r.contact and r.speed_mm_s == pytest.approx(v, rel=1e-6)
    # the bound: debounce + 5 ticks at the feed plus the braking distance at the probe's deceleration
    # (within the joints' limits: _effective_decel)
    decel = b.mon._decel[2]
    assert 0 < decel <= cfg.decel_mm_s2
    assert r.bound_mm == pytest.approx(v * (cfg.debounce_ticks + 5) * DT + v * v / (2 * decel), rel=1e-12)
    assert 0.0 < r.after_trigger_mm <= r.bound_mm
    # at rest where it stopped, the rest of the move dropped and the job counted as ended
    assert sc.sigma == 0.0 and b.fol.src.count() == 0 and b.fol.at_end and b.fol.ended_jobs == ended0 + 1
    assert np.allclose(r.stop[:3], b.fol.next_target()[:3], atol=1e-9)
    assert r.stop[2] > TIP0[2] - 2.0 + 1.0                        # well short of the programmed end
    assert (sc.accel, sc.jerk, sc.hold) == (a0, j0, False)
    assert b.mon.state == IDLE


def test_a_hold_before_the_contact_is_kept_after_the_stop():
    cfg = ProbeConfig()
    b = Bench(cfg)
    sc = b.fol.scaler

    def force(k, s):
        if s > 0.4:
            sc.hold = True                 # the operator's hold arrives with the contact
            return 10.0 * cfg.threshold_N
        return 0.0
    r = b.run(force)
    assert r.contact and sc.hold is True


def test_cancel_during_the_stop_gives_the_rate_limits_back():
    cfg = ProbeConfig()
    b = Bench(cfg)
    sc = b.fol.scaler
    a0, j0 = sc.accel, sc.jerk
    for _ in range(3000):
        tg = b.fol.next_target()
        s = float(np.dot(tg[:3] - b.segs[0].start, b.segs[0].direction))
        b.mon.tick(b.fol, tg, b.gauges(tg, 10.0 * cfg.threshold_N if s > 0.4 else 0.0), b.k)
        b.k += 1
        if b.mon.state == STOPPING:
            break
    assert b.mon.state == STOPPING and sc.accel > a0 and sc.hold
    b.mon.cancel(b.fol)
    assert (sc.accel, sc.jerk) == (a0, j0) and b.mon.state == IDLE and b.mon.seg is None and not b.mon.results
    b2 = Bench(cfg)
    b2.mon.cancel(b2.fol)                      # cancel while idle: nothing to give back
    assert b2.mon.state == IDLE and (b2.fol.scaler.accel, b2.fol.scaler.jerk) == (a0, j0)


def test_the_stops_deceleration_is_the_configured_one_within_the_joints_limits():
    """Along the move, the deceleration asked of each joint (|dq/ds| x decel) stays within
    JOINT_SHARE of its limit; the configured value is kept when the joints allow it."""
    seg = Bench().segs[0]
    h = 1e-3
    r = K.ik_batch(np.stack([seg.start, seg.start + h * seg.direction]),
                   np.broadcast_to(seg.axis, (2, 3)), M)
    dq = np.abs(r.q[1] - r.q[0]) / h
    lim = float(np.min(np.asarray(PARAMS.amax) * JOINT_SHARE / np.maximum(dq, 1e-12)))
    for want in (100.0, 1e5):
        mon = ProbeMonitor(M, [seg], ProbeConfig(decel_mm_s2=want), DT, PARAMS)
        a = mon._decel[seg.line]
        assert a == pytest.approx(min(want, lim), rel=1e-4)
        assert np.all(dq * a <= np.asarray(PARAMS.amax) * JOINT_SHARE * (1 + 1e-4))
    assert lim < 1e5                                   # the joints bind at 1e5 mm/s^2
    assert ProbeMonitor(M, [seg], ProbeConfig(decel_mm_s2=1e5), DT, None)._decel[seg.line] == 1e5


@pytest.mark.parametrize("feed_mm_s,cap", [(1.0, 1.0), (5.0, 1.0), (10.0, 0.5), (50.0, 0.1)])
def test_probing_rows_are_flagged_and_capped_at_the_probe_feed_limit(feed_mm_s, cap):
    """max_feed_mm_min 300 = 5 mm/s: a probing piece planned at F600 (10 mm/s) may run at half its
    samples' speed whatever the feed override; slower pieces keep their caps."""
    rows = np.zeros((4, 25))
    rows[:, S_CAP] = [1.0, 0.8, 0.3, 2.0]
    rows[:, S_FLAGS] = [0, 1, 2, 0]
    out = mark_probe_rows(rows.copy(), feed_mm_s, ProbeConfig(max_feed_mm_min=300.0))
    assert out[:, S_FLAGS].tolist() == [FLAG_PROBE, 1 + FLAG_PROBE, 2 + FLAG_PROBE, FLAG_PROBE]
    assert out[:, S_CAP] == pytest.approx(np.minimum([1.0, 0.8, 0.3, 2.0], cap), rel=1e-12)
    lowered = out[:, S_CAP] < rows[:, S_CAP]
    # lowered to the probe feed limit (5 mm/s), never above the planned speed (a cap of 1)
    assert np.allclose(out[lowered, S_CAP], min(1.0, 5.0 / feed_mm_s), rtol=1e-12) and lowered.any()


@pytest.mark.parametrize("fetch", [False, True])
def test_probes_one_after_another_each_judged_on_its_own(fetch):
    """A G38.3 without contact followed directly by a G38.2 that meets a surface 1.5 mm down, then a
    plain move: two results, the first without contact, the second stopped at the surface (the
    monitor given the segments up front, or fetching each as the daemon's rt side does)."""
    cfg = ProbeConfig(decel_mm_s2=1e5)                       # the joints bind: the stop's own deceleration
    z = TIP0[2]
    b = Bench(cfg, text=f"G21 G90\nG38.3 Z{z - 1:.4f} F60\nG38.2 Z{z - 3:.4f} F60\nG1 Z{z - 4:.4f} F60\n",
              fetch=fetch)
    r2 = b.run(lambda k, s: 10.0 * cfg.threshold_N if s > 1.5 else 0.0, ticks=6000, results=2)
    r1 = b.mon.results[0]
    # (recorded at the next move's first target: within a tick's travel, 1 um, of its end)
    assert (r1.line, r1.contact, r1.error) == (2, False, "") and abs(r1.stop[2] - (z - 1)) <= 1.0 * DT
    assert (r2.line, r2.contact, r2.error) == (3, True, "")
    assert z - 1.5 - r2.bound_mm <= r2.stop[2] < z - 1.5
    decel = ProbeMonitor(M, [b.segs[1]], cfg, DT, PARAMS)._decel[3]
    assert decel < 1e5 and b.mon._decel[3] == decel
    assert r2.bound_mm == pytest.approx(1.0 * (cfg.debounce_ticks + 5) * DT + 1.0 / (2 * decel), rel=1e-12)


def test_a_probe_without_contact_followed_by_a_plain_move_hands_over_to_it():
    z = TIP0[2]
    b = Bench(text=f"G21 G90\nG38.3 Z{z - 1:.4f} F60\nG1 Z{z - 1.5:.4f} F60\n")
    r = b.run(lambda k, s: 0.0)
    assert not r.contact and r.line == 2 and b.mon.state == IDLE
    for _ in range(1500):                                   # the plain move runs unwatched to its end
        tg = b.fol.next_target()
        b.mon.tick(b.fol, tg, b.gauges(tg, 0.0), b.k)
        b.k += 1
    assert len(b.mon.results) == 1 and abs(tg[2] - (z - 1.5)) < 1e-6


@pytest.mark.parametrize("feed,decel", [(300, 1000.0), (30, 10.0)])
def test_the_stop_decelerates_at_the_probe_deceleration_reached_within_two_ticks(feed, decel):
    """Along the path, tick by tick: the stop's deceleration reaches the configured one (the joints
    allow it here) within two ticks of the detection (the jerk ramp bound_mm counts) and never
    exceeds it."""
    cfg = ProbeConfig(decel_mm_s2=decel)
    b = Bench(cfg, text="G21 G90\nG38.3 Z{z:.4f} F%d\n" % feed)
    r = b.run(lambda k, s: 10.0 * cfg.threshold_N if s > 0.4 else 0.0)
    assert r.contact and b.mon._decel[2] == decel
    k0 = b.trace[0][0]
    s = np.array([t[1] for t in b.trace])
    v = np.diff(s) / DT
    a = -np.diff(v) / DT                    # a[i]: the change of speed over tick k0 + i + 2
    i = r.tick - k0                         # the stop's first tick
    assert a[i] >= 0.45 * decel and a[i + 1] >= 0.95 * decel
    assert a[i:].max() <= decel * (1 + 1e-3)


@pytest.mark.parametrize("start", [(TIP0, AXIS0), TILTED], ids=["home", "off-centre-tilted"])
def test_a_diagonal_probe_finds_where_the_force_began(start):
    """A probing move along x, y and z at once, from home or from x = 25, y = -15 with the tool
    tilted: the travel is measured from the move's start along its direction, so the contact point
    lies on the line where the force stepped in (within the moving average's reach), and the
    overtravel and the travel past the trigger are the rest point's distances along the move."""
    cfg = ProbeConfig()
    tip0 = start[0]
    b = Bench(cfg, text=f"G21 G90\nG38.2 X{tip0[0] + 1.2:.4f} Y{tip0[1] - 0.9:.4f} Z{{z:.4f}} F60\n", start=start)
    seg = b.segs[0]
    assert min(abs(seg.direction)) > 0.3 and np.allclose(seg.start, tip0)
    r = b.run(lambda k, s: 10.0 * cfg.threshold_N if s > 0.5 else 0.0)
    assert r.contact
    want = seg.start + 0.5 * seg.direction
    assert np.linalg.norm(r.point - want) < cfg.filter_ticks * 1.0 * DT, (r.point, want)
    assert 0.0 < r.after_trigger_mm <= r.bound_mm
    assert r.overtravel_mm == pytest.approx(float(np.dot(r.stop - r.point, seg.direction)), abs=1e-9)
    assert r.after_trigger_mm == pytest.approx(float(np.dot(r.stop - seg.start, seg.direction)) - 0.5,
                                               abs=cfg.filter_ticks * 1.0 * DT)


def test_a_probe_feed_limit_under_1_mm_s_caps_slow_probing_rows_too():
    """max_feed_mm_min 30 (0.5 mm/s): a piece planned at 0.8 mm/s runs at most at 0.5 mm/s."""
    rows = np.zeros((2, 25))
    rows[:, S_CAP] = [1.0, 0.5]
    out = mark_probe_rows(rows, 0.8, ProbeConfig(max_feed_mm_min=30.0))
    assert out[:, S_CAP] * 0.8 == pytest.approx([0.5, 0.4], rel=1e-12)


def test_a_force_step_during_the_tare_of_25_times_the_threshold_stops_the_move():
    """Against the running reference the guard trips at twice the threshold: a step to 2.5 x the
    threshold while the reference is still being taken stops the move (left in the reference, it
    would be tared off and the probe would go on to its end)."""
    cfg = ProbeConfig(tare_ticks=400)
    b = Bench(cfg)
    r = b.run(lambda k, s: 2.5 * cfg.threshold_N if s > 0.1 else 0.0)
    assert ARMED not in [st for *_, st in b.trace]           # stopped from the reference, before arming
    assert r.contact and r.point[2] == pytest.approx(TIP0[2] - 0.1, abs=cfg.filter_ticks * 1.0 * DT)


def test_the_gravity_load_changing_along_a_tilted_line_is_never_read_as_contact():
    """With the tool tilted the chains' gravity loads change along a 6 mm probing line by 7 to 13 mN,
    differently on each chain. The monitor subtracts each chain's own model at the tool's travel,
    so with gauges reading exactly that load and no contact force, even a threshold of 0.1 mN (70
    times smaller than the change, 20 times smaller than the change of one chain's load less
    another's) never trips, and the reference's noise is below 1 uN."""
    cfg = ProbeConfig(threshold_N=1e-4)
    b = Bench(cfg, text=f"G21 G90\nG38.3 Z{TILTED[0][2] - 6.0:.4f} F300\n",
              start=TILTED)
    seg = b.segs[0]
    load = (np.asarray(seg.grid_strain) - np.asarray(seg.grid_strain)[0]) / GAIN        # N, along the line
    change = np.ptp(load, axis=0)
    apart = [np.ptp(load[:, i] - load[:, j]) for i, j in ((0, 1), (1, 2), (2, 0))]
    assert change.min() > 70 * cfg.threshold_N and min(apart) > 20 * cfg.threshold_N, (change, apart)
    r = b.run(lambda k, s: 0.0)
    assert not r.contact and r.error == "" and r.noise_N < 1e-6
    assert abs(r.stop[2] - (TILTED[0][2] - 6.0)) < 1e-6
    # and a force just over that threshold, on the chain whose load changes most, is seen
    b = Bench(cfg, text=f"G21 G90\nG38.3 Z{TILTED[0][2] - 6.0:.4f} F300\n",
              start=TILTED, chain=int(np.argmax(change)))
    r = b.run(lambda k, s: 1.5 * cfg.threshold_N if s > 2.0 else 0.0)
    assert r.contact and np.dot(r.point - seg.start, seg.direction) == pytest.approx(2.0, abs=cfg.filter_ticks * 5.0 * DT)


@pytest.mark.parametrize("share,contact", [((0.0, 1.0, 0.0), False), ((1.0, -0.6, 0.3), True)])
def test_the_reported_noise_is_the_spread_of_the_reference_ticks_per_chain(share, contact):
    """A force alternating +-1 N tick by tick (no moving average: filter_ticks 1) over the 32
    reference ticks: its spread is exactly 1 N x the chain's share, so the reported noise, the rms
    over the three chains, is sqrt(sum(share^2) / 3) N, to the model's interpolation error; in the
    result of a probe that ran to its end and of one stopped by a contact (a 10 x threshold step at
    1 mm, well after the reference)."""
    cfg = ProbeConfig(filter_ticks=1)
    b = Bench(cfg, text="G21 G90\nG38.3 Z{z:.4f} F300\n", chain=share)
    r = b.run(lambda k, s: (1.0 if k % 2 else -1.0) + (10.0 * cfg.threshold_N if contact and s > 1.0 else 0.0))
    assert r.contact == contact and r.error == ""
    assert r.noise_N == pytest.approx(math.sqrt(sum(x * x for x in share) / 3.0), rel=1e-6)


def test_the_reference_is_taken_at_feed_not_while_held_at_the_start():
    """Held at rest at the probe's start, the ball screws hold a static friction load (here 7 N on a
    chain) that motion relieves: no reference tick is taken at rest, however long the hold, so the
    reference is the moving one and the probe runs to its end without a false contact. (Taken at rest
    it would carry the 7 N and read the moving tool as 7 N of contact.)"""
    cfg = ProbeConfig()
    b = Bench(cfg, text="G21 G90\nG38.2 Z{z:.4f} F300\n")
    sc = b.fol.scaler
    sc.sigma, sc.hold = 0.0, True
    for _ in range(3 * (cfg.tare_ticks + cfg.filter_ticks)):
        tg = b.fol.next_target()
        b.mon.tick(b.fol, tg, b.gauges(tg, 7.0), b.k)
        b.k += 1
    assert sc.sigma == 0.0 and b.mon.state == TARE and b.mon.n_tare == 0
    sc.hold = False
    r = b.run(lambda k, s: 0.0)
    assert not r.contact and r.error.startswith("probe fail")
    assert abs(r.stop[2] - (TIP0[2] - 2.0)) < 1e-6


def test_the_tare_guard_watches_from_its_first_reference_tick():
    """A force of 6 x the threshold that steps in at reference tick TARE_GUARD (no moving average)
    is seen on that very tick: against the running reference it is 7/8 of itself, over twice the
    threshold."""
    cfg = ProbeConfig(tare_ticks=400, filter_ticks=1)
    b = Bench(cfg)
    on = []

    def force(k, s):
        if not on and b.mon.state == TARE and b.mon.n_tare + 1 == TARE_GUARD:
            on.append(k)
        return 6.0 * cfg.threshold_N if on else 0.0
    r = b.run(force)
    assert r.contact and on and r.tick == on[0]
