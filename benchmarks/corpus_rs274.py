"""LinuxCNC's interpreter on the corpus of real part programs: writes tests/corpus/rs274.json.

    .venv/bin/python benchmarks/corpus_rs274.py            # run every corpus file, write the fixture
    .venv/bin/python benchmarks/corpus_rs274.py --check    # run them, compare with the fixture, write nothing

For every file of tests/corpus/ (gzipped ones are unpacked under their original name into a scratch
folder) it runs, in the program's folder,

    rs274 -t tests/corpus/rs274.tbl -g PROGRAM OUT < /dev/null

(rs274 from Debian's linuxcnc-uspace, its default configuration: no INI file, no parameter file, stop
at the first error; the tool table holds tools 1-100) and records whether rs274 accepts the program
(exit 0), its first error and the line of the block it names, and how many canonical calls and
motions it printed. Prints one line per file and the number accepted. Needs rs274
(tests/peers/install installs it).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import corpus_support as cs  # noqa: E402


def rs274_version() -> str:
    try:
        return subprocess.run(["dpkg-query", "-W", "-f=${Version}", "linuxcnc-uspace"], capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def run_all(files: list[str]) -> dict[str, dict]:
    results = {}
    with tempfile.TemporaryDirectory(prefix="pmctl-corpus-rs274-") as tmp:
        for rel in files:
            t0 = time.monotonic()
            r = cs.run_rs274(cs.materialise(rel, Path(tmp)))
            r = {"sha256": cs.sha256(rel), **r}
            results[rel] = r
            where = f" line {r['line']}" if r["line"] else ""
            print(f"{'ok ' if r['ok'] else 'ERR'} {rel:60s} {time.monotonic() - t0:6.2f} s  moves {r['moves']}"
                  + ("" if r["ok"] else f"  {r['error']}{where}"), flush=True)
    return results


def fixture(results: dict[str, dict]) -> dict:
    return {
        "about": "rs274 (LinuxCNC) on every corpus file; written by benchmarks/corpus_rs274.py",
        "command": cs.RS274_COMMAND.format(tbl="tests/corpus/rs274.tbl", program="PROGRAM", out="OUT"),
        "linuxcnc_uspace": rs274_version(),
        "tool_table": "tests/corpus/rs274.tbl",
        "accepted": sum(1 for r in results.values() if r["ok"]),
        "files": results,
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="compare with tests/corpus/rs274.json, write nothing")
    ap.add_argument("files", nargs="*", help="corpus files (relative to tests/corpus/); default: all")
    a = ap.parse_args(argv)
    if not cs.rs274_available():
        sys.exit("corpus_rs274: rs274 is not installed (Debian: linuxcnc-uspace; run tests/peers/install)")
    files = a.files or cs.corpus_files()
    results = run_all(files)
    print(f"rs274 accepts {sum(r['ok'] for r in results.values())} of {len(results)}")
    if a.check:
        old = json.loads(cs.RS274_JSON.read_text())["files"]
        keys = ("sha256", "ok", "error", "line", "moves")
        bad = [f for f in files if {k: old.get(f, {}).get(k) for k in keys} != {k: results[f][k] for k in keys}]
        for f in bad:
            print(f"differs from the fixture: {f}")
        sys.exit(1 if bad else 0)
    if a.files:
        sys.exit("corpus_rs274: the fixture is written from the whole corpus only (give no files, or --check)")
    cs.RS274_JSON.write_text(json.dumps(fixture(results), indent=1, sort_keys=True) + "\n")
    print(f"wrote {cs.RS274_JSON.relative_to(cs.ROOT)}")


if __name__ == "__main__":
    main()
