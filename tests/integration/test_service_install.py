"""What an integrator installs: `pmctl init-config` writes a commented, valid starting config for real
hardware (the chosen backend, no simulated device, the state under /var/lib/pmctl), refuses to
overwrite one, and `pmctl serve` runs on the written files (a dry run on the sim); the systemd unit,
installed as docs/service.md says (its /opt/pmctl/venv prefix and /etc/pmctl configs), passes
`systemd-analyze verify`, and its ExecStart reads /etc/pmctl/service.toml and machine.toml."""

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from grbl_sender import Sender, start_serve, stop_serve
from pmctl.core.config import load_machine
from pmctl.motion.service_config import load_service_config

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]


def pmctl(*args):
    return subprocess.run([sys.executable, "-m", "pmctl.interfaces.cli", *args], capture_output=True, text=True,
                          cwd=ROOT)


@pytest.mark.parametrize("backend", ["stepdir", "canopen"])
def test_init_config_writes_a_valid_config_for_real_hardware(tmp_path, backend):
    out = pmctl("init-config", "--backend", backend, str(tmp_path))
    assert out.returncode == 0, out.stderr
    svc = load_service_config(tmp_path / "service.toml")
    assert svc.backend == backend and svc.spindle is None and svc.daq is None
    assert svc.loop.state_file == "/var/lib/pmctl/counters.json"
    tables = svc.backend_tables
    assert tables["stepdir"]["port"] == "/dev/pmctl-bridge"
    assert tables["canopen"]["simulate"] is False and tables["canopen"]["channel"] == "can0"
    text = (tmp_path / "service.toml").read_text()
    assert text.startswith("# pmctl service config for backend " + backend)
    assert not re.search(r"^simulate\s*=\s*true", text, re.M)
    assert load_machine(tmp_path / "machine.toml").name == load_machine("prototype").name
    assert "PMCTL_CONSOLE=/dev/pmctl-console" in (tmp_path / "pmctl.env").read_text()
    again = pmctl("init-config", "--backend", backend, str(tmp_path))
    assert again.returncode == 1 and "--force" in again.stderr
    assert pmctl("init-config", "--backend", "sim", str(tmp_path)).returncode == 2


def test_serve_runs_on_the_written_configs(tmp_path):
    etc = tmp_path / "etc"
    etc.mkdir()
    assert pmctl("init-config", "--backend", "stepdir", str(etc)).returncode == 0
    p, link = start_serve(tmp_path, extra=("--service", str(etc / "service.toml"), "--config",
                                           str(etc / "machine.toml"), "--backend", "sim"))
    s = Sender(link)
    try:
        assert s.status()["state"] == "Idle"
        assert s.send("G21 G91 G1 X1 F600") == "ok" and s.send("G4 P0") == "ok"
    finally:
        s.close()
        assert stop_serve(p) == 0


def test_the_installed_unit_passes_systemd_analyze_verify(tmp_path):
    exe = shutil.which("systemd-analyze")
    assert exe, "systemd-analyze is missing: tests/peers/install installs it (tests/peers/systemd.apt)"
    unit = (ROOT / "systemd" / "pmctl.service").read_text()
    m = re.search(r"^ExecStart=(\S+) serve (.*)$", unit, re.M)
    assert m and m.group(1) == "/opt/pmctl/venv/bin/pmctl"
    assert "--service /etc/pmctl/service.toml" in m.group(2) and "--config /etc/pmctl/machine.toml" in m.group(2)
    assert "--backend" not in m.group(2)                  # the backend is the service config's
    # installed: the venv at its prefix (here the test's), the configs in /etc/pmctl (here tmp)
    etc = tmp_path / "etc-pmctl"
    etc.mkdir()
    assert pmctl("init-config", "--backend", "canopen", str(etc)).returncode == 0
    installed = unit.replace("/opt/pmctl/venv", sys.prefix).replace("/etc/pmctl", str(etc))
    path = tmp_path / "pmctl.service"
    path.write_text(installed)
    out = subprocess.run([exe, "verify", str(path)], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "pmctl.service" not in out.stderr, out.stderr
