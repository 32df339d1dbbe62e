"""Blind evaluation of the twin on bench runs of one ball-screw axis ("machine": "axes"; synth from
the one plant, pmctl.tools.twin.synth_axes). Per suite, N cases with every parameter drawn at random
(the drive's force model in every case, plus the suite's effect): a case is right when every hidden
effect is named on its axis or channel with every parameter within TOL, nothing else is named with a
confidence of 0.5 or more, and the held-out rms of the effect's channel falls. ``clean``: no effort
channel, an ideal drive: right when nothing is named and nothing is unexplained. ``external_force``:
right when the push is unexplained on effort_X at its time and only the force model is named.

    .venv/bin/python benchmarks/eval_axes.py [--n 5] [--seed-base 0] [--duration 15]
"""

from __future__ import annotations

import argparse
import time

import pmctl  # noqa: F401,I001  (one BLAS thread)
import numpy as np

from pmctl.core.recording_axes import axes_machine, convert
from pmctl.tools.twin.diagnose import diagnose
from pmctl.tools.twin.synth_axes import AXIS_EFFECTS, DRIVE, synth_axes_case

TOL = 0.15
SUITES = ("drive",) + tuple(e for e in AXIS_EFFECTS if e not in DRIVE) + ("asymmetric", "clean", "external_force")


def run_case(suite, seed, duration):
    rng = np.random.default_rng(seed)
    params = None
    if suite == "clean":
        case = synth_axes_case(rng, [], clean=True, duration_s=duration)
    elif suite == "external_force":
        case = synth_axes_case(rng, list(DRIVE), oddities=["external_force"], duration_s=duration)
    elif suite == "asymmetric":
        v = float(rng.uniform(80, 250))
        params = {"friction": {"coulomb_N": float(rng.uniform(8, 40)), "viscous_N_s_per_m": v,
                               "viscous_neg_N_s_per_m": v * float(rng.uniform(1.3, 2.0))}}
        case = synth_axes_case(rng, list(DRIVE), params=params, duration_s=duration)
    else:
        case = synth_axes_case(rng, list(DRIVE) + ([] if suite == "drive" else [suite]), duration_s=duration)
    cols, notes, ans = case
    m, conv = axes_machine(list(cols), {"channels": notes})
    cols = convert({k: np.asarray(v, float) for k, v in cols.items()}, conv)
    t0 = time.process_time()
    rep, _ = diagnose(cols, m)
    cpu = time.process_time() - t0
    found = rep["findings"]
    ok, worst = True, 0.0
    used = set()
    for e in ans["effects"]:
        loc = "channel" if "channel" in e else "axis"
        hit = [i for i, f in enumerate(found) if f["effect"] == e["effect"] and f.get(loc) == e[loc]]
        if not hit:
            ok = False
            continue
        used.add(hit[0])
        p = found[hit[0]]["parameters"]
        for k, v in e["parameters"].items():
            kk = {"viscous_neg_N_s_per_m": "viscous_neg_N_s_per_m"}.get(k, k)
            if suite == "asymmetric" and k == "viscous_N_s_per_m":
                kk = "viscous_pos_N_s_per_m"
            if kk not in p:
                ok = False
                continue
            err = abs(p[kk] - v) / max(abs(v), 1e-12)
            worst = max(worst, err)
            ok &= err <= TOL
    extra = [f for i, f in enumerate(found) if i not in used and f["confidence"] >= 0.5]
    if suite == "clean":
        ok = not found and not rep["unexplained"]
    elif suite == "external_force":
        t0s = ans["oddities"][0]["t_s"]
        located = any("effort_X" in u["channels"] and any(a - 0.25 <= t0s <= b + 0.25 for a, b in u["time_windows_s"])
                      for u in rep["unexplained"])
        ok = ok and located and not extra
    else:
        ok = ok and not extra
    return ok, worst, extra, cpu, rep


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=5)
    ap.add_argument("--seed-base", type=int, default=0)
    ap.add_argument("--duration", type=float, default=15.0)
    ap.add_argument("--suites", default=",".join(SUITES))
    a = ap.parse_args()
    print(f"{'suite':16s} {'right':>7s} {'worst param error':>18s} {'cpu s/case':>10s}")
    for si, suite in enumerate(a.suites.split(",")):
        res = [run_case(suite, [a.seed_base, si, k], a.duration) for k in range(a.n)]
        right = sum(r[0] for r in res)
        worst = max(r[1] for r in res)
        for k, r in enumerate(res):
            if not r[0]:
                print(f"    miss {suite} {k}: " + "; ".join(f"{f['effect']} {f.get('axis') or f.get('channel')} "
                                                       f"{f['parameters']} {f['confidence']}" for f in r[4]["findings"])
                      + "".join(f" | unexplained {u['channels']} {u['signature']} {u['time_windows_s']}"
                                for u in r[4]["unexplained"]))
        print(f"{suite:16s} {right:>3d}/{a.n:<3d} {100 * worst:>16.1f} % {np.mean([r[3] for r in res]):>10.1f}",
              flush=True)


if __name__ == "__main__":
    main()
