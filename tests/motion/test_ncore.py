"""The compiled NC core (pmctl.motion.ncore) against the Python reference (pmctl.motion.nc).

Both run on the same inputs: closed loops against the loopback sim plant (each NC drives its own
sim, same options and noise seed), with pulses compared tick for tick and the NC state at every
tick to 1e-9; paths, rates, pulse modes, K_theta and non-nominal geometry (base/platform joints,
revolute axes, length offsets, tool length and tilt) drawn by hypothesis. The supervision paths
(soft limit, following error, path error, lost model pose, dead sensor) must end in the same mode
with the same reason."""

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings, strategies as st

from pmctl import hal
from pmctl.core import kinematics as K
from pmctl.core.compensation import AxisComp, Compensation
from pmctl.core.config import load_machine
from pmctl.core.errors import ConfigError, KinematicsError
from pmctl.hal.base import Feedback
from pmctl.motion import ncore
from pmctl.motion.nc import DONE, HALTED, NCParams, PythonNC, RUN, counts_of, initial_state
from pmctl.motion.ncore import make_nc
from pmctl.core.model_fk import ModelFK
from pmctl.motion.service_config import NCConfig, service_from_dict

M = load_machine()
STATE_FIELDS = ("acc", "qdot", "P", "R", "tip", "axis", "path_error", "q_model", "T", "kth")
COMP_FIELDS = ("comp_dir", "comp_bl", "comp")
OFFSET_FIELDS = ("offset",)      # the chain-length offset applied (None before any input reads as zeros)


def perturbed(seed: int, size: float):
    """The machine with a calibrated-looking, non-nominal geometry: every joint moved by up to
    ``size`` mm, revolute axes turned by up to size/100 rad, length offsets, tool length and tilt."""
    if size == 0:
        return M
    rng = np.random.default_rng(seed)
    g = M.geometry
    n = g.revolute_axes + rng.uniform(-1, 1, (3, 3)) * size / 100
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    g2 = replace(g, base_joints=g.base_joints + rng.uniform(-1, 1, (3, 3)) * size,
                 platform_joints=g.platform_joints + rng.uniform(-1, 1, (3, 3)) * size,
                 revolute_axes=n, length_offsets=rng.uniform(-1, 1, 3) * size,
                 tool_length=g.tool_length + float(rng.uniform(-1, 1)) * 10 * size,
                 tool_tilt_deg=tuple(float(x) for x in rng.uniform(-1, 1, 2) * size), nominal=False)
    return replace(M, geometry=g2)


def joint_path(machine, params, dt, seconds, amp, freq, phase, q_off):
    """Target rows (tip, axis, their forward differences) of a smooth joint-space motion around
    home, by the FK of ``machine`` (no IK: valid for any geometry). Speeds stay within half the
    limit."""
    n = int(round(seconds / dt)) + 1
    t = np.arange(n) * dt
    home = np.array([machine.geometry.z_home] * 3 + [0.0, 0.0]) + q_off
    w = 2 * np.pi * freq
    a = np.minimum(np.minimum(amp, 0.4 * params.vmax / w), 0.2 * params.amax / w ** 2)
    tr = min(0.5, seconds / 2)
    u = np.minimum(np.minimum(t, t[-1] - t) / tr, 1.0)
    ramp = u * u * (3 - 2 * u)                                 # smooth start from rest, smooth stop
    q = home + ramp[:, None] * a * np.sin(w * t[:, None] + phase)
    pose, ok = K.fk_batch(q, machine)
    assert np.all(ok)
    rows = np.zeros((n, 12))
    rows[:, :3], rows[:, 3:6] = pose.tip, pose.axis
    rows[:-1, 6:9] = np.diff(pose.tip, axis=0) / dt
    rows[:-1, 9:12] = np.diff(pose.axis, axis=0) / dt
    return rows, q


def assert_same_state(a, b, tick):
    """a: Python NCState, b: compiled snapshot."""
    assert np.array_equal(a.counts, b.counts), f"tick {tick}: counters differ"
    assert a.mode == b.mode and a.reason == b.reason, f"tick {tick}: {a.mode} {a.reason!r} vs {b.mode} {b.reason!r}"
    for f in STATE_FIELDS:
        x, y = getattr(a, f), getattr(b, f)
        if x is None or y is None:
            assert x is None and y is None, f"tick {tick}: {f}"
            continue
        d = float(np.max(np.abs(np.asarray(x, float) - np.asarray(y, float))))
        assert d <= 1e-9, f"tick {tick}: {f} differs by {d:g}"
    for f in COMP_FIELDS + OFFSET_FIELDS:      # None (none yet) reads as zeros in the core
        x, y = getattr(a, f), getattr(b, f)
        if x is None and y is None:
            continue
        n = 3 if f in OFFSET_FIELDS else 5
        x = np.zeros(n) if x is None else x
        y = np.zeros(n) if y is None else y
        assert np.array_equal(x, y), f"tick {tick}: {f} {x} vs {y}"


