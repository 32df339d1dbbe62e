"""Settings resolved once (pmctl.motion.settings): what the supervisor resolves is what the rt process
runs, bit for bit, and the run-specific adjustments (a bridge's step rate, an offline run's simulated
devices) are made there, once."""

import ast
import tomllib
from pathlib import Path

import numpy as np
import pytest

from pmctl.core.config import CONFIG_DIR
from pmctl.motion.settings import OFFLINE_SIM_TIMEOUT_MS, Settings, resolve

# starts pmctl, its rt process or a peer in a child process, or runs the loop in real time
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]


def _same_params(a, b):
    for k, v in vars(a).items():
        if k.startswith("_"):
            continue                                     # caches derived from the fields (__post_init__)
        w = getattr(b, k)
        if isinstance(v, np.ndarray) or isinstance(w, np.ndarray):
            assert np.array_equal(np.asarray(v), np.asarray(w)), k
        else:
            assert v == w or (v != v and w != w), k


@pytest.mark.parametrize("backend", ["sim", "canopen", "stepdir"])
def test_the_rt_process_gets_the_supervisors_settings_bit_for_bit(backend):
    s = resolve("prototype", None, backend=backend, realtime=True,
                nc={"k_theta_per_s": (123.0,) * 3, "k_theta_auto": False})
    r = Settings.from_bytes(s.to_bytes())                # the spawn pipe
    assert r.backend == backend and r.rate_hz == s.rate_hz and r.machine.name == s.machine.name
    _same_params(s.params, r.params)
    want = 0.0 if backend == "canopen" else 123.0       # the drives carry no strain: K_theta off
    assert np.all(r.params.k_theta == want) and r.realtime and not r.offline
    with pytest.raises(TypeError):
        Settings.from_bytes(__import__("pickle").dumps({"not": "settings"}))


def test_the_rt_process_reads_no_config_file():
    """The rt process's module loads neither the machine nor the service config (they come as data)."""
    tree = ast.parse((ROOT / "src/pmctl/motion/rtproc.py").read_text())
    names = {a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names}
    assert not names & {"load_machine", "load_service_config", "resolve"}, names & {"load_machine", "load_service_config"}


def test_a_bridge_caps_the_joint_speeds_to_the_step_rate_it_holds():
    emu = resolve(backend="stepdir", hal={"stepdir": {"port": "rp2040-emu"}}, offline=True)
    assert np.allclose(emu.params.vmax, 10.0)                     # 20 kstep/s / 2000 pulse/mm
    assert any("joint speeds capped at 10 mm/s" in n for n in emu.setup.notes)
    assert not any("V-F converters limit" in n for n in emu.setup.notes)     # multi-pulse V-F: 100 mm/s
    fast = resolve(backend="stepdir", hal={"stepdir": {"max_step_rate_hz": 50_000}})
    assert np.allclose(fast.params.vmax, 25.0)
    host = resolve(backend="stepdir")                                  # the host build: no cap
    assert np.allclose(host.params.vmax, 100.0) and not any("capped" in n for n in host.setup.notes)
    assert np.allclose(resolve(backend="sim", hal={"stepdir": {"port": "rp2040-emu"}}).params.vmax, 100.0)


def test_an_offline_or_unprioritised_run_gives_simulated_devices_time_and_real_ones_keep_theirs(tmp_path):
    shipped = tomllib.loads((CONFIG_DIR / "service.toml").read_text())
    assert shipped["spindle"]["simulate"] is True and shipped["spindle"]["timeout_ms"] < OFFLINE_SIM_TIMEOUT_MS
    off = resolve(offline=True)
    assert off.svc.spindle.timeout_ms == OFFLINE_SIM_TIMEOUT_MS
    assert off.svc.daq is None or off.svc.daq.max_age_ms >= OFFLINE_SIM_TIMEOUT_MS
    paced = resolve(realtime=True, offline=False)          # pmctl serve with real-time priority
    assert paced.svc.spindle.timeout_ms == shipped["spindle"]["timeout_ms"]
    desk = resolve(realtime=False, offline=False)          # pmctl serve --no-realtime
    assert desk.svc.spindle.timeout_ms == OFFLINE_SIM_TIMEOUT_MS
    from test_stepdir_cli import _toml
    shipped["spindle"].update(simulate=False, port=502)
    svc = tmp_path / "service.toml"
    svc.write_text(_toml(shipped))
    for kw in ({"offline": True}, {"realtime": False, "offline": False}):
        real = resolve(service=str(svc), **kw)
        assert not real.svc.spindle.simulate and real.svc.spindle.timeout_ms == shipped["spindle"]["timeout_ms"]
