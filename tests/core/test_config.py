"""The machine config: nominal values load exactly; every bad file is rejected with file, key, reason."""

import math
import tomllib

import numpy as np
import pytest

from pmctl.core.config import CONFIG_DIR, load_machine, machine_from_dict
from pmctl.core.errors import ConfigError

BASE = tomllib.loads((CONFIG_DIR / "prototype.toml").read_text())


def _with(section, **changes):
    data = {k: dict(v) for k, v in BASE.items()}
    for k, v in changes.items():
        if v is None:
            data[section].pop(k, None)
        else:
            data[section][k] = v
    return data


def test_prototype_is_machine_md_section_2():
    m = load_machine("prototype")
    g = m.geometry
    assert g.nominal
    assert (g.base_radius, g.platform_radius, g.tool_length, g.z_home, g.z_table) == (330, 316, 100, 393, 120)
    assert np.allclose(g.base_joints[0], [0, -330, 0]) and np.allclose(g.base_joints[1], [330 * math.sqrt(3) / 2, 165, 0])
    assert np.allclose(g.platform_joints[2], [-316 * math.sqrt(3) / 2, 158, 0])
    assert m.limits.chain_length == (150, 570) and m.limits.table_x == (-75, 75)
    assert list(m.resolution.pulses_per_mm) == [2000] * 5
    assert m.mass.platform_kg == 25 and list(m.mass.com_offset) == [0, 0, 60] and m.mass.gravity == 9.80665
    assert m.strain_gain == 0.5
    assert np.allclose(g.tool_tip_p, [0, 0, -100]) and np.allclose(g.tool_axis_p, [0, 0, 1])


@pytest.mark.parametrize("section,changes,key,reason", [
    ("geometry", {"base_radius_mm": None}, "geometry.base_radius_mm", "missing"),
    ("geometry", {"base_radius_mm": None, "base_radius_m": 0.33}, "geometry.base_radius_m", "wrong unit"),
    ("geometry", {"platform_radius_mm": 0.0}, "geometry.platform_radius_mm", "within (0, "),
    ("geometry", {"platform_radius_mm": -3}, "geometry.platform_radius_mm", "within (0, "),
    ("geometry", {"tool_length_mm": "100"}, "geometry.tool_length_mm", "number"),
    ("geometry", {"length_offsets_mm": [0, 0]}, "geometry.length_offsets_mm", "3 numbers"),
    ("geometry", {"base_joints_mm": [[0, 1], [2, 3], [4, 5]]}, "geometry.base_joints_mm", "3 rows"),
    ("limits", {"chain_length_mm": [570, 150]}, "limits.chain_length_mm", "reversed"),
    ("limits", {"table_x_mm": [75, -75]}, "limits.table_x_mm", "reversed"),
    ("limits", {"chain_speed_mm_s": True}, "limits.chain_speed_mm_s", "number"),
    ("resolution", {"chain_pulses_per_mm": 0}, "resolution.chain_pulses_per_mm", "within (0, "),
    ("mass", {"com_offset_mm": [0, 0, float("nan")]}, "mass.com_offset_mm", "finite"),
    ("sensors", {"strain_gain_ue_per_N": None, "strain_gain": 0.5}, "sensors.strain_gain", "wrong unit"),
    ("limits", {"bogus": 1}, "limits.bogus", "unknown key"),
])
def test_bad_config_is_rejected_naming_key_and_reason(section, changes, key, reason):
    with pytest.raises(ConfigError) as e:
        machine_from_dict(_with(section, **changes), "bad.toml")
    assert e.value.key == key and reason in e.value.reason and e.value.path == "bad.toml"
    assert str(e.value).startswith("bad.toml: " + key)


def test_bad_files(tmp_path):
    with pytest.raises(ConfigError, match="cannot read"):
        load_machine(tmp_path / "none.toml")
    p = tmp_path / "x.toml"
    p.write_text("[geometry\nbase = 1")
    with pytest.raises(ConfigError, match="x.toml.*not valid TOML"):
        load_machine(p)
    p.write_text("[machine]\nname='x'\n")
    with pytest.raises(ConfigError, match="geometry: missing table"):
        load_machine(p)


# ---------------------------------------------------------------- the strict loader (machine and service config)

from pmctl.motion.service_config import load_service_config, service_from_dict  # noqa: E402

PROTO = (CONFIG_DIR / "prototype.toml").read_text()


@pytest.mark.parametrize("edit,key,reason", [
    (lambda t: t.replace("[stiffness]", "[stifness]"), "stifness", "did you mean [stiffness]"),
    (lambda t: t + "\n[service]\nrate = 1\n", "service", "unknown table"),
    (lambda t: t.replace("z_home_mm = 393.0", 'z_home_mm = "393.0"'), "geometry.z_home_mm", "got a string ('393.0')"),
    (lambda t: t.replace("z_home_mm = 393.0", "z_home_mm = true"), "geometry.z_home_mm", "got a bool"),
    (lambda t: t.replace("z_home_mm = 393.0", "z_home_mm = " + "9" * 400), "geometry.z_home_mm", "400 digits"),
    (lambda t: t.replace("z_home_mm = 393.0", "z_home_mm = 1e300"), "geometry.z_home_mm", "within (0, 10000]"),
    (lambda t: t.replace("z_home_mm = 393.0", "z_home_mm = inf"), "geometry.z_home_mm", "finite"),
    (lambda t: t.replace("length_offsets_mm = [0.0, 0.0, 0.0]",
                         'base_joints_mm = [["0.5", true, 0], [1, 2, 3], [4, 5, 6]]'),
     "geometry.base_joints_mm", "3 rows"),
    (lambda t: t.replace("com_offset_mm = [0.0, 0.0, 60.0]", 'com_offset_mm = [0.0, "0", 60.0]'),
     "mass.com_offset_mm", "holding a string"),
    (lambda t: t.replace("chain_axial_N_per_mm", "chain_axial_N_per_m"), "stiffness.chain_axial_N_per_m",
     "did you mean 'chain_axial_N_per_mm'"),
    (lambda t: t.replace('name = "prototype"', "name = 5"), "machine.name", "must be a string"),
    (lambda t: t.replace("[geometry]", "[[geometry]]"), "geometry", "must be a table"),
])
def test_strict_machine_config(tmp_path, edit, key, reason):
    p = tmp_path / "m.toml"
    p.write_text(edit(PROTO))
    with pytest.raises(ConfigError) as e:
        load_machine(p)
    assert e.value.key == key and reason in e.value.reason, str(e.value)
    assert e.value.path == str(p)


