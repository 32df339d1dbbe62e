"""ControlLoop's wiring as one LoopParts: the same ticks as the keywords, and a wrong wiring refused
before anything moves."""

import numpy as np
import pytest

from pmctl import hal
from pmctl.core.config import load_machine
from pmctl.motion.loop import ControlLoop, LoopParts, prepare
from pmctl.motion.nc import NCParams, counts_of, initial_state
from pmctl.motion.service_config import LoopConfig
from pmctl.motion.trajectory import Trajectory

M = load_machine()
DT = 1e-3


def _setup():
    params = NCParams.from_machine(M, DT, kv=0.4 / DT)
    n = 300
    t = np.arange(n) * DT
    tip = np.stack([2.0 * (1 - np.cos(np.pi * t / t[-1])), np.zeros(n), np.full(n, 10.0)], -1)
    axis = np.tile([0.0, 0.0, 1.0], (n, 1))
    z = np.zeros_like(tip)
    tg = prepare(M, params, Trajectory(DT, tip, axis, z, z.copy(), np.ones(n, int), np.zeros(n)), DT)
    c0 = counts_of(tg.q[0], params)
    be = hal.create("sim", M, DT, {})
    be.open(c0)
    cfg = LoopConfig(rate_hz=1 / DT, realtime=False, stall_timeout_s=60.0, state_file="")
    return be, params, tg, cfg, initial_state(M, c0)


def test_parts_and_keywords_run_the_same_ticks():
    """A hook that holds the path at tick 120 and releases it at 200, wired both ways: the same
    counters at every tick, the same pulses sent, and the hook saw every tick."""
    results, seen = [], []
    for how in ("keywords", "parts"):
        ticks = []

        def hook(lp, k, st, ticks=ticks):
            ticks.append(k)
            if k == 120:
                lp.follower.scaler.hold = True
            if k == 200:
                lp.follower.scaler.hold = False
            return st
        be, params, tg, cfg, st0 = _setup()
        if how == "keywords":
            lp = ControlLoop(M, be, params, tg, cfg, st0, log=lambda m: None, hook=hook)
        else:
            lp = ControlLoop(M, be, params, tg, cfg, st0, LoopParts(log=lambda m: None, hook=hook))
        results.append(lp.run())
        seen.append(ticks)
    a, b = results
    assert a.status == b.status == "done"
    assert a.ticks == b.ticks and np.array_equal(a.counts, b.counts) and np.array_equal(a.pulses_sent, b.pulses_sent)
    assert seen[0] == seen[1] == list(range(1, a.ticks + 1))
    assert a.sigma[199] < 0.75 * a.sigma[119]           # the hold took effect: both wirings ran the hook


def test_parts_and_keywords_together_or_an_unknown_part_are_refused():
    be, params, tg, cfg, st0 = _setup()
    truth0 = be.truth().copy()
    with pytest.raises(TypeError, match="hook"):
        ControlLoop(M, be, params, tg, cfg, st0, LoopParts(), hook=lambda lp, k, st: st)
    with pytest.raises(TypeError, match="recoder"):
        ControlLoop(M, be, params, tg, cfg, st0, recoder=None)
    assert np.array_equal(be.truth(), truth0)         # nothing moved
