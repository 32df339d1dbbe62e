"""The vibration table of issue 14 / docs/vibration.md §5: none, shaper only, K_theta only, both.

    .venv/bin/python benchmarks/vibration_table.py [--job examples/jobs/comb.ngc] [--k-theta 250|auto]
                                                   [--shaper auto] [--python]

The machine is the soft 40 Hz one: config/service.toml with [hal.sim] mode_stiffness_N_per_mm = 2000,
mode_mass_kg = 31.66, mode_damping_ratio = 0.02 (written to a temporary service file, whose path the
script prints). Each row runs the same code as

    pmctl run --service SOFT.toml --job JOB --k-theta K --shaper S --no-realtime --state ''

in this process (pmctl.interfaces.commands.run.prepare_run: the service config, the chain modes, the
NC parameters, the planner, the shaping stage, the loop and the sim), so the load-side truth is at
hand. The last rows put the shaper 20 % below the plant's mode (the plant's mode 20 % above the
shaper's frequency): the shaper is then designed for a 33.3 Hz mode that the 40 Hz plant does not
have, which is what a drifted or mistuned mode looks like.

Columns:
- vibration: RMS over the job of the chain deflection (load side minus motor side, per chain, from
  the sim's truth) band-passed to 0.6-1.6 x the mode, with the planned quasi-static stretch -a*/w^2
  (a* = the chain acceleration of the targets the loop followed) taken off: the oscillation, not
  the spring's stretch under the planned acceleration;
- tip vib: the same on the tool tip, load-side tip minus motor-side tip (FK of each), RMS of the
  band-passed difference's norm;
- path p99: the 99th percentile of the load-side tool tip's distance from the programmed path (the
  planner's samples as a polyline), over the job;
- job: job time (s) from the first job sample to the end.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default, pmctl/__init__.py)
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SOFT = {"flex": True, "mode_stiffness_N_per_mm": 2000.0, "mode_mass_kg": 31.66, "mode_damping_ratio": 0.02}


def soft_service_file(folder: Path) -> Path:
    """config/service.toml with the soft 40 Hz [hal.sim] values (the lines replaced in place)."""
    text = (ROOT / "config" / "service.toml").read_text(encoding="utf-8")
    out = []
    section = ""
    for line in text.splitlines():
        s = line.strip()
        if s.startswith("["):
            section = s.split("]")[0] + "]"
        key = s.split("=")[0].strip() if "=" in s and not s.startswith("#") else ""
        if section == "[hal.sim]" and key in SOFT:
            v = SOFT[key]
            line = f"{key} = {str(v).lower() if isinstance(v, bool) else v}"
        out.append(line)
    p = folder / "soft40.toml"
    p.write_text("\n".join(out) + "\n", encoding="utf-8")
    return p


def run_case(service: Path, job: str, k_theta, shaper: str, shaper_hz=None, python=False, tweak=None):
    """One run as pmctl run does it (the same calls: service config, nc_setup, params, plan,
    shape_trajectory, prepare, ControlLoop, sim); returns the figures of the docstring."""
    from scipy.signal import butter, sosfiltfilt

    from pmctl import hal
    from pmctl.core import kinematics as K
    from pmctl.core.config import load_machine
    from pmctl.core.shaper import path_error
    from pmctl.motion.loop import ControlLoop, prepare
    from pmctl.motion.nc import counts_of, initial_state
    from pmctl.motion.service_config import (load_service_config, nc_setup, parse_k_theta_flag,
                                             parse_shaper_flag)
    from pmctl.motion.timescale import shape_trajectory
    from pmctl.task.planner import home_pose, load_job, plan
    m = load_machine("prototype")
    svc = load_service_config(service)
    cfg = svc.loop
    cfg.realtime, cfg.settle_s, cfg.state_file = False, 0.0, ""
    k = parse_k_theta_flag(k_theta)
    svc.nc.k_theta_auto = k == "auto"
    svc.nc.k_theta_per_s = (0.0,) * 3 if k == "auto" else (k,) * 3
    svc.nc.shaper = parse_shaper_flag(shaper)
    if shaper_hz is not None:
        svc.nc.shaper_hz = (shaper_hz,) * 3
    if python:
        svc.nc.implementation = "python"
    dt = cfg.dt
    if tweak is not None:
        tweak(svc)
    setup = nc_setup(svc, m, dt, svc.backend)
    params = svc.nc.params(m, dt, where=svc.source, modes=setup.modes)
    h_tip, h_axis = home_pose(m)
    c0 = counts_of(K.ik(h_tip, h_axis, m).q, params)
    st = initial_state(m, c0)
    j = load_job(job, m, start=(st.tip, st.axis))
    planned = plan(j, m, dt, start=(st.tip, st.axis))
    traj = shape_trajectory(planned, setup.shaper)
    tg = prepare(m, params, traj, dt, c0)
    be = hal.create(svc.backend, m, dt, svc.backend_tables.get(svc.backend, {}))
    be.open(c0)
    lp = ControlLoop(m, be, params, tg, cfg, st, log=lambda s: None)
    t0 = time.perf_counter()
    try:
        res = lp.run()
    finally:
        be.close()
    wall = time.perf_counter() - t0
    i0 = res.job_start
    w = float(np.mean(be.omega))
    f0 = w / (2 * math.pi)
    y = res.truth[i0:, :3] - res.enc[i0:, :3]
    q = tg.q[i0:, :3]
    n = min(len(q), len(y))
    a_t = np.zeros_like(y)
    a_t[1:n - 1] = (q[2:n] - 2 * q[1:n - 1] + q[:n - 2]) / dt ** 2
    sos = butter(2, [0.6 * f0, 1.6 * f0], "bandpass", fs=1 / dt, output="sos")
    yb = sosfiltfilt(sos, y + a_t / w ** 2, axis=0)
    pl, _ = K.fk_batch(res.truth[i0:], m)
    pm, _ = K.fk_batch(res.enc[i0:], m)
    tb = sosfiltfilt(sos, pl.tip - pm.tip, axis=0)
    from pmctl.core.shaper import corner_samples
    keep = [0] + corner_samples(planned.tip, planned.axis, corner_deg=1e-3) + [len(planned) - 1]
    e = path_error(pl.tip, planned.tip[sorted(set(keep))])     # the same polyline, straight runs merged
    shtxt = [t for t in setup.notes if t.startswith("shaper")]
    return dict(status=res.status, reason=res.reason, vib_um=1e3 * float(np.sqrt(np.mean(yb ** 2))),
                tipvib_um=1e3 * float(np.sqrt(np.mean(np.sum(tb ** 2, -1)))),
                lm_um=1e3 * float(np.sqrt(np.mean(np.sum((pl.tip - pm.tip) ** 2, -1)))),
                p99_um=1e3 * float(np.percentile(e, 99)), job_s=(res.ticks - i0) * dt, wall_s=wall,
                kth=params.k_theta.tolist(), shaper=shtxt[0].split(",")[0] if shtxt else "")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--job", default=str(ROOT / "examples" / "jobs" / "comb.ngc"))
    ap.add_argument("--k-theta", default="250", help="K_theta of the K_theta rows: 1/s or auto (default 250)")
    ap.add_argument("--shaper", default="auto", help="shaper of the shaper rows: a type or auto")
    ap.add_argument("--python", action="store_true", help="run the Python reference NC (slower; same pulses)")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        svc = soft_service_file(Path(tmp))
        kth = a.k_theta
        f_mode = math.sqrt(SOFT["mode_stiffness_N_per_mm"] * 1e3 / SOFT["mode_mass_kg"]) / (2 * math.pi)
        off = f_mode / 1.2
        rows = [("none", "0", "none", None),
                ("shaper only", "0", a.shaper, None),
                ("K_theta only", kth, "none", None),
                ("both", kth, a.shaper, None),
                (f"shaper only, designed at {off:.1f} Hz (mode 20 % above)", "0", a.shaper, off),
                (f"both, shaper designed at {off:.1f} Hz", kth, a.shaper, off)]
        print(f"job {a.job}; soft machine: [hal.sim] {SOFT} ({f_mode:.1f} Hz); service file {svc} "
              f"(a copy of config/service.toml with those values)")
        print("each row: pmctl run --service SOFT.toml --job JOB --k-theta K --shaper S --no-realtime --state ''"
              " (same code, in-process); 20 % rows: [nc] shaper_hz = 33.3 in the service file")
        print(f"{'case':52s} {'K_theta':>10s} {'vibration':>10s} {'tip vib':>9s} {'load-motor':>10s} "
              f"{'path p99':>9s} {'job':>7s}  shaper")
        out = {}
        for name, k, sh, hz in rows:
            r = run_case(svc, a.job, k, sh, hz, a.python)
            out[name] = r
            st = "" if r["status"] == "done" else f"  {r['status']}: {r['reason']}"
            kt = "/".join(f"{x:.0f}" for x in sorted(set(r["kth"])))
            print(f"{name:52s} {kt:>10s} {r['vib_um']:7.3f} um {r['tipvib_um']:6.3f} um {r['lm_um']:7.3f} um "
                  f"{r['p99_um']:6.3f} um {r['job_s']:6.2f} s  {r['shaper']}{st}", flush=True)
        n, b = out["none"], out["both"]
        print(f"both vs none: vibration {n['vib_um'] / b['vib_um']:.1f}x less, path p99 {b['p99_um']:.3f} vs "
              f"{n['p99_um']:.3f} um, job time x{b['job_s'] / n['job_s']:.3f}; better than either alone: "
              f"{b['vib_um'] < min(out['shaper only']['vib_um'], out['K_theta only']['vib_um'])}")
        print(f"load average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
