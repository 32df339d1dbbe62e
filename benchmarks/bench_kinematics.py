"""Kinematics timing: single-pose FK/IK (median, p99) and batch throughput (poses/s).

    .venv/bin/python benchmarks/bench_kinematics.py [--batch 1000000]

Single-pose figures are per call on this machine (wall clock, perf_counter_ns); batch figures
are poses per second for the vectorised numpy forms, with the Newton iterations they took. The
warm batch starts each pose from the solution of the pose one control tick earlier (chains
moved by --tick-mm), as the loop does; a warm start from the exact answer would do no Newton
iteration at all and measure nothing. The load average is printed with the figures (the machine
may be shared). Not a test: nothing here asserts a time.
"""

import argparse
import math
import os
import time

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default, pmctl/__init__.py)
import numpy as np

from pmctl.core import kinematics as K
from pmctl.core.config import load_machine
from pmctl.core.model_fk import ModelFK
from pmctl.motion.ncore import CompiledFK


def stats(fn, n):
    ts = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter_ns()
        fn(i)
        ts[i] = time.perf_counter_ns() - t0
    ts /= 1e3
    return np.median(ts), np.percentile(ts, 99)


def workspace_poses(n, m, rng):
    P, R = K.platform_pose(rng.uniform(280, 500, n), rng.uniform(0.01, math.pi, n),
                           rng.uniform(-0.3, 0.3, n), m.geometry.platform_radius)
    tip, axis = K.tool_of_platform(P, R, rng.uniform(-30, 30, (n, 2)), m.geometry)
    return tip, axis


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=1_000_000, help="poses in the batch run")
    ap.add_argument("--single", type=int, default=3000, help="calls per single-pose figure")
    ap.add_argument("--tick-mm", type=float, default=0.05,
                    help="chain move between the warm start and the pose (default 0.05 mm = 100 mm/s at 2 kHz)")
    a = ap.parse_args()
    m = load_machine()
    print("load average %.2f %.2f %.2f, %d CPUs" % (os.getloadavg() + (os.cpu_count(),)))
    g = m.geometry
    rng = np.random.default_rng(0)

    tip, axis = workspace_poses(a.single, m, rng)
    r = K.ik_batch(tip, axis, m)
    tip, axis, q = tip[r.ok], axis[r.ok], r.q[r.ok]
    n = len(q)
    print(f"single pose ({n} calls each), microseconds: median  p99")
    print("  ik (closed form + limit checks)      %7.1f %7.1f" % stats(lambda i: K.ik(tip[i], axis[i], m), n))
    print("  fk cold start (batch code, 1 pose)   %7.1f %7.1f" % stats(lambda i: K.fk(q[i], m), n))
    # The control loop's case: a smooth path, warm-started from the previous tick (0.1 mm moves).
    path = q[0] + np.outer(np.arange(n), np.full(5, 0.1 / math.sqrt(5)))
    model = ModelFK(m)
    pose = list(K.forward_platform(path[0, :3], g))

    def loop_fk(i):
        pred = (path[i, :3] - path[i - 1, :3], model.last_T) if i else None
        pose[0], pose[1], _, _, _ = model.solve_l(path[i], pose[0], pose[1], pred)

    print("  fk warm + tool Jacobian, model_fk.ModelFK %7.1f %7.1f   (the loop's path, predictor warm start)"
          % stats(loop_fk, n))
    cfk = CompiledFK(m, *K.forward_platform(path[0, :3], g), path[0])
    its = []

    def loop_cfk(i):
        its.append(cfk.solve(path[i]))

    print("  fk warm + tool Jacobian, compiled    %7.1f %7.1f   (ncore.CompiledFK, same scheme; mean %.2f Newton "
          "iterations)" % (stats(loop_cfk, n) + (float(np.mean(its)),)))
    P, R = K.forward_platform(path[0, :3], g)
    print("  tool Jacobian, batch code (1 pose)   %7.1f %7.1f" % stats(lambda i: K.jacobian_tool(P, R, g), n))

    nb = a.batch
    tip, axis = workspace_poses(nb, m, rng)
    t0 = time.perf_counter()
    r = K.ik_batch(tip, axis, m)
    t_ik = time.perf_counter() - t0
    qb = r.q[r.ok]
    t0 = time.perf_counter()
    tp, ok = K.fk_batch(qb, m)
    t_fk = time.perf_counter() - t0
    it_cold = K.solve_platform(qb[:10000, :3], g).iterations          # iterations of the batch (its slowest pose)
    # warm: each pose from the solution one control tick away (chains moved by tick_mm)
    q_next = qb.copy()
    q_next[:, :3] += a.tick_mm * np.sign(rng.uniform(-1, 1, (len(qb), 3)))
    t0 = time.perf_counter()
    tp2, ok2 = K.fk_batch(q_next, m, guess=(tp.P, tp.R))
    t_fkw = time.perf_counter() - t0
    it_warm = K.solve_platform(q_next[:10000, :3], g, guess=(tp.P[:10000], tp.R[:10000])).iterations
    err = np.max(np.abs(tp.tip - tip[r.ok]))
    print(f"batch of {nb} poses ({r.ok.sum()} reachable):")
    print(f"  ik_batch        {nb / t_ik:12.0f} poses/s  ({t_ik:.2f} s)")
    print(f"  fk_batch cold   {ok.sum() / t_fk:12.0f} poses/s  ({t_fk:.2f} s, {it_cold} Newton iterations), "
          f"max |FK(IK(x)) - x| = {err:.2e} mm")
    print(f"  fk_batch warm   {ok2.sum() / t_fkw:12.0f} poses/s  ({t_fkw:.2f} s, {it_warm} Newton iterations; "
          f"start {a.tick_mm:g} mm per chain away)")
    print("load average %.2f %.2f %.2f" % os.getloadavg())


if __name__ == "__main__":
    main()
