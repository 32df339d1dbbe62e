"""The import contract (pyproject.toml, [tool.importlinter]; docs/architecture.md): pmctl's layers,
core < hal < motion < task < tools < interfaces, import only downward, and no two of pmctl's modules
import each other, directly or round a cycle. `lint-imports` (import-linter) reads every import
statement, the ones inside functions included; a broken contract fails here with its report."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
LINT = Path(sys.executable).with_name("lint-imports")


def lint(cwd: Path, src: Path) -> subprocess.CompletedProcess:
    """lint-imports on the package under ``src`` with the contract of ``cwd``/pyproject.toml
    (no cache: a stale graph would hide a new import)."""
    env = dict(os.environ, PYTHONPATH=str(src))
    return subprocess.run([str(LINT), "--no-cache"], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=300)


def test_pmctl_keeps_its_import_contract():
    assert LINT.exists(), f"{LINT} missing: install the test extra (pip install -e '.[test]')"
    r = lint(ROOT, ROOT / "src")
    assert r.returncode == 0, f"the import contract is broken:\n{r.stdout}\n{r.stderr}"
    assert "Contracts: 2 kept, 0 broken." in r.stdout


@pytest.fixture
def copy_of_pmctl(tmp_path):
    """The package's Python sources and the contract, copied where a test may break them."""
    shutil.copytree(ROOT / "src" / "pmctl", tmp_path / "src" / "pmctl",
                    ignore=shutil.ignore_patterns("__pycache__", "*.so", "*.c", "*.h", "config", "data"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    return tmp_path


UPWARD = {"core/alarms.py": "def _planted():\n    from pmctl.interfaces import cli\n    return cli\n"}
CYCLE = {"core/alarms.py": "from pmctl.core.errors import PmctlError  # noqa: E402,F401\n",
         "core/errors.py": "def _planted():\n    from pmctl.core import alarms\n    return alarms\n"}


@pytest.mark.parametrize("planted, broken", [
    (UPWARD, "pmctl.core.alarms -> pmctl.interfaces.cli"),       # core may not import interfaces
    (CYCLE, "No cycles are allowed in pmctl.core"),                # errors <-> alarms
], ids=["upward", "cycle"])
def test_the_contract_catches_an_import_inside_a_function(copy_of_pmctl, planted, broken):
    for module, text in planted.items():
        f = copy_of_pmctl / "src" / "pmctl" / module
        f.write_text(f.read_text() + "\n\n" + text)
    r = lint(copy_of_pmctl, copy_of_pmctl / "src")
    assert r.returncode != 0 and broken in r.stdout, r.stdout + r.stderr
