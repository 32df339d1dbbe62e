"""Feed hold and stop requests in the middle of a rapid, and the follower's starvation margin, pinned
at their boundaries in both path followers (timescale.PathFollower and the compiled
CompiledFollower), through the control loop, through `pmctl run` (SIGTERM) and through the console
(`!`). A rapid (G0) is where a hold matters most (the fastest moves) and where the existing hold
tests, all on feed moves, would not notice it ignored.

The bound: a hold at sigma = 1 brings sigma to 0 in 1/accel (sigma's rate limit, ``accel`` =
0.45 min(a_max/v_max) = 9 /s: the tool's v/a) plus the jerk ramp accel/jerk (50 ms) -- 161 ticks
at 1 kHz; the joints follow within the NC's lag. Offline ticks except where the fact needs the clock
(a signal or a console byte arriving during a move).
"""

import json
import os
import signal
import time

import numpy as np
import pytest

from grbl_sender import Sender, start_serve, stop_serve
from pmctl import hal
from pmctl.core.config import load_machine
from pmctl.core.recording import read_recording
from pmctl.motion.loop import ControlLoop
from pmctl.motion.nc import NCParams, counts_of, initial_state
from pmctl.motion.recorder import REC_CAPACITY, REC_WIDTH, Recorder
from pmctl.motion.ring import ArraySource, Ring
from pmctl.motion.service_config import LoopConfig
from pmctl.motion.timescale import (FLAG_RAPID, HELD, IDLE, S_FLAGS, STARVED, WIDTH, iter_job_rows,
                                    make_follower, scaling_limits)
from pmctl.task.gcode import parse_gcode
from pmctl.core.job import RAPID, home_pose
from pmctl.task.planner import PlannerLimits, plan
from test_first_hour import _start_and_wait_for_loop
from service_support import sim_service as _service
from test_run_client import PMCTL

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

M = load_machine()
DT = 1e-3
PARAMS = NCParams.from_machine(M, DT, kv=400.0)
ACCEL, JERK = scaling_limits(PARAMS)
V_RAPID = PlannerLimits().rapid_mm_s
STOP_TICKS = int(np.ceil((1.0 / ACCEL + ACCEL / JERK) / DT)) + 10      # 1/accel + the jerk ramp + 10 ticks
HOLD_AT = 600                 # mid-G0: 0.6 s into a 1.4 s rapid, at full speed


def _rows(text, start=None):
    """Follower rows of a G-code job from home (or ``start``: tip, axis), its rapids flagged as the
    supervisor flags them."""
    tip, axis = start if start is not None else home_pose(M)
    job = parse_gcode(text, "t.ngc", tip, axis)
    tr = plan(job, M, DT, start=(tip, axis))
    rapid = np.isin(tr.line, [m.line for m in job.moves if m.kind == RAPID])
    return np.concatenate(list(iter_job_rows(tr, M, PARAMS, rapid=rapid))), tr


G0_JOB = "G21 G90\nG0 X-60\nG1 X-55 F600\n"


@pytest.mark.parametrize("impl", ["python", "compiled"])
def test_a_feed_hold_in_the_middle_of_a_long_g0_stops_within_v_over_a(impl):
    """Held at full rapid speed (50 mm/s) in the middle of a 60 mm G0: sigma reaches 0 within
    1/accel + accel/jerk + 10 ticks, every target after that is the same point (no feed-forward),
    the tool travelled at most v^2/(2 a) + v x (the jerk ramp) beyond where the hold came, and after
    the resume the path runs to its end."""
    rows, tr = _rows(G0_JOB)
    fol = make_follower(ArraySource(rows), PARAMS, DT, implementation=impl)
    fol.scaler.sigma = 1.0
    tg, sig, state = [], [], []
    for k in range(HOLD_AT + 1500):
        if k == HOLD_AT:
            assert int(fol.src.row(0)[S_FLAGS]) & FLAG_RAPID           # in the G0
            fol.scaler.hold = True
        tg.append(fol.next_target().copy())
        sig.append(fol.sigma)
        state.append(fol.state)
    tg, sig = np.array(tg), np.array(sig)
    v_hold = np.linalg.norm(tg[HOLD_AT - 1, 6:9])
    assert v_hold > 0.98 * V_RAPID and sig[HOLD_AT - 1] == 1.0
    rest = HOLD_AT + int(np.argmax(sig[HOLD_AT:] == 0.0))
    assert sig[rest] == 0.0 and rest - HOLD_AT <= STOP_TICKS, rest - HOLD_AT
    assert np.all(sig[rest:] == 0.0) and np.all(tg[rest + 1:, 6:] == 0.0)
    assert np.all(tg[rest + 1:, :6] == tg[rest + 1, :6]) and state[-1] == HELD
    travel = np.linalg.norm(tg[rest + 1, :3] - tg[HOLD_AT, :3])
    a_tip = v_hold * ACCEL
    assert travel <= v_hold ** 2 / (2 * a_tip) + v_hold * (ACCEL / JERK + 0.01), travel
    assert np.linalg.norm(tg[rest + 1, :3] - tr.tip[-1]) > 10.0         # stopped mid-G0, not at its end
    fol.scaler.hold = False
    for _ in range(4000):
        t = fol.next_target()
        if fol.at_end:
            break
    assert fol.at_end and np.array_equal(t[:3], tr.tip[-1])


