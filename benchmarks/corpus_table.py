"""The corpus of real part programs, side by side: pmctl against LinuxCNC's rs274, file by file.

    .venv/bin/python benchmarks/corpus_table.py                 # pmctl check FILE --json on every file
    .venv/bin/python benchmarks/corpus_table.py --run           # ... and machine the accepted ones on the sim
    .venv/bin/python benchmarks/corpus_table.py --reader        # today's job reader instead (the "before")
    .venv/bin/python benchmarks/corpus_table.py --words         # how many files use each G/M code and word
    .venv/bin/python benchmarks/corpus_table.py FILE...         # some corpus files only (paths in tests/corpus/)

Every file of tests/corpus/ is unpacked under its original name into a scratch folder and given to

    pmctl check FILE --json      (exit 0: the job can run, 1: it cannot; a JSON verdict on stdout)

A program is *understood* when it has no problem of kind syntax or unsupported, *accepted* when ok; a
*crash* is a traceback, an exit code other than 0 or 1, a run longer than --timeout, or output that is not
the specified JSON (tests/corpus_support.py, ``judge_check``). rs274's verdict is the fixture
tests/corpus/rs274.json (``--rs274 live`` runs rs274 again). Prints one row per file, then the totals:
understood, accepted, crashes, rs274 accepted; the problem kinds (files affected, problems) and the most
frequent messages (numbers folded). With ``--run`` every accepted program is machined with

    pmctl run --backend sim --no-realtime --state '' --job FILE

bounded by --run-timeout seconds per file, and reported done or not done (with why).

``--reader`` measures today's reader instead of ``pmctl check``: a fresh ``python -c`` per file calls
``pmctl.task.job.load_job(FILE, machine)`` (what ``pmctl run`` reads a job with) and reports accepted or
its first error; a refusal for reach (unreachable pose, tilt beyond the limit, too many moves) counts as
understood, any other refusal as not understood.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import corpus_support as cs  # noqa: E402

READER = r"""
import json, sys
from pmctl.core.config import load_machine
from pmctl.core.errors import PmctlError
from pmctl.task.job import load_job
try:
    job = load_job(sys.argv[1], load_machine())
except PmctlError as e:
    print(json.dumps({"ok": False, "line": getattr(e, "line", None), "message": getattr(e, "reason", str(e))}))
    sys.exit(1)