def closed_loop(machine, params, rows, q0, sim_opt, *, every=1, inject=None, offset=None):
    """Each NC against its own sim; returns (ticks, final python state, final compiled snapshot,
    pulses sent per axis in absolute value). ``offset(k)``: the chain-length offset input of tick k
    (an array of 3 or None), the same for both."""
    dt = params.dt
    c0 = counts_of(q0, params)
    st0 = initial_state(machine, c0)
    py, cc = PythonNC(machine, params), make_nc(machine, params, "compiled")
    assert isinstance(cc, ncore.CompiledNC)
    sp, sc = py.load(st0), cc.load(st0)
    sims = [hal.create("sim", machine, dt, dict(sim_opt)) for _ in range(2)]
    for s in sims:
        s.open(c0)
    hold = rows[-1].copy()
    hold[6:] = 0.0
    n = len(rows) + int(0.05 / dt)
    k = 0
    moved = np.zeros(5, np.int64)
    for k in range(n):
        tg = rows[k] if k < len(rows) else hold
        fa, fb = sims[0].read(), sims[1].read()
        if inject is not None:
            inject(k, fa)
            inject(k, fb)
        off = None if offset is None else offset(k)
        pa, sp = py.step(sp, tg, fa, off)
        pb, sc = cc.step(sc, tg, fb, off)
        assert np.array_equal(pa, pb), f"tick {k}: pulses {pa} vs {pb}"
        assert sp.mode == sc.mode and sp.reason == sc.reason, f"tick {k}: {sp.reason!r} vs {sc.reason!r}"
        if k % every == 0:
            assert_same_state(sp, sc.snapshot(), k)
        if sp.mode in (HALTED, DONE):
            break
        moved += np.abs(pa)
        sims[0].write_pulses(pa)
        sims[1].write_pulses(pb.copy())
    assert_same_state(sp, sc.snapshot(), k)
    assert np.array_equal(sims[0].counts, sims[1].counts)
    return k + 1, sp, sc.snapshot(), moved


# ---------------------------------------------------------------- closed loops, tick for tick


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rate=st.sampled_from([500.0, 1000.0, 2000.0]),
       multi=st.booleans(),
       k_theta=st.sampled_from([0.0, 50.0, 200.0]),
       geom_seed=st.integers(0, 10_000), geom_size=st.sampled_from([0.0, 0.5, 3.0]),
       amp=st.lists(st.floats(0.0, 15.0), min_size=5, max_size=5),
       freq=st.floats(0.2, 2.0), phase=st.lists(st.floats(0, 6.3), min_size=5, max_size=5),
       q_off=st.lists(st.floats(-20.0, 20.0), min_size=5, max_size=5),
       flex=st.booleans(), noise=st.booleans())
# the half-pulse tie (X 0.34375 mm = 687.5 pulses from the counters): the two pseudo-inverses round
# the correction's rate a unit in the last place apart and the V-F sum lands on a whole pulse at tick
# 11; both must send it (pmctl.core.vf.TIE)
@example(rate=500.0, multi=False, k_theta=0.0, geom_seed=0, geom_size=0.0, amp=[0.0, 0.0, 0.0, 0.0, 1.0],
         freq=1.0, phase=[0.0] * 5, q_off=[0.0, 0.0, 0.0, 0.34375, 0.0], flex=False, noise=False)
def test_compiled_and_python_send_the_same_pulses_tick_for_tick(rate, multi, k_theta, geom_seed, geom_size,
                                                                amp, freq, phase, q_off, flex, noise):
    machine = perturbed(geom_seed, geom_size)
    dt = 1.0 / rate
    params = NCParams.from_machine(machine, dt, kv=min(400.0, 0.4 / dt), k_theta=k_theta,
                                   max_pulses_per_tick=None if multi else 1)
    rows, q = joint_path(machine, params, dt, 0.8, np.array(amp), freq, np.array(phase), np.array(q_off))
    sim = {"flex": flex, "strain_noise_ue": 0.01 if noise else 0.0, "enc_noise_mm": 1e-5 if noise else 0.0,
           "seed": geom_seed}
    ticks, sp, sc, moved = closed_loop(machine, params, rows, q[0], sim, every=7)
    assert sp.mode == RUN and ticks == len(rows) + int(0.05 / dt), sp.reason    # a feasible path: no stop


