"""Strain touch-off through the daemon (pmctl.task.supervisor + the rt process, real-time pacing) on
the sim plant: N jobs of G0 above a plane (a random height: random phase against the pulses), G38.2
onto it at F60, G0 back up, each submitted with Supervisor.submit. Prints the contact point's error
(mean, std, max), the rest point past the surface and past the trigger against their bounds, the
wall time from submit to idle (median, p99) and the load average.

    python benchmarks/bench_probe_daemon.py [N]
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default, pmctl/__init__.py)
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
from test_probe import DT, HOME_Z, KC, M, _z_share  # noqa: E402

from pmctl.core import kinematics as K  # noqa: E402
from pmctl.motion.nc import counts_of  # noqa: E402
from pmctl.motion.probe import ProbeConfig  # noqa: E402
from pmctl.task.gcode import parse_gcode  # noqa: E402
from pmctl.core.job import home_pose  # noqa: E402
from pmctl.task.supervisor import Supervisor  # noqa: E402


def main():
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 10
    cfg = ProbeConfig()
    zc = HOME_Z - 1.0
    feed, v = 60.0, 1.0
    rng = np.random.default_rng(5)
    with tempfile.TemporaryDirectory() as tmp:
        svc = Path(tmp) / "service.toml"
        svc.write_text('[loop]\nrate_hz = 1000\nstall_timeout_ms = 5000\nmax_overruns_in_row = 100000\n'
                       'state_file = ""\n[nc]\nk_theta_per_s = 200\n[hal]\nbackend = "sim"\n[hal.sim]\nflex = true\n'
                       f'strain_noise_ue = 0.01\ncontact_z_mm = {zc}\ncontact_stiffness_N_per_mm = {KC}\n')
        sup = Supervisor("prototype", service=str(svc), backend="sim")
        t, a = home_pose(M)
        sup.start(counts_of(K.ik(t, a, M).q, sup.params))
        err, past, aft, bnd, wall = [], [], [], [], []
        try:
            for _ in range(n):
                z0 = zc + 0.12 + rng.uniform(0.0, 0.01)
                job = parse_gcode(f"G21 G90\nG0 Z{z0:.4f}\nG38.2 Z{zc - 1:.4f} F{feed:g}\nG0 Z{HOME_Z:.4f}\n",
                                  "bench.ngc", t, a)
                t0 = time.monotonic()
                it = sup.submit(job)
                sup.wait_idle(300)
                wall.append(time.monotonic() - t0)
                (r,) = it.probe_results
                assert r.contact and not sup.alarm, (r, sup.alarm_msg)
                err.append(r.point[2] - zc)
                past.append(zc - r.stop[2])
                aft.append(r.after_trigger_mm)
                bnd.append(r.bound_mm)
        finally:
            sup.shutdown()
    err, past, aft, wall = (np.array(x) * s for x, s in ((err, 1e3), (past, 1e3), (aft, 1e3), (wall, 1.0)))
    bound_true = (cfg.threshold_N / (_z_share() * KC) + 0.5 * (cfg.filter_ticks - 1) * v * DT + max(bnd)) * 1e3
    print(f"{n} probes through the daemon at F{feed:g}, sim flex, k_c {KC:g} N/mm, K_theta 200/s")
    print(f"contact error: mean {err.mean():+.2f} um, std {err.std():.2f} um, max abs {np.abs(err).max():.2f} um")
    print(f"rest past the surface (commanded): {past.min():.1f}-{past.max():.1f} um (bound {bound_true:.1f} um); "
          f"past the trigger max {aft.max():.1f} um (bound {max(bnd) * 1e3:.1f} um)")
    print(f"submit to idle: median {np.median(wall):.2f} s, p99 {np.percentile(wall, 99):.2f} s; "
          f"load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
