"""The control loop's stop rules (pmctl.motion.loop.ControlLoop.run) at their boundaries, offline
against the loopback sim (a real-time run only where the rule is about the clock):

- a backend fault on read or write halts at once, and the counters follow what the device says it
  executed (a step/dir bridge reports its counters with the fault);
- a stop request holds on the path and halts at the first tick the joints are at rest (rates within
  2 Kv/ppm, a pulse or two's worth), or once the settling time has passed;
- a job ends the settling time after the tool rests on its last sample;
- quit ends the loop as stopped or, after a fault, as a fault, with its reason;
- a stall while nothing is commanded to move (the job done, settling) stops nothing; one during a
  move is handed to ``on_stall`` (the sim rides it out as a feed hold) when there is one;
- a backend that takes joint positions (CSP drives) is given the counters in mm;
- chain-length offset inputs beyond the chains or the bound are refused, said once, and the rest kept.
"""

import re
import time

import numpy as np
import pytest

from pmctl import hal
from pmctl.core.config import load_machine
from pmctl.hal.sim import SimBackend
from pmctl.hal.stepdir import BridgeFault, BridgeTimeout
from pmctl.motion.loop import ControlLoop, _was_stop, prepare
from pmctl.motion.nc import HALTED, NCParams, counts_of, initial_state
from pmctl.motion.service_config import LoopConfig
from test_loop import line_traj, rp

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

M = load_machine()
DT = 1e-3
P = NCParams.from_machine(M, DT, kv=400.0)
REST = 2.0 * P.kv / P.pulses_per_mm            # the loop's "at rest": rates within a pulse or two's worth


def _loop(tr=None, *, be=None, cfg=None, hook=None, logs=None, **kw):
    tr = tr if tr is not None else line_traj([0, 0, 5], [10, 0, 5], rp(0, 0), rp(0, 0), 10.0, DT)
    tg = prepare(M, P, tr, DT)
    c0 = counts_of(tg.q[0], P)
    be = be or hal.create("sim", M, DT, {})
    be.open(c0)
    cfg = cfg or LoopConfig(realtime=False, stall_timeout_s=5.0)
    lp = ControlLoop(M, be, P, tg, cfg, initial_state(M, c0), hook=hook,
                     log=(logs.append if logs is not None else (lambda m: None)), **kw)
    return lp, be, c0, tg


class _DeviceFault(SimBackend):
    """The sim as a step/dir bridge that faults at tick ``at`` (on read or on write) and reports the
    counters it executed: all but the last ``behind`` ticks' pulses."""

    def __init__(self, *a, at=200, where="read", timeout=False, behind=1, **k):
        super().__init__(*a, **k)
        self.at, self.where, self.timeout, self.behind = at, where, timeout, behind
        self.history = []

    def _fault(self):
        done = self.history[-1 - self.behind] if len(self.history) > self.behind else self.history[0]
        cls = BridgeTimeout if self.timeout else BridgeFault
        raise cls("bridge: link lost", counts=done)

    def read(self):
        if self.where == "read" and self.tick == self.at:
            self._fault()
        return super().read()

    def write_pulses(self, pulses):
        if self.where == "write" and self.tick == self.at:
            self._fault()
        super().write_pulses(pulses)
        self.history.append(self.counts.copy())

    def open(self, counts):
        super().open(counts)
        self.history = [np.array(counts, np.int64)]


@pytest.mark.parametrize("where,timeout", [("read", False), ("read", True), ("write", False)])
def test_a_backend_fault_halts_at_once_and_the_counters_follow_the_device(where, timeout):
    be = _DeviceFault(M, DT, {}, at=200, where=where, timeout=timeout, behind=2)
    lp, be, c0, tg = _loop(be=be)
    res = lp.run()
    assert res.status == "fault" and res.ticks == 200
    assert res.reason == ("backend not answering: " if timeout else "backend fault: ") + "bridge: link lost"
    assert res.state.mode == HALTED and res.state.reason == res.reason
    executed = be.history[-3]                     # what the bridge says it executed
    assert not np.array_equal(executed, c0 + res.pulses_sent)        # (it is behind the commands)
    assert np.array_equal(res.state.counts, executed)