@pytest.mark.parametrize("rate", [500.0, 1000.0, 2000.0])
@pytest.mark.parametrize("moving", [False, True])
def test_a_target_exactly_half_a_pulse_away_gives_the_same_pulses(rate, moving):
    """Every axis in turn with its target exactly half a pulse from the counters (687.5 pulses, and
    0.125 pulse from one: 0.5 + 1/8 is still exact), at rest (the rest deadband's edge) and with Y
    moving (the V-F accumulator summing to a whole pulse): both cores send the same pulses and hold
    the same state, tick for tick. Before the tie margin the Python NC sent X's pulse at tick 11 of
    the moving case at 500 Hz and the compiled one did not; at rest Y's half pulse at 0.00025 mm
    was held by one core and corrected by the other."""
    dt = 1.0 / rate
    params = NCParams.from_machine(M, dt, kv=min(400.0, 0.4 / dt), max_pulses_per_tick=1)
    for ax in range(5):
        for off in (0.34375, -0.34375, 0.00025, 0.0003125):
            q_off = np.zeros(5)
            q_off[ax] = off
            amp = np.array([0.0, 0.0, 0.0, 0.0, 1.0 if ax != 4 else 0.0]) if moving else np.zeros(5)
            if moving and ax == 4:
                amp[3] = 1.0
            rows, q = joint_path(M, params, dt, 0.12, amp, 1.0, np.zeros(5), q_off)
            closed_loop(M, params, rows, q[0], {}, every=1)


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rate=st.sampled_from([500.0, 1000.0, 2000.0]),
       k_theta=st.lists(st.sampled_from([0.0, 50.0, 200.0, 400.0]), min_size=3, max_size=3),
       mode_hz=st.lists(st.sampled_from([0.0, 15.0, 40.0, 120.0]), min_size=3, max_size=3),
       stiffness=st.sampled_from([500.0, 2000.0, 20000.0]),
       leak=st.lists(st.floats(0.0, 100.0), min_size=3, max_size=3),
       ff=st.booleans(), geom_seed=st.integers(0, 10_000), geom_size=st.sampled_from([0.0, 2.0]),
       amp=st.lists(st.floats(0.0, 15.0), min_size=5, max_size=5), freq=st.floats(0.2, 2.0),
       noise=st.booleans())
def test_soft_chain_k_theta_same_pulses_tick_for_tick(rate, k_theta, mode_hz, stiffness, leak, ff, geom_seed,
                                                      geom_size, amp, freq, noise):
    """The soft-chain K_theta (modal stiffness scale, planned stretch off, decoupled offset, deflection
    feed-forward; per-chain gains, modes and leaks) on a soft flexible plant: same pulses and state."""
    machine = perturbed(geom_seed, geom_size)
    dt = 1.0 / rate
    k_theta = [min(k, 0.4 / dt) for k in k_theta]
    params = NCParams.from_machine(machine, dt, kv=min(400.0, 0.4 / dt), k_theta=k_theta,
                                   modal_stiffness_N_per_mm=stiffness, mode_hz=mode_hz,
                                   k_theta_leak=leak, deflection_ff=ff)
    rows, q = joint_path(machine, params, dt, 0.6, np.array(amp), freq, np.zeros(5), np.zeros(5))
    sim = {"flex": True, "mode_stiffness_N_per_mm": stiffness, "mode_mass_kg": 31.66,
           "strain_noise_ue": 0.01 if noise else 0.0, "seed": geom_seed}
    ticks, sp, sc, moved = closed_loop(machine, params, rows, q[0], sim, every=5)
    # a mode assumed far from the plant's with no leak can drift off the path (a path-error stop):
    # both cores must still agree on it, which closed_loop checks
    if params._kth_modal and sp.mode == RUN:
        assert sp.kth is not None and np.all(np.isfinite(sp.kth))


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rate=st.sampled_from([500.0, 1000.0, 2000.0]), multi=st.booleans(),
       seed=st.integers(0, 10_000), geom_size=st.sampled_from([0.0, 1.0]),
       bound=st.sampled_from([0.0, 0.05, 0.2, 1.0]), slew=st.sampled_from([0.0, 0.01, 0.1, 2.0]),
       steps=st.lists(st.tuples(st.integers(0, 900), st.integers(0, 2),
                                st.one_of(st.floats(-2.0, 2.0), st.sampled_from([math.nan, math.inf, -math.inf]))),
                      max_size=8),
       gaps=st.lists(st.integers(0, 900), max_size=3), comp=st.booleans(),
       amp=st.lists(st.floats(0.0, 12.0), min_size=5, max_size=5), freq=st.floats(0.3, 2.0))
