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

# fitted by benchmarks/eval_diagnosis.py --n 2 --duration 10 --cap 2000 --calibrate (seed base 0):
# 40 blind cases (every catalogue effect x 2 at 1 kHz and 250 Hz, the 250 Hz one with recording
# imperfections; near-threshold pitch, 2.5 K thermal, pairs, clean, out-of-catalogue), 39
# findings, 32 right. Fitted bins: 0-0.5: 6 findings, 33 % right; 0.5-0.7: 3, 33 %; 0.7-0.85: 1,
# 100 %; 0.85-0.95: 6, 83 %; 0.95-1: 23, 100 %. Fitted on one half of the cases and judged on the
# other (by case parity), the top bin (≥ 0.95) held 32 findings of which 88 % were right.
COEF = {"const": -6.83, "snr": 0.683, "spread": -3.95, "rel": 4.131, "share": 4.075}
CALIBRATION = {"cases": 40, "findings": 39, "right": 32, "seed_base": 0,
               "bins": [{"bin": [0.0, 0.5], "n": 6, "right": 0.33}, {"bin": [0.5, 0.7], "n": 3, "right": 0.33},
                        {"bin": [0.7, 0.85], "n": 1, "right": 1.0}, {"bin": [0.85, 0.95], "n": 6, "right": 0.83},
                        {"bin": [0.95, 1.0], "n": 23, "right": 1.0}]}
DESCRIPTION = ("logistic in held-out gain over threshold, fold spread of the parameters, explained fraction and "
               "share of the channels' structure; fitted on 39 findings of 40 blind synth cases "
               "(benchmarks/eval_diagnosis.py --calibrate, seed base 0); small sample: read 0.9 as 'about 9 in 10'")


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
