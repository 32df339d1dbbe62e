"""The whole check of a job before anything moves: what ``pmctl check`` prints, what ``pmctl run`` and
the supervisor's queue do first.

``check_file(path, machine, dt, ...)`` reads and parses the job (pmctl.task.job.parse_job: every problem
the reader reports), then ``check_job`` checks it against the machine and plans it:

1. **feeds**: every feed move has a positive feed (or a G93 duration);
2. **the machine**: every programmed pose and the path between them (every ``grid_mm``) within the
   workspace, the tilt range and the joint limits (pmctl.task.planner.validate with a problem list:
   one problem of kind ``machine`` per line, all of them);
3. **planning**: the whole job planned by the planner the run uses, window by window in bounded
   memory, no samples kept (``validate(full=True)``: where re-planning does not meet the limits the
   planner's fallback goes into the checked path, so the run cannot fail midway for a planning
   reason); a job too long for the bounds, or one the fallback cannot plan, is a ``planning``
   problem with its line.

Every problem has file, line, column (None when not known), kind (syntax, unsupported, machine,
planning) and a message saying what to do. ``CheckReport.summary``: moves, the tool tip's path
length, the machining time as planned, the tools the job changes to, the extents of the programmed
points, and what the planner did (segments after merging runs of short lines, fallbacks).

The planner plans with ``machine_for_planning(machine, params)``: the machine's joint speed limits
capped by what the V-F converters can emit at the tick rate (the supervisor plans with the same).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace

import numpy as np

from pmctl.core.errors import InputError, Problem
from pmctl.task.job import ARC, DWELL, EVENT, LINE, Job, parse_job


@dataclass
class CheckReport:
    file: str
    problems: list = field(default_factory=list)
    summary: dict = field(default_factory=dict)
    job: Job | None = None
    path: object = None          # the planner's checked segment index (plan_stream(path=...)), when planned

    @property
    def ok(self) -> bool:
        return not self.problems

    def as_dict(self) -> dict:
        return {"ok": self.ok, "problems": [p.as_dict() for p in self.problems], "summary": self.summary}


def machine_for_planning(machine, params):
    """The machine the planner plans for: its joint speed limits capped by the V-F converters'
    top rates ``params.vmax`` (one pulse per tick in the seed's mode)."""
    if not np.any(params.vmax < machine.limits.joint_speed - 1e-9):
        return machine
    lim = replace(machine.limits, chain_speed=float(params.vmax[:3].min()), table_speed=float(params.vmax[3:].min()))
    return replace(machine, limits=lim)


def check_file(path, machine, dt, *, start=None, feed_override=1.0, limits=None, batch=False,
               **options) -> CheckReport:
    """Read, parse and check the job file ``path`` (see the module docstring)."""
    job, problems = parse_job(path, machine, start=start, **options)
    if job is None:
        return CheckReport(str(path), problems)
    return check_job(job, machine, dt, start=start, feed_override=feed_override, limits=limits, batch=batch,
                     problems=problems)


def check_job(job: Job, machine, dt, *, start=None, feed_override=1.0, limits=None, batch=False,
              problems=None) -> CheckReport:
    """Check a parsed job against ``machine`` and plan it (see the module docstring). ``batch``: the
    batch planner's bounds (a run with an input shaper plans the job whole)."""
    from pmctl.task.planner import PlanningError, validate
    problems = list(problems or [])
    rep = CheckReport(job.source, problems, job=job)
    for m in job.moves:
        if m.kind in (LINE, ARC) and not m.duration > 0 and not m.feed * feed_override > 0:
            problems.append(Problem(m.file or job.source, m.line or None, None, "syntax",
                                    "a feed move without a positive feed: program F (per minute) before it"))
    if problems:
        rep.summary = _summary(job, None, dt)
        return rep
    found = []
    path = None
    try:
        path = validate(job, machine, dt, feed_override=feed_override, limits=limits, start=start, batch=batch,
                        full=True, problems=found)
    except PlanningError as e:
        problems.append(Problem(e.path or job.source, e.line, None, "planning", _reason(str(e), e.path, e.line)))
    except InputError as e:
        problems.append(Problem(e.path, e.line, e.column, "planning", e.reason))
    problems.extend(_grouped(found, job))
    problems.sort(key=lambda p: (p.line is not None, p.line or 0))
    if not problems:
        rep.path = path
    rep.summary = _summary(job, path if not found else None, dt)
    return rep


_LIMIT = re.compile(r"unreachable: (tilt theta2|chain L\d|table [XY]|spherical joint swing|platform below|"
                    r"inverse kinematics)")


def _grouped(found, job):
    """The machine problems, one per stretch of consecutive moves out of the same limit: a program
    placed outside the workspace is one problem (its first line, and to which line it goes on), not
    one per line."""
    moving = sorted({m.line for m in job.moves if m.kind not in (DWELL, EVENT) and m.line})
    rank = {ln: i for i, ln in enumerate(moving)}
    groups = []                   # [first problem, limit, last line, count]
    for p in sorted(found, key=lambda p: p.line or 0):
        m = _LIMIT.search(p.message)
        g = groups[-1] if groups else None
        if (m and g is not None and g[1] == m.group(1) and p.line in rank and g[2] in rank
                and rank[p.line] == rank[g[2]] + 1):
            g[2], g[3] = p.line, g[3] + 1
        else:
            groups.append([p, m.group(1) if m else None, p.line, 1])
    out = []
    for p, _, last, n in groups:
        if n > 1:
            p = Problem(p.file, p.line, p.column, p.kind, f"{p.message} (so is every move from here to line {last}: "
                                                          f"{n} lines)")
        out.append(p)
    return out


def _reason(msg, path, line):
    """A PlanningError's message without its leading ``file:line: ``."""
    head = f"{path}:{line}: "
    return msg[len(head):] if path and msg.startswith(head) else msg


def _summary(job: Job, path, dt) -> dict:
    moving = [m for m in job.moves if m.kind not in (DWELL, EVENT)]
    tools = sorted({int(v) for m in job.moves if m.kind == EVENT for k, v in m.events if k == "tool_change"})
    out = {"moves": len(job.moves), "tools": tools}
    if moving:
        tips = np.array([m.tip for m in moving], float)
        axes = np.array([m.axis for m in moving], float)
        tilt = np.degrees(np.arccos(np.clip(axes[:, 2] / np.linalg.norm(axes, axis=1), -1.0, 1.0)))
        out["extents"] = {"x_mm": [float(tips[:, 0].min()), float(tips[:, 0].max())],
                          "y_mm": [float(tips[:, 1].min()), float(tips[:, 1].max())],
                          "z_mm": [float(tips[:, 2].min()), float(tips[:, 2].max())],
                          "tilt_deg_max": float(tilt.max())}
        offsets = sorted({float(m.tool_offset) for m in moving})
        if offsets != [0.0]:
            out["tool_offsets_mm"] = offsets
    if path is not None:
        out["length_mm"] = float(path.feed_length[~path.rot].sum()) if path.n else 0.0
        if getattr(path, "planned_samples", None) is not None:
            out["machining_time_s"] = round(path.planned_samples * dt, 6)
        out["planner"] = {"segments": int(path.n), "merged_moves": int(len(path.mrg_seg)),
                          "fallbacks": int(getattr(path, "fallbacks", 0))}
    return out