def test_compiled_and_python_same_pulses_with_chain_offsets(rate, multi, seed, geom_size, bound, slew, steps, gaps,
                                                            comp, amp, freq):
    """The chain-length offset input (slow compensation): random steps of random size per chain
    (beyond the bound, non-finite ones too), ticks without an input (held), random bounds and slew
    rates, with and without a compensation table: the same pulses and the same applied offset, tick
    for tick; the applied offset never moves faster than the slew nor beyond the bound."""
    machine = perturbed(seed, geom_size)
    dt = 1.0 / rate
    home = np.array([machine.geometry.z_home] * 3 + [0.0, 0.0])
    params = NCParams.from_machine(machine, dt, kv=min(400.0, 0.4 / dt), max_pulses_per_tick=None if multi else 1,
                                   chain_offset_max_mm=bound, chain_offset_rate_mm_s=slew,
                                   compensation=random_compensation(seed, 0.01, 0.005, 7, home) if comp else None)
    rows, q = joint_path(machine, params, dt, 0.6, np.array(amp), freq, np.zeros(5), np.zeros(5))
    want = np.zeros(3)
    by_tick = {}
    for k, i, v in steps:
        by_tick.setdefault(int(k * rate / 1000), []).append((i, v))
    holes = {int(g * rate / 1000) for g in gaps}

    def offset(k):
        for i, v in by_tick.get(k, ()):
            want[i] = v
        return None if k in holes else want.copy()
    ticks, sp, sc, moved = closed_loop(machine, params, rows, q[0], {"seed": seed}, every=3, offset=offset)
    assert sp.mode == RUN, sp.reason
    assert np.all(np.abs(sp.offset) <= bound)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rate=st.sampled_from([500.0, 1000.0, 2000.0]), multi=st.booleans(),
       band=st.sampled_from([0.5, 0.5, 0.75, 1.0, 0.0]),
       k_theta=st.sampled_from([0.0, 0.0, 200.0]), modal=st.booleans(), comp=st.booleans(),
       seed=st.integers(0, 10_000), geom_size=st.sampled_from([0.0, 1.0]),
       amp=st.lists(st.floats(0.0, 8.0), min_size=5, max_size=5), freq=st.floats(0.5, 2.0),
       rest_s=st.floats(0.2, 0.6),
       nudges=st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(0, 4), st.floats(-3.0, 3.0)), max_size=4),
       offsets=st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(0, 2), st.floats(-2e-3, 2e-3)), max_size=2),
       flex=st.booleans(), noise=st.booleans())
def test_compiled_and_python_same_pulses_at_rest(rate, multi, band, k_theta, modal, comp, seed, geom_size, amp,
                                                 freq, rest_s, nudges, offsets, flex, noise):
    """The rest deadband: a move (or none), then the target at rest (no feed-forward) with steps of
    up to 3 pulses' worth (sub-pulse ones too) on the tip or the tool axis, chain-length offset
    steps, K_theta (plain or soft-chain), compensation, noise, the band switched off too: the same
    pulses and the same state (V-F residues, rates) tick for tick. Undisturbed at the end, both hold
    still with no residue."""
    machine = perturbed(seed, geom_size)
    dt = 1.0 / rate
    home = np.array([machine.geometry.z_home] * 3 + [0.0, 0.0])
    params = NCParams.from_machine(machine, dt, kv=min(400.0, 0.4 / dt), k_theta=k_theta,
                                   max_pulses_per_tick=None if multi else 1, rest_deadband_pulses=band,
                                   mode_hz=60.0 if (modal and k_theta) else None, chain_offset_rate_mm_s=0.5,
                                   compensation=random_compensation(seed, 0.005, 0.003, 7, home) if comp else None)
    # off the pulse grid (an exact multiple of a pulse per tick would put the V-F residue exactly on
    # its threshold, where the two pseudo-inverses' last-bit differences may decide the pulse)
    q_off = np.array([0.0123, -0.0456, 0.0789, 0.0314, -0.0271]) * math.pi
    rows, q = joint_path(machine, params, dt, 0.4, np.array(amp), freq, np.zeros(5), q_off)
    n_rest = int(rest_s / dt)
    rest = np.repeat(rows[-1:], n_rest, 0)
    rest[:, 6:] = 0.0
    pulse_mm = 1.0 / float(params.pulses_per_mm[0]) * (1.0 + 1e-3 * math.e)
    for at, i, size in nudges:           # from tick k on: the tip moved along an axis, or the tool axis tilted
        k = int(at * n_rest * 0.8)
        if i < 3:
            rest[k:, i] += size * pulse_mm
        else:
            rest[k:, i] += size * pulse_mm / machine.geometry.tool_length
            rest[k:, 3:6] /= np.linalg.norm(rest[k:, 3:6], axis=1, keepdims=True)
    rows = np.concatenate([rows, rest])
    want = np.zeros(3)
    steps = {len(rows) - n_rest + int(at * n_rest * 0.8): (i, v) for at, i, v in offsets}

    def offset(k):
        if k in steps:
            want[steps[k][0]] = steps[k][1]
        return want.copy()
    sim = {"flex": flex, "strain_noise_ue": 0.01 if noise else 0.0, "enc_noise_mm": 1e-5 if noise else 0.0,
           "seed": seed}
    ticks, sp, sc, moved = closed_loop(machine, params, rows, q[0], sim, every=3, offset=offset)
    assert sp.mode == RUN, sp.reason
    if band and not (k_theta or noise or flex):
        # the end of the rest and closed_loop's extra 50 ms: held, rate zero, no residue owed
        assert not np.any(sp.qdot) and not np.any(sp.acc), (sp.qdot, sp.acc)