SLOW = NCParams.from_machine(M, DT, kv=20.0)   # a small rest band: 2 x 20 / 2000 = 0.02 mm/s
SLOW_REST = 2.0 * SLOW.kv / SLOW.pulses_per_mm
OFFSET_MM = 0.01     # a chain-length correction given during the hold: slewed at 0.05 mm/s, 0.2 s


def _stop_at(k0, settle_s):
    """A 10 mm/s line, a stop requested at tick k0, and 100 ticks later (the path still braking) a
    0.01 mm chain-length offset on L1, which the NC slews in at chain_offset_rate_mm_s (0.05 mm/s,
    above the rest band): the joints still move once the path is held. Returns (result, loop, the
    ticks at which the path was held, each tick's largest joint rate over the rest band)."""
    held, ratio = [], []

    def hook(loop, k, st):
        if k == k0:
            loop.stop_request = "operator stop"
        if k == k0 + 100:
            assert loop.follower.sigma > 0.0              # (still braking on the path)
            assert loop.set_chain_offsets([OFFSET_MM, 0.0, 0.0])
        if loop.stop_request and loop.follower.sigma == 0.0:
            held.append(k)
        ratio.append(float(np.max(np.abs(st.qdot) / SLOW_REST)))
        return st
    tr = line_traj([0, 0, 5], [10, 0, 5], rp(0, 0), rp(0, 0), 10.0, DT)
    tg = prepare(M, SLOW, tr, DT)
    c0 = counts_of(tg.q[0], SLOW)
    be = hal.create("sim", M, DT, {})
    be.open(c0)
    lp = ControlLoop(M, be, SLOW, tg, LoopConfig(realtime=False, stall_timeout_s=5.0, settle_s=settle_s),
                     initial_state(M, c0), hook=hook, log=lambda m: None)
    res = lp.run()
    assert np.array_equal(be.counts, res.state.counts)
    return res, lp, held, ratio


def test_a_stop_request_holds_on_the_path_and_halts_at_the_first_tick_at_rest():
    """Held on the path (sigma 0) the joints still move (the chain offset slewing in); the loop halts
    at the first tick their rates are within 2 Kv/ppm (a pulse or two's worth), not before, not later:
    with the offset applied in full."""
    res, lp, held, ratio = _stop_at(300, 1.0)
    assert res.status == "stopped" and res.reason == "operator stop"
    assert res.state.mode == HALTED and res.state.reason == "operator stop"
    # ratio[i] is tick i + 1's; held[0] is the first tick (1-based) held on the path
    assert ratio[-1] <= 1.0 and all(r > 1.0 for r in ratio[held[0] - 1:-1])
    assert res.ticks - held[0] > 20                       # (the slew took its time: the rule decided)
    assert res.state.offset is not None and res.state.offset[0] == pytest.approx(OFFSET_MM, abs=1e-12)
    x = res.target[-1, 0]
    assert 1.0 < x < 9.0 and np.allclose(res.target[-1, 1:3], [0.0, 5.0], atol=1e-9)   # on the line, short of its end


def test_held_but_not_at_rest_the_stop_halts_after_the_settling_time():
    res, lp, held, ratio = _stop_at(300, 0.02)
    assert res.status == "stopped" and res.reason == "operator stop"
    assert ratio[-1] > 1.0                                # not at rest yet
    assert res.ticks == held[0] + lp.settle_ticks and lp.settle_ticks == 20
    assert 0.0 < res.state.offset[0] < OFFSET_MM          # the offset only partly applied


