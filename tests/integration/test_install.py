"""pmctl after a normal (non-editable) install, as a service runs it: built from a copy of the source
tree and installed into a folder of its own, then used from a folder outside the repository. The
default configs, the drive EDS and the compiled parts come from the installed package, and a job
runs to its end."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
import pytest

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
SKIP = shutil.ignore_patterns(".git", ".venv", "build", "*.egg-info", "__pycache__", "*.so", "runs", "out",
                              ".hypothesis", ".pytest_cache")


def test_a_non_editable_install_finds_its_configs_and_runs_a_job(tmp_path):
    src, site, work = tmp_path / "src", tmp_path / "site", tmp_path / "work"
    src.mkdir()
    for name in ("pyproject.toml", "setup.py", "MANIFEST.in", "README.md"):
        shutil.copy(ROOT / name, src / name)
    shutil.copytree(ROOT / "src", src / "src", ignore=SKIP, symlinks=True)
    shutil.copytree(ROOT / "config", src / "config", ignore=SKIP)
    r = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(site), str(src)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    work.mkdir()
    (work / "job.ngc").write_text("G17 G21 G90 G94\nG1 X2 Y1 Z170 F600\nG4 P0.2\nM2\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    env["PYTHONPATH"] = str(site)
    check = ("import pmctl, json; from pmctl.core.config import CONFIG_DIR, load_machine; "
             "from pmctl.motion.service_config import load_service_config; "
             "import pmctl.motion.ncore._ncore, pmctl.hal._simplant, pmctl.motion._follow; "
             "from importlib.resources import files; "
             "print(json.dumps([pmctl.__file__, str(CONFIG_DIR), load_machine().name, "
             "load_service_config(None).loop.rate_hz, "
             "files('pmctl.hal').joinpath('data/cia402_drive.eds').is_file()]))")
    r = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, cwd=work, env=env, timeout=120)
    assert r.returncode == 0, r.stderr
    where, config_dir, machine, rate, eds = json.loads(r.stdout)
    assert Path(where).resolve().is_relative_to(site.resolve())          # the installed copy, not the repo's
    assert Path(config_dir).resolve().is_relative_to(site.resolve()) and (Path(config_dir) / "service.toml").is_file()
    assert machine == "prototype" and rate > 0 and eds
    r = subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", "run", "--backend", "sim", "--job", "job.ngc",
                        "--state", str(work / "state.json"), "--no-realtime", "--quiet"],
                       capture_output=True, text=True, cwd=work, env=env, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "result: done" in r.stdout and "pulses sent = pulse counters: yes" in r.stdout
    assert (work / "state.json").is_file()
