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
- ``oddity``: physics outside the catalogue (synth.ODDITIES, case k takes kind k mod 7: a bent
  table guide, a chatter burst, a spike after each reversal of one axis, a crash that displaces an
  axis at one instant, an intermittent encoder, a table that sags with its overhang, a periodic
  knock from outside): success = located in ``unexplained`` (one of its channels) and no finding
  with confidence ≥ 0.5 (the out-of-catalogue honesty rate; the confidences are recomputed from the
  saved features with the shipped coefficients, so a refit changes the rate without a rerun).

A catalogue effect counts as found (pmctl.tools.twin.scoring) with the right name and locator,
every parameter within ±TOL, and the held-out RMS of its main channel cut ≥ CUT-fold (or down to
1.3 x noise). Every finding of every case is also labelled right (it is one of the hidden effects,
parameters within ±TOL) or wrong, with the four numbers its confidence is computed from.

Confidence calibration (docs/diagnosis-report.md, "Confidence"): ``--calibrate`` fits the
logistic to the labelled findings of the seed bases ``--seed-base`` (or the ``--merge`` files) and
judges it on other seed bases (``--holdout-bases``, or ``--holdout`` files): the reliability table
(per confidence bin: findings, right, mean predicted, fraction right) and the expected calibration
error on those held-out findings. ``--write`` stores the coefficients and that held-out table in
pmctl/tools/twin/calibration.py. The refit, one command (results kept per base in DIR, resumed)::

    .venv/bin/python benchmarks/eval_diagnosis.py --n 3 --duration 12 --cap 2000 \
        --seed-base 1000,2000 --holdout-bases 3000 --save-dir cal --calibrate --write

Other uses::

    .venv/bin/python benchmarks/eval_diagnosis.py [--n 3] [--duration 15] [--suites friction,pair,...]
        [--seed-base 0] [--save results.jsonl] [--merge f1 f2 ...] [--holdout f3 ...] [--calibrate]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default, pmctl/__init__.py)
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
        ok = [honest(r) for r in odd]
        print(f"out-of-catalogue honesty: located and not confidently named {sum(ok)}/{len(odd)} "
              f"(located {sum(r['located'] for r in odd)}, with a confident name "
              f"{sum(bool(confident_names(r)) for r in odd)}; confidences of the shipped coefficients)")
        kinds = {}
        for r, h in zip(odd, ok):
            kinds.setdefault(r["oddities"][0]["kind"], []).append(h)
        print("  per kind: " + ", ".join(f"{k} {sum(v)}/{len(v)}" for k, v in kinds.items()))
    rows = [(f, ok) for r in results for f, ok in zip(r["features"], r["labels"])]
    if rows:
        print("\nreliability of the shipped confidence (findings of these runs):")
        print_bins(calibration.reliability(rows))
    return rows


def confident_names(r, coef=None):
    """The findings of a saved case with confidence >= 0.5 under ``coef`` (default: the shipped ones)."""
    return [f[:2] for f, x in zip(r["found"], r["features"]) if calibration.confidence(x, coef) >= 0.5]


def honest(r, coef=None):
    """An out-of-catalogue case is handled honestly when it is located in ``unexplained`` on one of
    its channels and no finding carries a confidence of 0.5 or more."""
    return bool(r["located"]) and not confident_names(r, coef)


def print_bins(bins):
    for b in bins:
        print(f"  confidence {b['bin'][0]:.2f}-{b['bin'][1]:.2f}: {b['n']:4d} findings, {b['right']:4d} right; "
              f"predicted {b['predicted']:.2f}, observed {b['observed']:.2f}")
    print(f"  expected calibration error {calibration.ece(bins):.3f} over {sum(b['n'] for b in bins)} findings")


def collect(a, base, machine, save):
    """The cases of one seed base: those already in ``save`` (JSON lines), plus the missing ones run now."""
    res, done = [], set()
    if save:
        try:
            for line in open(save):
                r = json.loads(line)
                res.append(r)
                done.add((r["suite"], r["k"], r["seed"]))
        except FileNotFoundError:
            pass
    out = open(save, "a") if save else None
    for k in range(a.n):
        for s in a.suites.split(","):
            if (s, k, _seed(s, k, base)) in done:
                continue
            r = run_case(s, k, machine, a.duration, a.cap, base)
            r["seed_base"] = base
            res.append(r)
            print(f"{'ok ' if r['success'] else 'MISS'} {s:15s} k{k} {r['run']:11s} {r['rate_hz']:5.0f} Hz "
                  f"{'imp ' if r['imperfect'] else ''}{r['cpu_s']:5.1f}s truth "
                  f"{[(t['effect'], t.get('axis', t.get('channel', t.get('chain'))), t['parameters']) for t in r['truth']]}"
                  f"{[o['kind'] for o in r['oddities']] or ''} found {r['found']} unexplained {r['unexplained']}",
                  flush=True)
            if out:
                out.write(json.dumps(r, default=float) + "\n")
                out.flush()
    return res


def seed_base(r):
    """The seed base a saved case was drawn with (inverse of _seed)."""
    return r.get("seed_base", r["seed"] - 7919 * ((list(synth.EFFECTS) + list(SPECIAL)).index(r["suite"]) + 1) - r["k"])


def _bases(text):
    return [int(x) for x in str(text).split(",") if x.strip()] if text else []


def _rows(results):
    return [(f, ok) for r in results for f, ok in zip(r["features"], r["labels"])]