def test_a_job_ends_the_settling_time_after_the_tool_rests_on_its_last_sample():
    """The tool reaches the last sample at tick ``last``, the follower rests on it from the next, and
    the NC runs on for the settling time before the job is done."""
    tr = line_traj([0, 0, 5], [3, 0, 5], rp(0, 0), rp(0, 0), 10.0, DT)
    for settle in (0.02, 0.07):
        lp, be, c0, tg = _loop(tr, cfg=LoopConfig(realtime=False, stall_timeout_s=5.0, settle_s=settle))
        res = lp.run()
        assert res.status == "done" and res.reason == ""
        last = int(np.argmax(res.path_s >= res.path_s[-1]))      # the first tick on the last sample
        assert res.ticks - last == round(settle / DT) + 2, (settle, res.ticks, last)
        assert res.state.mode == 3                                  # DONE


@pytest.mark.parametrize("reason", ["", "shutting down"])
def test_quit_ends_the_loop_as_a_stop_with_its_reason(reason):
    def hook(loop, k, st):
        if k == 150:
            loop.quit, loop.quit_reason = True, reason
        return st
    lp, be, c0, tg = _loop(hook=hook)
    res = lp.run()
    assert res.status == "stopped" and res.reason == (reason or "quit") and res.ticks == 150


def _quit_once_halted(halted, running=None):
    """A hook that notes the ticks the NC is halted in ``halted`` and quits at the 20th; ``running(k)``
    runs on the others."""
    def hook(loop, k, st):
        if st.mode == HALTED:
            halted.append(k)
            if len(halted) == 20:
                loop.quit = True
        elif running is not None:
            running(k)
        return st
    return hook


def test_quit_after_a_fault_is_a_fault_with_the_faults_reason():
    """exit_when_done=False (the daemon's rt loop): a following-error fault halts the NC, the loop
    runs on; quit then ends it as the fault it was."""
    halted = []
    hook = _quit_once_halted(halted)
    be = hal.create("sim", M, DT, {"lost_steps_at_tick": 200, "lost_steps_axis": 3, "lost_steps_mm": 0.5})
    lp, be, c0, tg = _loop(be=be, hook=hook, exit_when_done=False)
    res = lp.run()
    assert res.status == "fault" and res.reason.startswith("following error: X")
    assert res.ticks == halted[0] + 19


@pytest.mark.parametrize("reason,stop", [("following error: X 0.2 mm", False), ("model pose lost: no FK", False),
                                         ("soft limit: X", True), ("path error 0.6 mm", True),
                                         ("operator stop", True)])
def test_a_halt_is_a_fault_for_a_lost_axis_or_model_and_a_stop_otherwise(reason, stop):
    lp, be, c0, tg = _loop()
    assert _was_stop(lp.state0.halted(reason)) is stop


def test_a_stall_while_nothing_moves_stops_nothing():
    """Real time: the process sleeps 0.8 s (over the 0.3 s stall limit) once the job is done and the
    loop settles; the drives were given nothing to do, so the run ends done, the stall said in the
    log. (The limit is ten times a busy machine's scheduling delay: a CPU hog beside the test does
    not make a stall during the short move.)"""
    logs = []
    tr = line_traj([0, 0, 5], [0.5, 0, 5], rp(0, 0), rp(0, 0), 10.0, DT)
    cfg = LoopConfig(realtime=True, lock_memory=False, stall_timeout_s=0.3, max_overruns_in_row=10**6,
                     settle_s=0.2)
    slept = []

    def hook(loop, k, st):
        if not slept and loop.follower.at_end and k > 20:
            slept.append(k)
            time.sleep(0.8)
        return st
    lp, be, c0, tg = _loop(tr, cfg=cfg, hook=hook, logs=logs)
    res = lp.run()
    assert slept and res.status == "done", res.reason
    assert lp.stalls >= 1
    assert any("at rest, nothing was commanded to move: no stop" in m for m in logs), logs


STALL = re.compile(r"^loop stalled: ([0-9.]+) ms between two commands, ([0-9.]+) ms of it computing "
                   r"\(limit ([0-9.]+) ms\)(?:; the process was not scheduled for ([0-9]+) ms: .*)?$")


