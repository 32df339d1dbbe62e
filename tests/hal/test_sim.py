"""The loopback simulation plant (pmctl.hal.sim) and the backend registry."""

import math

import numpy as np
import pytest

from pmctl import hal
from pmctl.core import kinematics as K
from pmctl.core.statics import static_strain
from pmctl.core.config import load_machine
from pmctl.core.errors import ConfigError
from pmctl.hal.sim import SimBackend, SimOptions

M = load_machine()
DT = 1e-3
C0 = np.array([786499, 786499, 786499, 0, 0], np.int64)     # home: L = 393.2495 mm


def _sim(**opt):
    s = hal.create("sim", M, DT, opt)
    s.open(C0)
    return s


def test_registry_builds_the_sim_and_rejects_unknown_names():
    assert isinstance(hal.create("sim", M, DT), SimBackend)
    with pytest.raises(ConfigError, match="unknown backend"):
        hal.create("nope", M, DT)
    with pytest.raises(ConfigError, match="unknown sim option"):
        hal.create("sim", M, DT, {"stiffnes": 1})


def test_ideal_drive_encoder_equals_counter():
    s = _sim()
    rng = np.random.default_rng(0)
    for _ in range(200):
        s.write_pulses(rng.integers(-50, 51, 5))
        fb = s.read()
        assert np.array_equal(fb.counts, s.counts)
        assert np.allclose(fb.enc, fb.counts / M.resolution.pulses_per_mm, atol=1e-12)
        assert np.allclose(s.truth(), fb.enc)                 # rigid: load side = motor side


def test_first_order_lag_follows_a_ramp_with_lag_v_tau():
    tau = 0.01
    s = _sim(drive_tau_s=[tau, 0, 0, 0, 0])
    for _ in range(300):                                       # 20 pulses/tick = 10 mm/s on L1
        s.write_pulses(np.array([20, 0, 0, 0, 0]))
    fb = s.read()
    lag = fb.counts[0] / 2000.0 - fb.enc[0]
    assert lag == pytest.approx(10.0 * tau, rel=1e-6)          # exact for a ramp after 30 tau
    assert fb.enc[1] == fb.counts[1] / 2000.0


def test_flexible_mode_rings_at_its_natural_frequency_and_strain_reads_the_deflection():
    k, m, zeta = 131.6, 8.333, 0.0                              # ~20 Hz, undamped
    s = _sim(flex=True, mode_stiffness_N_per_mm=[k] * 3, mode_mass_kg=[m] * 3, mode_damping_ratio=[zeta] * 3,
             gravity_update_ticks=1)
    for _ in range(10):                                        # a short move on chain 1, then stop
        s.write_pulses(np.array([100, 0, 0, 0, 0]))
    strain, y, truth = [], [], []
    for _ in range(1000):
        s.write_pulses(np.zeros(5, np.int64))
        fb = s.read()
        strain.append(fb.strain[0])
        y.append(s.truth()[0] - fb.enc[0])
        truth.append(s.truth())
    strain, y = np.array(strain), np.array(y)
    # strain gauge = gravity strain of the true pose (pmctl.core.statics) + k_eps * k * (load - motor)
    pose, ok = K.fk_batch(np.array(truth), M)
    grav = static_strain(pose.P, pose.R, M)[:, 0]
    assert np.allclose(strain - grav, M.strain_gain * k * y, rtol=0, atol=1e-6)
    # zero crossings of a free undamped oscillation: frequency sqrt(k/m)/2pi
    zc = np.nonzero(np.diff(np.sign(y)) != 0)[0]
    f_meas = (len(zc) - 1) / 2 / ((zc[-1] - zc[0]) * DT)
    assert f_meas == pytest.approx(math.sqrt(k * 1e3 / m) / (2 * math.pi), rel=0.01)
    assert np.ptp(y[-200:]) > 0.5 * np.ptp(y[:200])            # undamped: still ringing
    assert np.abs(strain[1:] - strain[:-1]).max() > 0


def test_flexible_mode_damping_decays_the_ringing():
    k, m = 131.6, 8.333
    s = _sim(flex=True, mode_stiffness_N_per_mm=[k] * 3, mode_mass_kg=[m] * 3, mode_damping_ratio=[0.05] * 3)
    for _ in range(10):
        s.write_pulses(np.array([100, 0, 0, 0, 0]))
    y = []
    for _ in range(1000):
        s.write_pulses(np.zeros(5, np.int64))
        y.append(s.truth()[0] - s.read().enc[0])
    y = np.array(y)
    wn = math.sqrt(k * 1e3 / m)
    # envelope decays as exp(-zeta wn t): over 0.8 s by exp(-0.05 * 125.7 * 0.8) = 0.0066
    ratio = np.abs(y[800:]).max() / np.abs(y[:200]).max()
    assert ratio == pytest.approx(math.exp(-0.05 * wn * 0.8), rel=0.3)


