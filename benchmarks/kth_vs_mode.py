"""K_theta (strain-gauge feedback) against the chain mode: eq. 3.1's prediction vs the closed loop.

    .venv/bin/python benchmarks/kth_vs_mode.py [--freqs 10 20 40 80 160 250] [--gains 0 100 200 400] [--limits]
    .venv/bin/python benchmarks/kth_vs_mode.py --comb examples/jobs/comb.ngc [--comb-gains 200] [--comb-shaper ZVD]

The second form is the comb table of docs/vibration.md: on the soft 40 Hz sim, the feedback as
shipped, each part of the proposed change, a time-law input shaper (pmctl.core.shaper), a shaper
20 % off the mode, and the combinations: vibration, load-vs-motor, path error p99 and job time.

For each chain-mode frequency f (sim plant: modal mass 31.66 kg, stiffness m (2 pi f)^2, 2 % damping)
and each K_theta, the real NC loop (pmctl.motion.loop.ControlLoop, nc_step, the sim backend with its
flexible mode and strain gauges, V-F converters in multi-pulse mode, 1 kHz) holds a fixed pose while
the chains start with a 50 um deflection; the damping ratio of the decay is fitted to the load-side
deflection. The soft-chain K_theta is the NC's own (NCParams mode_hz and k_theta_leak: decoupled
feedback, in both cores); the strain -> deflection scale uses the chain's modal stiffness
(``NCParams.from_machine(modal_stiffness_N_per_mm=...)``), the value the sim plant has, instead of
the machine config's 20 000 N/mm. Column "as today" repeats K_theta = 200/s with the machine
config's stiffness, as ``pmctl run --k-theta`` does.

Predictions (kv = seed K_G K_v K_R, K_theta = seed K_theta K_v K_R, both 1/s), from
pmctl.tools.analysis.resonance (predict_continuous, predict_sampled):
- eq. 3.1 (continuous, with the plant damping added): s^3 + (kv + K_theta + 2 zeta w) s^2 +
  (w^2 + 2 zeta w kv) s + kv w^2 = 0 (pmctl.tools.analysis.vibration.eq31_roots when zeta = 0);
- eq. 3.1 sampled: the same loop with the tick's ramp and the one-tick delay of the feedback (the
  motor rate of tick k uses the deflection read at its start), as a discrete-time state matrix; its
  least damped oscillating pole gives zeta = -ln|z| / |ln z|.
The best gain per mode (largest mode damping of the sampled model, K_theta dt < 1) is printed too.
"""

from __future__ import annotations

import argparse
import math
import sys

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default, pmctl/__init__.py)
import numpy as np
from scipy.optimize import curve_fit

from pmctl import hal
from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.motion import loop as L
from pmctl.motion import nc as NC
from pmctl.motion.service_config import LoopConfig
from pmctl.task.planner import home_pose
from pmctl.tools.analysis import resonance as R
from pmctl.tools.analysis.vibration import ringdown_on_sim

MASS, ZETA, KV, DT = 31.66, 0.02, 400.0, 1e-3


def predict_continuous(f, kth, kv=KV, zeta=ZETA, leak=None):
    return R.predict_continuous(f, kth, kv, zeta, leak)


def predict_sampled(f, kth, kv=KV, zeta=ZETA, dt=DT, leak=None):
    return R.predict_sampled(f, kth, kv, dt, zeta, leak)


def best_gain(f, kv=KV, dt=DT, leak=None):
    """K_theta (1/s, K_theta dt < 0.95) giving the sampled model's mode the most damping."""
    g = np.linspace(0.0, 0.95 / dt, 400)
    zs = np.array([predict_sampled(f, k, kv, leak=None if leak is None else leak) [1] for k in g])
    i = int(np.nanargmax(zs))
    return float(g[i]), float(zs[i])


