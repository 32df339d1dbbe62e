"""Blind evaluation of `pmctl twin diagnose` on concealed synth cases (issue 4 "Must show").

For every catalogue effect, N random cases (random axis/channel/magnitude, run, noise, tracker rate)
are generated with pmctl.tools.twin.synth, diagnosed without the answer key, and scored with
pmctl.tools.twin.scoring: success = right effect + locator, every parameter within ±TOL, held-out RMS of
the main channel cut ≥ CUT-fold (or down to 1.3 x noise). Clean cases: success = no finding.

    .venv/bin/python benchmarks/eval_diagnosis.py [--n 20] [--duration 30] [--effects a,b] [--shard k/K]

Shards let two processes split the work (a run resumes where its --save file stops); ``--merge f1 f2`` prints the table of saved shard results.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from pmctl.core.config import load_machine
from pmctl.tools.twin import synth
from pmctl.tools.twin.diagnose import diagnose
from pmctl.tools.twin.scoring import score


def run_case(effect, k, machine, duration, cap):
    seed = 7919 * (synth.EFFECTS.index(effect) + 1 if effect != "clean" else 0) + k
    rng = np.random.default_rng(seed)
    names = [] if effect == "clean" else [effect]
    case = synth.synth_case(rng, names, machine=machine, seed=seed,
                            duration_s=None if effect == "thermal_growth" else duration)
    t0 = time.perf_counter()
    rep, ex = diagnose(case.columns, machine, cap=cap)
    dt = time.perf_counter() - t0
    sc = score(rep, case.answer, noise=ex["ctx"].obs.sigma)
    eff = sc["effects"][0] if sc["effects"] else {}
    return {"effect": effect, "seed": seed, "run": case.answer["run"], "n": len(case.columns["t"]),
            "time_s": dt, "success": sc["clean_ok"] if effect == "clean" else eff["success"],
            "named": eff.get("named"), "params_ok": eff.get("params_ok"), "cut_ok": eff.get("cut_ok"),
            "param_errors": eff.get("param_errors"), "cut": eff.get("cut"),
            "truth": case.answer["effects"], "extra": sc["extra_findings"],
            "found": [(f["effect"], f.get("axis", f.get("channel", f.get("chain"))), f["parameters"])
                      for f in rep["findings"]]}


def table(results):
    by = {}
    for r in results:
        by.setdefault(r["effect"], []).append(r)
    print(f"\n{'effect':16s} {'cases':>5s} {'success':>8s} {'named':>6s} {'params':>7s} {'cut':>5s} "
          f"{'extra':>6s} {'median s':>8s}")
    for e in list(synth.EFFECTS) + ["clean"]:
        rs = by.get(e)
        if not rs:
            continue
        n = len(rs)
        pc = (lambda key: f"{100 * sum(bool(r[key]) for r in rs) / n:5.0f}%")
        extra = sum(bool(r["extra"]) for r in rs)
        print(f"{e:16s} {n:5d} {pc('success'):>8s} {pc('named') if e != 'clean' else '':>6s} "
              f"{pc('params_ok') if e != 'clean' else '':>7s} {pc('cut_ok') if e != 'clean' else '':>5s} "
              f"{extra:6d} {np.median([r['time_s'] for r in rs]):8.1f}")
    clean = by.get("clean", [])
    if clean:
        print(f"clean recordings with no finding: {sum(r['success'] for r in clean)}/{len(clean)}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--duration", type=float, default=30.0, help="run length (s) except thermal warm-ups")
    ap.add_argument("--effects", default=",".join(list(synth.EFFECTS) + ["clean"]))
    ap.add_argument("--cap", type=int, default=8000)
    ap.add_argument("--shard", default="0/1")
    ap.add_argument("--save", help="write the per-case results (JSON lines) here")
    ap.add_argument("--merge", nargs="*", help="print the table of saved results and exit")
    a = ap.parse_args(argv)
    if a.merge:
        res = [json.loads(line) for f in a.merge for line in open(f)]
        table(res)
        return 0
    k0, K = (int(x) for x in a.shard.split("/"))
    m = load_machine()
    jobs = [(e, k) for k in range(a.n) for e in a.effects.split(",")]
    res, done = [], set()
    if a.save:
        try:
            for line in open(a.save):
                r = json.loads(line)
                res.append(r)
                done.add(r["seed"])
        except FileNotFoundError:
            pass
    out = open(a.save, "a") if a.save else None
    for j, (e, k) in enumerate(jobs):
        if j % K != k0:
            continue
        seed = 7919 * (synth.EFFECTS.index(e) + 1 if e != "clean" else 0) + k
        if seed in done:          # resumed: this case is already in the save file
            continue
        r = run_case(e, k, m, a.duration, a.cap)
        res.append(r)
        flag = "ok " if r["success"] else "MISS"
        print(f"{flag} {e:15s} seed {r['seed']:6d} {r['run']:11s} {r['time_s']:5.1f}s truth "
              f"{[(t['effect'], t.get('axis', t.get('channel', t.get('chain'))), t['parameters']) for t in r['truth']]}"
              f" found {r['found']} errs {r['param_errors']}", flush=True)
        if out:
            out.write(json.dumps(r, default=float) + "\n")
            out.flush()
    table(res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
