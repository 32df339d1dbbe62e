"""Strain touch-off through the whole loop on the sim plant (pmctl.motion.probe): G38.2 toward a
plane at random heights (random phase against the pulses), per feed: the reported contact point's
error (mean, std, max), the overtravel past the true surface and past the trigger with their bounds,
and the load average.

    python benchmarks/bench_probe.py [N] [--flex|--rigid]
"""

from __future__ import annotations

import os
import sys

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default, pmctl/__init__.py)
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
from test_probe import DT, HOME_Z, KC, M, _z_share, probe_run  # noqa: E402

from pmctl.core import kinematics as K  # noqa: E402
from pmctl.motion.probe import ProbeConfig  # noqa: E402


def main():
    n = int(sys.argv[1]) if len(sys.argv) > 1 and sys.argv[1].isdigit() else 20
    flex = "--rigid" not in sys.argv
    cfg = ProbeConfig()
    rng = np.random.default_rng(11)
    print(f"{n} probes per feed, sim flex={flex}, k_c {KC:g} N/mm, threshold {cfg.threshold_N:g} N, "
          f"filter {cfg.filter_ticks} ticks, decel {cfg.decel_mm_s2:g} mm/s^2, K_theta 200/s")
    for feed in (30.0, 60.0, 120.0, 300.0):
        v = feed / 60.0
        err, over, aft, bnd, btrue = [], [], [], [], []
        for _ in range(n):
            zc = HOME_Z - 1.0 - rng.uniform(0.0, 0.01)
            res, mon, be = probe_run(f"G21 G90\nG0 Z{zc + 0.08 + 0.1 * v:.4f}\nG38.2 Z{zc - 1:.4f} F{feed:g}\n",
                                     {"flex": flex, "strain_noise_ue": 0.01, "contact_z_mm": zc,
                                      "contact_stiffness_N_per_mm": KC})
            (r,) = mon.results
            assert r.contact, r
            rest = K.fk(be.truth(), M).tip
            err.append(r.point[2] - zc)
            over.append(zc - rest[2])
            aft.append(r.after_trigger_mm)
            bnd.append(r.bound_mm)
            btrue.append(cfg.threshold_N / (_z_share() * KC) + 0.5 * (cfg.filter_ticks - 1) * v * DT + r.bound_mm)
        e = np.array(err) * 1e3
        print(f"F{feed:>5g}: contact error mean {e.mean():+.2f} um, std {e.std():.2f} um, max |e| {np.abs(e).max():.2f} um; "
              f"overtravel past the surface {np.min(over)*1e3:.1f}..{np.max(over)*1e3:.1f} um (bound {np.min(btrue)*1e3:.1f} um); "
              f"past the trigger max {np.max(aft)*1e3:.1f} um (bound {bnd[0]*1e3:.1f} um)")
    print(f"load average: {os.getloadavg()}")


if __name__ == "__main__":
    main()
