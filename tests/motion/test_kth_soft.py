"""K_theta on soft chains (docs/vibration.md): the sampled eq. 3.1 model predicts the damping the NC's
feedback gives a chain mode in the closed loop, the chain modes and K_theta = auto come from the
service config or the sim's declared plant, and the [nc] keys are validated strictly."""

import math

import numpy as np
import pytest
from scipy.optimize import curve_fit

from kth_support import DT, KV, ZETA, M, ringdown
from pmctl.core.errors import ConfigError
from pmctl.motion.service_config import chain_modes, nc_setup, service_from_dict
from pmctl.tools.analysis.resonance import predict_sampled


def decay(f, kth, leak, y0=0.05):
    """Closed loop (NC, sim with its flexible mode and gauges) holding a pose while the chains start
    from a y0 deflection: fitted (frequency, damping ratio) of the load-side deflection."""
    y = ringdown(f, kth, y0, **(dict(mode_hz=f, k_theta_leak=leak) if leak is not None else {}))
    t = np.arange(len(y)) * DT
    fp, zp = predict_sampled(f, kth, KV, DT, ZETA, leak)
    w0 = 2 * math.pi * fp
    nfit = int(3.0 / (f * DT)) + 5
    model = lambda t, a, b, s, w, c: np.exp(-s * t) * (a * np.cos(w * t) + b * np.sin(w * t)) + c   # noqa: E731
    pp, _ = curve_fit(model, t[:nfit], y[:nfit], p0=[y0, 0.0, zp * w0, w0, 0.0], maxfev=20000)
    s, w = abs(pp[2]), abs(pp[3])
    return w / (2 * math.pi), s / math.hypot(s, w), (fp, zp)


@pytest.mark.parametrize("f,kth,leak", [(40.0, 200.0, "dec"), (80.0, 200.0, "dec"), (40.0, 200.0, None)])
def test_eq31_sampled_predicts_the_closed_loop_damping(f, kth, leak):
    lk = 0.1 * 2 * math.pi * f if leak else None
    fs, zs, (fp, zp) = decay(f, kth, lk)
    assert zs == pytest.approx(zp, abs=0.04)
    assert fs == pytest.approx(fp, rel=0.03)
    assert zs > 4 * ZETA                 # and the feedback does damp the mode


def _svc(nc=None, sim=None):
    d = {"nc": nc or {}, "hal": {"backend": "sim", "sim": sim or {}}}
    return service_from_dict(d, "svc.toml")


SOFT = {"flex": True, "mode_stiffness_N_per_mm": 2000.0, "mode_mass_kg": 31.66, "mode_damping_ratio": 0.02}


def test_chain_modes_from_the_sim_plant_and_from_nc():
    m = chain_modes(_svc(sim=SOFT), M)
    assert np.allclose(m.hz, math.sqrt(2e6 / 31.66) / (2 * math.pi)) and "hal.sim" in m.source
    assert np.allclose(m.stiffness_N_per_mm, 2000.0)
    m2 = chain_modes(_svc(nc={"mode_hz": [40.0, 41.0, 42.0], "modal_stiffness_N_per_mm": 2100.0}, sim=SOFT), M)
    assert list(m2.hz) == [40.0, 41.0, 42.0] and "[nc] mode_hz" in m2.source    # [nc] wins over the plant
    assert chain_modes(_svc(sim={"flex": False}), M) is None
    # the default (stiff, 246 Hz) plant keeps the plain feedback: its mode is above 2 kv
    st = _svc(nc={"k_theta_per_s": 200.0}, sim={"flex": True})
    p = st.nc.params(M, DT, modes=chain_modes(st, M))
    assert not p._kth_modal and np.allclose(p.deflection_per_ue, 1 / (M.strain_gain * M.stiffness.chain_axial))


def test_k_theta_auto_and_soft_params():
    from pmctl.core.strain_loop import DAMPING_TARGET, closed_loop_poles, pole_damping
    s = _svc(nc={"k_theta_per_s": "auto"}, sim=SOFT)
    setup = nc_setup(s, M, DT)
    p = s.nc.params(M, DT, modes=setup.modes)
    assert p._kth_modal and np.all(p.k_theta > 0) and np.all(p.k_theta * DT <= 0.5)
    f = math.sqrt(2e6 / 31.66) / (2 * math.pi)
    for r in (0.8, 1.0, 1.2):              # the gain and leak the NC runs damp every pole to 0.7, mode 20 % off
        z = closed_loop_poles(f * r, ZETA, float(p.k_theta[0]), KV, DT, float(p.k_theta_leak[0]))
        assert np.min(pole_damping(z, DT)[1]) >= DAMPING_TARGET - 1e-9
    assert np.allclose(p.deflection_per_ue, 1 / (M.strain_gain * 2000.0))
    assert any("K_theta auto" in n for n in setup.notes)


def test_k_theta_auto_without_a_mode_designs_for_the_machine_configs_chain():
    """No measured or declared mode: auto designs for chain_axial under a third of the platform mass
    (what the NC scales the strain with), the plain law at 246.6 Hz; the shaper still needs a mode."""
    s = _svc(nc={"k_theta_per_s": "auto"}, sim={"flex": False})
    setup = nc_setup(s, M, DT)
    p = s.nc.params(M, DT, modes=setup.modes)
    assert setup.modes.nominal and np.allclose(setup.modes.hz, math.sqrt(2e7 / (25.0 / 3)) / (2 * math.pi))
    assert np.all(p.k_theta > 0) and not p._kth_modal
    assert np.allclose(p.deflection_per_ue, 1 / (M.strain_gain * M.stiffness.chain_axial))


@pytest.mark.parametrize("nc,key", [
    ({"k_theta_per_s": "fast"}, "k_theta_per_s"),
    ({"mode_hz": -3.0}, "mode_hz"),
    ({"mode_hz": [40.0, 40.0]}, "mode_hz"),
    ({"mode_damping_ratio": 0.02}, "nc.mode_damping_ratio"),         # without mode_hz
    ({"modal_stiffness_N_per_mm": 2000.0}, "nc.modal_stiffness_N_per_mm"),
    ({"shaper": "ZVX"}, "shaper"),
    ({"shaper": "auto"}, "nc.shaper"),                               # auto without any mode
    ({"shaper_hz": 0.0}, "shaper_hz"),
    ({"deflection_feedforward": 1}, "deflection_feedforward"),
])
def test_nc_keys_refused_with_their_name(nc, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        s = _svc(nc=nc, sim={"flex": False})
        setup = nc_setup(s, M, DT)
        s.nc.params(M, DT, modes=setup.modes)
