"""Confidence of a finding, calibrated on blind synth runs. Pure math.

A finding's confidence is a logistic function of five numbers measured on it:

- ``snr``: its held-out improvement ΔSSE_cv over the acceptance threshold max(MIN_DSSE, p·ln N)
  (log10; 0 = just accepted);
- ``spread``: how far the training folds' parameter estimates stray from the full fit, in units
  of their tolerance (0 = identical, 1 = at the identifiability limit);
- ``rel``: the fraction of the residual energy of its channels that it removes on held-out data;
- ``share``: its in-sample gain over that of a flexible, physics-free description of its channels
  (functions of time, of each axis' position, and of each axis' direction; see
  :func:`pmctl.tools.twin.unexplained.flexible_gain`); the effect is refused when the same ratio of
  the gains beyond chance (``net_share``, carried in the features but not in the logistic) is
  below 0.3;
- ``left``: the structure its channels keep after all findings: log10(1 + g/n), g what the
  flexible description still removes from the final residual of its channels, n their samples
  (:func:`pmctl.tools.twin.unexplained.left_structure`; ~0 when only noise is left).

The coefficients come from ``benchmarks/eval_diagnosis.py --calibrate``: every finding of the
blind runs is labelled right (its effect and locator are among the hidden ones, parameters within
the scoring tolerance) or wrong, and a logistic regression of the label on the five numbers is
fitted on the runs of some seed bases; the reliability table (per confidence bin: findings, mean
predicted, fraction right) and the expected calibration error are then measured on the runs of
other seed bases, which the fit never saw. ``--write`` puts the coefficients, both run sizes and
that held-out table into the FITTED block below (docs/diagnosis-report.md, "Confidence"); the
report's ``confidence_calibration`` states it in one sentence.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

KEYS = ("snr", "spread", "rel", "share", "left")
# the acceptance threshold (pmctl.tools.twin.diagnose.accept), whitened: ~ 5 sigma of the held-out SSE
# difference of a null effect
MIN_DSSE = 30.0

# BEGIN FITTED (written by benchmarks/eval_diagnosis.py --calibrate --write; do not edit by hand)
COEF = {'const': 0.462, 'snr': 1.0006, 'spread': -0.1804, 'rel': 0.2058, 'share': 0.1826, 'left': -0.0257, 'partial_cap': 0.152}
CALIBRATION = {'fit': {'seed_bases': [1000, 2000, 3000, 5000, 6000], 'cases': 142, 'findings': 104, 'right': 74}, 'heldout': {'seed_bases': [7000, 9000], 'cases': 100, 'findings': 85, 'right': 70, 'bins': [{'bin': [0.0, 0.5], 'n': 10, 'right': 1, 'predicted': 0.152, 'observed': 0.1}, {'bin': [0.7, 0.85], 'n': 2, 'right': 2, 'predicted': 0.809, 'observed': 1.0}, {'bin': [0.85, 0.95], 'n': 16, 'right': 15, 'predicted': 0.911, 'observed': 0.938}, {'bin': [0.95, 1.0], 'n': 57, 'right': 52, 'predicted': 0.984, 'observed': 0.912}], 'ece': 0.064}}
DESCRIPTION = "logistic in held-out gain over threshold, fold spread of the parameters, explained fraction and share of the channels' structure, fitted on 104 findings of 142 blind synth cases (seed bases [1000, 2000, 3000, 5000, 6000]) and checked on 85 findings of 100 other cases (seed bases [7000, 9000]): expected calibration error 0.064; of the held-out findings at 0.85 or more, 67 of 73 were right"
# END FITTED


def features(ev) -> dict:
    """The five numbers of the logistic, plus ``weight_share`` for a finding named among look-alikes
    (its share of their weights: a cap, not a feature of the fit)."""
    thr = max(MIN_DSSE, ev["pen"])
    out = {"snr": math.log10(max(ev["d_cv"] / thr, 1e-3)),
           "spread": float(min(ev.get("spread", 0.0), 5.0)),
           "rel": float(min(max(ev["rel"], 0.0), 1.0)),
           "share": float(min(ev.get("share", 1.0), 1.5)),
           "left": float(min(ev.get("left", 0.0), 5.0))}
    if "weight_share" in ev:
        out["weight_share"] = float(ev["weight_share"])
    if "net_share" in ev:               # the share beyond chance (the SHARE_MIN rule's; not in the logistic)
        out["net_share"] = float(min(ev["net_share"], 1.5))
    return out


# A partial description: a finding that describes less than this share of its channels' structure,
# or leaves more than this much structure on them (``left``), is a partial fit of something more often
# than a logistic in these numbers can say (on the fit's blind runs of 26 November 2026, 5 of 33 such
# findings were right, against 69 of 71 of the others). Its confidence is the fraction right among
# such findings on the fit's runs (``partial_cap`` in COEF) at most, and the logistic is fitted on the others.
# A look-alike's confidence is capped further, at its share of the look-alikes' weights (``weight_share``
# in its features; pmctl.tools.twin.lookalikes). The saved features carry it, so a blind evaluation
# that recomputes confidences from them judges what the report printed.
PARTIAL_SHARE = 0.55
PARTIAL_LEFT = 0.55


def partial(feat: dict) -> bool:
    return feat.get("share", 1.0) < PARTIAL_SHARE or feat.get("left", 0.0) > PARTIAL_LEFT


def confidence(feat: dict, coef: dict | None = None) -> float:
    c = COEF if coef is None else coef
    z = c["const"] + sum(c.get(k, 0.0) * feat.get(k, 0.0) for k in KEYS)
    p = 1.0 / (1.0 + math.exp(-max(min(z, 40.0), -40.0)))
    if "partial_cap" in c and partial(feat):
        p = min(p, c["partial_cap"])
    if "weight_share" in feat:          # a look-alike: at most its share (pmctl.tools.twin.lookalikes)
        p = min(p, feat["weight_share"])
    return p


def fit(rows, l2=1.0) -> dict:
    """The coefficients of :func:`confidence`: the logistic fitted on the findings that are no partial
    description, and ``partial_cap``, the fraction right among those that are (rows = [(feat, bool)])."""
    whole = [(f, ok) for f, ok in rows if not partial(f)]
    part = [ok for f, ok in rows if partial(f)]
    coef = fit_logistic(whole if len({ok for _, ok in whole}) == 2 else rows, l2=l2)
    coef["partial_cap"] = round(sum(part) / len(part), 3) if part else 0.5
    return coef


def fit_logistic(rows, iters=200, l2=1.0) -> dict:
    """Logistic regression (Newton, small ridge) of labels on features; rows = [(feat, bool)]."""
    keys = KEYS
    X = np.array([[1.0] + [f.get(k, 0.0) for k in keys] for f, _ in rows])
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


EDGES = (0.0, 0.5, 0.7, 0.85, 0.95, 1.0)


def reliability(rows, coef=None, edges=EDGES) -> list[dict]:
    """Per confidence bin [lo, hi) (the last one closed): number of findings, how many were right,
    mean predicted confidence, fraction right. ``rows`` = [(features, right)]."""
    return bin_table([(confidence(f, coef), bool(ok)) for f, ok in rows], edges)


def bin_table(ps, edges=EDGES) -> list[dict]:
    """:func:`reliability` of (predicted confidence, right) pairs."""
    out = []
    for i, (lo, hi) in enumerate(zip(edges, edges[1:])):
        last = i == len(edges) - 2
        sel = [(p, ok) for p, ok in ps if lo <= p < hi or (last and p == hi)]
        if sel:
            out.append({"bin": [lo, hi], "n": len(sel), "right": sum(ok for _, ok in sel),
                        "predicted": round(sum(p for p, _ in sel) / len(sel), 3),
                        "observed": round(sum(ok for _, ok in sel) / len(sel), 3)})
    return out


def ece(bins) -> float:
    """Expected calibration error of a :func:`reliability` table: Σ n_b/N · |predicted_b − observed_b|."""
    n = sum(b["n"] for b in bins)
    return sum(b["n"] * abs(b["predicted"] - b["observed"]) for b in bins) / n if n else float("nan")


def fitted_block(coef, calib, description) -> str:
    """The source text between the BEGIN FITTED / END FITTED markers of this module."""
    return ("# BEGIN FITTED (written by benchmarks/eval_diagnosis.py --calibrate --write; do not edit by hand)\n"
            f"COEF = {({k: round(float(v), 4) for k, v in coef.items()})!r}\n"
            f"CALIBRATION = {calib!r}\n"
            f"DESCRIPTION = {description!r}\n"
            "# END FITTED\n")


def write_fitted(coef, calib, description, path=None) -> Path:
    """Replace the fitted block of this module's source (``path``: another copy of it) in place."""
    p = Path(path or __file__)
    text = p.read_text(encoding="utf-8")
    a, b = text.index("# BEGIN FITTED"), text.index("# END FITTED")
    b = text.index("\n", b) + 1
    p.write_text(text[:a] + fitted_block(coef, calib, description) + text[b:], encoding="utf-8")
    return p