def simulate(f, kth, modal=True, y0_mm=0.05, duration=None, accel_scale=100.0, leak=None):
    """Fitted (frequency Hz, damping ratio, loop status) of the decay in the closed loop.
    ``accel_scale`` multiplies the NC's joint acceleration limit: the feedback alone needs
    K_theta w y0 (20 000 mm/s^2 at 40 Hz, 400/s, 50 um), far over the 2000 mm/s^2 limit, which clips
    it by uniform scaling (see --limits)."""
    from dataclasses import replace
    m = load_machine("prototype")
    k = MASS * (2 * math.pi * f) ** 2 / 1e3                    # N/mm
    dec = dict(mode_hz=f, k_theta_leak=leak) if leak is not None and kth > 0 else {}
    params = NC.NCParams.from_machine(m, DT, k_theta=kth, kv=KV, modal_stiffness_N_per_mm=k if modal else None,
                                      **dec)
    params = replace(params, amax=params.amax * accel_scale)
    y, res = ringdown_on_sim(m, params, k, MASS, ZETA, y0_mm, duration or max(0.3, 10.0 / f))
    t = np.arange(len(y)) * DT
    fd, zp = predict_sampled(f, kth if modal else kth / 10.0, leak=leak)
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


def shape_traj(traj, sh):
    """The planner's trajectory with its time law shaped (pmctl.core.shaper.shape_time_law): same
    path, later arrival; velocities by forward difference, line/spindle held at the end."""
    from dataclasses import replace
    from pmctl.core import shaper as S
    tip, axis = S.shape_time_law(traj.tip, traj.axis, traj.dt, sh)
    n, m = len(traj.tip), len(tip)
    ext = lambda a: np.concatenate([a, np.repeat(a[-1:], m - n, 0)])  # noqa: E731
    tv = np.zeros_like(tip)
    av = np.zeros_like(axis)
    tv[:-1] = np.diff(tip, axis=0) / traj.dt
    av[:-1] = np.diff(axis, axis=0) / traj.dt
    return replace(traj, tip=tip, axis=axis, tip_vel=tv, axis_vel=av, line=ext(np.asarray(traj.line)),
                   spindle_rpm=ext(np.asarray(traj.spindle_rpm)))


def comb_run(job, kth, *, stiff=2000.0, mass=MASS, zeta=ZETA, modal=True, scheme=None, leak_frac=0.1,
             shaper=None):
    """The comb job through planner, loop and sim (in-process, as ``pmctl run --no-realtime``).
    scheme: None (the plain K_theta), or a dict: the soft-chain K_theta of the NC (NCParams mode_hz:
    planned stretch off, decoupled with leak = leak_frac w), with deflection feed-forward if "ff".
    Returns a dict: vibration = RMS of the chain deflection band-passed around the mode (0.6-1.6 f),
    load-vs-motor tip RMS (what the issue measured), tool-tip error p99 (load side vs target) and
    the job time."""
    from scipy.signal import butter, sosfiltfilt
    m = load_machine("prototype")
    w = math.sqrt(stiff * 1e3 / mass)
    soft = dict(mode_hz=w / (2 * math.pi), leak_frac=leak_frac, deflection_ff=bool(scheme.get("ff"))) \
        if scheme and kth != 0 else {}
    params = NC.NCParams.from_machine(m, DT, k_theta=kth, kv=KV, modal_stiffness_N_per_mm=stiff if modal else None,
                                      **soft)
    h_tip, h_axis = home_pose(m)
    c0 = NC.counts_of(K.ik(h_tip, h_axis, m).q, params)
    st = NC.initial_state(m, c0)
    from pmctl.task.planner import load_job, plan
    j = load_job(job, m, start=(st.tip, st.axis))
    traj = plan(j, m, DT, start=(st.tip, st.axis))
    if shaper is not None:
        traj = shape_traj(traj, shaper)
    tg = L.prepare(m, params, traj, DT, c0)
    be = hal.create("sim", m, DT, dict(flex=True, mode_stiffness_N_per_mm=[stiff] * 3, mode_mass_kg=[mass] * 3,
                                       mode_damping_ratio=[zeta] * 3))
    be.open(c0)
    lp = L.ControlLoop(m, be, params, tg, LoopConfig(realtime=False, state_file="", stall_timeout_s=60.0), st,
                       log=lambda s: None)
    res = lp.run()
    i0 = res.job_start
    pl, _ = K.fk_batch(res.truth[i0:], m)
    pm, _ = K.fk_batch(res.enc[i0:], m)
    y = res.truth[i0:, :3] - res.enc[i0:, :3]
    f0 = w / (2 * math.pi)
    sos = butter(2, [0.6 * f0, 1.6 * f0], "bandpass", fs=1 / DT, output="sos")
    # the quasi-static stretch of the planned acceleration, -a*/w^2, is not vibration: take it off
    q = tg.q[i0:, :3]
    n = min(len(q), len(y))
    a_t = np.zeros_like(y)
    a_t[1:n - 1] = (q[2:n] - 2 * q[1:n - 1] + q[:n - 2]) / DT ** 2
    yb = sosfiltfilt(sos, y + a_t / w ** 2, axis=0)
    yb_raw = sosfiltfilt(sos, y, axis=0)
    # path error: distance of the load-side tip from the programmed path (the job's polyline through
    # the planner's samples), not from the (shaped, later) target of the same tick
    from pmctl.core.shaper import path_error
    e = path_error(pl.tip[::2], traj.tip[::1])
    return dict(status=res.status, reason=res.reason, vib_um=1e3 * float(np.sqrt(np.mean(yb ** 2))),
                band_um=1e3 * float(np.sqrt(np.mean(yb_raw ** 2))),
                lm_um=1e3 * float(np.sqrt(np.mean(np.sum((pl.tip - pm.tip) ** 2, -1)))),
                err_p99_um=1e3 * float(np.percentile(e, 99)), job_s=(res.ticks - i0) * DT)


