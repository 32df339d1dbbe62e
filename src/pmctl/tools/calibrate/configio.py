"""Writing machine configs: a small TOML writer and the calibrated machine file.

The calibrated file is the reference config with its ``[geometry]`` joints, revolute axes, length
offsets and tool replaced by the identified values; every other table is copied. The identification
summary goes into comments at the top, so the file stays a plain machine config that every command
accepts with ``--config`` (it is read back through ``load_machine`` before it is written).
"""

from __future__ import annotations

import math
import os
import re
import tomllib
from pathlib import Path

import numpy as np

from pmctl.core.config import Geometry, Machine, load_machine
from pmctl.core.errors import ConfigError, PmctlError

_BARE = re.compile(r"^[A-Za-z0-9_-]+$")


def _key(k: str) -> str:
    return k if _BARE.match(k) else '"' + k.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        f = float(v)
        if not math.isfinite(f):
            raise PmctlError(f"cannot write the non-finite number {f} to a machine config")
        return repr(f)
    if isinstance(v, str):
        s = v.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n").replace("\t", "\\t")
        return f'"{s}"'
    if isinstance(v, np.ndarray):
        v = v.tolist()
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + "}"
    raise PmctlError(f"cannot write a {type(v).__name__} to a machine config")


def dumps(data: dict, header: str = "") -> str:
    """TOML text of a dict of tables (nested tables become [a.b] headers)."""
    out = []
    if header:
        out += ["# " + ln if ln else "#" for ln in header.splitlines()]
        out.append("")

    def table(name, d):
        scalars = {k: v for k, v in d.items() if not isinstance(v, dict)}
        subs = {k: v for k, v in d.items() if isinstance(v, dict)}
        if name and (scalars or not subs):
            out.append(f"[{name}]")
        for k, v in scalars.items():
            out.append(f"{_key(k)} = {_value(v)}")
        if name and (scalars or not subs):
            out.append("")
        for k, v in subs.items():
            table(f"{name}.{_key(k)}" if name else _key(k), v)

    top = {k: v for k, v in data.items() if not isinstance(v, dict)}
    for k, v in top.items():
        out.append(f"{_key(k)} = {_value(v)}")
    if top:
        out.append("")
    table("", {k: v for k, v in data.items() if isinstance(v, dict)})
    return "\n".join(out).rstrip() + "\n"


def geometry_table(base: dict, geom: Geometry) -> dict:
    """The [geometry] table of ``base`` with the general geometry of ``geom``."""
    g = dict(base)
    g.update({
        "tool_length_mm": float(geom.tool_length),
        "tool_tilt_deg": [float(x) for x in geom.tool_tilt_deg],
        "base_joints_mm": np.asarray(geom.base_joints, float).tolist(),
        "platform_joints_mm": np.asarray(geom.platform_joints, float).tolist(),
        "revolute_axes": np.asarray(geom.revolute_axes, float).tolist(),
        "length_offsets_mm": np.asarray(geom.length_offsets, float).tolist(),
    })
    return g


def machine_dict(machine: Machine) -> dict:
    """The raw TOML tables of a loaded machine (re-read from its source file)."""
    try:
        return tomllib.loads(Path(machine.source).read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise ConfigError(machine.source, "-", f"cannot re-read the reference config: {e}") from None


def calibrated_dict(base: Machine, geom: Geometry, *, name=None, description=None) -> dict:
    data = machine_dict(base)
    data["machine"] = dict(data.get("machine", {}))
    data["machine"]["name"] = name or f"{base.name}-calibrated"
    data["machine"]["description"] = description or f"{base.name} with identified geometry"
    data["geometry"] = geometry_table(data["geometry"], geom)
    return data


def write_machine(path, data: dict, header: str = "") -> Machine:
    """Write a machine config atomically, after checking it loads; returns the loaded machine."""
    path = Path(path)
    text = dumps(data, header)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        tmp.write_text(text, encoding="utf-8")
        load_machine(tmp)                       # refuse to write a file the loader would reject
        os.replace(tmp, path)
    except OSError as e:
        raise PmctlError(f"{path}: cannot write: {e.strerror or e}") from None
    finally:
        if tmp.exists():
            tmp.unlink()
    return load_machine(path)
