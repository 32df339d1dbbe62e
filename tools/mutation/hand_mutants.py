#!/usr/bin/env python3
"""Hand mutants of the safety code, applied one at a time to a scratch copy of the repository.

The compiled parts (the NC core ``src/pmctl/motion/ncore``, the path follower ``follow/``, the step/dir
bridge's portable core ``firmware_bridge/``) are out of reach of a Python mutation tool, and some
safety rules are only exercised through real processes (the rt process, ``pmctl run``, ``pmctl
serve`` and its console) where a tool's in-process switch does not reach. This script keeps a listed
set of small semantic changes to them (``MUTANTS`` below, the issue-31 audit's dangerous ones among
them), and for each one: copies the repository (``git ls-files`` of the working tree or of ``--ref``)
into a scratch folder, changes the one place, rebuilds the C extensions there, runs the tests named
for it with that copy first on the path (subprocesses too, through PYTHONPATH), records which tests
failed, and restores the file. Not part of CI: a full run takes minutes per compiled mutant.

    .venv/bin/python tools/mutation/hand_mutants.py                  # all, a table per file
    .venv/bin/python tools/mutation/hand_mutants.py --only H2,H3b    # some, by id
    .venv/bin/python tools/mutation/hand_mutants.py --show H1a       # the diff of one, nothing run
    .venv/bin/python tools/mutation/hand_mutants.py --ref main       # the same mutants against main's tests

A mutant is killed when at least one of its tests fails (a test that errors counts; a timeout too,
said so). ``--json FILE`` writes every result. Exit status 0 when every mutant was killed.
"""

from __future__ import annotations

import argparse
import difflib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class Mutant:
    id: str
    file: str            # path in the repository
    old: str             # text that must occur exactly once
    new: str
    why: str             # what the change breaks, in the machine's terms
    tests: tuple         # pytest node ids / files (with -k expressions after "::-k ")
    also: tuple = ()     # further (old, new) changes in the same file, made together with the first


NCORE = "src/pmctl/motion/ncore/ncore.c"
FOLLOW = "src/pmctl/motion/follow/follow.c"
BRIDGE = "firmware_bridge/core.c"
PROTO = "firmware_bridge/proto.c"

SAFETY_NC = "tests/motion/test_safety_nc.py"
SAFETY_HOLD = "tests/task/test_safety_hold.py"
SAFETY_LIMITS = "tests/task/test_safety_limits.py"
TWIN_FA = "tests/tools/test_twin_false_alarms.py"