def test_chain_offset_is_added_to_the_commanded_lengths_at_the_slew_rate():
    """At rest on a fixed target, an offset step of +0.1 mm on L2 (-0.05 on L3) moves the counters
    of L2 by +0.1 mm (L3 by -0.05) once the slew time has passed, the applied offset ramps at the
    slew rate (never a jump), and a request over the bound is clipped to it."""
    dt = 1e-3
    params = NCParams.from_machine(M, dt, kv=400.0, chain_offset_max_mm=0.08, chain_offset_rate_mm_s=0.2)
    q0 = np.array([M.geometry.z_home] * 3 + [0.0, 0.0])
    rows, q = joint_path(M, params, dt, 0.05, np.zeros(5), 1.0, np.zeros(5), np.zeros(5))
    n = 1000
    rows = np.repeat(rows[:1], n, 0)
    seen = []

    def offset(k):
        return np.zeros(3) if k < 100 else np.array([0.0, 0.1, -0.05])
    for impl in ("python", "compiled"):
        nc = make_nc(M, params, impl)
        c0 = counts_of(q0, params)
        s = nc.load(initial_state(M, c0))
        be = hal.create("sim", M, dt, {})
        be.open(c0)
        offs = []
        for k in range(n):
            pl, s = nc.step(s, rows[k], be.read(), offset(k))
            be.write_pulses(np.array(pl))
            offs.append(np.array(s.offset, float).copy())
        offs = np.array(offs)
        assert np.max(np.abs(np.diff(offs, axis=0))) <= 0.2 * dt + 1e-15        # slew-limited
        np.testing.assert_allclose(offs[-1], [0.0, 0.08, -0.05])                # L2 clipped to the bound
        np.testing.assert_allclose(offs[100 + 199], [0.0, 0.04, -0.04], atol=1e-12)   # 200 ticks of 0.2 um
        np.testing.assert_allclose(offs[100 + 399], [0.0, 0.08, -0.05], atol=1e-12)   # 0.08 mm / 0.2 mm/s = 0.4 s
        dq = (np.asarray(s.counts) - c0) / params.pulses_per_mm
        tol = 2.0 / params.pulses_per_mm[:3]            # within two pulses (the servo's dither at rest)
        assert np.all(np.abs(dq[:3] - [0.0, 0.08, -0.05]) <= tol), dq
        seen.append(np.asarray(s.counts).copy())
    assert np.array_equal(seen[0], seen[1])


@pytest.mark.parametrize("impl", ["python", "compiled"])
def test_a_restart_keeps_the_applied_chain_offset(impl):
    """A restart (unlock, homing) from counters that carry an applied offset, holding the model
    pose it starts from (the rt side's rest pose): with the offset given to initial_state the
    counters stay; without, the NC would slew the offset in a second time."""
    dt = 1e-3
    params = NCParams.from_machine(M, dt, kv=400.0, chain_offset_rate_mm_s=1.0)
    off = np.array([0.03, -0.02, 0.01])
    c = counts_of(np.array([M.geometry.z_home] * 3 + [0.0, 0.0]) + np.r_[off, 0.0, 0.0], params)
    st0 = initial_state(M, c, offset=off)
    tip0 = initial_state(M, c).tip
    for with_offset, moved in ((True, False), (False, True)):
        nc = make_nc(M, params, impl)
        s = nc.load(initial_state(M, c, offset=off if with_offset else None))
        target = np.r_[np.array(s.tip, float), np.array(s.axis, float), np.zeros(6)]   # the rest pose (rtproc)
        be = hal.create("sim", M, dt, {})
        be.open(c)
        for _ in range(200):
            pl, s = nc.step(s, target, be.read(), off)
            be.write_pulses(np.array(pl))
        d = (np.asarray(s.counts) - c)[:3] / params.pulses_per_mm[:3]
        assert (np.max(np.abs(d)) > 0.005) == moved, d
    assert np.linalg.norm(st0.tip - tip0) > 0.01


