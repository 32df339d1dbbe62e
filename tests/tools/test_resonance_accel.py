"""`pmctl analyze resonance` on accelerometer logs, the way Klipper's calibrate_shaper scores input
shapers: the PSD of a frequency sweep, each shaper at its best frequency, the recommended one."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import signal

from pmctl.core import shaper as S
from pmctl.core.errors import InputError
from pmctl.interfaces.cli import main
from pmctl.tools.analysis import resonance as R


def _sweep(path, fn=48.0, z=0.07, fs=1600.0, hz_per_s=5.0, seed=0):
    """A toolhead shaken from 5 to 135 Hz (commanded acceleration 75 mm/s² per Hz, as Klipper's
    TEST_RESONANCES does) through one mode of X, written as Klipper's raw CSV (mm/s²)."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(130 / hz_per_s * fs)) / fs
    f = 5.0 + hz_per_s * t
    a_cmd = 75.0 * f * np.sin(2 * np.pi * np.cumsum(f) / fs)
    w = 2 * np.pi * fn
    b, a = signal.bilinear([2 * z * w, w * w], [1, 2 * z * w, w * w], fs)
    ax = signal.lfilter(b, a, a_cmd) + rng.normal(0, 30, len(t))
    with open(path, "w") as fh:
        fh.write("#time,accel_x,accel_y,accel_z\n")
        for ti, x, y in zip(t, ax, rng.normal(0, 30, len(t))):
            fh.write(f"{ti + 500:.6f},{x:.3f},{y:.3f},{9810 + y:.3f}\n")
    return path


def test_a_sweep_through_one_mode_gets_a_shaper_at_that_mode(tmp_path, capsys):
    path = _sweep(tmp_path / "raw.csv")
    assert main(["analyze", "resonance", str(path), "--out", str(tmp_path / "o")]) == 0
    out = json.loads((tmp_path / "o" / "resonance.json").read_text())
    assert abs(out["psd_peak_hz"] - 48.0) < 1.5
    rec = out["recommended"]
    fit = {s["name"]: s for s in out["shapers"]}[rec["shaper"].upper()]
    # the recommended shaper leaves under 5 % of the vibration at the 48 Hz mode
    sh = S.make_shaper(rec["shaper"], rec["freq_hz"], R.SHAPER_DAMPING)
    assert float(S.residual_vibration(sh, 48.0, 0.07)) < 0.05 and fit["vibrations"] < 0.05
    assert "recommended shaper:" in capsys.readouterr().out and (tmp_path / "o" / "resonance.png").is_file()


def test_zv_vibration_share_and_smoothing_follow_the_shaper_math():
    """One narrow peak at f0: a ZV designed at f0 removes it (its residual is 0 at f0 for the design
    damping), and its smoothing grows as 1/f (the impulses' spread is half a period)."""
    f = np.arange(0, 200, 0.5)
    psd = np.exp(-0.5 * ((f - 60.0) / 1.0) ** 2)
    fits, _ = R.fit_shapers(f, psd)
    zv = next(s for s in fits if s.name == "ZV")
    assert abs(zv.freq_hz - 60.0) < 3.0
    # without a square-corner velocity the offsets are accel x (time spread)²: 1/f² exactly
    s40, s80 = (R.shaper_smoothing(S.make_shaper("ZV", q, 0.1), scv=0.0) for q in (40.0, 80.0))
    assert s40 / s80 == pytest.approx(4.0, rel=1e-9)
    sh = S.make_shaper("ZV", 40.0, 0.1)
    assert R.shaper_smoothing(sh, R.shaper_max_accel(sh)) == pytest.approx(0.12, rel=1e-6)


def test_a_klipper_psd_csv_is_read_and_a_bad_header_is_refused(tmp_path):
    f = np.arange(0, 150, 0.5)
    p = 1e4 * np.exp(-0.5 * ((f - 42.0) / 2.0) ** 2) + 10.0
    rows = "\n".join(f"{a:.1f},{b:.1f},{b * 0.1:.1f},{b * 0.05:.1f},{b * 1.15:.1f}" for a, b in zip(f, p))
    (tmp_path / "psd.csv").write_text("freq,psd_x,psd_y,psd_z,psd_xyz\n" + rows + "\n")
    fq, psd, fits, rec, src = R.analyse_accel(tmp_path / "psd.csv")
    assert src == "a resonance PSD" and abs(fq[np.argmax(psd["sum"])] - 42.0) < 1.0
    (tmp_path / "bad.csv").write_text("when,ax,ay\n1,2,3\n")
    with pytest.raises(InputError) as e:
        R.read_accel_csv(tmp_path / "bad.csv")
    assert "bad.csv" in str(e.value) and "#time,accel_x,accel_y,accel_z" in str(e.value)
    (tmp_path / "nan.csv").write_text("#time,accel_x,accel_y,accel_z\n" + "".join(
        f"{k * 0.001},1,2,3\n" for k in range(9)) + "0.02,x,2,3\n")
    with pytest.raises(InputError) as e:
        R.read_accel_csv(tmp_path / "nan.csv")
    assert e.value.line == 11 and "'x' is not a number" in str(e.value)