MUTANTS = [
    # ---- the dangerous ones (1-5)
    Mutant("H1a", FOLLOW,
           "goal = hold ? 0.0 : ((flags & c->flag_rapid) ? st[FL_RAPID_OV] : st[FL_FEED_OV]);",
           "goal = (flags & c->flag_rapid) ? st[FL_RAPID_OV] : (hold ? 0.0 : st[FL_FEED_OV]);",
           "feed hold ignored during rapids (compiled follower)", (SAFETY_HOLD,)),
    Mutant("H1b", "src/pmctl/motion/timescale.py",
           "goal = 0.0 if sc.hold else (sc.rapid_override if flags & FLAG_RAPID else sc.feed_override)",
           "goal = sc.rapid_override if flags & FLAG_RAPID else (0.0 if sc.hold else sc.feed_override)",
           "feed hold ignored during rapids (Python follower)", (SAFETY_HOLD,)),
    Mutant("H2", NCORE,
           "sd = fabs(v) * (0.5 * Tb + 2.0 * dt)", "sd = fabs(v) * (0.45 * Tb + 2.0 * dt)",
           "the C core brakes later for a soft limit than Python (0.5 -> 0.45 T_b)", (SAFETY_NC,)),
    Mutant("H2b", "src/pmctl/motion/nc.py",
           "s = abs(v) * (0.5 * T + 2.0 * dt)", "s = abs(v) * (0.45 * T + 2.0 * dt)",
           "the Python NC brakes later for a soft limit (0.5 -> 0.45 T_b)", (SAFETY_NC,)),
    Mutant("H3a", NCORE,
           "if (fe > lim) {", "if (fe > 1.1 * lim) {",
           "the following-error trip loosened by 10 % (C core)", (SAFETY_NC,)),
    Mutant("H3b", "src/pmctl/motion/nc.py",
           "        if fe > lim:\n", "        if fe > 1.1 * lim:\n",
           "the following-error trip loosened by 10 % (Python NC)", (SAFETY_NC,)),
    Mutant("H4", "src/pmctl/tools/calibrate/identify.py",
           "@ Vr * chi2 if chi2 > 1", "@ Vr * math.sqrt(chi2) if chi2 > 1",
           "calibration covariance scaled by sqrt(chi2) instead of chi2 (uncertainties too small)",
           ("tests/tools/test_calibration.py::-k uncertainties",)),
    Mutant("H5a", "src/pmctl/tools/twin/calibration.py",
           "MIN_DSSE = 30.0", "MIN_DSSE = 15.0",
           "the twin's acceptance threshold halved", (TWIN_FA,)),
    Mutant("H5b", "src/pmctl/tools/twin/unexplained.py",
           "        if not glob or max((v[0] for v in sig.values()), default=0.0) < STRUCT_MIN:",
           "        if not glob:",
           "an excess without structure is reported (the rule removed, both places)", (TWIN_FA,),
           also=(("        if frac < STRUCT_MIN:\n", "        if False:\n"),)),
    # ---- the smaller ones (6) and the tie (7)
    Mutant("H6a", "src/pmctl/motion/timescale.py",
           "g = math.sqrt(2.0 * 0.5 * sc.accel * remain) * 0.9", "g = math.sqrt(2.0 * 0.5 * sc.accel * remain) * 1.0",
           "no starvation margin (Python follower)", (SAFETY_HOLD + "::-k starved",)),
    Mutant("H6b", FOLLOW,
           "g = sqrt(2.0 * 0.5 * st[FL_ACCEL] * remain) * 0.9;", "g = sqrt(2.0 * 0.5 * st[FL_ACCEL] * remain) * 1.0;",
           "no starvation margin (compiled follower)", (SAFETY_HOLD + "::-k starved",)),
    Mutant("H6c", "src/pmctl/task/planner.py",
           '    ratios.append(("v", np.concatenate([qv.max(-1), [0.0]])))\n', "",
           "the planner's last joint-speed check removed", (SAFETY_LIMITS,)),
    Mutant("H6d", "src/pmctl/core/kinematics.py",
           "           | (swing > lim.spherical_swing_deg) | (pz <= 0)", "           | (pz <= 0)",
           "the spherical-joint swing check removed", (SAFETY_LIMITS,)),
    Mutant("H7", NCORE,
           "m = trunc(a >= 0.0 ? a / 1.0 + NC_VF_TIE : a / 1.0 - NC_VF_TIE);", "m = trunc(a / 1.0);",
           "the half-pulse tie broken by rounding again (C core)",
           ("tests/motion/test_ncore.py::-k half_a_pulse or tick_for_tick",)),
    # ---- more of the C core
    Mutant("C1", NCORE,
           "        if (lim < c->min_ferror)\n            lim = c->min_ferror;\n", "",
           "no MIN_FERROR floor: at rest any error trips (C core)", (SAFETY_NC, "tests/motion/test_ncore.py")),
    Mutant("C2", NCORE,
           "        if (!isfinite(enc[i])) {", "        if (0) {",
           "a dead encoder (NaN) no longer halts (C core)", (SAFETY_NC,)),
    Mutant("C3", NCORE,
           "xq > c->upper[i] ||", "0 ||",
           "a joint already beyond its upper limit is not stopped (C core)",
           (SAFETY_NC, "tests/motion/test_ncore.py::-k soft_limit")),
    Mutant("C4", NCORE,
           "if (perr > c->max_path_error) {", "if (perr > 2.0 * c->max_path_error) {",
           "path error stop at twice its limit (C core)", (SAFETY_NC,)),
    Mutant("C5", NCORE,
           "out[i] = m > 1.0 ? prev[i] + dq[i] / m : des[i];", "out[i] = des[i];",
           "no acceleration limit on the joint rates (C core)", (SAFETY_NC, "tests/motion/test_ncore.py")),
    Mutant("C6", NCORE,
           "if (m > c->max_pulses)\n                m = c->max_pulses;", "if (0)\n                m = c->max_pulses;",
           "more pulses a tick than the converter may send (C core)", ("tests/motion/test_ncore.py",)),
    Mutant("C7", NCORE,
           "if (c->rest_band[i] > 0.0 && fabs(qd_des[i]) <= c->rest_band[i] &&",
           "if (c->rest_band[i] > 0.0 && fabs(qd_des[i]) < 0.5 * c->rest_band[i] &&",
           "the rest deadband halved (limit cycle at rest; C core)", ("tests/motion/test_ncore.py::-k rest or half_a_pulse",)),
    Mutant("F1", FOLLOW,
           "if (goal > cap)\n        goal = cap;", "if (0)\n        goal = cap;",
           "the path's speed caps ignored (compiled follower)", ("tests/motion/test_follow.py", "tests/motion/test_timescale.py")),
    Mutant("F2", FOLLOW,
           "    if (ds > A)\n        ds = A;\n    else if (ds < -A)\n        ds = -A;\n    if (e >= 0.0",
           "    if (e >= 0.0",
           "sigma's rate limit not applied after the joint interval (compiled follower)",
           ("tests/motion/test_follow.py", SAFETY_HOLD)),
    # ---- the step/dir bridge's portable core (a scratch copy only: firmware_bridge/ is the chip branch's)
    Mutant("B1", BRIDGE,
           "        } else {                             /* behind: a duplicate, already executed */\n"
           "            send_ack(c, SB_ACK_DUP, SB_E_OK, f->type);\n        }\n        return;",
           "        } else {                             /* behind: a duplicate, already executed */\n"
           "            send_ack(c, SB_ACK_DUP, SB_E_OK, f->type);\n            return;\n        }",
           "a frame ahead of the sequence (frames lost) is executed instead of NAKed",
           ("tests/hal/test_stepdir.py::-k noise or corrupted or sequence",)),
    Mutant("B2", BRIDGE,
           "        if (wd <= now) {", "        if (0) {",
           "the bridge's command watchdog never trips", ("tests/hal/test_stepdir.py::-k watchdog or killed or lost",)),
    Mutant("B3", BRIDGE,
           "if ((uint32_t)(p < 0 ? -p : p) > sb_max_pulses(&c->cfg, 0))",
           "if ((uint32_t)(p < 0 ? -p : p) > 2u * sb_max_pulses(&c->cfg, 0))",
           "a tick with more pulses than it holds is accepted", ("tests/hal/test_safety_bridge.py",)),
    Mutant("B4", BRIDGE,
           "    if (c->inputs & SB_IN_ESTOP)", "    if (0)",
           "the E-stop input ignored by the bridge", ("tests/hal/test_stepdir.py::-k estop",)),
    Mutant("B5", PROTO,
           "crc = (uint16_t)((crc << 8) ^ crc_table[((crc >> 8) ^ p[i]) & 0xffu]);",
           "crc = (uint16_t)((crc << 8) ^ crc_table[((crc >> 8) ^ p[i]) & 0x7fu]);",
           "the bridge's CRC computed wrong (frames refused or corrupted ones accepted)",
           ("tests/hal/test_bridge_protocol.py", "tests/hal/test_stepdir.py::-k noise")),
    # ---- the console's realtime bytes and the rt process (only real processes exercise them)
    Mutant("R1", "src/pmctl/interfaces/console/grbl.py",
           '                if state in ("Run", "Idle"):  # grbl 1.1: a hold while idle is a hold too (Hold:0)\n'
           "                    self.sup.hold()",
           '                if state in ("Idle",):  # grbl 1.1: a hold while idle is a hold too (Hold:0)\n'
           "                    self.sup.hold()",
           "'!' ignored while a job runs", (SAFETY_HOLD + "::-k console",)),
    Mutant("R2", "src/pmctl/motion/rtproc.py",
           '        if self.term and not self.quitting:\n            self.quitting = "SIGTERM"\n            sc.hold = True',
           '        if self.term and not self.quitting:\n            self.quitting = "SIGTERM"',
           "SIGTERM quits without braking on the path", (SAFETY_HOLD + "::-k sigterm",)),
]


