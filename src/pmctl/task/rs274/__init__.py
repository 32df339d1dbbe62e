"""pmctl's RS-274/NGC interpreter: one interpreter for job files, the console and the queue.

It reads G-code as LinuxCNC 2.9's interpreter does (the oracle of its tests is LinuxCNC's ``rs274``)
for everything that has a meaning on this machine, and produces the moves of pmctl.task.job
(``Move``, ``Job``) -- tool tip X Y Z in the workpiece frame W and the tool tilt A B -- with the
events of the program (spindle, coolant, tool changes, tool offsets, outputs, messages, pauses) in
order. What a program may use, what is refused and why: docs/gcode.md.

Modules, one concept each:

- ``words``        a line -> words, parameter assignments, comments, O-word command
- ``expressions``  expressions and functions
- ``parameters``   numbered, named and global parameters, LinuxCNC's system parameters
- ``modal``        the modal state and the codes (groups, what is refused and why)
- ``execute``      one block in LinuxCNC's order of execution -> moves and events
- ``arcs``         G2/G3 geometry in any plane
- ``cycles``       canned cycles G73 G74 G81-G86 G89
- ``cutter_comp``  cutter radius compensation G41/G42
- ``tools``        the tool table (LinuxCNC .tbl)
- ``flow``         O-word subroutines and control flow
- ``program``      running a program or a console line, collecting every problem

Public API:

- ``interpret(text, path, start=(tip, axis), config=InterpreterConfig, ...) -> (Job, [Problem])``:
  never raises for a problem of the program; ``pmctl check`` lists the problems with the machine's.
- ``make_config(...)`` and ``Interpreter`` (pmctl.task.rs274.program) for a caller that keeps the
  state between lines (the console: pmctl.task.interp).
"""

from __future__ import annotations

import gc
import math
import os

from pmctl.core import kinematics as K
from pmctl.task.rs274.execute import Config
from pmctl.task.rs274.flow import Source
from pmctl.task.rs274.program import Interpreter
from pmctl.task.rs274.tools import ToolTable, load_tool_table

__all__ = ["interpret", "make_config", "Interpreter", "Config", "Source", "start_position", "tool_table"]

_TABLES: dict = {}


def tool_table(path) -> ToolTable:
    """The tool table at ``path``, read again when the file changes (ConfigError when bad)."""
    p = str(path)
    try:
        key = (p, os.stat(p).st_mtime_ns)
    except OSError:
        key = (p, None)
    t = _TABLES.get(key)
    if t is None:
        t = load_tool_table(p)
        if len(_TABLES) > 16:
            _TABLES.clear()
        _TABLES[key] = t
    return t


def start_position(tip, axis):
    """X Y Z A B (mm, deg) of a pose: the tip and the roll/pitch of the axis (docs/machine.md §3)."""
    a, b = K.roll_pitch_from_axis(tuple(float(x) for x in axis))
    return [float(tip[0]), float(tip[1]), float(tip[2]), math.degrees(float(a)), math.degrees(float(b))]


def make_config(config=None, *, tools=None, home=None, probe_ok=True, ahead=True) -> Config:
    """The interpreter's Config from the service config's [interpreter] (pmctl.motion.service_config
    .InterpreterConfig; None: its defaults). ``home``: (tip, axis) of the machine's home pose, the
    default G28/G30 position (None: the origin of W, vertical tool). ``ahead``: the program is
    interpreted before it runs (a job file), so the probe result parameters are not known."""
    if config is None:
        from pmctl.motion.service_config import InterpreterConfig
        config = InterpreterConfig()
    table = tools if tools is not None else tool_table(config.tool_table)
    h = start_position(*home) if home is not None else [0.0, 0.0, 0.0, 0.0, 0.0]
    return Config(table, user_m_codes=config.user_m_codes, optional_stop=config.optional_stop,
                  block_delete=config.block_delete, digital_outputs=config.digital_outputs,
                  analog_outputs=config.analog_outputs, subroutine_path=config.subroutine_path, home=h,
                  probe_ok=probe_ok, ahead=ahead)


def interpret(text: str, path="<string>", *, start=None, config=None, cfg: Config | None = None, offsets=None,
              home=None, probe_ok=True):
    """Interpret a whole program. Returns (Job, problems): every problem found (file, line, column,
    kind syntax / unsupported / machine, message), the job of the blocks that had none.

    ``start``: (tip, axis) where the machine is when the program begins (default: W's origin with the
    tool vertical); ``config``: the [interpreter] section (InterpreterConfig) or ``cfg`` a ready
    Config; ``offsets``: the work offsets in force (the console journal's format); ``home``: (tip,
    axis) of the home pose (G28/G30 default)."""
    if cfg is None:
        cfg = make_config(config, home=home, probe_ok=probe_ok)
    tip, axis = start if start is not None else ((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    was = gc.isenabled()
    gc.disable()                 # long-lived moves, no garbage: see Interpreter.run_program
    try:
        it = Interpreter(cfg, start_position(tip, axis), offsets)
        it.run_program(Source(text, path))
        return it.job(path), list(it.problems)
    finally:
        if was:
            gc.enable()
