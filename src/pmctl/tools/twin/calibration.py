"""Confidence of a finding, calibrated on blind synth runs. Pure math.

A finding's confidence is a logistic function of three numbers the selection measured on it:

- ``snr``: its held-out improvement ΔSSE_cv over the acceptance threshold max(MIN_DSSE, p·ln N)
  (log10; 0 = just accepted);
- ``spread``: how far the training folds' parameter estimates stray from the full fit, in units
  of their tolerance (0 = identical, 1 = at the identifiability limit);
- ``rel``: the fraction of the residual energy of its channels that it removes on held-out data;
- ``share``: its in-sample gain over that of a flexible, physics-free description of its channels
  (functions of time, of each axis' position, and of each axis' direction; see
  :func:`pmctl.tools.twin.unexplained.flexible_gain`); below 0.3 the effect is refused.

The coefficients come from ``benchmarks/eval_diagnosis.py --calibrate``: every finding of the
blind runs is labelled right (its effect and locator are among the hidden ones, parameters within
the scoring tolerance) or wrong, and a logistic regression of the label on the three numbers is
fitted. The run sizes and the reliability table (predicted against observed, per bin) are in
CALIBRATION below and in the report's ``confidence_calibration``.
"""

from __future__ import annotations

import math

KEYS = ("snr", "spread", "rel", "share")

# fitted by benchmarks/eval_diagnosis.py --calibrate (see CALIBRATION)
COEF = {"const": 0.0, "snr": 2.0, "spread": -2.0, "rel": 2.0, "share": 2.0}
CALIBRATION = {"cases": 0, "findings": 0, "right": 0, "bins": []}
DESCRIPTION = ("logistic in held-out gain over threshold, fold spread of the parameters and "
               "explained fraction; not yet calibrated")


def features(ev) -> dict:
    from pmctl.tools.twin.diagnose import MIN_DSSE
    thr = max(MIN_DSSE, ev["pen"])
    return {"snr": math.log10(max(ev["d_cv"] / thr, 1e-3)),
            "spread": float(min(ev.get("spread", 0.0), 5.0)),
            "rel": float(min(max(ev["rel"], 0.0), 1.0)),
            "share": float(min(ev.get("share", 1.0), 1.5))}


def confidence(feat: dict, coef: dict | None = None) -> float:
    c = COEF if coef is None else coef
    z = c["const"] + sum(c[k] * feat[k] for k in KEYS)
    return 1.0 / (1.0 + math.exp(-max(min(z, 40.0), -40.0)))


def fit_logistic(rows, iters=200, l2=1e-2) -> dict:
    """Logistic regression (Newton, small ridge) of labels on features; rows = [(feat, bool)]."""
    import numpy as np
    keys = KEYS
    X = np.array([[1.0] + [f[k] for k in keys] for f, _ in rows])
    y = np.array([1.0 if ok else 0.0 for _, ok in rows])
    w = np.zeros(X.shape[1])
    for _ in range(iters):
        p = 1 / (1 + np.exp(-np.clip(X @ w, -40, 40)))
        g = X.T @ (p - y) + l2 * w
        H = (X * (p * (1 - p))[:, None]).T @ X + l2 * np.eye(len(w))
        step = np.linalg.solve(H, g)
        w -= step
        if np.abs(step).max() < 1e-9:
            break
    return {"const": float(w[0]), **{k: float(v) for k, v in zip(keys, w[1:])}}


def reliability(rows, coef, edges=(0.0, 0.5, 0.7, 0.85, 0.95, 1.0)) -> list[dict]:
    """Per confidence bin: number of findings, mean predicted, fraction right."""
    out = []
    for lo, hi in zip(edges, edges[1:]):
        sel = [(confidence(f, coef), ok) for f, ok in rows if lo <= confidence(f, coef) < hi + (hi == 1.0)]
        if sel:
            out.append({"bin": [lo, hi], "n": len(sel), "predicted": round(sum(p for p, _ in sel) / len(sel), 3),
                        "observed": round(sum(ok for _, ok in sel) / len(sel), 3)})
    return out
