"""Hardware abstraction layer: backends by name. Add a backend by adding one entry to BACKENDS
("module:Class", imported on first use) — the loop never changes."""

from __future__ import annotations

import importlib

from pmctl.core.errors import ConfigError
from pmctl.hal.base import AXES, Backend, Feedback, HalError, HalTimeout, Inputs, Status

BACKENDS = {
    "sim": "pmctl.hal.sim:SimBackend",
    "stepdir": "pmctl.hal.stepdir:StepDirBackend",
    "canopen": "pmctl.hal.canopen_csp:CanopenCSP",
}


def backend_class(name: str):
    if name not in BACKENDS:
        raise ConfigError("service config", "hal.backend",
                          f"unknown backend {name!r}; known: {', '.join(sorted(BACKENDS))}")
    mod, cls = BACKENDS[name].split(":")
    return getattr(importlib.import_module(mod), cls)


def validate_options(name: str, table: dict, where: str):
    """Validate backend ``name``'s options table (see Backend.validate_options)."""
    return backend_class(name).validate_options(table, where)


def create(name: str, machine, dt: float, options: dict | None = None, **kw) -> Backend:
    """Instantiate backend ``name`` for ``machine`` at tick period ``dt`` with its options."""
    return backend_class(name)(machine, dt, options or {}, **kw)


__all__ = ["AXES", "BACKENDS", "Backend", "Feedback", "HalError", "HalTimeout", "Inputs", "Status", "backend_class", "create", "validate_options"]
