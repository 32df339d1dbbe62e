"""The corpus of real part programs (tests/corpus/) stays whole and its rs274 fixture stays true.

Cheap checks only (a few seconds): the full side-by-side measure is benchmarks/corpus_table.py.
- every stored program has a row in SOURCES.md and an entry in rs274.json, and nothing else does;
- the fixture and SOURCES.md describe these very bytes (SHA-256, size), and a gzipped file keeps its
  original name in the gzip header;
- rs274, run now on a few small files (accepted and refused ones), says what the fixture says;
- the helpers the benchmark judges ``pmctl check --json`` and counts words with do what they say.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys

import pytest
from hypothesis import given
from hypothesis import strategies as st

import corpus_support as cs

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

FIXTURE = json.loads(cs.RS274_JSON.read_text())
# small files covering: accepted with G93 and cutter compensation, O-word subs, % framing and G28.1;
# refused for a TCP M-code above 199, a P word on G83, a missing program end, an unknown M-code
LIVE = ["handwritten/inverse.ngc", "linuxcnc/comp.ngc", "linuxcnc/retval.ngc", "handwritten/g28.ngc",
        "linuxcnc/daisy.ngc", "multiaxis/xyzab-tdr-demo.ngc", "handwritten/G83.NC",
        "handwritten/helical-thread-milling.gcode", "handwritten/PROGRAM2.NC"]


def test_corpus_is_large_enough_and_of_the_kinds_the_issue_names():
    files = cs.corpus_files()
    assert len(files) >= 70
    kinds = {f.split("/")[0] for f in files}
    assert {"fusion360", "linuxcnc", "multiaxis", "handwritten", "3d", "vcarve", "cambam", "pycam"} <= kinds
    big = [f for f in files if 1_250_000 <= len(cs.program_bytes(f)) <= 1_700_000]
    assert len(big) >= 2, big


def test_every_file_is_listed_in_sources_and_in_the_fixture_and_nothing_else():
    files = set(cs.corpus_files())
    assert set(cs.sources_rows()) == files
    assert set(FIXTURE["files"]) == files


def test_sources_and_fixture_describe_these_bytes():
    rows = cs.sources_rows()
    for f in cs.corpus_files():
        data = cs.program_bytes(f)
        assert int(rows[f]["bytes"]) == len(data), f
        assert re.fullmatch(r"`[0-9a-f]{12}`", rows[f]["commit"]), f
        assert rows[f]["licence"] and rows[f]["repository"].count("/") == 1, f
        assert FIXTURE["files"][f]["sha256"] == cs.sha256(f), f
    assert FIXTURE["accepted"] == sum(r["ok"] for r in FIXTURE["files"].values())


def test_a_gzipped_file_keeps_its_original_name_inside():
    gz = [f for f in cs.corpus_files() if f.endswith(".gz")]
    assert gz
    for f in gz:
        raw = (cs.CORPUS / f).read_bytes()
        assert raw[:2] == b"\x1f\x8b" and raw[3] & 0x08, f          # gzip, with FNAME
        name = raw[10:raw.index(b"\0", 10)].decode()
        assert name == cs.original_name(f) == f.rsplit("/", 1)[1][:-3]
        # stored gzipped only because it is large
        assert len(cs.program_bytes(f)) > 200_000, f


def test_rs274_now_agrees_with_the_fixture(tmp_path):
    assert cs.rs274_available(), "rs274 is missing: run tests/peers/install (Debian package linuxcnc-uspace)"
    for f in LIVE:
        got = cs.run_rs274(cs.materialise(f, tmp_path))
        want = FIXTURE["files"][f]
        assert {k: got[k] for k in ("ok", "error", "line", "moves")} == \
               {k: want[k] for k in ("ok", "error", "line", "moves")}, f
    assert {FIXTURE["files"][f]["ok"] for f in LIVE} == {True, False}


def test_rs274_refusal_names_the_line_of_the_bad_block(tmp_path):
    assert cs.rs274_available(), "rs274 is missing: run tests/peers/install (Debian package linuxcnc-uspace)"
    prog = tmp_path / "k.ngc"
    prog.write_text("G21 G17\nG0 X0 Y0\nG1 X1 F100\nG2 X2 Y1 I1 J0 K0\nM2\n")
    r = cs.run_rs274(prog)
    assert not r["ok"] and r["exit"] == 1
    assert r["line"] == 4 and r["block"] == "G2 X2 Y1 I1 J0 K0"
    assert "K word" in r["error"]
    assert r["moves"] == 2      # the rapid and the feed before the refused arc


# ------------------------------------------------------------------ judging pmctl check --json
def _doc(ok, *kinds):
    return json.dumps({"ok": ok, "problems": [{"file": "p.ngc", "line": k + 1, "column": 1, "kind": kind,
                                               "message": f"problem {k}"} for k, kind in enumerate(kinds)],
                       "summary": {"moves": 3}})


def test_check_verdicts_follow_the_specification():
    v = cs.judge_check(0, _doc(True))
    assert (v["crash"], v["ok"], v["understood"], v["summary"]) == (None, True, True, {"moves": 3})
    v = cs.judge_check(1, _doc(False, "machine", "planning"))
    assert (v["crash"], v["ok"], v["understood"], len(v["problems"])) == (None, False, True, 2)
    for kind in ("syntax", "unsupported"):
        v = cs.judge_check(1, _doc(False, "machine", kind))
        assert (v["crash"], v["ok"], v["understood"]) == (None, False, False)


@pytest.mark.parametrize("code,out,err,why", [
    (None, "", "", "timeout"),
    (2, _doc(False, "syntax"), "", "exit code 2"),
    (1, _doc(False, "syntax"), "Traceback (most recent call last):\n  ...\nKeyError: 'x'", "traceback: KeyError"),
    (1, "not json", "", "not JSON"),
    (0, _doc(False, "machine"), "", "exit code 0 with ok=False"),
    (1, _doc(True), "", "exit code 1 with ok=True"),
    (1, json.dumps({"ok": False, "problems": [{"file": "p", "line": 1, "kind": "machine", "message": "m"}]}), "",
     "malformed problem"),
    (1, json.dumps({"ok": False, "problems": [{"file": "p", "line": 1, "column": None, "kind": "other",
                                               "message": "m"}]}), "", "malformed problem"),
    (1, json.dumps({"ok": "no", "problems": []}), "", "JSON is not"),
])
def test_anything_else_is_a_crash(code, out, err, why):
    v = cs.judge_check(code, out, err)
    assert v["crash"] and why in v["crash"]
    assert not v["ok"] and not v["understood"]


def test_table_says_clearly_when_pmctl_check_is_missing_or_judges_its_output():
    """The benchmark against today's pmctl: without a check command it says so and exits 2; with one it
    prints a verdict row for the file it was given."""
    script = cs.ROOT / "benchmarks" / "corpus_table.py"
    r = subprocess.run([sys.executable, str(script), "linuxcnc/comp.ngc"], capture_output=True, text=True,
                       timeout=300)
    if r.returncode == 2:
        assert "pmctl check is not available" in r.stderr
    else:
        assert r.returncode == 0, r.stderr
        assert "linuxcnc/comp.ngc" in r.stdout and "rs274 accepted 1 of 1" in r.stdout


# ------------------------------------------------------------------ words a program uses
def test_words_of_a_fanuc_style_program():
    text = "%\nO1003 (PART)\nN10 G00 G90 G54 X1. Y2.\n/M01\nT01 M06 ; tool\nG43 H01 Z5.\n" \
           "G41 D01 G01 X0 F100.\n#1 = [2 * 3]\nG91.1 (G77 in a comment)\nM30\n%\n"
    w = cs.program_words(text)
    assert {"%", "O-number", "N", "G0", "G90", "G54", "/", "M1", "T", "M6", "; comment", "G43", "H", "G41", "D",
            "G1", "#param", "[expr]", "G91.1", "M30"} <= w
    assert "G77" not in w and "O-word" not in w


@given(st.integers(0, 99), st.sampled_from(["", "0", "00"]), st.text("XYZABC(); ", max_size=12))
def test_a_code_counts_by_value_and_comments_never_count(n, pad, comment):
    comment = comment.replace("(", "").replace(")", "")
    w = cs.program_words(f"G{pad}{n} X1 ({comment} G{n + 100})\n")
    assert f"G{n}" in w and f"G{n + 100}" not in w


def test_message_patterns_fold_numbers_not_codes():
    assert cs.message_pattern("line 12: G18 arc at -3.5 mm, 'T5' missing") == "line N: G18 arc at N mm, '...' missing"
