"""`pmctl analyze resonance`: the test move, a sim recording with a known chain mode, the modes found
from the strain gauges, the shaper and K_theta advice and the PNG."""

import json
import math

import numpy as np
import pytest

from pmctl.core import shaper as S
from pmctl.interfaces.cli import main
from pmctl.tools.analysis import resonance as R
from service_support import service_toml

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

MASS = 31.66


def _service(path, f_hz, zeta, noise=0.01):
    """A simulated plant whose three chain modes ring at f_hz with damping ratio zeta."""
    k = MASS * (2 * math.pi * f_hz) ** 2 / 1e3
    return service_toml(path, realtime=False, stall_ms=10000, k_theta=0.0,
                        sim=f"flex = true\nmode_stiffness_N_per_mm = [{k}, {k}, {k}]\n"
                            f"mode_mass_kg = [{MASS}, {MASS}, {MASS}]\n"
                            f"mode_damping_ratio = [{zeta}, {zeta}, {zeta}]\n"
                            f"strain_noise_ue = {noise}\nseed = 3\n")


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    d = tmp_path_factory.mktemp("res")
    job = d / "impulse.ngc"
    assert main(["analyze", "resonance", "--make-job", str(job), "--strokes", "2", "--dwell-s", "0.3"]) == 0
    svc = _service(d / "svc.toml", 75.0, 0.04)
    rec = d / "rec"
    assert main(["run", "--job", str(job), "--record", str(rec), "--no-realtime", "--service", str(svc),
                 "--state", "", "--quiet"]) == 0
    return d, rec


@pytest.fixture(scope="module")
def analysed(recording):
    """The analysis of the recording, once, with --write into a copy of its service config."""
    import contextlib
    import io
    d, rec = recording
    out = d / "out"
    svc = d / "svc_write.toml"
    svc.write_text((d / "svc.toml").read_text().replace("[nc]\n", "[nc]\nmode_hz = 10.0\n"))
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(["analyze", "resonance", str(rec), "--out", str(out), "--write", str(svc)]) == 0
    return d, out, svc, buf.getvalue()


