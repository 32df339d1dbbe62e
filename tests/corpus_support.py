"""The corpus of real part programs (tests/corpus/) and LinuxCNC's interpreter as its oracle, shared by
tests/integration/test_corpus.py (cheap checks), benchmarks/corpus_rs274.py (writes tests/corpus/rs274.json) and
benchmarks/corpus_table.py (the side-by-side measure with ``pmctl check``).

A corpus file is stored as found (``NAME.EXT``) or, above about 200 kB, gzipped (``NAME.EXT.gz``, the
gzip header keeps ``NAME.EXT``). ``materialise`` writes the original file, under its original name,
into a scratch folder: that is what rs274 and pmctl read. ``tests/corpus/SOURCES.md`` has one table row
per stored file (its path relative to tests/corpus/ in the first column); ``rs274.json`` has one entry
per stored file.

rs274 (Debian ``linuxcnc-uspace``) is run in its default configuration: no INI file, no parameter
file, batch mode, stop at the first error, with the corpus tool table ``tests/corpus/rs274.tbl``.
It prints its canonical machining calls to the output file, and on an error the message and the
offending block on stderr (no line number: ``run_rs274`` finds the block's line in the file).
"""

from __future__ import annotations

import gzip
import json
import hashlib
import re
import shutil
import subprocess
from pathlib import Path

import rs274_oracle                # the tests' one way to start rs274 (a lock: two at once crash)

ROOT = Path(__file__).resolve().parents[1]
CORPUS = ROOT / "tests" / "corpus"
SOURCES = CORPUS / "SOURCES.md"
RS274_JSON = CORPUS / "rs274.json"
TOOL_TABLE = CORPUS / "rs274.tbl"
PROGRAM_SUFFIXES = (".ngc", ".nc", ".gcode", ".tap", ".cnc", ".gc")
RS274_TIMEOUT_S = 120.0
# the exact command, as SOURCES.md documents it ({tbl}, {program}, {out} filled in by run_rs274)
RS274_COMMAND = "rs274 -t {tbl} -g {program} {out} < /dev/null"
MOTION_CALLS = ("STRAIGHT_TRAVERSE", "STRAIGHT_FEED", "ARC_FEED", "STRAIGHT_PROBE")


def corpus_files() -> list[str]:
    """Every stored program, as a path relative to tests/corpus/ (sorted)."""
    out = []
    for p in CORPUS.rglob("*"):
        if not p.is_file():
            continue
        name = p.name[:-3] if p.name.endswith(".gz") else p.name
        if Path(name).suffix.lower() in PROGRAM_SUFFIXES:
            out.append(p.relative_to(CORPUS).as_posix())
    return sorted(out)


def original_name(rel: str) -> str:
    """The program's own file name (without the storage's .gz)."""
    name = Path(rel).name
    return name[:-3] if name.endswith(".gz") else name


def program_bytes(rel: str) -> bytes:
    """The program as found in its repository (decompressed when stored gzipped)."""
    p = CORPUS / rel
    return gzip.decompress(p.read_bytes()) if rel.endswith(".gz") else p.read_bytes()


def sha256(rel: str) -> str:
    return hashlib.sha256(program_bytes(rel)).hexdigest()


def materialise(rel: str, folder: Path) -> Path:
    """Write the program under its original name into ``folder`` (a folder of its own per program, so
    two programs of the same name never meet) and return its path."""
    sub = Path(folder) / rel.replace("/", "__")
    sub.mkdir(parents=True, exist_ok=True)
    out = sub / original_name(rel)
    out.write_bytes(program_bytes(rel))
    return out


def sources_rows() -> dict[str, dict[str, str]]:
    """The table of SOURCES.md: {file: {column: value}} for every row whose first cell is a file."""
    rows: dict[str, dict[str, str]] = {}
    header: list[str] | None = None
    for line in SOURCES.read_text(encoding="utf-8").splitlines():
        if not line.startswith("|"):
            header = None if not line.strip() else header
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if header is None:
            header = [c.lower() for c in cells]
            continue
        if set("".join(cells)) <= set("-: "):
            continue
        name = cells[0].strip("`")
        if "/" in name and header and header[0] == "file":
            rows[name] = dict(zip(header, cells))
    return rows