def test_noise_is_seeded_and_has_the_configured_size():
    a = _sim(enc_noise_mm=1e-3, strain_noise_ue=0.5, seed=7)
    b = _sim(enc_noise_mm=1e-3, strain_noise_ue=0.5, seed=7)
    ea, sa = [], []
    for _ in range(2000):
        a.write_pulses(np.zeros(5, np.int64))
        b.write_pulses(np.zeros(5, np.int64))
        fa, fb = a.read(), b.read()
        assert np.array_equal(fa.enc, fb.enc) and np.array_equal(fa.strain, fb.strain)
        ea.append(fa.enc - fa.counts / 2000.0)
        sa.append(fa.strain.copy())
    assert np.std(ea) == pytest.approx(1e-3, rel=0.05)
    assert np.std(sa) == pytest.approx(0.5, rel=0.05)


def test_injected_stall_times_out_and_lost_steps_shift_the_motor():
    from pmctl.hal import HalTimeout
    s = _sim(stall_at_tick=3, read_timeout_s=0.001)
    for _ in range(3):
        s.read()
        s.write_pulses(np.zeros(5, np.int64))
    with pytest.raises(HalTimeout, match="no answer"):
        s.read()
    s = _sim(lost_steps_at_tick=0, lost_steps_axis=4, lost_steps_mm=-0.02)
    s.write_pulses(np.zeros(5, np.int64))
    fb = s.read()
    assert fb.enc[4] - fb.counts[4] / 2000.0 == pytest.approx(-0.02)


def test_sim_options_validation():
    with pytest.raises(ConfigError, match="drive_tau_s"):
        SimOptions.from_dict({"drive_tau_s": [0.0, 0.0]})
    with pytest.raises(ConfigError, match="mode_mass_kg"):
        SimOptions.from_dict({"mode_mass_kg": -1.0})


def test_rigid_sim_strain_is_the_nominal_twin_gravity_strain():
    """docs/diagnosis-report.md §1: at rest on a rigid plant the gauges read the static weight of the platform."""
    s = _sim(flex=True)
    for _ in range(50):
        s.write_pulses(np.array([30, -10, 5, 40, -20]))
    for _ in range(3000):                                      # let the 246 Hz mode die out
        s.write_pulses(np.zeros(5, np.int64))
    fb = s.read()
    pose = K.fk(s.truth(), M)
    assert np.allclose(fb.strain, static_strain(pose.P, pose.R, M), atol=1e-6)


def test_model_static_strain_matches_statics():
    from pmctl.core.model_fk import ModelFK
    mf = ModelFK(M)
    for q in ([393.0, 380.0, 400.0, 5.0, -3.0], [300.0, 310.0, 290.0, 0.0, 0.0]):
        q = np.array(q)
        ref = K.fk(q, M)
        P, R, *_ = mf.solve(q, ref.P, ref.R)
        assert np.allclose(mf.static_strain(R.tolist(), mf.last_T), static_strain(ref.P, ref.R, M), atol=1e-9)