# tests of a file at a revision that does not have a mutant's own tests yet (``--ref``, the "before")
FALLBACK = {
    NCORE: ("tests/motion/test_ncore.py", "tests/motion/test_nc.py"),
    "src/pmctl/motion/nc.py": ("tests/motion/test_ncore.py", "tests/motion/test_nc.py"),
    FOLLOW: ("tests/motion/test_follow.py", "tests/motion/test_timescale.py"),
    "src/pmctl/motion/timescale.py": ("tests/motion/test_follow.py", "tests/motion/test_timescale.py"),
    "src/pmctl/tools/calibrate/identify.py": ("tests/tools/test_calibration.py",),
    "src/pmctl/tools/twin/diagnose.py": ("tests/tools/test_diagnose.py", "tests/tools/test_twin_honesty.py"),
    "src/pmctl/tools/twin/calibration.py": ("tests/tools/test_diagnose.py", "tests/tools/test_twin_honesty.py"),
    "src/pmctl/tools/twin/unexplained.py": ("tests/tools/test_diagnose.py", "tests/tools/test_twin_honesty.py"),
    "src/pmctl/task/planner.py": ("tests/task/test_planner.py",),
    "src/pmctl/core/kinematics.py": ("tests/core/test_kinematics.py",),
    "src/pmctl/interfaces/console/grbl.py": ("tests/interfaces/test_console_sync.py",),
    "src/pmctl/motion/rtproc.py": ("tests/interfaces/test_run_client.py::-k sigterm", "tests/integration/test_first_hour.py::-k sigterm"),
}