def rs274_available() -> bool:
    return shutil.which("rs274") is not None


def _line_of(text: str, block: str | None, error: str | None) -> int | None:
    """1-based line of the block rs274 names (it echoes the failing block as read, without the line
    end): the file's last line for "File ended with no percent sign or program end", else the one line
    that is that block; None when no line or more than one line is that block."""
    lines = text.splitlines()
    if error and error.startswith("File ended"):
        return len(lines)
    want = (block or "").strip()
    hits = [k for k, line in enumerate(lines, start=1) if want and line.strip() == want]
    return hits[0] if len(hits) == 1 else None


def run_rs274(program: Path, *, tool_table: Path = TOOL_TABLE, timeout: float = RS274_TIMEOUT_S) -> dict:
    """Run rs274 on one program file (in the program's folder, so relative sub files resolve there).

    Returns {"ok", "exit", "error", "line", "block", "calls", "moves"}: ok when rs274 exited 0;
    ``error`` the first line of its message, ``block`` the block it names and ``line`` where that
    block is in the file; ``calls`` the canonical calls printed and ``moves`` those that move
    (traverse, feed, arc, probe). A run longer than ``timeout`` is not ok, with error "timeout"."""
    program = Path(program)
    out = program.with_name(program.name + ".canon")
    cmd = ["rs274", "-t", str(Path(tool_table).resolve()), "-g", program.name, out.name]
    try:                          # on the tests' rs274 lock, again after a SIGBUS (rs274_oracle.invoke)
        r = rs274_oracle.invoke(cmd, cwd=program.parent, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"ok": False, "exit": None, "error": "timeout", "line": None, "block": None,
                "calls": None, "moves": None}
    canon = out.read_text(errors="replace").splitlines() if out.exists() else []
    calls = sum(1 for c in canon if re.match(r"\s*\d+ N", c))
    moves = sum(1 for c in canon if any(m + "(" in c for m in MOTION_CALLS))
    err_lines = [ln for ln in r.stderr.decode(errors="replace").splitlines()
                 if ln.strip() and ln.strip() != "executing"]
    error = err_lines[0].strip() if err_lines else None
    block = err_lines[1].rstrip() if len(err_lines) > 1 else None
    line = _line_of(program.read_text(errors="replace"), block, error)
    ok = r.returncode == 0
    return {"ok": ok, "exit": r.returncode, "error": None if ok else (error or f"exit {r.returncode}"),
            "line": None if ok else line, "block": None if ok else block, "calls": calls, "moves": moves}


# ------------------------------------------------------------------ what a program contains
_COMMENT = re.compile(r"\([^)]*\)?")
_CODE = re.compile(r"([GM])\s*([-+]?\d+(?:\.\d*)?)")
_WORD = re.compile(r"([A-Z])\s*(?=[-+.\d#\[])")


def _code(letter: str, number: str) -> str:
    v = float(number)
    return f"{letter}{int(v)}" if v == int(v) else f"{letter}{v:g}"