def test_modes_found_from_the_gauges(analysed):
    d, out, _, text = analysed
    res = json.loads((out / "resonance.json").read_text())
    for ch in res["chains"]:
        m = ch["modes"][0]
        assert m["freq_hz"] == pytest.approx(75.0, rel=0.01)        # the sim's mode: 75 Hz, 4 % damping
        assert m["damping"] == pytest.approx(0.04, rel=0.25)
        best = next(a for a in ch["shapers"] if a["name"] == ch["recommended_shaper"])
        assert best["remaining_worst"] <= R.MAX_REMAINING
        # nothing shorter also meets the tolerance
        assert all(a["duration_ms"] >= best["duration_ms"] - 1e-9 for a in ch["shapers"]
                   if a["remaining_worst"] <= R.MAX_REMAINING)
        k = ch["k_theta"]                                           # what k_theta_per_s = "auto" runs
        assert k["k_theta_per_s"] > 0 and k["gain_margin"] >= 2.0 and k["phase_margin_deg"] >= 45.0
        assert ch["auto_shaper"] == S.recommend(m["freq_hz"], m["damping"])
    png = (out / "resonance.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert "recommended" in text and "chain 3: mode" in text


def test_impulse_job_is_valid_gcode_and_refuses_bad_input(tmp_path):
    from pmctl.task.gcode import parse_gcode
    text = R.make_impulse_job("x", 3, 0.5, 0.2, 2400)
    assert text.count("G4 P0.2") == 7 and "G91" in text
    job = parse_gcode(text, start_tip=(1.0, 2.0, 100.0))      # incremental: ends where it started
    assert np.allclose(job.points[-1][:3] if np.ndim(job.points[-1]) else job.points[-1], [1.0, 2.0, 100.0])
    from pmctl.core.errors import InputError
    with pytest.raises(InputError):
        R.make_impulse_job("w")
    with pytest.raises(InputError):
        R.make_impulse_job("z", stroke_mm=50)


def test_arx_recovers_a_synthetic_mode_exactly():
    """A mode driven through the sim's own discretisation (motor ramps per tick) is fitted exactly."""
    from scipy.linalg import expm
    fs, f, z = 1000.0, 42.0, 0.025
    w = 2 * math.pi * f
    rng = np.random.default_rng(1)
    u = np.cumsum(np.cumsum(rng.normal(0, 1e-3, 4000)))       # motor position, mm
    phi = expm(np.array([[0, 1.0], [-w * w, -2 * z * w]]) / fs)
    y, yd, v_prev = 0.0, 0.0, 0.0
    ys = []
    for k in range(len(u)):
        v = (u[k] - u[k - 1]) * fs if k else 0.0
        yd -= v - v_prev
        y, yd = phi[0, 0] * y + phi[0, 1] * yd, phi[1, 0] * y + phi[1, 1] * yd
        v_prev = v
        ys.append(y)
    modes, rms = R.arx_modes(u, np.array(ys) * 1000.0, fs)
    assert modes[0][0] == pytest.approx(f, rel=1e-3)
    assert modes[0][1] == pytest.approx(z, rel=2e-2)


def test_missing_channels_are_named(tmp_path):
    from pmctl.core.recording import write_recording
    t = np.arange(200) / 1000.0
    cols = {"t": t, **{f"cmd_{a}": t * 0 for a in ("L1", "L2", "L3", "X", "Y")}}
    write_recording(tmp_path / "r", cols, sample_rate_hz=1000.0)
    assert main(["analyze", "resonance", str(tmp_path / "r"), "--out", str(tmp_path / "o")]) == 1
    assert main(["analyze", "resonance"]) == 1


def test_advice_uses_the_shaper_curves():
    adv, best = R.shaper_advice(40.0, 0.02)
    zv = next(a for a in adv if a.name == "ZV")
    assert zv.remaining_at_mode < 1e-9
    assert zv.remaining_worst == pytest.approx(float(S.residual_vibration(S.make_shaper("ZV", 40.0, 0.02), 44.0, 0.02)),
                                               rel=0.02)
    assert best.remaining_worst <= R.MAX_REMAINING


def test_write_puts_the_modes_into_the_service_config_and_run_uses_them(analysed, capsys):
    """--write SERVICE: [nc] mode_hz / damping / modal stiffness (from the fit's static gain: the sim's
    75 Hz chain is 31.66 kg on 7031 N/mm); pmctl run --k-theta auto --shaper auto then takes them."""
    d, _, svc, text = analysed
    assert f"into {svc}" in text
    from pmctl.motion.service_config import load_service_config
    nc = load_service_config(svc).nc
    assert np.allclose(nc.mode_hz, 75.0, rtol=0.01) and np.allclose(nc.mode_damping_ratio, 0.04, rtol=0.25)
    k_true = MASS * (2 * math.pi * 75.0) ** 2 / 1e3
    assert np.allclose(nc.modal_stiffness_N_per_mm, k_true, rtol=0.1)
    assert svc.read_text().count("mode_hz") == 1            # replaced, not added twice
    capsys.readouterr()
    assert main(["run", "--job", str(d / "impulse.ngc"), "--no-realtime", "--service", str(svc), "--state", "",
                 "--quiet", "--k-theta", "auto", "--shaper", "auto"]) == 0
    err = capsys.readouterr().err
    assert "[nc] mode_hz" in err and "K_theta auto" in err and "shaper: " in err and "(auto)" in err
    assert main(["run", "--job", str(d / "impulse.ngc"), "--no-realtime", "--service", str(svc), "--state", "",
                 "--quiet", "--shaper", "ZVX"]) == 1
    assert main(["run", "--job", str(d / "impulse.ngc"), "--no-realtime", "--service", str(svc), "--state", "",
                 "--quiet", "--k-theta", "-3"]) == 1