@pytest.mark.parametrize("impl", ["python", "compiled"])
def test_the_counters_stop_after_a_hold_in_a_g0(impl):
    """The same hold through the control loop against the sim: the pulse counters stop changing
    (within the pulse the NC may settle by) within the follower's bound plus the NC's lag, and stay;
    every pulse sent is in the counters."""
    rows, tr = _rows(G0_JOB)
    params = NCParams.from_machine(M, DT, kv=400.0, implementation=impl)
    fol = make_follower(ArraySource(rows), params, DT, implementation=impl)
    fol.scaler.sigma = 1.0
    q0 = np.array([M.geometry.z_home] * 3 + [0.0, 0.0])
    c0 = counts_of(q0, params)
    be = hal.create("sim", M, DT, {})
    be.open(c0)

    def hook(lp, k, st):
        if k == HOLD_AT:
            lp.follower.scaler.hold = True
        if k == HOLD_AT + 1200:
            lp.quit = True
        return st

    ring = Ring(REC_CAPACITY, REC_WIDTH)
    lp = ControlLoop(M, be, params, None, LoopConfig(realtime=False, stall_timeout_s=5.0), initial_state(M, c0),
                     log=lambda m: None, follower=fol, hook=hook, records=ring, recorder=Recorder(ring, keep=True))
    assert lp.nc.implementation == impl
    res = lp.run()
    counts = res.counts
    speed = np.abs(np.diff(counts[:, 3])) / params.pulses_per_mm[3] / DT
    assert speed[HOLD_AT - 50:HOLD_AT].min() > 0.95 * V_RAPID             # X at rapid speed at the hold
    settle = HOLD_AT + STOP_TICKS + 30                                      # + the NC's lag (kv 400: 2.5 ms)
    still = counts[settle:]
    assert len(still) > 800 and np.abs(still - still[0]).max() <= 1, np.abs(still - still[0]).max(0)
    assert np.array_equal(c0 + res.pulses_sent, res.state.counts) and np.array_equal(be.counts, res.state.counts)


@pytest.mark.parametrize("impl", ["python", "compiled"])
def test_jobs_back_to_back_stop_on_each_end_and_an_empty_queue_holds_the_rest_pose(impl):
    """Nothing queued: the target is the rest pose, at rest (IDLE, HELD under a hold). A job: the
    follower stops exactly on its last sample, counts it once, stays there at rest; a hold there is
    HELD; a second job queued behind it starts from it and ends on its own last sample, counted."""
    tip0, axis0 = (np.asarray(x, float) for x in home_pose(M))
    ring = Ring(8192, WIDTH)
    fol = make_follower(ring, PARAMS, DT, implementation=impl, pose=list(tip0) + list(axis0))
    for hold, want in ((False, IDLE), (True, HELD), (False, IDLE)):
        fol.scaler.hold = hold
        tg = fol.next_target()
        assert fol.state == want and np.array_equal(tg, np.r_[tip0, axis0, np.zeros(6)])
    a, tra = _rows("G21 G90\nG0 X-8\n")
    b, trb = _rows("G21 G90\nG1 X-2 Y3 F1200\n", start=(tra.tip[-1], tra.axis[-1]))
    ring.push(a)
    ends = []
    for k in range(3000):
        tg = fol.next_target().copy()
        ends.append(fol.ended_jobs)
        if k == 2000:
            ring.push(b)
        if 1500 <= k < 1600:
            assert fol.at_end and fol.state == IDLE and fol.ended_jobs == 1
            assert np.array_equal(tg, np.r_[tra.tip[-1], tra.axis[-1], np.zeros(6)])
        if k == 1600:
            fol.scaler.hold = True
        if k == 1601:
            assert fol.state == HELD and np.array_equal(tg[:6], np.r_[tra.tip[-1], tra.axis[-1]])
        if k == 1700:
            fol.scaler.hold = False
    assert fol.at_end and fol.ended_jobs == 2 and fol.state == IDLE and ring.count() == 1
    assert np.array_equal(tg, np.r_[trb.tip[-1], trb.axis[-1], np.zeros(6)])
    assert ends.count(1) > 1000 and sorted(set(ends)) == [0, 1, 2]      # each end counted once


