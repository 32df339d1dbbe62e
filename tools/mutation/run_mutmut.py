#!/usr/bin/env python3
"""Mutation testing of the safety modules with mutmut (the ``[mutation]`` extra), module by module.

Each group below names a module, the functions of it that carry the safety rules (mutmut's mutant
names are matched against these globs) and the test files that guard them. For each group the
repository (the working tree, or ``--ref``) is copied into a scratch folder, its C extensions are
built there, a ``[tool.mutmut]`` table for the group is written into the copy's pyproject.toml, and
``mutmut run`` mutates those functions and runs the tests that reach each mutant (mutmut learns which
tests call which function in a first, traced run). The table at the end is the kill rate per group:
killed / (killed + survived + no test reaches it + timeouts counted as killed).

    pip install -e '.[test,mutation]'
    .venv/bin/python tools/mutation/run_mutmut.py                       # every group
    .venv/bin/python tools/mutation/run_mutmut.py --group nc,bridge      # some
    .venv/bin/python tools/mutation/run_mutmut.py --ref main --json before.json   # main's tests
    .venv/bin/python tools/mutation/run_mutmut.py --group nc --survivors  # list what survived, with diffs

Not part of CI: a group takes minutes to an hour on two cores. mutmut switches mutants inside the
test process, so code that only runs in a child process (the rt process of ``pmctl run`` and
``pmctl serve``, the console behind a pty) is out of its reach: tools/mutation/hand_mutants.py keeps
listed mutants of those, and of the C code. Survivors that are equivalent (no test can tell them
from the original) are explained in tools/mutation/EQUIVALENT.md.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from hand_mutants import ROOT, _copy_tree  # noqa: E402

# group: (module, [function globs: x_<name> for functions, xǁ<Class>ǁ<method> for methods], [test files],
#         a pytest -k expression over them or None). The tests are the ones that guard the rules and
#         are quick enough to run once per mutant; the broader suites (test_ncore's tick-for-tick
#         comparisons, the daemon's) kill more but cost minutes per mutant.
GROUPS = {
    "nc": ("src/pmctl/motion/nc.py",
           ["x__stopping_violation", "x__ferror_violation", "x__nonfinite_feedback", "x__limit_rates_l",
            "x__slew_offset"],
           ["tests/test_safety_nc.py", "tests/test_nc.py", "tests/test_ncore.py"],
           "not tick_for_tick and not same_pulses_with and not same_pulses_at_rest and not long_run "
           "and not bit_for_bit and not fk_equals_model_fk"),
    "vf": ("src/pmctl/core/vf.py", ["x_vf_step", "x_vf_tick"], ["tests/test_vf.py", "tests/test_nc.py"], None),
    "timescale": ("src/pmctl/motion/timescale.py",
                  ["xǁTimeScalerǁstep", "xǁTimeScalerǁset_feed_override", "xǁTimeScalerǁset_rapid_override",
                   "xǁPathFollowerǁnext_target", "x_backward_pass", "x_sample_caps", "x_scaling_limits"],
                  ["tests/test_safety_hold.py", "tests/test_timescale.py"], "not sigterm and not console"),
    "bridge": ("src/pmctl/hal/bridge_protocol.py", ["x_*", "xǁParserǁ*"],
               ["tests/test_bridge_protocol.py", "tests/test_safety_protocol.py", "tests/test_safety_bridge.py"],
               None),
    "planner": ("src/pmctl/task/planner.py", ["x__violations", "x__check_samples", "x__check_reachable"],
                ["tests/test_safety_limits.py"], None),
    "swing": ("src/pmctl/core/kinematics.py", ["x_limit_violations"],
              ["tests/test_safety_limits.py", "tests/test_kinematics.py"], None),
    "calibration": ("src/pmctl/tools/calibrate/identify.py", ["x_identify"], ["tests/test_calibration.py"],
                    "uncertaint or held_out or noise_free or unidentifiable or without_a_measured or too_few"),
    "twin": ("src/pmctl/tools/twin/diagnose.py", ["x_accept"], ["tests/test_twin_false_alarms.py"], "threshold"),
}

# a revision without a group's own test files (``--ref`` before they were written): the tests it had
FALLBACK = {
    "planner": (["tests/test_planner.py"], None),
    "twin": (["tests/test_diagnose.py"], "clean_recording or concealed_effect"),
}

KILLED = {"killed", "timeout", "segfault", "caught by type check"}


def _module(path: str) -> str:
    return path[len("src/"):-len(".py")].replace("/", ".")


def _setup(work: Path, group: str, module: str, tests: list[str], kexpr: str | None):
    """pyproject.toml of the copy: no xdist, the group's module and tests."""
    pp = work / "pyproject.toml"
    text = pp.read_text()
    text = re.sub(r'^addopts = .*$', 'addopts = "-p no:cacheprovider"', text, flags=re.M)
    sel = [t for t in tests if (work / t).exists()]
    if not sel and group in FALLBACK:
        tests, kexpr = FALLBACK[group]
        sel = [t for t in tests if (work / t).exists()]
    if not sel:
        raise RuntimeError(f"group {group}: none of its test files {tests} is in the copy")
    if kexpr:
        sel += ["-k", kexpr]
    text += ("\n[tool.mutmut]\n"
             'source_paths = ["src"]\n'
             f"only_mutate = {json.dumps([module])}\n"
             f"pytest_add_cli_args_test_selection = {json.dumps(sel)}\n"
             'also_copy = ["config", "examples", "firmware_bridge", "setup.py", "src/pmctl/config"]\n')
    pp.write_text(text)
    return sel


