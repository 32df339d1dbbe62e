"""Score a diagnosis report against a synth answer key (issue 4 "Must show"). Pure functions.

A hidden effect counts as **found** when a finding has the same effect and locator (axis,
channel, or chain), every numeric parameter of the answer is recovered within ``tol`` (relative;
a gain is compared as gain − 1, the time of lost steps within 2 % of the run), and the held-out
RMS of the finding's most affected channel is cut at least ``cut``-fold, or down to 1.3 x that
channel's noise where the effect itself is too small for a ``cut``-fold cut. With several findings
the cut is that of all of them together (each finding's rms_after is cumulative anyway; the first of
two effects on the same channels cannot cut them alone).
"""

from __future__ import annotations


LOCATORS = ("axis", "channel", "chain")


def _locator(d):
    for k in LOCATORS:
        if k in d:
            return k, d[k]
    return None, None


def param_errors(found: dict, true: dict, duration_s: float | None = None) -> dict:
    """Relative error per answer parameter (None when the finding lacks it)."""
    out = {}
    for k, v in true.items():
        f = found.get(k)
        if isinstance(v, str):
            out[k] = 0.0 if f == v else None
            continue
        if f is None or isinstance(f, (list, str)):
            out[k] = None
            continue
        if k == "gain":
            out[k] = abs((f - 1) - (v - 1)) / abs(v - 1)
        elif k == "t_s":
            out[k] = abs(f - v) / (0.1 * duration_s if duration_s else abs(v))   # 2 % of run = 0.2
        else:
            out[k] = abs(f - v) / abs(v) if v else abs(f)
    return out


def cut_ok(finding: dict, noise: dict | None = None, cut: float = 3.0, last: dict | None = None) -> tuple[bool, float]:
    """Nominal held-out RMS over the RMS with the findings (cumulative up to ``last`` when given)."""
    rb, ra = finding.get("rms_before", {}), dict(finding.get("rms_after", {}))
    if last is not None:
        ra.update({c: v for c, v in last.get("rms_after", {}).items() if c in ra})
    best_ch, best = None, -1.0
    for c, b in rb.items():
        if b is not None and ra.get(c) is not None and b > best:
            best_ch, best = c, b
    if best_ch is None:
        return False, 0.0
    ratio = best / max(ra[best_ch], 1e-300)
    nz = (noise or {}).get(best_ch)
    return ratio >= cut or (nz is not None and ra[best_ch] <= 1.3 * nz), ratio


def score(report: dict, answer: dict, *, tol=0.2, cut=3.0, noise=None) -> dict:
    """Per hidden effect: found (name+locator), params_ok, cut_ok; plus unexpected findings."""
    res, used = [], set()
    for eff in answer.get("effects", []):
        lk, lv = _locator(eff)
        hit = None
        for i, f in enumerate(report.get("findings", [])):
            if i in used or f["effect"] != eff["effect"]:
                continue
            if f.get(lk) == lv:
                hit = i
                break
        r = {"effect": eff["effect"], lk: lv, "named": hit is not None, "params_ok": False, "cut_ok": False}
        if hit is not None:
            used.add(hit)
            f = report["findings"][hit]
            errs = param_errors(f["parameters"], eff["parameters"], answer.get("duration_s"))
            r["param_errors"] = errs
            r["params_ok"] = all(e is not None and e <= tol for e in errs.values())
            r["cut_ok"], r["cut"] = cut_ok(f, noise, cut, report["findings"][-1])
        r["success"] = r["named"] and r["params_ok"] and r["cut_ok"]
        res.append(r)
    extra = [f["effect"] + ":" + str(_locator(f)[1]) for i, f in enumerate(report.get("findings", []))
             if i not in used]
    return {"effects": res, "extra_findings": extra,
            "all_found": all(r["success"] for r in res), "clean_ok": not report.get("findings")}