def _steady_sigma(impl, ahead):
    """sigma of a follower whose queue the planner keeps at exactly ``ahead`` samples of a fast G1
    (no job end among them): the starvation rule's own speed."""
    rows, _ = _rows("G21 G90\nG1 X-60 F3000\n")
    ring = Ring(4096, WIDTH)
    fol = make_follower(ring, PARAMS, DT, implementation=impl)
    fed = ring.push(rows[:ahead])
    fol.scaler.sigma = 1.0
    out = []
    for k in range(1500):
        fol.next_target()
        fed += ring.push(rows[fed:fed + ahead - ring.count()])
        out.append((fol.sigma, fol.state, ring.count() - 1 - fol.frac))
    return out


@pytest.mark.parametrize("impl", ["python", "compiled"])
@pytest.mark.parametrize("ahead", [40, 90])
def test_a_starved_follower_keeps_the_speed_that_can_still_stop_with_the_margin(impl, ahead):
    """With the queue kept at ``ahead`` samples and no job end in it, sigma settles where a stop at
    half the rate limit fits 0.9 x into what is queued: sigma = 0.9 sqrt(accel x tau_left) (tau_left =
    the samples left ahead x dt), within 2 %: not faster (the 10 % margin gone) and not slower; the
    state says why."""
    out = _steady_sigma(impl, ahead)
    sig = np.array([s for s, _, _ in out[1000:]])
    left = np.array([r for _, _, r in out[999:-1]]) * DT
    want = 0.9 * np.sqrt(ACCEL * left)
    assert want.max() < 0.9                                   # the rule binds (below the feed's sigma 1)
    assert np.all(np.abs(sig / want - 1.0) < 0.02), (sig[:5], want[:5])
    assert all(st == STARVED for _, st, _ in out[1000:])


# ---------------------------------------------------------------- SIGTERM and the console, in real time

@pytest.mark.parametrize("to", ["client", "rt"])
def test_sigterm_during_a_rapid_stops_it_on_the_line_within_v_over_a(tmp_path, to):
    """`pmctl run` (real time: the signal must arrive during a move) of a job of nothing but long
    rapids; SIGTERM, to the client or to the rt process alone (systemctl stop signals both), once the
    table moves through the middle of one: a controlled stop there, the counters saved clean, far
    from every programmed point, on the line (Y and the chains never move), the table braking from
    the rapid's speed to rest within 1/accel + the jerk ramp + the NC's lag."""
    job = tmp_path / "rapids.ngc"
    job.write_text("G21 G90\nG0 X-70\nG0 X70\nG0 X-70\nG0 X70\nM2\n")
    state = tmp_path / "state.json"
    args = [*PMCTL, "run", "--job", str(job), "--service", str(_service(tmp_path)), "--state", str(state),
            "--record", str(tmp_path / "rec"), "--quiet"]
    p, seen_lines = _start_and_wait_for_loop(args)
    rt_pid = int(seen_lines[-1].split("(pid ")[1].split(")")[0])
    try:
        # the signal goes once the counters the rt process saves every 100 ticks show the table moving
        # through the middle of a rapid (10 < |X| < 30 mm: full speed there), whatever the machine's load
        t0, seen = time.monotonic(), None
        while time.monotonic() - t0 < 120 and p.poll() is None:
            try:
                x = json.loads(state.read_text())["counts"][3] / 2000.0
            except (OSError, ValueError, KeyError):
                x = None
            if x is not None and seen is not None and x != seen and 10.0 < abs(x) < 30.0:
                break
            seen = x
            time.sleep(0.01)
        assert p.poll() is None, "the run ended before the signal"
        if to == "client":
            p.send_signal(signal.SIGTERM)
        else:                              # systemctl stop signals every process of the unit: the rt side brakes by itself
            os.kill(rt_pid, signal.SIGTERM)
        out, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    if to == "client":
        assert p.returncode == 3 and "result: stopped (stop requested (SIGTERM" in out, out + err
    else:                                  # (the client reports the rt side's exit as a fault: its own matter)
        assert "pmctl rt: stopped: SIGTERM;" in err, out + err
    assert json.loads(state.read_text())["clean"] is True
    rec = read_recording(tmp_path / "rec")
    x = rec["cmd_X"]
    v = np.diff(x) / DT
    fast = np.nonzero(np.abs(v) > 0.95 * V_RAPID)[0]
    assert len(fast), "never at rapid speed"
    last_fast = fast[-1]
    still = np.nonzero(np.abs(v) > 0.5 / 2000 / DT)[0][-1] + 1     # from here on at most a pulse a tick
    assert still - last_fast <= STOP_TICKS + 30, still - last_fast
    # stopped mid-rapid: nowhere near a programmed X, and nothing else moved (on the line)
    assert min(abs(x[-1] - 70.0), abs(x[-1] + 70.0)) > 5.0, x[-1]
    for c in ("cmd_Y", "cmd_L1", "cmd_L2", "cmd_L3"):
        assert np.ptp(rec[c]) < 2e-3, c


