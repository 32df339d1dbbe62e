"""The command line explains itself without loading the numerical stack, and points only inside
the repository. (How fast `pmctl --help` is, is measured by a benchmark, not asserted here.)"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path
import pytest

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
HEAVY = ("numpy", "scipy", "matplotlib")
# Names of notes and folders that exist only outside the repository.
OUTSIDE = ("../shared", "MACHINE.md", "RECORDING.md", "DAEMON.md", "IO.md", "/work/")


def _all_help() -> str:
    """The help text of pmctl and of every subcommand, at every depth."""
    from pmctl.interfaces.cli import build_parser
    out = []

    def walk(p):
        out.append(p.format_help())
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                for sub in a.choices.values():
                    walk(sub)
    walk(build_parser())
    return "\n".join(out)


def test_building_every_parser_imports_no_numerical_module():
    code = ("import sys\n"
            "from pmctl.interfaces.cli import build_parser\n"
            "p = build_parser()\n"
            "for argv in (['run', '--help'], ['twin', 'synth', '--help'], ['analyze', 'vf', '--help'],\n"
            "             ['kin', 'ik', '--help'], ['twin', 'diagnose', '--help']):\n"
            "    try:\n"
            "        p.parse_args(argv)\n"
            "    except SystemExit:\n"
            "        pass\n"
            f"print('LOADED=' + ','.join(m for m in {HEAVY!r} if m in sys.modules))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "usage: pmctl twin synth" in r.stdout          # the help texts were really built
    loaded = r.stdout.strip().splitlines()[-1]
    assert loaded == "LOADED=", f"building the parsers loaded {loaded}"


def test_every_subcommand_is_registered_and_runs_its_module_lazily():
    from pmctl.interfaces.cli import build_parser
    p = build_parser()
    args = p.parse_args(["analyze", "vf", "--out", "x"])
    assert getattr(args.func, "target", "") == "pmctl.tools.analysis.vibration:cmd_vf"
    args = p.parse_args(["twin", "synth", "out", "--force"])
    assert args.force and args.func.target == "pmctl.tools.twin.synth:_cmd"
    # the lazy target exists
    import importlib
    for argv in (["analyze", "io-ratio"], ["analyze", "drive"], ["analyze", "path-error"],
                 ["analyze", "compliance"], ["analyze", "vibration"], ["analyze", "vf"],
                 ["twin", "diagnose", "f"], ["twin", "synth", "o"]):
        f = p.parse_args(argv).func
        mod, _, name = f.target.partition(":")
        assert callable(getattr(importlib.import_module(mod), name)), f.target


def test_synth_arguments_all_have_help():
    from pmctl.interfaces.cli import build_parser
    p = build_parser()
    twin = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction)).choices["twin"]
    synth = next(a for a in twin._actions if isinstance(a, argparse._SubParsersAction)).choices["synth"]
    missing = [a.dest for a in synth._actions if not a.help]
    assert missing == []


def test_help_texts_point_only_inside_the_repository():
    text = _all_help()
    assert "docs/" in text
    for name in OUTSIDE:
        assert name not in text, name
    assert "seed 00" not in text


def test_no_tracked_file_points_outside_the_repository():
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True).stdout.split()
    if not files:                      # not a git checkout (e.g. an sdist): nothing to check
        return
    me = Path(__file__).name
    bad = []
    for f in files:
        p = ROOT / f
        if f.endswith(me) or not p.is_file() or p.suffix in (".png", ".csv"):
            continue
        try:
            text = p.read_text(encoding="utf-8")
        except (UnicodeDecodeError, OSError):
            continue
        for name in OUTSIDE[:5]:
            if name in text:
                bad.append(f"{f}: {name}")
    assert bad == []


def test_docs_index_and_readme_links_resolve():
    import re
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", page.read_text(encoding="utf-8")):
            if target.startswith(("http://", "https://")):
                continue
            assert (page.parent / target).exists(), f"{page.name} links to missing {target}"
