"""Blind evaluation of `pmctl twin diagnose` on concealed synth cases (issues 4 and 12 "Must show").

Suites (``--suites``, comma list; default all):

- every catalogue effect (pmctl.tools.twin.synth.EFFECTS): N random cases each (random axis or
  channel, magnitude, run, noise, tracker rate), at 1 kHz (even k) or 250 Hz (odd k) logs, with
  recording imperfections (dropped rows, time-stamp jitter, coloured noise, a tracker drop-out;
  pmctl.tools.twin.synth.imperfect) in cases k = 1, 4, 7, ... (so with --n 2: the 250 Hz case);
- ``pitch_near``: pitch error of 2-3 µm on the 5 mm lead in 10-20 s runs (the near-threshold case);
- ``thermal_2.5K``: thermal growth with a 2.5 K rise of the heated screw (10 min warm-up at 100 Hz);
- ``pair``: two different random effects at once;
- ``clean``: no effect (every other one with imperfections): success = no finding, no unexplained;
- ``oddity``: physics outside the catalogue (synth.ODDITIES: a bent table guide, a chatter
  burst): success = located in ``unexplained`` (one of its channels) and no finding with
  confidence ≥ 0.5 (the out-of-catalogue honesty rate).

A catalogue effect counts as found (pmctl.tools.twin.scoring) with the right name and locator,
every parameter within ±TOL, and the held-out RMS of its main channel cut ≥ CUT-fold (or down to
1.3 x noise). Every finding of every case is also labelled right (it is one of the hidden effects)
or wrong, with the numbers its confidence is computed from; ``--calibrate`` fits the confidence's
logistic to those labels and prints the coefficients and the reliability table (predicted against
observed per confidence bin) of the fitted and of the shipped coefficients.

    .venv/bin/python benchmarks/eval_diagnosis.py [--n 3] [--duration 15] [--suites friction,pair,...]
        [--seed-base 0] [--save results.jsonl] [--merge f1 f2 ...] [--calibrate]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from pmctl.core.config import load_machine
from pmctl.tools.twin import calibration, synth
from pmctl.tools.twin.diagnose import diagnose
from pmctl.tools.twin.scoring import score

SPECIAL = ("pitch_near", "thermal_2.5K", "pair", "clean", "oddity")


def _seed(suite, k, base):
    names = list(synth.EFFECTS) + list(SPECIAL)
    return base + 7919 * (names.index(suite) + 1) + k


def make_case(suite, k, machine, duration, base):
    seed = _seed(suite, k, base)
    rng = np.random.default_rng(seed)
    rate = 1000.0 if k % 2 == 0 else 250.0
    imp = k % 3 == 1
    kw = dict(machine=machine, seed=seed, duration_s=duration, rate_hz=rate, imperfections=imp)
    if suite in synth.EFFECTS:
        if suite == "thermal_growth":
            kw.update(duration_s=None, rate_hz=None)
        return synth.synth_case(rng, [suite], **kw)
    if suite == "pitch_near":
        ax = str(rng.choice(synth.AXES))
        e = synth.Effect("pitch_error", {"axis": ax}, {"period_mm": 5.0, "amplitude_mm": float(rng.uniform(0.002, 0.003))},
                         {"phase_rad": float(rng.uniform(0, 2 * np.pi))})
        kw["duration_s"] = float(rng.uniform(10, 20))
        return synth.synth_case(rng, [e], **kw)
    if suite == "thermal_2.5K":
        e = synth.make_effect("thermal_growth", rng, duration_s=600.0)
        e.details["rise_K"] = 2.5
        kw.update(duration_s=None, rate_hz=None)
        return synth.synth_case(rng, [e], **kw)
    if suite == "pair":
        pool = [e for e in synth.EFFECTS if e not in ("thermal_growth", "compliance")]
        names = [str(x) for x in rng.choice(pool, 2, replace=False)]
        return synth.synth_case(rng, names, **kw)
    if suite == "clean":
        kw["imperfections"] = k % 2 == 1
        return synth.synth_case(rng, [], **kw)
    if suite == "oddity":
        return synth.synth_case(rng, [], oddities=[synth.ODDITIES[k % len(synth.ODDITIES)]], **kw)
    raise SystemExit(f"unknown suite {suite!r}")


def _label_findings(rep, answer, sc):
    """Per finding: is it one of the hidden effects (name, locator, parameters within tolerance)?"""
    right = set()
    for r in sc["effects"]:
        if r["named"] and r["params_ok"]:
            right.add((r["effect"], str(r.get("axis", r.get("channel", r.get("chain"))))))
    return [(f["effect"], str(f.get("axis", f.get("channel", f.get("chain"))))) in right for f in rep["findings"]]


def run_case(suite, k, machine, duration, cap, base):
    case = make_case(suite, k, machine, duration, base)
    t0 = time.process_time()
    rep, ex = diagnose(case.columns, machine, cap=cap)
    dt = time.process_time() - t0
    sc = score(rep, case.answer, noise=ex["ctx"].obs.sigma)
    labels = _label_findings(rep, case.answer, sc)
    odd = case.answer.get("oddities", [])
    located = any(set(o["channels"]) & set(u["channels"]) for o in odd for u in rep["unexplained"])
    confident = [f for f in rep["findings"] if f["confidence"] >= 0.5]
    if suite == "clean":
        success = not rep["findings"] and not rep["unexplained"]
    elif suite == "oddity":
        success = located and not confident
    else:
        success = sc["all_found"]
    return {"suite": suite, "k": k, "seed": _seed(suite, k, base), "run": case.answer["run"],
            "rate_hz": case.answer["sample_rate_hz"], "imperfect": bool(case.answer.get("imperfections")),
            "n": len(case.columns["t"]), "cpu_s": dt, "success": bool(success), "verdict": rep["verdict"],
            "all_found": sc["all_found"], "located": located, "confident_names": len(confident),
            "effects": sc["effects"], "extra": sc["extra_findings"],
            "truth": case.answer["effects"], "oddities": odd,
            "found": [(f["effect"], f.get("axis", f.get("channel", f.get("chain"))), f["parameters"], f["confidence"])
                      for f in rep["findings"]],
            "unexplained": [(u["channels"], u["signature"], u["excess_over_noise"]) for u in rep["unexplained"]],
            "features": ex["features"], "labels": labels}


def table(results):
    by = {}
    for r in results:
        by.setdefault(r["suite"], []).append(r)
    print(f"\n{'suite':16s} {'cases':>5s} {'success':>8s} {'named':>6s} {'params':>7s} {'cut':>5s} "
          f"{'extra':>6s} {'unexpl':>6s} {'cpu s':>6s}")
    for e in list(synth.EFFECTS) + list(SPECIAL):
        rs = by.get(e)
        if not rs:
            continue
        n = len(rs)
        effs = [x for r in rs for x in r["effects"]]

        def pc(key):
            return f"{100 * sum(bool(x[key]) for x in effs) / len(effs):5.0f}%" if effs else ""
        extra = sum(bool(r["extra"]) for r in rs)
        unex = sum(bool(r["unexplained"]) for r in rs)
        print(f"{e:16s} {n:5d} {100 * sum(r['success'] for r in rs) / n:7.0f}% {pc('named'):>6s} "
              f"{pc('params_ok'):>7s} {pc('cut_ok'):>5s} {extra:6d} {unex:6d} {np.median([r['cpu_s'] for r in rs]):6.1f}")
    cat = [r for r in results if r["suite"] not in ("clean", "oddity")]
    odd = by.get("oddity", [])
    clean = by.get("clean", [])
    print(f"\ncatalogue cases all found: {sum(r['all_found'] for r in cat)}/{len(cat)}; "
          f"clean with no finding and no unexplained: {sum(r['success'] for r in clean)}/{len(clean)}")
    if odd:
        print(f"out-of-catalogue honesty: located and not confidently named {sum(r['success'] for r in odd)}/{len(odd)} "
              f"(located {sum(r['located'] for r in odd)}, with a confident name {sum(r['confident_names'] > 0 for r in odd)})")
    rows = [(f, ok) for r in results for f, ok in zip(r["features"], r["labels"])]
    if rows:
        print("\nreliability of the shipped confidence (findings of these runs):")
        for b in calibration.reliability(rows, calibration.COEF):
            print(f"  confidence {b['bin'][0]:.2f}-{b['bin'][1]:.2f}: {b['n']:3d} findings, predicted "
                  f"{b['predicted']:.2f}, right {b['observed']:.2f}")
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=3)
    ap.add_argument("--duration", type=float, default=15.0, help="run length (s) except thermal warm-ups")
    ap.add_argument("--suites", default=",".join(list(synth.EFFECTS) + list(SPECIAL)))
    ap.add_argument("--cap", type=int, default=3000)
    ap.add_argument("--seed-base", type=int, default=0, help="another base gives another blind set")
    ap.add_argument("--save", help="append the per-case results (JSON lines) here; a rerun resumes")
    ap.add_argument("--merge", nargs="*", help="print the table of saved results and exit")
    ap.add_argument("--calibrate", action="store_true", help="fit the confidence logistic to these runs")
    a = ap.parse_args(argv)
    if a.merge:
        res = [json.loads(line) for f in a.merge for line in open(f)]
    else:
        m = load_machine()
        res, done = [], set()
        if a.save:
            try:
                for line in open(a.save):
                    r = json.loads(line)
                    res.append(r)
                    done.add((r["suite"], r["k"], r["seed"]))
            except FileNotFoundError:
                pass
        out = open(a.save, "a") if a.save else None
        for k in range(a.n):
            for s in a.suites.split(","):
                if (s, k, _seed(s, k, a.seed_base)) in done:
                    continue
                r = run_case(s, k, m, a.duration, a.cap, a.seed_base)
                res.append(r)
                print(f"{'ok ' if r['success'] else 'MISS'} {s:15s} k{k} {r['run']:11s} {r['rate_hz']:5.0f} Hz "
                      f"{'imp ' if r['imperfect'] else ''}{r['cpu_s']:5.1f}s truth "
                      f"{[(t['effect'], t.get('axis', t.get('channel', t.get('chain'))), t['parameters']) for t in r['truth']]}"
                      f"{[o['kind'] for o in r['oddities']] or ''} found {r['found']} unexplained {r['unexplained']}",
                      flush=True)
                if out:
                    out.write(json.dumps(r, default=float) + "\n")
                    out.flush()
    rows = table(res)
    if a.calibrate and rows:
        # held-out check of the calibration: fit on the cases of even k, judge on odd k, and back
        held = []
        for part in (0, 1):
            fit_rows = [(f, ok) for r in res if r["k"] % 2 != part for f, ok in zip(r["features"], r["labels"])]
            test_rows = [(f, ok) for r in res if r["k"] % 2 == part for f, ok in zip(r["features"], r["labels"])]
            if fit_rows and test_rows and len({ok for _, ok in fit_rows}) == 2:
                c = calibration.fit_logistic(fit_rows)
                held += [({**f, "_p": calibration.confidence(f, c)}, ok) for f, ok in test_rows]
        if held:
            print("\nheld-out reliability (logistic fitted on the other half of the cases, by k parity):")
            edges = (0.0, 0.5, 0.7, 0.85, 0.95, 1.0001)
            for lo, hi in zip(edges, edges[1:]):
                sel = [(f["_p"], ok) for f, ok in held if lo <= f["_p"] < hi]
                if sel:
                    print(f"  confidence {lo:.2f}-{min(hi, 1):.2f}: {len(sel):3d} findings, predicted "
                          f"{sum(p for p, _ in sel) / len(sel):.2f}, right {sum(ok for _, ok in sel) / len(sel):.2f}")
        coef = calibration.fit_logistic(rows)
        print("\nfitted coefficients:", json.dumps({k: round(v, 3) for k, v in coef.items()}))
        for b in calibration.reliability(rows, coef):
            print(f"  fitted confidence {b['bin'][0]:.2f}-{b['bin'][1]:.2f}: {b['n']:3d} findings, predicted "
                  f"{b['predicted']:.2f}, right {b['observed']:.2f}")
        print(f"findings {len(rows)}, right {sum(ok for _, ok in rows)}, cases {len(res)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