def test_a_console_hold_during_a_g0_stops_it_and_the_position_stays(tmp_path):
    """`pmctl serve` in real time, a 140 mm G0 sent from the console, `!` once the table moves at
    rapid speed: Hold:0 within v/a (and the status loop's latency) of where it was, far short of the
    G0's end; the position then stays put; `~` finishes the G0 on its programmed end."""
    p, link = start_serve(tmp_path, realtime=True)
    s = Sender(link)
    try:
        s.reset()
        p0 = np.array(s.status()["pos"])
        assert s.send("G21 G91 G0 X-70") == "ok"
        assert s.wait_state(("Idle",), 60)["state"] == "Idle"
        assert s.send("G0 X140") == "ok"
        t0 = time.time()
        seen = s.status()
        while seen["pos"][0] - p0[0] < -40 and time.time() - t0 < 60:    # under way, well into the G0
            seen = s.status()
        assert seen["state"] == "Run", seen
        s.realtime(b"!")
        held = s.wait_state(("Hold:0",), 30)
        assert held["state"] == "Hold:0", held
        x_seen, x_held = seen["pos"][0], held["pos"][0]
        assert 0.0 <= x_held - x_seen <= 15.0, (x_seen, x_held)         # v/a is 5.6 mm; the rest is latency
        assert x_held - p0[0] < 60.0                                     # far short of the G0's end (+70)
        time.sleep(0.5)
        assert np.allclose(s.status()["pos"], held["pos"], atol=2e-3)   # the counters stopped
        s.realtime(b"~")
        done = s.wait_state(("Idle",), 60)
        assert abs(done["pos"][0] - (p0[0] + 70.0)) < 2e-3, done
        assert s.send("G90") == "ok"
    finally:
        s.close()
        assert stop_serve(p) == 0


@pytest.mark.parametrize("impl", ["python", "compiled"])
def test_the_rapid_override_takes_only_grbls_three_values_and_scales_rapids_not_feeds(impl):
    """0.25, 0.5 or 1 (the nearest, whatever is asked); a G0 then runs at that share of the rapid
    speed, the G1 after it at its own feed (the feed override 1)."""
    rows, tr = _rows(G0_JOB)
    fol = make_follower(ArraySource(rows), PARAMS, DT, implementation=impl)
    sc = fol.scaler
    for ask, got in ((0.3, 0.25), (0.4, 0.5), (0.1, 0.25), (2.0, 1.0), (0.74, 0.5), (0.76, 1.0)):
        assert sc.set_rapid_override(ask) == got and sc.rapid_override == got
    sc.set_rapid_override(0.5)
    sigmas, rapid = [], []
    for _ in range(6000):
        r0 = fol.src.row(0) if fol.src.count() else None
        fol.next_target()
        sigmas.append(fol.sigma)
        rapid.append(r0 is not None and bool(int(r0[S_FLAGS]) & FLAG_RAPID))
        if fol.at_end:
            break
    sigmas, rapid = np.array(sigmas), np.array(rapid)
    assert np.max(sigmas[rapid]) == 0.5 and np.max(sigmas[~rapid]) == 1.0