def test_long_run_20000_ticks_same_pulses_and_state():
    """A 10 s circle-like joint motion at 2 kHz with K_theta on the flexible, noisy sim plant."""
    dt = 5e-4
    params = NCParams.from_machine(M, dt, kv=400.0, k_theta=200.0)
    rows, q = joint_path(M, params, dt, 10.0, np.array([20.0, 15.0, 10.0, 25.0, 25.0]), 0.3,
                         np.array([0.0, 2.1, 4.2, 0.0, 1.57]), np.zeros(5))
    ticks, sp, sc, moved = closed_loop(M, params, rows, q[0], {"flex": True, "strain_noise_ue": 0.01, "seed": 3},
                                       every=50)
    assert ticks > 20000 and sp.mode == RUN
    assert np.all(moved > 100_000)          # every axis travelled over 50 mm


# ---------------------------------------------------------------- compensation (pmctl.core.compensation)


def random_compensation(seed, backlash, pitch, points, home):
    """Backlash per axis, a screw table of ``points`` irregular positions around ``home`` (the path
    crosses its ends too) with different forward and reverse errors, random take-up rates."""
    rng = np.random.default_rng(seed)
    axes = []
    for a in range(5):
        if points:
            pos = np.sort(home[a] + rng.uniform(-12.0, 12.0, points))
            pos = np.unique(pos)
            fwd = pitch * np.sin(2 * np.pi * pos / 5.0 + rng.uniform(0, 6.3)) + rng.uniform(-1, 1, len(pos)) * 1e-3
            rev = fwd + rng.uniform(-1, 1, len(pos)) * pitch
            tab = (tuple(pos.tolist()), tuple(fwd.tolist()), tuple(rev.tolist()))
        else:
            tab = ((), (), ())
        axes.append(AxisComp(float(backlash * rng.uniform(0.2, 1.0)), float(rng.uniform(0.5, 20.0)), *tab))
    return Compensation(tuple(axes))


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rate=st.sampled_from([500.0, 1000.0, 2000.0]), multi=st.booleans(),
       seed=st.integers(0, 10_000), backlash=st.sampled_from([0.0, 0.005, 0.05]),
       pitch=st.sampled_from([0.0, 0.003, 0.02]), points=st.sampled_from([0, 2, 7, 60]),
       amp=st.lists(st.floats(0.0, 15.0), min_size=5, max_size=5),
       freq=st.floats(0.3, 2.0), phase=st.lists(st.floats(0, 6.3), min_size=5, max_size=5),
       k_theta=st.sampled_from([0.0, 100.0]), geom_size=st.sampled_from([0.0, 1.0]))
def test_compiled_and_python_same_pulses_with_compensation(rate, multi, seed, backlash, pitch, points, amp,
                                                           freq, phase, k_theta, geom_size):
    """Backlash and screw tables (both directions, irregular positions, the path crossing the
    table ends, reversals on every axis): the two NCs send the same pulses and hold the same
    compensation state, tick for tick."""
    machine = perturbed(seed, geom_size)
    dt = 1.0 / rate
    home = np.array([machine.geometry.z_home] * 3 + [0.0, 0.0])
    comp = random_compensation(seed, backlash, pitch, points, home)
    params = NCParams.from_machine(machine, dt, kv=min(400.0, 0.4 / dt), k_theta=k_theta,
                                   max_pulses_per_tick=None if multi else 1, compensation=comp)
    rows, q = joint_path(machine, params, dt, 0.8, np.array(amp), freq, np.array(phase), np.zeros(5))
    ticks, sp, sc, moved = closed_loop(machine, params, rows, q[0], {"seed": seed}, every=5)
    assert sp.mode == RUN, sp.reason
    assert sp.comp is not None and np.array_equal(sp.comp, sc.comp)
    if backlash and np.any(moved[np.array(amp) > 1.0] > 0):
        assert np.any(sp.comp_bl != 0.0)          # the backlash term is in play


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(amp=st.lists(st.floats(1.0, 12.0), min_size=5, max_size=5),
       phase=st.lists(st.floats(0, 6.3), min_size=5, max_size=5), flex=st.booleans())
@pytest.mark.parametrize("impl", ["python", "compiled"])
def test_zero_compensation_is_todays_nc_bit_for_bit(impl, amp, phase, flex):
    """An all-zero table (backlash 0, screw errors 0) goes through the compensation code and
    changes nothing: the same pulses and the same model pose to the last bit as no table."""
    dt = 1e-3
    home = np.array([M.geometry.z_home] * 3 + [0.0, 0.0])
    zero = Compensation(tuple(AxisComp(0.0, 3.0, (h - 30.0, h, h + 30.0), (0.0,) * 3, (0.0,) * 3)
                              for h in home))
    runs = []
    for comp in (None, zero):
        params = NCParams.from_machine(M, dt, kv=400.0, compensation=comp)
        rows, q = joint_path(M, params, dt, 1.0, np.array(amp), 1.0, np.array(phase), np.zeros(5))
        nc = make_nc(M, params, impl)
        sim = hal.create("sim", M, dt, {"flex": flex, "seed": 1})
        c0 = counts_of(q[0], params)
        sim.open(c0)
        st = nc.load(initial_state(M, c0))
        out = []
        for k in range(len(rows)):
            p, st = nc.step(st, rows[k], sim.read())
            out.append((p.copy(), st.snapshot().P.copy(), st.snapshot().tip.copy()))
            sim.write_pulses(p.copy())
        runs.append(out)
    assert sum(int(np.abs(p).sum()) for p, _, _ in runs[0]) > 2_000
    for k, (a, b) in enumerate(zip(*runs)):
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]) and np.array_equal(a[2], b[2]), k