def test_a_stall_during_a_move_goes_to_on_stall_when_there_is_one():
    """Two 60 ms sleeps during a move (stall limit 30 ms): each goes to ``on_stall`` with a reason that
    says the gap between two commands (at least the sleep, at most the run's duration), the part of
    it spent computing (no more than the gap), the limit, and the time the process was not running."""
    tr = line_traj([0, 0, 5], [10, 0, 5], rp(0, 0), rp(0, 0), 10.0, DT)
    cfg = LoopConfig(realtime=True, lock_memory=False, stall_timeout_s=0.03, max_overruns_in_row=10**6)
    told = []

    def hook(loop, k, st):
        if k in (300, 600):
            time.sleep(0.06)
        return st
    lp, be, c0, tg = _loop(tr, cfg=cfg, hook=hook)
    lp.on_stall = told.append
    t0 = time.monotonic()
    res = lp.run()
    run_ms = (time.monotonic() - t0) * 1e3
    assert res.status == "done", res.reason
    assert lp.stalls == len(told) >= 2            # (a busy machine may add stalls of its own)
    slept = 0
    for why in told:
        m = STALL.match(why)
        assert m, why
        gap, comp, lim = float(m[1]), float(m[2]), float(m[3])
        assert lim == 30.0 and 30.0 <= gap <= run_ms and 0.0 <= comp <= gap + 0.1, why
        if m[4] is not None:
            assert abs(int(m[4]) - (gap - comp)) <= 1.0, why
        if gap >= 60.0:
            slept += 1
            assert m[4] is not None, why          # a sleep, not computing: the hint says so
    assert slept >= 2


def test_missed_deadlines_in_a_row_stop_at_the_limit_and_quit_then_is_a_stop():
    """Real time, exit_when_done=False (the daemon's rt loop): from tick 300 every tick overruns its
    1 ms deadline (the hook sleeps 3 ms); the run is stopped (braked, then halted) when the count in a
    row reaches max_overruns_in_row, and says that count; quit after the halt ends it as a stop, with
    the stop's reason."""
    halted = []
    hook = _quit_once_halted(halted, running=lambda k: time.sleep(0.003) if k >= 300 else None)
    cfg = LoopConfig(realtime=True, lock_memory=False, stall_timeout_s=5.0, max_overruns_in_row=4)
    lp, be, c0, tg = _loop(cfg=cfg, hook=hook, exit_when_done=False)
    res = lp.run()
    assert res.reason == "4 deadlines missed in a row at 1000 Hz"
    assert res.status == "stopped" and res.state.mode == HALTED
    assert res.timing.max_overruns_in_row >= 4


def test_an_unexpected_error_after_the_backend_took_the_pulses_halts_with_them_counted():
    """An error of the loop's own (here: in the hook, after the tick's pulses were written) halts it
    with the error's text; the pulses the backend took are in the counters: they equal the device's."""
    def hook(loop, k, st):
        if k == 150:
            raise RuntimeError("boom")
        return st
    lp, be, c0, tg = _loop(hook=hook)
    res = lp.run()
    assert res.status == "fault" and res.reason == "loop error at tick 150: RuntimeError: boom"
    assert res.state.mode == HALTED
    assert np.array_equal(res.state.counts, be.counts) and np.array_equal(be.counts, c0 + res.pulses_sent)


def test_an_offline_run_reports_no_slow_ticks_when_none_took_the_stall_limit():
    logs = []
    lp, be, c0, tg = _loop(logs=logs)
    res = lp.run()
    assert res.status == "done"
    assert not [m for m in logs if "took longer than the stall limit" in m], logs


class _PositionSim(SimBackend):
    """The sim behind a position interface (a CSP drive: the target in mm, its own steps)."""
    accepts = "positions"

    def write_positions(self, q):
        self.given.append(np.array(q))
        super().write_pulses(np.rint(np.asarray(q) * self.ppm).astype(np.int64) - self.counts)

    def open(self, counts):
        super().open(counts)
        self.given = []


def test_a_backend_that_takes_positions_is_given_the_counters_in_mm():
    lp, be, c0, tg = _loop(be=_PositionSim(M, DT, {}))
    res = lp.run()
    assert res.status == "done", res.reason
    assert np.allclose(be.given[-1], res.state.counts / P.pulses_per_mm, atol=1e-12)
    assert np.array_equal(be.counts, res.state.counts)
    assert np.allclose(res.state.counts / P.pulses_per_mm, tg.q[-1], atol=1.0 / P.pulses_per_mm)