def _results(work: Path) -> dict[str, str]:
    r = subprocess.run([sys.executable, "-m", "mutmut", "results", "--all", "true"], cwd=work,
                       capture_output=True, text=True)
    out = {}
    for ln in r.stdout.splitlines():
        if ":" in ln:
            name, status = ln.strip().rsplit(":", 1)
            out[name.strip()] = status.strip()
    return out


def run_group(name: str, ref: str | None, work_root: Path, max_children: int, survivors: bool) -> dict:
    module, funcs, tests, kexpr = GROUPS[name]
    work = work_root / name
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    _copy_tree(ROOT, work, ref)
    r = subprocess.run([sys.executable, "setup.py", "-q", "build_ext", "--inplace"], cwd=work, capture_output=True,
                       text=True)
    if r.returncode:
        raise RuntimeError(r.stderr[-2000:])
    sel = _setup(work, name, module, tests, kexpr)
    mod = _module(module)
    globs = [f"{mod}.{f}__mutmut_*" for f in funcs]
    t0 = time.monotonic()
    log = (work_root / f"{name}.log").open("w")
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)
    subprocess.run([sys.executable, "-m", "mutmut", "run", "--max-children", str(max_children), *globs], cwd=work,
                   stdout=log, stderr=subprocess.STDOUT, env=env)
    secs = time.monotonic() - t0
    res = {k: v for k, v in _results(work).items()
           if any(re.fullmatch(g.replace(".", r"\.").replace("*", ".*"), k) for g in globs)}
    counts = {}
    for st in res.values():
        counts[st] = counts.get(st, 0) + 1
    killed = sum(v for k, v in counts.items() if k in KILLED)
    judged = sum(v for k, v in counts.items() if k not in ("not checked", "skipped"))
    out = {"group": name, "module": module, "tests": sel, "mutants": len(res), "counts": counts,
           "killed": killed, "judged": judged, "rate": killed / judged if judged else None,
           "seconds": round(secs), "survived": sorted(k for k, v in res.items() if v not in KILLED)}
    if survivors:
        diffs = {}
        for m in out["survived"]:
            d = subprocess.run([sys.executable, "-m", "mutmut", "show", m], cwd=work, capture_output=True, text=True)
            diffs[m] = d.stdout
        out["diffs"] = diffs
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--group", default="", help=f"comma-separated groups (default all: {', '.join(GROUPS)})")
    ap.add_argument("--ref", default=None, help="a git revision to copy instead of the working tree (e.g. main)")
    ap.add_argument("--work", default=None, help="scratch folder (kept; default: a temporary one, removed)")
    ap.add_argument("--max-children", type=int, default=2)
    ap.add_argument("--json", default=None, help="write the results here")
    ap.add_argument("--survivors", action="store_true", help="print each survivor's diff")
    a = ap.parse_args(argv)
    names = [g for g in (a.group.split(",") if a.group else GROUPS)]
    for g in names:
        if g not in GROUPS:
            ap.error(f"unknown group {g!r}; groups: {', '.join(GROUPS)}")
    root = Path(a.work) if a.work else Path(tempfile.mkdtemp(prefix="pmctl-mutmut-"))
    root.mkdir(parents=True, exist_ok=True)
    results = []
    try:
        for g in names:
            r = run_group(g, a.ref, root, a.max_children, a.survivors)
            results.append(r)
            rate = "-" if r["rate"] is None else f"{100 * r['rate']:.0f} %"
            print(f"{g:12s} {r['module']:42s} {r['killed']:4d}/{r['judged']:<4d} {rate:>6s}  {r['seconds']:5d} s  "
                  f"{r['counts']}", flush=True)
            if a.survivors:
                for m in r["survived"]:
                    print(r["diffs"].get(m, m))
            if a.json:
                Path(a.json).write_text(json.dumps(results, indent=1))
    finally:
        if not a.work:
            shutil.rmtree(root, ignore_errors=True)
    k = sum(r["killed"] for r in results)
    n = sum(r["judged"] for r in results)
    print(f"{'all':12s} {'':42s} {k:4d}/{n:<4d} {100 * k / n if n else 0:5.0f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
