"""`[daq] k_theta_source = "daq"` with K_theta on is refused when the DAQ samples slower than twice the
chain mode K_theta damps (Nyquist): by the Supervisor as it sets up the NC, so `pmctl serve` refuses it
as `pmctl run` does, before anything starts (no device simulator, no rt process, no state file or
journal, no console link, no recording). The shipped [daq] polls every 20 ms: 50 Hz, the prototype's
chain mode is 246.6 Hz, so the DAQ would have to sample faster than 493 Hz."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from pmctl.core.config import load_machine
from pmctl.core.errors import ConfigError
from pmctl.hal.modbus_daq import chain_mode_hz

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
PMCTL = [sys.executable, "-m", "pmctl.interfaces.cli"]
SHIPPED = ROOT / "config" / "service.toml"


def _daq_source_service(tmp_path, k_theta='"auto"'):
    """The shipped service config (K_theta auto) with the DAQ named as K_theta's strain source."""
    text = SHIPPED.read_text()
    assert 'k_theta_source = "backend"' in text and 'k_theta_per_s = "auto"' in text
    text = text.replace('k_theta_source = "backend"', 'k_theta_source = "daq"')
    text = text.replace('k_theta_per_s = "auto"', f"k_theta_per_s = {k_theta}")
    p = tmp_path / "service.toml"
    p.write_text(text)
    return p


def _says_too_slow(msg: str, service: Path):
    f = chain_mode_hz(load_machine("prototype"))
    assert 246 < f < 247            # sqrt(k / (m / 3)) / 2 pi of the prototype: 20 N/um, 25 kg
    assert f"{service}: daq: k_theta_source:" in msg, msg
    assert "50 Hz (poll_ms = 20)" in msg and f"{f:.0f} Hz" in msg and f"{2 * f:.0f} Hz" in msg, msg


def test_supervisor_refuses_a_daq_too_slow_for_k_theta(tmp_path):
    from pmctl.task.supervisor import Supervisor
    svc = _daq_source_service(tmp_path)
    with pytest.raises(ConfigError) as e:
        Supervisor("prototype", service=str(svc), backend="sim", state_file="")
    assert e.value.key == "k_theta_source"
    _says_too_slow(str(e.value), svc)
    # K_theta off (the config's or a run's override): nothing to damp, nothing refused
    Supervisor("prototype", service=str(svc), backend="sim", state_file="", nc={"k_theta_per_s": [0.0] * 3})
    Supervisor("prototype", service=str(_daq_source_service(tmp_path, "0.0")), backend="sim", state_file="")
    # the backend's strain (the shipped source): accepted whatever the DAQ's rate
    Supervisor("prototype", service=str(SHIPPED), backend="sim", state_file="")


@pytest.mark.parametrize("backend", ["sim", "canopen"])
def test_serve_refuses_a_daq_too_slow_for_k_theta_before_anything_starts(tmp_path, backend):
    svc = _daq_source_service(tmp_path)
    state = tmp_path / "state.json"
    state.write_text('{"keep": "me"}')
    r = subprocess.run([*PMCTL, "serve", "--service", str(svc), "--backend", backend, "--state", str(state),
                        "--console", f"pty:{tmp_path}/tty", "--record", str(tmp_path / "rec")],
                       capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert r.returncode == 1, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    _says_too_slow(lines[0], svc)
    assert "rt motion process" not in r.stderr
    assert state.read_text() == '{"keep": "me"}'
    assert not (tmp_path / "state.json.journal").exists() and not (tmp_path / "state.json.lock").exists()
    assert not (tmp_path / "tty").is_symlink() and not (tmp_path / "rec").exists()


@pytest.mark.parametrize("backend", ["sim", "canopen"])
def test_run_refuses_a_daq_too_slow_for_k_theta_before_anything_starts(tmp_path, backend):
    """canopen too: its drives carry no strain, so the run switches K_theta off, but the config asks for
    K_theta fed by a DAQ that cannot, and serve refuses the same config."""
    svc = _daq_source_service(tmp_path)
    state = tmp_path / "state.json"
    r = subprocess.run([*PMCTL, "run", "--service", str(svc), "--backend", backend, "--state", str(state),
                        "--job", str(ROOT / "examples" / "jobs" / "cone.ngc"), "--record", str(tmp_path / "rec")],
                       capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert r.returncode == 1, r.stdout + r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    _says_too_slow(lines[0], svc)
    assert "result:" not in r.stdout and "rt motion process" not in r.stderr
    assert not state.exists() and not (tmp_path / "state.json.lock").exists() and not (tmp_path / "rec").exists()


@pytest.mark.parametrize("backend", ["sim", "canopen"])
def test_k_theta_runs_only_where_the_backend_carries_strain_in_its_cyclic_data(backend):
    """The canopen drives carry no strain gauges: K_theta is off for pmctl serve as for pmctl run (the
    Supervisor resolves it once, and the rt process gets the resolved settings as data: the same gains). The sim plant's gauges are in
    its cyclic data: on."""
    import numpy as np

    from pmctl.motion.settings import Settings
    from pmctl.task.supervisor import Supervisor
    from pmctl.core.strain_loop import design_k_theta
    sup = Supervisor("prototype", service=str(SHIPPED), backend=backend, state_file="")
    f = chain_mode_hz(sup.machine)                  # the shipped sim plant's 246.6 Hz, K_theta "auto"
    want = np.zeros(3) if backend == "canopen" else np.full(3, design_k_theta(f, 0.02, 400.0, sup.dt).k_theta)
    assert backend == "canopen" or want[0] > 0
    assert np.array_equal(sup.params.k_theta, want)
    off = [n for n in sup.nc_setup.notes if n.startswith("K_theta off")]
    assert off == (["K_theta off: backend canopen carries no strain gauges in its cyclic data"]
                   if backend == "canopen" else [])
    rt = Settings.from_bytes(sup.settings.to_bytes())        # what the rt process reads from its spawn pipe
    assert np.array_equal(rt.params.k_theta, want) and rt.backend == backend
