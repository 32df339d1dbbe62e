"""Side-by-side: pmctl's physics diagnosis vs a generic sparse regression (PySINDy) on the same residuals.

Not part of the test suite; PySINDy is not a project dependency (``.venv/bin/pip install pysindy``).

For each concealed synth case, both tools see the same nominal-twin residual of the channel the
residual is largest in (whitened excess over noise), with the same blocked cross-validation in time
(pmctl.tools.twin.diagnose.folds_of). PySINDy gets a generic library of the machine state -- polynomials
(degree 1 or 2, chosen like the threshold) and Fourier terms (sin/cos of k·x, k = 1, 2) of the commanded axes, their speeds, the
sign of each speed, temperatures, tip loads and time -- fitted by sequentially thresholded least
squares (STLSQ on the residual scaled to unit variance, ridge 1e-2, threshold of a small grid with
the best held-out fit). Printed per case: what each tool names,
and the held-out RMS of that channel before and after each.

    .venv/bin/python benchmarks/compare_generic.py [--n 2] [--duration 30]
"""

from __future__ import annotations

import argparse
import math
import sys

import pmctl  # noqa: F401,I001  (before numpy: its one-BLAS-thread default, pmctl/__init__.py)
import numpy as np

from pmctl.core.config import load_machine
from pmctl.tools.twin import synth
from pmctl.tools.twin.diagnose import diagnose, folds_of, N_FOLDS
from pmctl.tools.twin.effects import AXES

try:
    import pysindy as ps
except ImportError:            # pragma: no cover
    sys.exit("pip install pysindy into the venv first (not a project dependency)")


def features(ctx, rows):
    t = ctx.t
    cols, names = [], []
    for a, ax in enumerate(AXES):
        x = ctx.q_cmd[:, a]
        v = np.gradient(x, t)
        cols += [x[rows] - x.mean(), v[rows], np.sign(v[rows])]
        names += [f"{ax}", f"v{ax}", f"sgn(v{ax})"]
    for k, T in ctx.temps.items():
        cols.append(T[rows] - T.mean())
        names.append(k)
    F = ctx.extra.get("tip_force")
    if F is not None:
        pos = np.searchsorted(ctx.rows, rows)
        for i, c in enumerate("xyz"):
            cols.append(F[pos, i])
            names.append(f"F{c}")
    cols.append(t[rows] - t[0])
    names.append("t")
    X = np.stack(cols, 1)
    sc = X.std(0)
    sc[sc == 0] = 1
    return X / sc, names


def sindy_fit(Xtr, ytr, Xte, names, threshold, degree=2):
    """SINDy with the residual as the 'derivative' of the machine state: sparse regression on the library."""
    lib = ps.GeneralizedLibrary([ps.PolynomialLibrary(degree=degree), ps.FourierLibrary(n_frequencies=2)])
    s = float(np.std(ytr)) or 1.0
    opt = ps.STLSQ(threshold=threshold, alpha=1e-2, normalize_columns=False)
    model = ps.SINDy(feature_library=lib, optimizer=opt)
    model.fit(Xtr, t=1.0, x_dot=np.column_stack([ytr / s] + [np.zeros_like(ytr)] * (Xtr.shape[1] - 1)),
              feature_names=names)
    pred_te = s * model.predict(Xte)[:, 0]
    pred_tr = s * model.predict(Xtr)[:, 0]
    coef = s * np.asarray(model.coefficients())[0]
    return pred_te, pred_tr, coef, model.get_feature_names()


def compare(case, m, cap):
    rep, ex = diagnose(case.columns, m, cap=cap)
    ctx = ex["ctx"]
    o = ctx.obs
    loc = ex["locate"]["channels"]
    ch = max(loc, key=lambda c: loc[c]["excess"])
    msk = o.ch == o.channels.index(ch)
    y = o.y[msk] / o.w[msk]
    rows = o.row[msk]
    folds = folds_of(ctx)[msk]
    X, names = features(ctx, rows)
    # threshold: the one of a small grid with the best inner held-out fit
    best = None
    for deg in (1, 2):
        for thr in (0.01, 0.05, 0.2):
            pred = np.zeros_like(y)
            for k in range(N_FOLDS):
                te = folds == k
                pred[te], _, _, _ = sindy_fit(X[~te], y[~te], X[te], names, thr, deg)
            r = float(np.sqrt(np.mean((y - pred) ** 2)))
            if best is None or r < best[0]:
                best = (r, thr, deg)
    _, _, coef, fn = sindy_fit(X, y, X, names, best[1], best[2])
    top = sorted(zip(np.abs(coef), fn, coef), reverse=True)[:3]
    rms0 = float(np.sqrt(np.mean(y ** 2)))
    ours = None
    for f in rep["findings"]:
        if ch in f["rms_after"]:
            ours = f["rms_after"][ch]          # cumulative: the last one that touches ch
    return {"channel": ch, "rms0": rms0, "sindy_rms": best[0], "ours_rms": ours if ours is not None else rms0,
            "sindy_terms": [f"{c:+.3g}·{n}" for _, n, c in top if c != 0] or ["(none)"],
            "ours": [f"{f['effect']} {f.get('axis', f.get('channel', f.get('chain')))}" for f in rep["findings"]]
            or ["consistent"]}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=2)
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--cap", type=int, default=4000)
    ap.add_argument("--effects", default=",".join(synth.EFFECTS))
    a = ap.parse_args()
    m = load_machine()
    print(f"{'hidden effect':28s} {'channel':8s} {'nominal':>9s} {'pmctl':>9s} {'PySINDy':>9s}  "
          f"pmctl names | PySINDy's largest terms")
    cuts = {"pmctl": [], "sindy": []}
    named = 0
    total = 0
    for e in a.effects.split(","):
        for k in range(a.n):
            seed = 424242 + 31 * synth.EFFECTS.index(e) + k
            rng = np.random.default_rng(seed)
            case = synth.synth_case(rng, [e], machine=m, seed=seed,
                                    duration_s=None if e == "thermal_growth" else a.duration)
            r = compare(case, m, a.cap)
            tr = case.answer["effects"][0]
            loc = tr.get("axis", tr.get("channel", tr.get("chain")))
            total += 1
            named += any(s == f"{e} {loc}" for s in r["ours"])
            cuts["pmctl"].append(r["rms0"] / r["ours_rms"])
            cuts["sindy"].append(r["rms0"] / r["sindy_rms"])
            print(f"{e + ' ' + str(loc):28s} {r['channel']:8s} {r['rms0']:9.3g} {r['ours_rms']:9.3g} "
                  f"{r['sindy_rms']:9.3g}  {', '.join(r['ours'])} | {'; '.join(r['sindy_terms'])}", flush=True)
    g = (lambda v: math.exp(np.mean(np.log(v))))
    print(f"\nheld-out RMS cut, geometric mean over {total} cases: pmctl x{g(cuts['pmctl']):.1f}, "
          f"PySINDy x{g(cuts['sindy']):.1f}; pmctl named the hidden effect and its locator in {named}/{total}; "
          f"PySINDy names no physics (a sparse sum of library terms).")


if __name__ == "__main__":
    main()