def calibrate(res, held, fit_bases, held_bases, write=False):
    """Fit the confidence logistic on ``res``; the reliability table and ECE on ``held`` (other seed
    bases). Without ``held``: a check by case parity (fit on even k, judge odd k, and back)."""
    rows = _rows(res)
    if not rows or len({ok for _, ok in rows}) < 2:
        print("\ncalibration: need right and wrong findings to fit")
        return None
    coef = calibration.fit(rows)
    print(f"\nfitted on {len(rows)} findings ({sum(ok for _, ok in rows)} right) of {len(res)} cases, seed bases "
          f"{fit_bases or 'as saved'}:\n  coefficients {json.dumps({k: round(v, 3) for k, v in coef.items()})}")
    print("in-sample reliability (the fit's own findings):")
    print_bins(calibration.reliability(rows, coef))
    hrows = _rows(held)
    if hrows:
        bins = calibration.reliability(hrows, coef)
        print(f"\nHELD-OUT reliability: the fitted coefficients on {len(hrows)} findings of {len(held)} cases of seed "
              f"bases {held_bases or 'as saved'}, which the fit never saw:")
        print_bins(bins)
        old = calibration.reliability(hrows)
        print("the shipped coefficients on the same held-out findings:")
        print_bins(old)
        odd = [r for r in held if r["suite"] == "oddity"]
        if odd:
            print(f"held-out out-of-catalogue honesty with the fitted coefficients: "
                  f"{sum(honest(r, coef) for r in odd)}/{len(odd)}")
        if write:
            def size(rs, bases):
                return {"seed_bases": bases, "cases": len(rs), "findings": len(_rows(rs)),
                        "right": sum(ok for _, ok in _rows(rs))}
            calib = {"fit": size(res, fit_bases), "heldout": {**size(held, held_bases), "bins": bins,
                                                               "ece": round(calibration.ece(bins), 4)}}
            top = [b for b in bins if b["bin"][0] >= 0.85]
            desc = (f"logistic in held-out gain over threshold, fold spread of the parameters, explained fraction and "
                    f"share of the channels' structure, fitted on {calib['fit']['findings']} findings of "
                    f"{len(res)} blind synth cases (seed bases {fit_bases}) and checked on "
                    f"{calib['heldout']['findings']} findings of {len(held)} other cases (seed bases {held_bases}): "
                    f"expected calibration error {calibration.ece(bins):.3f}"
                    + (f"; of the held-out findings at 0.85 or more, {sum(b['right'] for b in top)} of "
                       f"{sum(b['n'] for b in top)} were right" if top else ""))
            p = calibration.write_fitted(coef, calib, desc)
            print(f"\nwrote the fitted coefficients and the held-out table to {p}")
    else:
        held = []
        for part in (0, 1):
            fit_rows = _rows([r for r in res if r["k"] % 2 != part])
            test_rows = _rows([r for r in res if r["k"] % 2 == part])
            if fit_rows and test_rows and len({ok for _, ok in fit_rows}) == 2:
                c = calibration.fit(fit_rows)
                held += [(calibration.confidence(f, c), ok) for f, ok in test_rows]
        if held:
            print("\nheld-out by case parity (no held-out seed bases given; fit on even k, judge odd k, and back):")
            print_bins(calibration.bin_table(held))
        if write:
            print("\n--write needs held-out seed bases (--holdout-bases or --holdout FILES): nothing written")
    return coef


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=3)
    ap.add_argument("--duration", type=float, default=15.0, help="run length (s) except thermal warm-ups")
    ap.add_argument("--suites", default=",".join(list(synth.EFFECTS) + list(SPECIAL)))
    ap.add_argument("--cap", type=int, default=3000)
    ap.add_argument("--seed-base", default="0", help="another base gives another blind set; a comma list runs several")
    ap.add_argument("--save", help="append the per-case results (JSON lines) here; a rerun resumes (one seed base)")
    ap.add_argument("--save-dir", help="per seed base B, results in DIR/eval-B.jsonl (resumed)")
    ap.add_argument("--merge", nargs="*", help="use these saved results instead of running cases")
    ap.add_argument("--holdout-bases", default="", help="seed bases whose cases judge the calibration (not fitted)")
    ap.add_argument("--holdout", nargs="*", help="saved results that judge the calibration (not fitted)")
    ap.add_argument("--calibrate", action="store_true", help="fit the confidence logistic to these runs")
    ap.add_argument("--write", action="store_true",
                    help="with --calibrate and held-out runs: write the coefficients into pmctl/tools/twin/calibration.py")
    a = ap.parse_args(argv)
    bases, hbases = _bases(a.seed_base), _bases(a.holdout_bases)
    if a.save and len(bases) > 1:
        raise SystemExit("--save takes one seed base; use --save-dir with several")
    m = None if a.merge and (a.holdout or not hbases) else load_machine()

    def path(b):
        if a.save_dir:
            from pathlib import Path
            Path(a.save_dir).mkdir(parents=True, exist_ok=True)
            return str(Path(a.save_dir) / f"eval-{b}.jsonl")
        return a.save

    if a.merge:
        res = [json.loads(line) for f in a.merge for line in open(f)]
    else:
        res = [r for b in bases for r in collect(a, b, m, path(b))]
    held = [json.loads(line) for f in (a.holdout or []) for line in open(f)]
    held += [r for b in hbases for r in collect(a, b, m, path(b))]
    table(res)
    if held:
        print("\nheld-out runs:")
        table(held)
    if a.calibrate:
        fb, hb = sorted({seed_base(r) for r in res}), sorted({seed_base(r) for r in held})
        calibrate(res, held, fb, hb, write=a.write)
    return 0


if __name__ == "__main__":
    sys.exit(main())