def _specs(work: Path, m: Mutant) -> tuple:
    """The mutant's tests that exist in the copy; at a revision without them, the file's older tests."""
    have = tuple(s for s in m.tests if (work / s.split("::")[0]).exists())
    return have or FALLBACK.get(m.file, ())


def _copy_tree(src_root: Path, dst: Path, ref: str | None):
    """The repository's tracked files (of the working tree, or of ``ref``) into ``dst``."""
    if ref:
        arch = subprocess.run(["git", "-C", str(src_root), "archive", "--format=tar", ref], check=True,
                              capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(dst)], input=arch, check=True)
        return
    files = subprocess.run(["git", "-C", str(src_root), "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                           check=True, capture_output=True).stdout.split(b"\0")
    for f in files:
        if not f:
            continue
        p = src_root / f.decode()
        if not p.is_file():
            continue
        q = dst / f.decode()
        q.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(p, q)


def _build(work: Path, log) -> None:
    r = subprocess.run([sys.executable, "setup.py", "-q", "build_ext", "--inplace", "--force"], cwd=work,
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"build failed:\n{r.stdout[-2000:]}{r.stderr[-2000:]}")


def _pytest_args(spec: str) -> list[str]:
    if "::-k " in spec:
        path, expr = spec.split("::-k ", 1)
        return [path, "-k", expr]
    return [spec]


def _run_tests(work: Path, specs, timeout: float) -> tuple[str, list[str], float]:
    """('killed' | 'survived' | 'timeout', failing tests, seconds)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(work / "src") + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    failed, status, t0 = [], "survived", time.monotonic()
    for spec in specs:
        args = [sys.executable, "-m", "pytest", "-q", "-x", "-n", "0", "-p", "no:cacheprovider", "-o", "addopts=",
                "-rf", *_pytest_args(spec)]
        try:
            r = subprocess.run(args, cwd=work, env=env, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return "timeout", failed + [f"{spec} (timed out after {timeout:g} s)"], time.monotonic() - t0
        if r.returncode not in (0, 5):
            status = "killed"
            failed += [ln.split(" ", 1)[1].split(" - ")[0] for ln in r.stdout.splitlines()
                       if ln.startswith(("FAILED ", "ERROR "))] or [f"{spec} (exit {r.returncode})"]
            break
    return status, failed, time.monotonic() - t0


def mutate(m: Mutant, text: str) -> str:
    """The file's text with the mutant's change(s) made."""
    out = text.replace(m.old, m.new, 1)
    for old, new in m.also:
        if out.count(old) != 1:
            raise ValueError(f"{m.id}: {old!r} occurs {out.count(old)} times in {m.file}")
        out = out.replace(old, new, 1)
    return out


def diff_of(m: Mutant, text: str) -> str:
    new = mutate(m, text)
    return "".join(difflib.unified_diff(text.splitlines(True), new.splitlines(True), f"a/{m.file}", f"b/{m.file}", n=1))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", default="", help="comma-separated mutant ids (default: all)")
    ap.add_argument("--show", default="", help="print the diff of these mutants and exit")
    ap.add_argument("--ref", default=None, help="a git revision to copy instead of the working tree")
    ap.add_argument("--work", default=None, help="scratch folder (default: a new temporary one, removed after)")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per test file of a mutant")
    ap.add_argument("--json", default=None, help="write the results here")
    ap.add_argument("--list", action="store_true", help="list the mutants and exit")
    a = ap.parse_args(argv)
    chosen = [m for m in MUTANTS if not a.only or m.id in a.only.split(",")]
    if a.list:
        for m in chosen:
            print(f"{m.id:4s} {m.file:42s} {m.why}")
        return 0
    if a.show:
        for m in MUTANTS:
            if m.id in a.show.split(","):
                print(f"# {m.id}: {m.why}\n" + diff_of(m, (ROOT / m.file).read_text()))
        return 0
    tmp = Path(a.work) if a.work else Path(tempfile.mkdtemp(prefix="pmctl-hand-mutants-"))
    tmp.mkdir(parents=True, exist_ok=True)
    results = []
    try:
        _copy_tree(ROOT, tmp, a.ref)
        _build(tmp, print)
        for m in chosen:
            path = tmp / m.file
            orig = path.read_text()
            if orig.count(m.old) != 1:
                results.append({"id": m.id, "file": m.file, "why": m.why, "status": "not applicable",
                                "failed": [f"the text to change occurs {orig.count(m.old)} times"]})
                print(f"{m.id:4s} not applicable ({orig.count(m.old)} matches) {m.why}", flush=True)
                continue
            try:
                path.write_text(mutate(m, orig))
                if m.file.startswith("src/") and m.file.endswith((".c", ".h")):
                    _build(tmp, print)
                status, failed, secs = _run_tests(tmp, _specs(tmp, m), a.timeout)
            finally:
                path.write_text(orig)
                os.utime(path)          # newer than any build: the bridge binary is made again
                if m.file.startswith("src/") and m.file.endswith((".c", ".h")):
                    _build(tmp, print)
            results.append({"id": m.id, "file": m.file, "why": m.why, "status": status, "failed": failed,
                            "seconds": round(secs, 1), "diff": diff_of(m, orig)})
            print(f"{m.id:4s} {status:8s} {secs:6.1f} s  {m.why}" + (f"  <- {failed[0]}" if failed else ""), flush=True)
    finally:
        if not a.work:
            shutil.rmtree(tmp, ignore_errors=True)
    by_file = {}
    for r in results:
        by_file.setdefault(r["file"], []).append(r)
    print("\nkill rate by file:")
    for f, rs in sorted(by_file.items()):
        k = sum(r["status"] in ("killed", "timeout") for r in rs)
        n = sum(r["status"] != "not applicable" for r in rs)
        print(f"  {f:44s} {k}/{n}" + (f"  {100 * k / n:.0f} %" if n else ""))
    k = sum(r["status"] in ("killed", "timeout") for r in results)
    n = sum(r["status"] != "not applicable" for r in results)
    print(f"  {'all':44s} {k}/{n}" + (f"  {100 * k / n:.0f} %" if n else ""))
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=1))
    return 0 if k == n else 1


if __name__ == "__main__":
    sys.exit(main())
