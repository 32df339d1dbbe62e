"""pmctl's RS-274 interpreter beside LinuxCNC's rs274 on real programs: understood, accepted, and the motion
compared where both run them.

    .venv/bin/python benchmarks/rs274_compare.py [PATH ...] [--tools N] [--problems]

PATH: program files or folders (searched for .ngc .nc .gcode .tap .cnc, gzipped ones too; default:
LinuxCNC's sample programs installed with rs274, /usr/share/linuxcnc/ncfiles). For every file:

- rs274 (tests/rs274_oracle.py): accepted or its error; the tool table holds tools 0..--tools (default 100)
  with length 0 and a 0.01 mm diameter, so no program fails for a tool it names;
- pmctl (``pmctl.task.rs274.interpret`` from W's origin as rs274 starts from machine 0, G28/G30 there too,
  with the bundled [interpreter] settings and the same tool table, the file's folder on the subroutine
  path): *understood* = no ``syntax`` or
  ``unsupported`` problem, *accepted* = no problem at all (the planner's machine checks are not run here:
  that is ``pmctl check``);
- where both accept: the motion compared (end points, arc centres, normals and sweeps, feeds, dwells,
  tool offsets) within what rs274 prints; the count of motions compared and the largest deviation of an
  end point or centre in mm (G20 programs: rs274 prints 0.0001 in, so up to 1.3e-3 mm is its rounding).

Prints a line per file and the totals. Not a test: files and their verdicts vary with what is installed.
"""

import argparse
import collections
import gzip
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import rs274_oracle as O  # noqa: E402

from pmctl.motion.service_config import InterpreterConfig  # noqa: E402
from pmctl.task.rs274 import interpret, make_config  # noqa: E402
from pmctl.task.rs274.tools import Tool, ToolTable  # noqa: E402

SUFFIXES = (".ngc", ".nc", ".gcode", ".tap", ".cnc")
G20 = re.compile(r"[gG]\s*0*20(?![0-9.])")
SPLINE = re.compile(r"[gG]\s*0*5\s*(\.\s*1)?(?![0-9.])")


def programs(paths):
    for p in map(Path, paths):
        if p.is_dir():
            for f in sorted(p.rglob("*")):
                name = f.name[:-3] if f.name.endswith(".gz") else f.name
                if f.is_file() and name.lower().endswith(SUFFIXES):
                    yield f
        elif p.is_file():
            yield p


def read(f):
    if f.name.endswith(".gz"):
        return gzip.open(f, "rt", errors="replace").read()
    return f.read_text(errors="replace")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("paths", nargs="*", default=["/usr/share/linuxcnc/ncfiles"])
    ap.add_argument("--tools", type=int, default=100, help="tools 0..N in both tool tables")
    ap.add_argument("--problems", action="store_true", help="print each file's first problems")
    a = ap.parse_args()
    tools = [(n, 0.0, 0.01) for n in range(a.tools + 1)]
    table = ToolTable([Tool(n, n, length, d) for n, length, d in tools], "the benchmark's table")
    origin = ((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    tot = collections.Counter()
    worst_by = {False: 0.0, True: 0.0}      # largest deviation (mm) in mm programs, in programs with G20
    kinds = collections.Counter()
    for f in programs(a.paths):
        text = read(f)
        try:
            res = O.run(text, tools, timeout=120)
        except Exception as e:                      # noqa: BLE001  (a timeout: counted as refused)
            res = O.Result(False, f"rs274 did not finish: {e}")
        cfg = make_config(InterpreterConfig(subroutine_path=(str(f.parent),)), tools=table, home=origin)
        try:
            job, problems = interpret(text, str(f), cfg=cfg, start=origin)
        except Exception as e:                      # noqa: BLE001
            tot["crash"] += 1
            print(f"CRASH {f}: {type(e).__name__}: {e}")
            continue
        ks = {p.kind for p in problems}
        understood = not ({"syntax", "unsupported"} & ks)
        tot["files"] += 1
        tot["understood"] += understood
        tot["accepted"] += not problems
        tot["rs274"] += res.ok
        tot["both understood"] += understood and res.ok
        for p in problems:
            kinds[p.kind] += 1
        cmp = ""
        if res.ok and not problems:
            mine = O.pmctl_motions(job)
            splines = {k + 1 for k, ln in enumerate(text.splitlines()) if SPLINE.search(ln.split(";")[0])}
            if splines:     # rs274 prints NURBS_FEED without its points: compare every other motion
                lines = [m.line for m in job.moves if m.kind != "event"]
                mine = [m for m, ln in zip(mine, lines) if ln not in splines]
            diffs, n, worst = O.compare(mine, res.motions)
            note = ""
            if diffs:
                # micro-segments below rs274's printed resolution (4 decimals) print as repeated points,
                # which the plain comparison drops as zero-length moves: match the ends in order instead
                tol = 2e-4 * (25.4 if G20.search(text) else 1.0)
                diffs, n, merged = O.compare_merged(mine, res.motions, tol)
                worst = 0.0
                note = ", matched end by end (points closer than rs274 prints)"
            tot["compared programs"] += 1
            tot["motions compared"] += n
            tot["agree"] += not diffs
            if not diffs:
                inch = any(m.unit != 1.0 for m in res.motions)
                worst_by[inch] = max(worst_by[inch], worst)
            cmp = f"{'same motion' if not diffs else 'DIFFERENT'} ({n} motions, {worst:.1e} mm{note})"
        verdict = ("understood" if understood else "not understood") + (", accepted" if not problems else "")
        print(f"{str(f):70s} rs274 {'ok ' if res.ok else 'err'} | pmctl {verdict:26s} {','.join(sorted(ks)):24s} {cmp}")
        if a.problems:
            if not res.ok:
                print(f"      rs274: {res.error.splitlines()[0] if res.error else '(no message)'}"[:180])
            for p in problems[:3]:
                print(f"      pmctl: {p.line}: {p.kind}: {p.message}"[:180])
    print()
    print(f"files {tot['files']}: pmctl understood {tot['understood']}, accepted {tot['accepted']}; rs274 accepted "
          f"{tot['rs274']} (both {tot['both understood']}); crashes {tot['crash']}")
    print(f"both accept {tot['compared programs']} programs: same motion in {tot['agree']}, {tot['motions compared']} "
          f"motions compared; largest deviation where they agree: {worst_by[False]:.1e} mm in mm programs, "
          f"{worst_by[True]:.1e} mm in G20 programs (rs274 prints 4 decimals of the unit)")
    print("problems by kind:", dict(kinds))


if __name__ == "__main__":
    main()
