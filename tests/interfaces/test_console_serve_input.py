"""`pmctl serve` refuses bad flags as `pmctl run` does: one line naming the flag or file, exit 1,
before anything starts (no rt process, no console link, the state file untouched)."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("flags, says", [
    (["--backend", "nope"], "--backend 'nope': unknown backend"),
    (["--record", "{tmp}/afile"], "{tmp}/afile: exists and is not a folder"),
    (["--record", "{tmp}/rec"], "{tmp}/rec: a recording is already there; choose another name"),
    (["--record", "{tmp}/killed"], "{tmp}/killed: {tmp}/killed.partial exists (a killed run or session left it"),
    (["--console", "ptyy:{tmp}/tty"], "--console ptyy:{tmp}/tty: no such device"),
    (["--console", "pty:{tmp}/missing/tty"], "--console pty:{tmp}/missing/tty: the folder {tmp}/missing does not exist"),
    (["--socket", "{tmp}/missing/sock"], "--socket {tmp}/missing/sock: the folder {tmp}/missing does not exist"),
])
def test_bad_flags_are_refused_before_anything_starts(tmp_path, flags, says):
    (tmp_path / "afile").write_text("not a recording\n")
    shutil.copytree(ROOT / "examples" / "recordings" / "backlash-circle" / "recording", tmp_path / "rec")
    shutil.copytree(tmp_path / "rec", tmp_path / "killed.partial")      # what a killed session leaves
    state = tmp_path / "state.json"
    state.write_text('{"keep": "me"}')
    flags = [f.format(tmp=tmp_path) for f in flags]
    if "--console" not in flags:
        flags += ["--console", f"pty:{tmp_path}/tty"]
    r = subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", "serve", "--no-realtime", "--state", str(state),
                        *flags], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert r.returncode == 1, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and says.format(tmp=tmp_path) in lines[0], r.stderr
    assert "--force" not in r.stderr          # pmctl run's flag; serve has none and never replaces one
    assert state.read_text() == '{"keep": "me"}' and not (tmp_path / "state.json.journal").exists()
    assert not (tmp_path / "tty").is_symlink() and not (tmp_path / "missing").exists()