def test_core_rejects_a_bad_compensation_layout():
    params = NCParams.from_machine(M, 1e-3)
    c = ncore.constants(M, params)
    good = Compensation(tuple(AxisComp(0.01, 5.0, (0.0, 1.0), (0.0, 0.001), (0.0, 0.001)) for _ in range(5))).flat()
    ncore._ncore.Core(c, np.zeros(ncore.S_LEN), np.zeros(ncore.N_LEN, np.int64), good)
    for bad in (good[:-1], np.where(np.arange(len(good)) == 20, 2.0, good), good[:10]):
        with pytest.raises(ValueError, match="comp"):
            ncore._ncore.Core(c, np.zeros(ncore.S_LEN), np.zeros(ncore.N_LEN, np.int64), bad)


# ---------------------------------------------------------------- supervision: same mode, same reason


def _supervision_case(rows_fn, sim=None, inject=None, rate=1000.0, **kw):
    dt = 1.0 / rate
    params = NCParams.from_machine(M, dt, kv=400.0, **kw)
    rows, q0 = rows_fn(params, dt)
    return closed_loop(M, params, rows, q0, sim or {}, inject=inject)[:3]


def _toward(q_end_fn, seconds=1.0):
    def fn(params, dt):
        q0 = np.array([M.geometry.z_home] * 3 + [0.0, 0.0])
        q1 = q_end_fn(params, q0)
        n = int(seconds / dt) + 1
        s = 0.5 - 0.5 * np.cos(np.pi * np.arange(n) / (n - 1))
        q = q0 + s[:, None] * (q1 - q0)
        pose, ok = K.fk_batch(q, M)
        rows = np.zeros((n, 12))
        rows[:, :3], rows[:, 3:6] = pose.tip, pose.axis
        rows[:-1, 6:9] = np.diff(pose.tip, axis=0) / dt
        rows[:-1, 9:12] = np.diff(pose.axis, axis=0) / dt
        return rows, q0
    return fn


def test_soft_limit_same_stop_and_reason():
    def end(params, q0):
        q1 = q0.copy()
        q1[3] = params.upper[3] + 5.0          # X beyond its soft limit
        return q1
    ticks, sp, sc = _supervision_case(_toward(end, 3.0))
    assert sp.mode == sc.mode == HALTED
    assert sp.reason.startswith("soft limit: X") and sp.reason == sc.reason


def test_following_error_same_halt_and_reason():
    ticks, sp, sc = _supervision_case(_toward(lambda p, q0: q0 + [5.0, 0, 0, 10.0, 0]),
                                      sim={"lost_steps_at_tick": 300, "lost_steps_axis": 1, "lost_steps_mm": 0.2})
    assert sp.mode == sc.mode == HALTED and ticks == 302
    assert sp.reason.startswith("following error: L2") and sp.reason == sc.reason


def test_dead_sensor_same_halt_and_reason():
    def inject(k, fb):
        if k == 120:
            fb.strain[2] = math.nan
    ticks, sp, sc = _supervision_case(_toward(lambda p, q0: q0 + [2.0, 0, 0, 3.0, 0]), inject=inject)
    assert sp.mode == sc.mode == HALTED and ticks == 121
    assert sp.reason == sc.reason == "feedback fault: strain gauge 3 reads nan"


def test_path_error_same_stop_and_reason():
    def fn(params, dt):
        rows, q0 = _toward(lambda p, q0: q0 + [1.0, 0, 0, 0, 0])(params, dt)
        rows[200:, 0] += 2.0                 # the target jumps 2 mm
        return rows, q0
    ticks, sp, sc = _supervision_case(fn)
    assert sp.mode == sc.mode == HALTED
    assert sp.reason.startswith("path error") and sp.reason == sc.reason


