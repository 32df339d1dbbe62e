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


def test_the_spectrum_plot_covers_the_channel_up_to_its_own_nyquist_frequency(tmp_path):
    """A 246.6 Hz line in a 1 kHz gauge, diagnosed with the analysis thinned to every 5th row (100 Hz
    of band): the plot's spectrum of the nominal residual still peaks at 246.6 Hz, not at an alias."""
    from pmctl.tools.twin.effects import welch_runs
    from pmctl.tools.twin.plots import full_rate_residual, write_plots
    rng = np.random.default_rng(7)
    case = synth.synth_case(rng, [], run="circle", duration_s=10.0, rate_hz=1000.0)
    cols = {k: np.asarray(v, float) for k, v in case.columns.items()}
    cols["strain_1"] = cols["strain_1"] + 2.0 * np.sin(2 * np.pi * 246.6 * cols["t"])
    rep, ex = diagnose(cols, load_machine(), cap=2000)
    t, r = full_rate_residual(rep, ex, "strain_1")
    assert len(t) == len(cols["t"])
    f, p = welch_runs(t, r)
    assert abs(f[np.argmax(p)] - 246.6) < 1.0 and f[-1] >= 499.0
    paths = write_plots(rep, ex, tmp_path)
    assert (tmp_path / "spectrum.png").is_file() and len(paths) == 3


def test_the_report_gives_units_and_says_what_its_percentages_are(tmp_path):
    cols = _wandering_clean_case()
    cols["strain_3"] = cols["strain_3"] + 0.08 * (cols["t"] - cols["t"].mean())
    rep, ex = diagnose(cols, load_machine(), cap=2000)
    assert rep["units"]["strain_3"] == "µε" and rep["units"]["tip_x"] == "mm" and rep["units"]["tool_k"] == "1"
    text = format_text(rep, ex)
    row = next(ln for ln in text.splitlines() if ln.strip().startswith("strain_3 "))
    assert row.split()[1] == "µε"
    assert "not cumulative" in text and "cumulative, in the channel's unit" in text
    held = next(ln for ln in text.splitlines() if "held-out rms:" in ln)
    assert held.rstrip().split(";")[0].endswith("µε")
