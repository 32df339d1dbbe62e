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
    ("geometry", {"platform_radius_mm": 0.0}, "geometry.platform_radius_mm", "> 0"),
    ("geometry", {"platform_radius_mm": -3}, "geometry.platform_radius_mm", "> 0"),
    ("geometry", {"tool_length_mm": "100"}, "geometry.tool_length_mm", "number"),
    ("geometry", {"length_offsets_mm": [0, 0]}, "geometry.length_offsets_mm", "3 numbers"),
    ("geometry", {"base_joints_mm": [[0, 1], [2, 3], [4, 5]]}, "geometry.base_joints_mm", "3 rows"),
    ("limits", {"chain_length_mm": [570, 150]}, "limits.chain_length_mm", "reversed"),
    ("limits", {"table_x_mm": [75, -75]}, "limits.table_x_mm", "reversed"),
    ("limits", {"chain_speed_mm_s": True}, "limits.chain_speed_mm_s", "number"),
    ("resolution", {"chain_pulses_per_mm": 0}, "resolution.chain_pulses_per_mm", "> 0"),
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