print(json.dumps({"ok": True, "moves": len(job)}))
"""
# today's reader refusals that are about the machine or the job's size, not about the language
READER_MACHINE = ("unreachable", "beyond the machine", "theta2 limit", "moves; the limit", "limit of")


def pmctl_exe() -> str:
    here = Path(sys.executable).with_name("pmctl")
    return str(here) if here.exists() else (shutil.which("pmctl") or "pmctl")


def check_available(pmctl: str) -> bool:
    try:
        r = subprocess.run([pmctl, "check", "--help"], capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return r.returncode == 0


def run(cmd, cwd, timeout):
    """(exit code or None on timeout, stdout, stderr, seconds)."""
    t0 = time.monotonic()
    try:
        r = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout,
                           stdin=subprocess.DEVNULL, errors="replace")
        return r.returncode, r.stdout, r.stderr, time.monotonic() - t0
    except subprocess.TimeoutExpired as e:
        out = e.stdout.decode(errors="replace") if isinstance(e.stdout, bytes) else (e.stdout or "")
        return None, out, "", time.monotonic() - t0


def judge_reader(exit_code, stdout, stderr) -> dict:
    """The verdict on one run of READER, in the shape of ``cs.judge_check``."""
    if exit_code is None:
        return {"crash": "timeout", "ok": False, "understood": False, "problems": [], "summary": {}}
    if "Traceback (most recent call last)" in stderr or exit_code not in (0, 1):
        last = [ln for ln in stderr.strip().splitlines() if ln.strip()][-1:]
        return {"crash": f"exit {exit_code}: {last[0].strip() if last else ''}", "ok": False, "understood": False,
                "problems": [], "summary": {}}
    doc = json.loads(stdout)
    if doc["ok"]:
        return {"crash": None, "ok": True, "understood": True, "problems": [], "summary": {"moves": doc["moves"]}}
    msg = doc["message"]
    kind = "machine" if any(k in msg for k in READER_MACHINE) else "unsupported"
    return {"crash": None, "ok": False, "understood": kind == "machine", "summary": {},
            "problems": [{"file": "", "line": doc.get("line"), "column": None, "kind": kind, "message": msg}]}


def machine_it(pmctl, program: Path, timeout: float) -> tuple[bool, str]:
    code, out, err, secs = run([pmctl, "run", "--backend", "sim", "--no-realtime", "--state", "", "--job",
                                str(program)], program.parent, timeout)
    if code is None:
        return False, f"not done: still running after {timeout:.0f} s"
    result = next((ln.split(":", 1)[1].strip() for ln in out.splitlines() if ln.strip().startswith("result:")), None)
    if code == 0 and result == "done":
        return True, f"done in {secs:.0f} s"
    lines = [ln.strip() for ln in (err + "\n" + out).splitlines() if ln.strip()]
    why = [ln for ln in lines if ln.startswith(("pmctl: error", "pmctl rt: stopped", "reason:", "Traceback"))]
    last = why[-1:] or [ln for ln in lines if "resource_tracker" not in ln and "warnings.warn" not in ln][-1:]
    return False, f"not done: exit {code}, result {result}: {last[0] if last else ''}"[:240]


def rs274_verdicts(files, live: bool) -> dict[str, dict]:
    if not live:
        fx = json.loads(cs.RS274_JSON.read_text())["files"]
        return {f: fx.get(f) for f in files}
    if not cs.rs274_available():
        sys.exit("corpus_table: rs274 is not installed (Debian: linuxcnc-uspace; run tests/peers/install)")
    with tempfile.TemporaryDirectory(prefix="pmctl-corpus-rs274-") as tmp:
        return {f: cs.run_rs274(cs.materialise(f, Path(tmp))) for f in files}


def pct(n, d):
    return f"{n} of {d} ({100.0 * n / d:.0f} %)" if d else "0 of 0"


def words_table(files):
    use = Counter()
    for f in files:
        use.update(cs.program_words(cs.program_bytes(f).decode("utf-8", "replace")))
    print(f"files using each word ({len(files)} files; G/M codes by value, other letters as words):")
    for w, n in sorted(use.items(), key=lambda kv: (-kv[1], kv[0])):
        print(f"  {w:12s} {n:3d}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="*", help="corpus files relative to tests/corpus/ (default: all)")
    ap.add_argument("--reader", action="store_true", help="today's job reader (load_job) instead of pmctl check")
    ap.add_argument("--run", action="store_true", help="machine the accepted programs on the sim")
    ap.add_argument("--words", action="store_true", help="only print how many files use each word")
    ap.add_argument("--rs274", choices=("fixture", "live"), default="fixture",
                    help="rs274's verdicts from tests/corpus/rs274.json (default) or run now")
    ap.add_argument("--timeout", type=float, default=600.0, help="seconds for one check (default 600)")
    ap.add_argument("--run-timeout", type=float, default=1800.0, help="seconds to machine one program (default 1800)")
    ap.add_argument("--json", type=Path, help="also write the per-file verdicts to this file")
    a = ap.parse_args(argv)
    files = a.files or cs.corpus_files()
    unknown = [f for f in files if f not in cs.corpus_files()]
    if unknown:
        sys.exit(f"corpus_table: not corpus files: {' '.join(unknown)}")
    if a.words:
        words_table(files)
        return 0
    pmctl = pmctl_exe()
    if not a.reader and not check_available(pmctl):
        print(f"pmctl check is not available: `{pmctl} check --help` fails (this pmctl has no check command); "
              "use --reader for today's job reader", file=sys.stderr)
        return 2
    rs = rs274_verdicts(files, a.rs274 == "live")
    what = "today's reader (load_job)" if a.reader else "pmctl check --json"
    print(f"{what} and rs274 on {len(files)} corpus files   (load average {os.getloadavg()[0]:.2f})")
    print(f"{'file':58s} {'pmctl':11s} {'probs':>5s}  {'rs274':5s}  first problem / rs274's first error")
    rows = {}
    with tempfile.TemporaryDirectory(prefix="pmctl-corpus-") as tmp:
        for f in files:
            prog = cs.materialise(f, Path(tmp))
            if a.reader:
                code, out, err, secs = run([sys.executable, "-c", READER, str(prog)], prog.parent, a.timeout)
                v = judge_reader(code, out, err)
            else:
                code, out, err, secs = run([pmctl, "check", str(prog), "--json"], prog.parent, a.timeout)
                v = cs.judge_check(code, out, err)
            v["seconds"] = round(secs, 2)
            r = rs.get(f) or {}
            if a.run and v["ok"]:
                v["done"], v["run"] = machine_it(pmctl, prog, a.run_timeout)
            rows[f] = v
            state = "CRASH" if v["crash"] else ("accepted" if v["ok"] else ("understood" if v["understood"] else "refused"))
            first = v["crash"] or (f"{v['problems'][0]['kind']}: {v['problems'][0]['message']}" if v["problems"] else "")
            rs_txt = "ok" if r.get("ok") else ("ERR" if r else "?")
            print(f"{f:58s} {state:11s} {len(v['problems']):5d}  {rs_txt:5s}  {first[:90]}"
                  + ("" if r.get("ok") or not r else f"  | rs274: {(r.get('error') or '')[:60]}"), flush=True)
            if "run" in v:
                print(f"{'':58s} run: {v['run']}", flush=True)
    n = len(files)
    und = sum(v["understood"] for v in rows.values())
    acc = sum(v["ok"] for v in rows.values())
    crashes = [f for f, v in rows.items() if v["crash"]]
    rs_ok = {f for f in files if (rs.get(f) or {}).get("ok")}
    print()
    print(f"files {n};  {what}:  understood {pct(und, n)},  accepted {pct(acc, n)},  crashes {len(crashes)}")
    print(f"rs274 accepted {pct(len(rs_ok), n)}")
    ours = {f for f, v in rows.items() if v["ok"]}
    print(f"accepted by both {len(ours & rs_ok)}, by pmctl only {len(ours - rs_ok)}, by rs274 only {len(rs_ok - ours)}")
    for f in crashes:
        print(f"  crash: {f}: {rows[f]['crash']}")
    kinds_files, kinds_count, msgs = Counter(), Counter(), Counter()
    per_file = []
    for v in rows.values():
        kinds_files.update({p["kind"] for p in v["problems"]})
        kinds_count.update(p["kind"] for p in v["problems"])
        msgs.update({cs.message_pattern(p["message"]) for p in v["problems"]})
        if v["problems"]:
            per_file.append(len({cs.message_pattern(p["message"]) for p in v["problems"]}))
    if kinds_files:
        print("problem kinds (files affected / problems): "
              + ", ".join(f"{k} {kinds_files[k]}/{kinds_count[k]}" for k in cs.CHECK_KINDS if kinds_files[k]))
        per_file.sort()
        print(f"distinct messages per refused file: median {per_file[len(per_file) // 2]}, max {per_file[-1]}")
        print("most frequent messages (files):")
        for m, c in msgs.most_common(20):
            print(f"  {c:3d}  {m[:130]}")
    if a.run:
        ran = {f: v for f, v in rows.items() if "done" in v}
        done = [f for f, v in ran.items() if v["done"]]
        print(f"machined on the sim: done {len(done)} of {len(ran)} accepted")
        for f, v in ran.items():
            if not v["done"]:
                print(f"  {f}: {v['run']}")
    if a.json:
        a.json.write_text(json.dumps({"what": what, "files": rows}, indent=1, sort_keys=True) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
