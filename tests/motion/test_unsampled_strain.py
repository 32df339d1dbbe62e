"""A backend without strain gauges in its cyclic data (canopen) records strain_* as not sampled
(NaN: an empty cell, docs/recording.md), not as 0.0; and the diagnosis does not fit a channel that
is all empty or one value throughout (it reported "sensor_gain on strain_1 confidence 1.00")."""

import numpy as np

from pmctl.core.config import load_machine
from pmctl.task.run_sink import RunSink
from pmctl.motion.recorder import R_COUNTS, R_STRAIN, R_TICK, REC_WIDTH
from pmctl.tools.twin import synth
from pmctl.tools.twin.diagnose import build_context

M = load_machine()


def _rows(n=50):
    rows = np.zeros((n, REC_WIDTH))
    rows[:, R_TICK] = np.arange(n)
    rows[:, R_COUNTS:R_COUNTS + 5] = 1000.0
    rows[:, R_STRAIN:R_STRAIN + 3] = 0.0          # what the rt side holds for a backend without gauges
    return rows


def test_strain_of_a_backend_without_gauges_is_not_sampled():
    ppm = M.resolution.pulses_per_mm
    sink = RunSink(M, ppm, 1000.0, False, 0, load=False, strain=False)
    got = {}
    sink.writer = type("W", (), {"append": lambda self, cols: got.update(cols)})()
    sink(_rows())
    names, _ = sink.channels()
    assert {"strain_1", "strain_2", "strain_3"} <= set(names)
    for i in (1, 2, 3):
        assert np.all(np.isnan(got[f"strain_{i}"]))
    with_gauges = RunSink(M, ppm, 1000.0, False, 0)
    with_gauges.writer = sink.writer
    with_gauges(_rows())
    assert np.all(got["strain_1"] == 0.0)         # a backend with gauges: the values as read


def test_the_diagnosis_skips_empty_and_constant_channels():
    case = synth.synth_case(np.random.default_rng(5), [], machine=M, seed=5, duration_s=6.0, rate_hz=400.0)
    cols = dict(case.columns)
    n = len(cols["t"])
    cols["strain_1"] = np.zeros(n)                # written as 0.0 by a backend without gauges
    cols["strain_2"] = np.full(n, np.nan)         # not sampled
    ctx = build_context(cols, M, cap=2000)
    assert "strain_1" not in ctx.obs.channels and "strain_2" not in ctx.obs.channels
    assert "strain_3" in ctx.obs.channels and "enc_X" in ctx.obs.channels
