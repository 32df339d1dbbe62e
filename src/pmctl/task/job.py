"""Job files: ``load_job(path, machine)`` reads a file of either format (G-code: pmctl.task.gcode, CL
data: pmctl.task.cldata) by its suffix into a Job (pmctl.core.job, the moves); ``parse_job`` gives
every problem instead of raising at the first."""

from __future__ import annotations

from pathlib import Path

from pmctl.core.errors import InputError, JobProblems, Problem
from pmctl.core.job import CL_SUFFIXES, GCODE_SUFFIXES, Job, read_job_text
from pmctl.task.cldata import cl_job, parse_cl, read_cl_job
from pmctl.task.gcode import interpret_file, read_gcode


def load_job(path, machine, *, start=None, **options) -> Job:
    """Read a job file, dispatching on its suffix (G-code: .ngc .nc .gcode .tap; CL: .cl .cls .txt .csv).

    ``start`` = (tip, axis) where the machine is when the job begins (default: the home pose). G-code
    needs it (G91 moves, arcs and the initial A/B are relative to it), so pass the planner's start
    pose here too; CL data is absolute and ignores it. ``options`` go to the reader (CL data:
    ``vector``, ``feed_mm_min``, ``clearance_mm``, ``spindle_rpm``)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in GCODE_SUFFIXES:
        return read_gcode(path, machine, start=start, **options)
    if suffix in CL_SUFFIXES:
        return read_cl_job(path, machine, **options)
    raise InputError(path, None, f"unknown job format {suffix!r}: use G-code ({' '.join(GCODE_SUFFIXES)}) "
                                 f"or CL data ({' '.join(CL_SUFFIXES)})")


_UNSUPPORTED_WORDS = ("not supported", "unsupported", "refused", "unknown job format", "is not implemented")


def problem_kind(reason: str) -> str:
    """The kind of a reader's refusal (``syntax`` or ``unsupported``) from its message: what the reader
    understood but does not do is ``unsupported``, anything malformed ``syntax``."""
    low = reason.lower()
    return "unsupported" if any(w in low for w in _UNSUPPORTED_WORDS) else "syntax"


def parse_job(path, machine, *, start=None, **options) -> tuple:
    """Read and parse a job file without checking it against the machine, and without raising:
    (Job or None, [Problem, ...]). Every problem the reader reports is listed: the G-code reader
    (pmctl.task.rs274) finds them all and gives the job of the blocks that had none; the CL reader
    stops at its first refusal (no job). The machine and the planner are checked by pmctl.task.jobcheck.
    ``start`` and ``options`` as for :func:`load_job`."""
    path = Path(path)
    suffix = path.suffix.lower()
    try:
        if suffix in GCODE_SUFFIXES:
            return interpret_file(path, machine, start=start, **options)
        if suffix in CL_SUFFIXES:
            vector = options.pop("vector", "axis")
            return cl_job(parse_cl(read_job_text(path), path, vector=vector), None, **options), []
        raise InputError(path, None, f"unknown job format {suffix!r}: use G-code ({' '.join(GCODE_SUFFIXES)}) "
                                     f"or CL data ({' '.join(CL_SUFFIXES)})")
    except JobProblems as e:
        return None, list(e.problems)
    except InputError as e:
        return None, [Problem(e.path, e.line, e.column, problem_kind(e.reason), e.reason)]