def comb_table(job, gains=(200.0,), shaper_name="ZVD"):
    from pmctl.core import shaper as S
    f0 = math.sqrt(2e6 / MASS) / 2 / math.pi
    print(f"comb job {job}: sim chain mode 2000 N/mm, {MASS} kg ({f0:.1f} Hz), {ZETA:g} damping; kv {KV:g}/s")
    print("vibration = RMS of the chain deflection band-passed 0.6-1.6 x the mode; path error = distance of the "
          "load-side tip from the programmed path; K_theta 'proposed' = modal scale + quasi-static removed + "
          "decoupled + deflection feed-forward (the NC's soft-chain K_theta)")
    print(f"{'case':62s} {'vibration':>10s} {'load-motor':>11s} {'path p99':>9s} {'job':>7s}")
    full = dict(qs=True, leak=True, ff=True)
    rows = [("none (K_theta 0)", 0.0, {})]
    for g in gains:
        rows += [(f"K_theta {g:g}, as shipped (scale from 20000 N/mm)", g, dict(modal=False)),
                 (f"K_theta {g:g}, modal stiffness scale", g, {}),
                 (f"K_theta {-g:g}, modal stiffness scale (wrong sign)", -g, {}),
                 (f"K_theta {g:g}, + quasi-static removed, decoupled", g, dict(scheme=dict(qs=True, leak=True))),
                 (f"K_theta {g:g}, + deflection feed-forward (= proposed)", g, dict(scheme=full))]
    sh = S.make_shaper(shaper_name, f0, ZETA)
    sh_off = S.make_shaper(shaper_name, f0 / 1.2, ZETA)
    g = gains[-1]
    rows += [(f"shaper {shaper_name} at {f0:.1f} Hz (time law)", 0.0, dict(shaper=sh)),
             (f"shaper + K_theta {g:g} proposed", g, dict(shaper=sh, scheme=full)),
             (f"shaper {shaper_name} at {f0 / 1.2:.1f} Hz (mode 20 % above it)", 0.0, dict(shaper=sh_off)),
             (f"  + K_theta {g:g} proposed", g, dict(shaper=sh_off, scheme=full))]
    for name, g, kw in rows:
        r = comb_run(job, g, **kw)
        st = "" if r["status"] == "done" else f"  {r['status']}: {r['reason']}"
        print(f"{name:62s} {r['vib_um']:7.3f} um {r['lm_um']:8.3f} um {r['err_p99_um']:6.3f} um {r['job_s']:6.2f} s{st}")


