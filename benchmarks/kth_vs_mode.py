"""K_theta (strain-gauge feedback) against the chain mode: eq. 3.1's prediction vs the closed loop.

    .venv/bin/python benchmarks/kth_vs_mode.py [--freqs 10 20 40 80 160 250] [--gains 0 100 200 400]

For each chain-mode frequency f (sim plant: modal mass 31.66 kg, stiffness m (2 pi f)^2, 2 % damping)
and each K_theta, the real NC loop (pmctl.motion.loop.ControlLoop, nc_step, the sim backend with its
flexible mode and strain gauges, V-F converters in multi-pulse mode, 1 kHz) holds a fixed pose while
the chains start with a 50 um deflection; the damping ratio of the decay is fitted to the load-side
deflection. The change proposed for K_theta on soft machines is applied *by configuration, not by
patching nc.py*: the strain -> deflection scale uses the chain's modal stiffness
(``NCParams.from_machine(modal_stiffness_N_per_mm=...)``), the value the sim plant has, instead of
the machine config's 20 000 N/mm. Column "as today" repeats K_theta = 200/s with the machine
config's stiffness, as ``pmctl run --k-theta`` does.

Predictions (kv = seed K_G K_v K_R, K_theta = seed K_theta K_v K_R, both 1/s):
- eq. 3.1 (continuous, with the plant damping added): s^3 + (kv + K_theta + 2 zeta w) s^2 +
  (w^2 + 2 zeta w kv) s + kv w^2 = 0 (pmctl.tools.analysis.vibration.eq31_roots when zeta = 0);
- eq. 3.1 sampled: the same loop with the tick's zero-order hold and the one-tick delay of the
  feedback (the motor rate of tick k uses the deflection read at its start), as a discrete-time
  state matrix; its mode pole gives zeta = -ln|z| / |ln z|.
The best gain per mode (largest mode damping of the sampled model, K_theta dt < 1) is printed too.
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np
from scipy.linalg import expm
from scipy.optimize import curve_fit

from pmctl import hal
from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.motion import loop as L
from pmctl.motion import nc as NC
from pmctl.motion.service_config import LoopConfig
from pmctl.task.planner import home_pose

MASS, ZETA, KV, DT = 31.66, 0.02, 400.0, 1e-3


def predict_continuous(f, kth, kv=KV, zeta=ZETA):
    w = 2 * math.pi * f
    r = np.roots([1.0, kv + kth + 2 * zeta * w, w * w + 2 * zeta * w * kv, kv * w * w])
    c = r[np.argmax(r.imag)]
    if c.imag < 1e-9:                   # over-damped: no oscillating pole left
        return float("nan"), 1.0
    return abs(c) / (2 * math.pi), -c.real / abs(c)


def predict_sampled(f, kth, kv=KV, zeta=ZETA, dt=DT):
    """Discrete model: state (x_m, y, y', v_prev); tick: v = -kv x_m + kth y; y' jumps by -(v - v_prev);
    (y, y') propagate exactly for dt; x_m += v dt."""
    w = 2 * math.pi * f
    Phi = expm(np.array([[0.0, 1.0], [-w * w, -2 * zeta * w]]) * dt)
    Vrow = np.array([-kv, kth, 0.0, 0.0])
    Jmp = np.eye(4)
    Jmp[2] -= Vrow
    Jmp[2, 3] += 1.0                     # y' - (v - v_prev)
    Prop = np.eye(4)
    Prop[1:3, 1:3] = Phi
    Mv = np.eye(4)
    Mv[0] += dt * Vrow
    Mv[3] = Vrow
    # x_m and v_prev update from the pre-jump state; y, y' from the jumped one
    A = np.zeros((4, 4))
    A[0] = Mv[0]
    A[3] = Mv[3]
    A[1:3] = (Prop @ Jmp)[1:3]
    z = np.linalg.eigvals(A)
    osc = z[z.imag > 1e-12]
    if len(osc) == 0:
        return float("nan"), 1.0
    c = osc[np.argmax(np.abs(osc))]              # the mode pole (the slowest-decaying oscillating one)
    lz = np.log(c)
    return abs(lz.imag) / (2 * math.pi * dt), -lz.real / abs(lz)


def best_gain(f, kv=KV, dt=DT):
    g = np.linspace(0.0, 0.95 / dt, 400)
    zs = np.array([predict_sampled(f, k, kv)[1] for k in g])
    i = int(np.nanargmax(zs))
    return float(g[i]), float(zs[i])


def simulate(f, kth, modal=True, y0_mm=0.05, duration=None, accel_scale=100.0):
    """Fitted (frequency Hz, damping ratio, loop status) of the decay in the closed loop.
    ``accel_scale`` multiplies the NC's joint acceleration limit: the feedback alone needs
    K_theta w y0 (20 000 mm/s^2 at 40 Hz, 400/s, 50 um), far over the 2000 mm/s^2 limit, which clips
    it by uniform scaling (see --limits)."""
    from dataclasses import replace
    m = load_machine("prototype")
    k = MASS * (2 * math.pi * f) ** 2 / 1e3                    # N/mm
    params = NC.NCParams.from_machine(m, DT, k_theta=kth, kv=KV, modal_stiffness_N_per_mm=k if modal else None)
    params = replace(params, amax=params.amax * accel_scale)
    tip, axis = home_pose(m)
    tip = np.asarray(tip, float) + [0, 0, -100.0]
    q0 = K.ik(tip, axis, m).q
    c0 = NC.counts_of(q0, params)
    st = NC.initial_state(m, c0)
    duration = duration or max(0.3, 10.0 / f)
    n = int(duration / DT)
    tg = L.build_targets(np.repeat(st.tip[None], n, 0), np.repeat(st.axis[None], n, 0), np.zeros(n, int), DT, m, params)
    be = hal.create("sim", m, DT, dict(flex=True, mode_stiffness_N_per_mm=[k] * 3, mode_mass_kg=[MASS] * 3,
                                       mode_damping_ratio=[ZETA] * 3))
    be.open(c0)
    be.y[:] = y0_mm
    be._sample()                       # the gauges read the initial deflection
    ys = []
    wp = be.write_pulses

    def write(p):
        wp(p)
        ys.append(be.y[0])
    be.write_pulses = write
    lp = L.ControlLoop(m, be, params, tg, LoopConfig(realtime=False, state_file="", settle_s=0.0), st, log=lambda s: None)
    res = lp.run()
    y = np.array(ys)
    t = np.arange(len(y)) * DT
    fd, zp = predict_sampled(f, kth if modal else kth / 10.0)
    w0 = 2 * math.pi * (fd if math.isfinite(fd) else f)

    def model(t, a, b, s, w, c):
        return np.exp(-s * t) * (a * np.cos(w * t) + b * np.sin(w * t)) + c
    # fit while the oscillation is well above the pulse size (0.5 um)
    env = np.abs(y - np.median(y[-len(y) // 4:]))
    last = np.nonzero(env > 0.004)[0]
    nfit = max(int(last[-1]) + 1 if len(last) else 20, int(3.0 / (f * DT)) + 5)
    tt, yy = t[:nfit], y[:nfit]
    try:
        p, _ = curve_fit(model, tt, yy, p0=[y0_mm, 0.0, max(zp, 0.01) * w0, w0, 0.0], maxfev=20000)
        s, w = abs(p[2]), abs(p[3])
        return w / (2 * math.pi), s / math.hypot(s, w), res.status
    except RuntimeError:
        return float("nan"), float("nan"), res.status


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--freqs", type=float, nargs="+", default=[10, 20, 40, 80, 160, 250])
    import warnings
    warnings.filterwarnings("ignore", message="Covariance of the parameters")
    ap.add_argument("--gains", type=float, nargs="+", default=[0, 100, 200, 400])
    ap.add_argument("--limits", action="store_true",
                    help="also run with the machine's own acceleration limit (2000 mm/s^2) to show it clipping the feedback")
    a = ap.parse_args(argv)
    print(f"kv {KV:g}/s, {1 / DT:g} Hz, plant damping {ZETA:g}; zeta: eq.3.1 continuous | eq.3.1 sampled | simulation")
    worst = 0.0
    for f in a.freqs:
        kb, zb = best_gain(f)
        print(f"mode {f:6.1f} Hz: best K_theta (sampled model) {kb:6.0f}/s -> zeta {zb:.3f}")
        for g in list(a.gains) + [round(kb)]:
            _, zc = predict_continuous(f, g)
            _, zd = predict_sampled(f, g)
            fs, zs, status = simulate(f, g)
            worst = max(worst, abs(zs - zd)) if math.isfinite(zs) else worst
            print(f"   K_theta {g:6.0f}/s: {zc:7.3f} | {zd:7.3f} | {zs:7.3f}  (sim {fs:6.1f} Hz, {status})")
        if a.limits:
            for g in (200.0, 400.0):
                fs, zs, status = simulate(f, g, accel_scale=1.0)
                print(f"   K_theta {g:6.0f}/s with the 2000 mm/s^2 joint acceleration limit, 50 um start: sim zeta "
                      f"{zs:.3f} ({fs:.1f} Hz) vs sampled {predict_sampled(f, g)[1]:.3f}")
        _, zd = predict_sampled(f, 20.0)
        fs, zs, status = simulate(f, 200.0, modal=False)
        print(f"   as today (K_theta 200/s, machine stiffness 20000 N/mm -> 20/s effective): sampled {zd:.3f} | sim {zs:.3f}")
    print(f"largest |zeta_sim - zeta_sampled| over the table: {worst:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