def program_words(text: str) -> set[str]:
    """The features one program uses: G and M codes by value (G01 and G1 are both ``G1``), the other
    word letters (``T``, ``H``, ``A``, ...), and ``%`` (a percent line), ``/`` (block delete), ``O-word``
    (O sub/call/if/while/...), ``O-number`` (a Fanuc program number ``O1003``), ``#param``,
    ``[expr]``, ``; comment``, ``(MSG,)``, ``(DEBUG,)``, ``(PRINT,)``, ``$grbl`` (a grbl system line) and
    ``@^ polar``. Comments are not scanned for words."""
    found: set[str] = set()
    for raw in text.splitlines():
        line = raw.strip()
        up = line.upper()
        for tag in ("(MSG,", "(DEBUG,", "(PRINT,"):
            if tag in up.replace(" ", ""):
                found.add(tag + ")")
        if line.startswith("%"):
            found.add("%")
            continue
        if line.startswith("$"):
            found.add("$grbl")
            continue
        if line.startswith("/"):
            found.add("/")
            up = up[1:]
        body = _COMMENT.sub(" ", up)
        if ";" in body:
            found.add("; comment")
            body = body.split(";", 1)[0]
        body = re.sub(r"^N\s*\d+", " N ", body.strip())
        if body.startswith(" N "):
            found.add("N")
        m = re.match(r"\s*O\s*(<[^>]*>|\d+)\s*([A-Z]*)", body)
        if m:
            found.add("O-word" if m.group(2) else "O-number")
            body = body[m.end():]
        if "#" in body:
            found.add("#param")
        if "[" in body:
            found.add("[expr]")
        if "@" in body or "^" in body:
            found.add("@^ polar")
        body = re.sub(r"#<[^>]*>", "#1", body)
        body = re.sub(r"\[[^\]]*\]", "0", body)
        for letter, number in _CODE.findall(body):
            found.add(_code(letter, number))
        for letter in _WORD.findall(re.sub(r"[GM]\s*[-+]?\d+(?:\.\d*)?", " ", body)):
            if letter not in "GMN":
                found.add(letter)
    return found


# ------------------------------------------------------------------ pmctl check --json, as specified
CHECK_KINDS = ("syntax", "unsupported", "machine", "planning")
PROBLEM_FIELDS = ("file", "line", "column", "kind", "message")


def judge_check(exit_code: int | None, stdout: str, stderr: str = "") -> dict:
    """The verdict on one ``pmctl check FILE --json`` run, by its specification: it prints
    ``{"ok": bool, "problems": [{"file", "line", "column", "kind", "message"}], "summary": {...}}`` and
    exits 0 when the job can run, 1 when it cannot. A program is *understood* when no problem is of
    kind syntax or unsupported, *accepted* when ok.

    Returns {"crash": reason or None, "ok", "understood", "problems", "summary"}. A crash is a
    traceback on stderr, an exit code other than 0 or 1 (or none: a timeout), output that is not that
    JSON, or an exit code that contradicts ``ok``; then ok and understood are False."""
    def crash(reason):
        return {"crash": reason, "ok": False, "understood": False, "problems": [], "summary": {}}

    if exit_code is None:
        return crash("timeout")
    if "Traceback (most recent call last)" in stderr:
        last = [ln for ln in stderr.strip().splitlines() if ln.strip()][-1:]
        return crash("traceback: " + (last[0].strip() if last else "?"))
    if exit_code not in (0, 1):
        return crash(f"exit code {exit_code}")
    try:
        doc = json.loads(stdout)
    except ValueError:
        return crash("output is not JSON")
    if not isinstance(doc, dict) or not isinstance(doc.get("ok"), bool) or not isinstance(doc.get("problems"), list) \
            or not isinstance(doc.get("summary", {}), dict):
        return crash("JSON is not {ok: bool, problems: [...], summary: {...}}")
    problems = doc["problems"]
    for p in problems:
        if not isinstance(p, dict) or any(k not in p for k in PROBLEM_FIELDS) or p["kind"] not in CHECK_KINDS \
                or not isinstance(p["message"], str):
            return crash(f"malformed problem {p!r}"[:200])
    if doc["ok"] != (exit_code == 0):
        return crash(f"exit code {exit_code} with ok={doc['ok']}")
    if doc["ok"] and problems and any(p["kind"] in ("syntax", "unsupported") for p in problems):
        return crash("ok with a syntax or unsupported problem")
    understood = not any(p["kind"] in ("syntax", "unsupported") for p in problems)
    return {"crash": None, "ok": doc["ok"], "understood": understood, "problems": problems,
            "summary": doc.get("summary", {})}


def message_pattern(message: str) -> str:
    """A problem message with its numbers and quoted values replaced by N and '...', so that the same
    refusal on different lines or values counts as one message."""
    s = re.sub(r"'[^']*'|\"[^\"]*\"", "'...'", message)
    return re.sub(r"(?<![A-Za-z_\d.])[-+]?\d+(?:\.\d+)?", "N", s)
