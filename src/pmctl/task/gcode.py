"""The G-code job reader: a file (or text) -> a Job (pmctl.task.job) for the planner, by pmctl's RS-274
interpreter (pmctl.task.rs274: LinuxCNC's language for what has a meaning on this machine; the words
it runs and the ones it refuses are in docs/gcode.md).

- ``interpret(text, path, ...) -> (Job, problems)`` (pmctl.task.rs274): never raises for a problem of
  the program; every problem is listed with file, line, column, kind and message (``pmctl check``).
- ``parse_gcode(text, path, start_tip, start_axis)`` -> Job: the same, raising ``JobProblems`` (an
  InputError naming the first problem and counting the others) when there is any.
- ``read_gcode(path, machine, start=None, config=None, offsets=None)`` -> Job: reads the file (UTF-8,
  the size bounds of pmctl.task.job), interprets it from ``start`` (default: the home pose; G91 moves,
  arcs and the first A/B are relative to it) with the [interpreter] settings ``config`` (tool table,
  subroutine path, ...) and the work ``offsets`` in force (the console journal's format), and checks
  that every programmed end pose is reachable (kinematics.ik_batch, with each move's tool length).

There is no bound on the number of moves here: a move costs about 0.4 kB (the tool axis array is
shared while the tilt stays the same).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pmctl.core.errors import JobProblems
from pmctl.task.job import DWELL, EVENT, Job, check_reach, home_pose, read_job_text
from pmctl.task.rs274 import interpret
from pmctl.task.rs274.arcs import SPIRAL_MM
from pmctl.task.rs274.execute import MAX_ARC_TURNS, MAX_DWELL_S
from pmctl.task.rs274.modal import MM_PER_INCH

ARC_RADIUS_TOL_MM = SPIRAL_MM     # |r_end - r_start| an I/J/K arc may have (LinuxCNC's 0.0283 mm and 0.1 %)

__all__ = ["interpret", "interpret_file", "parse_gcode", "read_gcode", "reader_options", "ARC_RADIUS_TOL_MM",
           "MAX_DWELL_S", "MAX_ARC_TURNS", "MM_PER_INCH", "check_job_reach"]


def parse_gcode(text: str, path="<string>", start_tip=(0.0, 0.0, 0.0), start_axis=(0.0, 0.0, 1.0), *, config=None,
                offsets=None, home=None, probe_ok=True) -> Job:
    """Interpret a program (pure); JobProblems lists every problem."""
    job, problems = interpret(text, path, start=(start_tip, start_axis), config=config, offsets=offsets, home=home,
                              probe_ok=probe_ok)
    if problems:
        raise JobProblems(problems)
    return job


def read_gcode(path, machine, *, start=None, config=None, offsets=None) -> Job:
    """Read, interpret and check a G-code file; every programmed end pose must be reachable."""
    path = Path(path)
    text = read_job_text(path)
    home = home_pose(machine)
    tip, axis = home if start is None else start
    job = parse_gcode(text, path, tip, axis, config=config, offsets=offsets, home=home)
    check_job_reach(job, machine, path)
    return job


def interpret_file(path, machine, *, start=None, config=None, offsets=None):
    """(Job, problems) of a G-code file, without raising for a problem of the program (``pmctl check``
    lists them with the machine's and the planner's); reading the file may still raise InputError
    (missing, too large, not UTF-8). ``start``: default the home pose, also the G28/G30 default."""
    path = Path(path)
    home = home_pose(machine)
    return interpret(read_job_text(path), path, start=home if start is None else start, config=config,
                     offsets=offsets, home=home)


def reader_options(path, config=None, offsets=None) -> dict:
    """The options ``load_job`` passes to the G-code reader for ``path`` (the service config's
    [interpreter] section and the work offsets in force); none for CL data."""
    from pmctl.task.job import GCODE_SUFFIXES
    if Path(path).suffix.lower() not in GCODE_SUFFIXES:
        return {}
    return {"config": config, "offsets": offsets}


def check_job_reach(job: Job, machine, path):
    """IK of every programmed end pose, each with its tool length (the machine config's reference tool
    + the move's tool_offset); InputError at the first unreachable one (pmctl.task.job.check_reach)."""
    ends = [m for m in job.moves if m.kind != DWELL and m.kind != EVENT]
    if ends:
        check_reach(np.array([m.tip for m in ends]), np.array([m.axis for m in ends]),
                    np.array([m.line for m in ends]), machine, path,
                    tool_offset=np.array([m.tool_offset for m in ends]))
