"""Fixes of the diagnosis found by trying it as a new user would (issue 27): a clean gauge's slow
wander is no sensor drift; the report's tables carry units; the spectrum plot covers the whole band
of the channel as recorded."""

from __future__ import annotations

import numpy as np

from pmctl.core.config import load_machine
from pmctl.tools.twin import synth
from pmctl.tools.twin.diagnose import diagnose, format_text


def _wandering_clean_case():
    """A clean raster run whose strain_3 gauge wanders slowly (an amplifier's 1/f noise: a smoothed
    random walk of 0.1 µε rms): a straight line through it removes about 4 % of its residual."""
    rng = np.random.default_rng(100)
    case = synth.synth_case(rng, [], run="raster", duration_s=10.0, rate_hz=1000.0)
    cols = {k: np.asarray(v, float) for k, v in case.columns.items()}
    w = np.convolve(np.cumsum(rng.normal(0, 1, len(cols["t"]))), np.ones(200) / 200, "same")
    cols["strain_3"] = cols["strain_3"] + 0.1 * (w - w.mean()) / np.std(w)
    return cols


def test_a_slow_wander_of_a_clean_gauge_is_no_sensor_drift():
    rep, ex = diagnose(_wandering_clean_case(), load_machine(), cap=2000)
    assert rep["findings"] == [] and rep["unexplained"] == []
    assert rep["verdict"] == "consistent with the nominal twin"


def test_a_true_drift_of_the_same_gauge_is_still_named():
    cols = _wandering_clean_case()
    cols["strain_3"] = cols["strain_3"] + 0.08 * (cols["t"] - cols["t"].mean())
    rep, _ = diagnose(cols, load_machine(), cap=2000)
    d = [f for f in rep["findings"] if f["effect"] == "sensor_drift" and f["channel"] == "strain_3"]
    assert d and abs(d[0]["parameters"]["rate_per_s"] - 0.08) < 0.03