def test_bad_bytes_huge_numbers_and_deep_nesting_are_config_errors(tmp_path):
    p = tmp_path / "m.toml"
    p.write_bytes(PROTO.encode().replace(b"# Units", b"# Uni\xe9ts"))
    with pytest.raises(ConfigError, match=r"line 2, column 6: byte 0xe9 is not UTF-8"):
        load_machine(p)
    p.write_text(PROTO + "\n[x]\ny = " + "9" * 5000 + "\n")           # beyond Python's int-parsing limit
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_machine(p)
    p.write_text("a = " + "[" * 100_000 + "]" * 100_000 + "\n")
    with pytest.raises(ConfigError, match="nested too deeply|not valid TOML"):
        load_machine(p)
    p.write_bytes(b"\xef\xbb\xbf" + PROTO.encode())                    # a BOM is fine
    assert load_machine(p).name == "prototype"


SVC = (CONFIG_DIR / "service.toml").read_text()


@pytest.mark.parametrize("edit,key,reason", [
    (lambda t: t.replace("[loop]", "[lop]"), "lop", "did you mean [loop]"),
    (lambda t: t.replace("rt_priority = 50", "rt_priority = 50.0"), "loop.rt_priority", "must be an integer"),
    (lambda t: t.replace("rt_priority = 50", "rt_priority = 500"), "loop.rt_priority", "within [1, 99]"),
    (lambda t: t.replace("realtime = true", 'realtime = "no"'), "loop.realtime", "true or false"),
    (lambda t: t.replace("realtime = true", "realtime = 0"), "loop.realtime", "true or false"),
    (lambda t: t.replace("rate_hz = 1000", "rate_hz = " + "1" * 300), "loop.rate_hz", "300 digits"),
    (lambda t: t.replace("spin_us = 0", "spin_us = 5000"), "loop.spin_us", "shorter than the tick"),
    (lambda t: t.replace("kv_per_s = 400", "kv_per_s = 4000"), "nc.kv_per_s", "must be < 1"),
    (lambda t: t.replace('k_theta_per_s = "auto"', 'k_theta_per_s = ["1", 2, 3]'), "nc.k_theta_per_s", "numbers"),
    (lambda t: t.replace('pulse_mode = "multi"', 'pulse_mode = "fast"'), "nc.pulse_mode", "one of 'multi'"),
    (lambda t: t.replace("seed = 1 ", 'seed = "" '), "seed", "must be an integer, got a string"),
    (lambda t: t.replace("mode_damping_ratio = [0.02, 0.02, 0.02]", 'mode_damping_ratio = "low"'),
     "mode_damping_ratio", "got a string ('low')"),
    (lambda t: t.replace("[hal.sim]\n", "[hal.sim]\nread_timeout_s = -0.001\n"), "read_timeout_s", "within (0, 1]"),
    (lambda t: t.replace("flex = true", 'flex = "no"'), "flex", "true or false"),
    (lambda t: t.replace("flex = true", "flex = 1"), "flex", "true or false"),
    (lambda t: t.replace("enc_noise_mm = 0.0", "enc_noise_mm = false"), "enc_noise_mm", "must be a number"),
    (lambda t: t.replace("seed = 1 ", "seed = 1.5 "), "seed", "must be an integer"),
    (lambda t: t.replace("[hal.sim]\n", "[hal.sim]\nstiffnes = 1\n"), "stiffnes", "unknown sim option"),
])
def test_strict_service_config_and_backend_options_at_load(tmp_path, edit, key, reason):
    p = tmp_path / "s.toml"
    text = edit(SVC)
    assert text != SVC
    p.write_text(text)
    with pytest.raises(ConfigError) as e:
        load_service_config(p)
    assert e.value.key == key and reason in e.value.reason, str(e.value)
    assert str(p) in str(e.value)


def test_service_defaults_and_python_values():
    cfg = service_from_dict({})
    assert cfg.loop.rate_hz == 1000 and cfg.backend == "sim" and cfg.nc.k_theta_per_s == (0.0, 0.0, 0.0)
    cfg = service_from_dict({"nc": {"k_theta_per_s": [1, 2, 3]}, "hal": {"sim": {"drive_tau_s": (0.001,) * 5}}})
    assert cfg.nc.k_theta_per_s == (1.0, 2.0, 3.0) and list(cfg.backend_options["drive_tau_s"]) == [0.001] * 5
    cfg = load_service_config()
    assert cfg.loop.rate_hz == 1000 and cfg.backend_options["flex"] is True