def test_extrapolated_gravity_strain_stays_below_the_gauge_noise():
    """Default: exact gravity strain every 10 ticks, secant-extrapolated between (a cheaper tick).
    Chains at 15-35 mm/s with reversals: measured worst 0.014 microstrain (default gauge noise 0.01)."""
    a = _sim()
    b = _sim(gravity_update_ticks=1)
    v = np.array([60, -40, 30, 50, -70])
    worst = 0.0
    for k in range(2000):
        p = v if (k // 500) % 2 == 0 else -v
        a.write_pulses(p)
        b.write_pulses(p)
        worst = max(worst, np.abs(a.read().strain - b.read().strain).max())
    assert worst < 0.02


# ---------------------------------------------------------------- the effect catalogue on the sim

def _effect_run(s, n=1500, seed=3):
    """Random pulse bursts with reversals and holds; per tick: commanded, encoder, load side."""
    rng = np.random.default_rng(seed)
    cmd, enc, load = [], [], []
    v = rng.integers(-60, 61, 5)
    for k in range(n):
        if k % 100 == 0:
            v = rng.integers(-60, 61, 5) * (rng.random(5) < 0.8)
        s.write_pulses(v + rng.integers(-3, 4, 5))
        fb = s.read()
        cmd.append(fb.counts / 2000.0)
        enc.append(fb.enc.copy())
        load.append(s.truth())
    return np.array(cmd), np.array(enc), np.array(load)


def test_sim_effects_are_the_catalogue_physics_tick_for_tick():
    """The sim's load side = motor side + play + pitch + thermal growth of the screw position, the
    encoders = drive + friction following error: the batch functions of pmctl.core.plant_effects on
    the recorded motor positions give the same numbers."""
    from pmctl.core import plant_effects as PE
    opt = dict(backlash_mm=[0.02, 0.0, 0.01, 0.015, 0.0], backlash_start=[-1, 0, 0.5, 1, 0],
               pitch_error_amp_mm=[0.004, 0.0, 0.0, 0.0, 0.003], pitch_error_period_mm=[5.0, 5, 5, 5, 2.5],
               pitch_error_phase_rad=[0.3, 0, 0, 0, 1.0], thermal_delta_K=[0, 3.0, 0, 0, 0],
               friction_coulomb_mm=[0.0, 0.0, 0.0, 0.006, 0.0], friction_stribeck_mm=[0, 0, 0, 0.004, 0])
    s = _sim(**opt)
    o = s.opt
    x0 = C0 / 2000.0
    cmd, enc, load = _effect_run(s)
    cmd, enc, load = np.vstack([x0, cmd]), np.vstack([x0, enc]), np.vstack([x0, load])
    fric = PE.friction_offset(cmd, DT, o.friction_coulomb_mm, o.friction_stribeck_mm, o.friction_stribeck_speed_mm_s)
    assert np.max(np.abs(enc - cmd - fric)) < 1e-12
    assert np.max(np.abs(fric[:, 3])) > 0.005 and np.all(fric[:, [0, 1, 2, 4]] == 0)
    play = np.stack([PE.play_error(enc[:, j], o.backlash_mm[j], o.backlash_start[j]) for j in range(5)], 1)
    want = (play + PE.periodic_error(enc, o.pitch_error_amp_mm, o.pitch_error_period_mm, o.pitch_error_phase_rad)
            + PE.thermal_growth(enc, o.thermal_alpha_per_K, o.thermal_delta_K, o.thermal_fixed_end_mm))
    assert np.max(np.abs(load[1:] - enc[1:] - want[1:])) < 1e-12
    assert np.ptp(load[:, 0] - enc[:, 0]) > 0.02          # backlash flips and pitch error both seen on L1


def test_sim_without_effects_keeps_the_fast_tick_and_with_zero_effects_is_identical():
    a, b = _sim(), _sim(backlash_mm=0.0, pitch_error_amp_mm=0.0, thermal_delta_K=0.0)
    assert not a.opt.effects_on and not b.opt.effects_on
    c = _sim(backlash_mm=[0, 0, 0, 0, 1e-9])
    assert c.opt.effects_on
    ra, rc = _effect_run(a, 300), _effect_run(c, 300)
    assert np.array_equal(ra[0], rc[0]) and np.array_equal(ra[1], rc[1])
    assert np.max(np.abs(ra[2] - rc[2])) <= 1e-9


def test_sim_effect_options_are_strictly_checked():
    o = SimOptions.from_dict({"backlash_mm": 0.01, "pitch_error_amp_mm": [0, 0, 0, 0.002, 0]}, M)
    assert np.array_equal(o.backlash_mm, [0.01] * 5) and o.pitch_error_period_mm[3] == M.resolution.table_screw_lead
    for bad, key in (({"backlash_mm": -0.01}, "backlash_mm"), ({"backlash_mm": [0.01, 0.02]}, "backlash_mm"),
                     ({"backlash_mm": "0.01"}, "backlash_mm"), ({"pitch_error_period_mm": 0.0}, "pitch_error_period_mm"),
                     ({"backlash_start": 2.0}, "backlash_start"), ({"friction_coulomb_mm": True}, "friction_coulomb_mm")):
        with pytest.raises(ConfigError, match=key):
            SimOptions.from_dict(bad)
    with pytest.raises(ConfigError, match="did you mean 'backlash_mm'"):
        SimOptions.from_dict({"backlash": 0.01})