@pytest.mark.parametrize("jump", [[4_000_000, 0, 0, 0, 0], [-700_000, 0, 0, 0, 0], [0, 3_000_000, -500_000, 0, 0]])
def test_model_pose_lost_same_halt_and_reason(jump):
    """Counters that no pose of the platform matches (a chain far too long or short): both NCs halt
    at once with the same 'model pose lost' reason."""
    dt = 1e-3
    params = NCParams.from_machine(M, dt, kv=400.0)
    q0 = np.array([M.geometry.z_home] * 3 + [0.0, 0.0])
    st0 = initial_state(M, counts_of(q0, params))
    bad = replace(st0, counts=st0.counts + np.array(jump))
    fb = Feedback()
    fb.enc[:] = bad.counts / params.pulses_per_mm
    tg = np.concatenate([st0.tip, st0.axis, np.zeros(6)])
    pa, sp = PythonNC(M, params).step(bad, tg, fb)
    cc = make_nc(M, params, "compiled")
    pb, sc = cc.step(cc.load(bad), tg, fb)
    assert sp.mode == sc.mode == HALTED
    assert sp.reason.startswith("model pose lost: forward kinematics") and sp.reason == sc.reason
    assert not pa.any() and not pb.any()
    assert_same_state(sp, sc.snapshot(), 0)


# ---------------------------------------------------------------- the FK alone, general geometry


@settings(max_examples=40, deadline=None)
@given(geom_seed=st.integers(0, 10_000), geom_size=st.sampled_from([0.0, 0.5, 3.0]),
       dq=st.lists(st.floats(-60.0, 60.0), min_size=5, max_size=5),
       step=st.lists(st.floats(-0.5, 0.5), min_size=3, max_size=3))
def test_compiled_fk_equals_model_fk(geom_seed, geom_size, dq, step):
    """Model FK with the predictor warm start: same pose, same Newton iterations, on non-nominal
    geometry; FK(q) reproduces the chain lengths of the pose."""
    machine = perturbed(geom_seed, geom_size)
    q = np.array([machine.geometry.z_home] * 3 + [0.0, 0.0]) + np.array(dq)
    P, R = K.forward_platform(q[:3], machine.geometry)
    mf = ModelFK(machine)
    mf.solve(q, P, R)
    cf = ncore.CompiledFK(machine, P, R, q)
    cf.solve(q)
    q2 = q.copy()
    q2[:3] += step
    try:
        P1, R1, tip1, ax1, J1 = mf.solve(q2, P, R, ((q2 - q)[:3], mf.last_T))
    except KinematicsError as e:
        with pytest.raises(KinematicsError) as ei:
            cf.solve(q2)
        assert str(ei.value) == str(e)
        return
    it = cf.solve(q2)
    assert it >= 0
    assert np.array_equal(P1, cf.P) and np.array_equal(R1.ravel(), cf.R)     # same arithmetic, same bits
    assert np.array_equal(mf.last_T.ravel(), cf.T)
    Cw = (R1 @ machine.geometry.platform_joints.T).T + P1
    L = np.linalg.norm(Cw - machine.geometry.base_joints, axis=1) - machine.geometry.length_offsets
    assert np.allclose(L, q2[:3], atol=1e-9)
    assert np.allclose(cf.static_strain(), mf.static_strain(R1, mf.last_T), atol=1e-12, rtol=0)


# ---------------------------------------------------------------- the switch


def test_the_service_config_selects_the_implementation_strictly():
    assert NCConfig().implementation == "compiled"
    svc = service_from_dict({"nc": {"implementation": "python"}})
    assert svc.nc.implementation == "python"
    assert svc.nc.params(M, 1e-3).implementation == "python"
    assert isinstance(make_nc(M, svc.nc.params(M, 1e-3)), PythonNC)
    assert isinstance(make_nc(M, NCConfig().params(M, 1e-3)), ncore.CompiledNC)
    for bad in ("fortran", "Compiled", 1, True):
        with pytest.raises(ConfigError, match="nc.implementation"):
            service_from_dict({"nc": {"implementation": bad}})
    with pytest.raises(ValueError, match="implementation"):
        NCParams.from_machine(M, 1e-3, implementation="numba")


def test_core_rejects_wrong_buffers():
    c = ncore.constants(M, NCParams.from_machine(M, 1e-3))
    with pytest.raises(ValueError, match="consts"):
        ncore._ncore.Core(c[:-1], np.zeros(ncore.S_LEN), np.zeros(ncore.N_LEN, np.int64))
    with pytest.raises(ValueError, match="int64"):
        ncore._ncore.Core(c, np.zeros(ncore.S_LEN), np.zeros(ncore.N_LEN))
    core = ncore._ncore.Core(c, np.zeros(ncore.S_LEN), np.zeros(ncore.N_LEN, np.int64))
    with pytest.raises(ValueError, match="target"):
        core.step(np.zeros(11), np.zeros(5), np.zeros(3))
    with pytest.raises(ValueError, match="float64"):
        core.step(np.zeros(12), np.zeros(5, np.float32), np.zeros(3))