def main(argv=None):
    import warnings
    warnings.filterwarnings("ignore", message="Covariance of the parameters")
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--freqs", type=float, nargs="+", default=[10, 20, 40, 80, 160, 250])
    ap.add_argument("--gains", type=float, nargs="+", default=[0, 100, 200, 400])
    ap.add_argument("--limits", action="store_true",
                    help="also run with the machine's own acceleration limit (2000 mm/s^2) to show it clipping the feedback")
    ap.add_argument("--comb", metavar="JOB", default=None,
                    help="instead: the table of feedback schemes on a comb job (examples/jobs/comb.ngc) on the 40 Hz sim")
    ap.add_argument("--comb-gains", type=float, nargs="+", default=[200.0])
    ap.add_argument("--comb-shaper", default="ZVD")
    a = ap.parse_args(argv)
    if a.comb:
        comb_table(a.comb, a.comb_gains, a.comb_shaper)
        return 0
    print(f"kv {KV:g}/s, {1 / DT:g} Hz, plant damping {ZETA:g}, start deflection 50 um; "
          f"mode damping ratio: eq.3.1 continuous | eq.3.1 sampled | closed-loop simulation")
    print("  today = the plain K_theta (deflection scale from the modal stiffness); "
          "decoupled = the NC's soft-chain law (mode_hz, leak = 0.1 w)")
    worst = worst_mod = 0.0
    for f in a.freqs:
        leak = 0.1 * 2 * math.pi * f
        kb, zb = best_gain(f)
        kd, zdb = best_gain(f, leak=leak)
        print(f"mode {f:6.1f} Hz: best K_theta today {kb:6.0f}/s -> zeta {zb:.3f}; decoupled {kd:6.0f}/s -> zeta {zdb:.3f}")
        gains = sorted(set(list(a.gains) + [round(kb), round(kd)]))
        for g in gains:
            row = []
            for lk in (None, leak):
                _, zc = predict_continuous(f, g, leak=lk)
                _, zd = predict_sampled(f, g, leak=lk)
                fs, zs, status = simulate(f, g, leak=lk)
                if math.isfinite(zs) and math.isfinite(zd):
                    worst = max(worst, abs(zs - zd))
                    if g * DT <= 0.4 and zd < 0.5:
                        worst_mod = max(worst_mod, abs(zs - zd))
                row.append(f"{zc:6.3f} | {zd:6.3f} | {zs:6.3f}" + ("" if status == "done" else f" ({status})"))
            print(f"   K_theta {g:6.0f}/s  today: {row[0]}   decoupled: {row[1]}")
        if a.limits:
            for g in (200.0, 400.0):
                fs, zs, status = simulate(f, g, accel_scale=1.0)
                print(f"   K_theta {g:6.0f}/s today with the 2000 mm/s^2 joint acceleration limit: sim zeta "
                      f"{zs:.3f} ({fs:.1f} Hz) vs sampled {predict_sampled(f, g)[1]:.3f}")
        k_sim = MASS * (2 * math.pi * f) ** 2 / 1e3
        eff = 200.0 * k_sim / load_machine("prototype").stiffness.chain_axial
        _, zd = predict_sampled(f, eff)
        fs, zs, status = simulate(f, 200.0, modal=False)
        print(f"   as shipped (K_theta 200/s, deflection scale from 20000 N/mm, chain {k_sim:.0f} N/mm -> "
              f"{eff:.0f}/s effective): sampled {zd:.3f} | sim {zs:.3f}")
    print(f"largest |zeta_sim - zeta_sampled|: {worst_mod:.3f} where K_theta dt <= 0.4 and zeta < 0.5; "
          f"{worst:.3f} over the whole table (gains near 1/dt: fit and pulse quantisation)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