def test_chain_offset_inputs_beyond_the_chains_or_the_bound_are_refused_once_and_the_rest_kept():
    logs = []
    lp, be, c0, tg = _loop(logs=logs)
    lim = P.chain_offset_max_mm
    assert lp.set_chain_offsets([0.1, -0.15, 0.12]) is True and np.array_equal(lp.chain_offset, [0.1, -0.15, 0.12])
    assert lp.set_chain_offsets({3: 0.1, 0: 0.05}) is False         # no chain 3; chain 0 taken
    assert np.array_equal(lp.chain_offset, [0.05, -0.15, 0.12])
    assert logs == ["chain offset refused: chain 3 is not 0, 1 or 2 (L1, L2, L3)"]
    assert not lp.set_chain_offsets({-1: 0.1})
    for bad in (lim * 1.001, -lim * 1.001, float("nan"), float("inf")):
        assert not lp.set_chain_offset(1, bad)
        assert np.array_equal(lp.chain_offset, [0.05, -0.15, 0.12])
    refused = [m for m in logs if m.startswith("chain offset refused: L2 ")]
    assert len(refused) == 1 and "the offset stays at -0.1500 mm" in refused[0]      # said once
    assert lp.set_chain_offset(1, lim) and lp.chain_offset[1] == lim                # the bound itself is in
    assert not lp.set_chain_offset(1, float("nan"))
    assert len([m for m in logs if m.startswith("chain offset refused: L2 ")]) == 2   # said again after a good one
    assert lp.set_chain_offsets((0.0, 0.0, -lim)) and np.array_equal(lp.chain_offset, [0.0, 0.0, -lim])
    assert lp.set_chain_offsets((0.03, 2 * lim, 0.04)) is False     # one beyond the bound: the others taken
    assert np.array_equal(lp.chain_offset, [0.03, 0.0, 0.04])


@pytest.mark.parametrize("impl", ["python", "compiled"])
def test_a_job_of_one_sample_queued_as_the_last_one_ends_is_run_and_settled_before_the_loop_ends(impl):
    """The daemon's rt process queues jobs between ticks: a one-sample job (a G4 P0, a lone M3) that
    arrives on the tick the follower reaches the first job's end is still run: both job ends are
    counted and the loop ends after the settling time on the appended sample, later than the first
    job alone (it must not end on the first job's settling time with a job still queued)."""
    from dataclasses import replace
    from pmctl.motion.loop import LoopParts, target_samples
    from pmctl.motion.ring import Ring
    from pmctl.motion.timescale import WIDTH, make_follower

    def go(append):
        tr = line_traj([0, 0, 5], [3, 0, 5], rp(0, 0), rp(0, 0), 10.0, DT)
        tg = prepare(M, P, tr, DT)
        rows = target_samples(tg, DT, P)
        c0 = counts_of(tg.q[0], P)
        be = hal.create("sim", M, DT, {})
        be.open(c0)
        fol = make_follower(Ring(8192, WIDTH), replace(P, implementation=impl), DT)
        fol.src.push(rows)
        pushed = []

        def hook(loop, k, st):
            if append and not pushed and fol.at_end:
                pushed.append(k)
                fol.src.push(rows[-1:])                    # one sample, a job end, where the tool is
            return st
        cfg = LoopConfig(realtime=False, stall_timeout_s=5.0, settle_s=0.02)
        lp = ControlLoop(M, be, P, None, cfg, initial_state(M, c0),
                         parts=LoopParts(follower=fol, hook=hook, log=lambda m: None))
        res = lp.run()
        assert res.status == "done", res.reason
        return res.ticks, fol.ended_jobs, pushed

    alone, ended_alone, _ = go(False)
    ticks, ended, pushed = go(True)
    assert ended_alone == 1 and ended == 2 and pushed
    assert ticks == alone + 2                             # the appended sample's tick, then its settling
