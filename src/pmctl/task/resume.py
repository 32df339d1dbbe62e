"""Resume an interrupted job from a line (after a crash or a power cut, once the position is
confirmed with ``$X`` or homed with ``$H``).

The rest of the job is the job's moves from the first one of that line on; it starts where the
move before it ended (S, with that move's tool axis). From the current pose P the machine gets
there by a safe approach:

1. retract along the current tool axis by the clearance, at the plunge feed (the tool leaves the
   cut the way it points);
2. move over, at rapid, to the point the clearance above S along S's tool axis;
3. plunge along S's tool axis to S at the feed of the resumed line (or ``PLUNGE_MM_S`` when that
   line is a rapid).

Every approach segment is checked for reachability and the joint soft limits before anything is
queued (pmctl.task.jog.check_jog); an unreachable approach refuses the resume. The approach moves
carry line 0, the resumed moves their own lines.
"""

from __future__ import annotations

import numpy as np

from pmctl.core.errors import PmctlError
from pmctl.core.job import Job, LINE, Move, RAPID
from pmctl.task.interp import LineError
from pmctl.task.jog import check_jog

CLEARANCE_MM = 5.0
PLUNGE_MM_S = 5.0


class ResumeRefused(PmctlError):
    pass


def resume_job(job: Job, line: int, tip, axis, machine, params, clearance_mm: float = CLEARANCE_MM) -> Job:
    """The approach from the pose (tip, axis) plus the moves of ``job`` from line ``line`` on."""
    moving = [m for m in job.moves]
    k = next((n for n, m in enumerate(moving) if m.line >= line and m.kind != "dwell"), None)
    if k is None:
        raise ResumeRefused(f"job {job.source}: no motion at or after line {line}")
    if k == 0:                     # nothing before it ends anywhere known: approach its end directly
        s_tip, s_axis, rest = moving[0].tip, moving[0].axis, moving[1:]
    else:
        prev = next((m for m in reversed(moving[:k]) if m.kind != "dwell"), moving[k])
        s_tip, s_axis, rest = prev.tip, prev.axis, moving[k:]
    tip, axis = np.asarray(tip, float), np.asarray(axis, float)
    s_tip, s_axis = np.asarray(s_tip, float), np.asarray(s_axis, float)
    feed = moving[k].feed if moving[k].kind != RAPID and moving[k].feed > 0 else PLUNGE_MM_S
    up = tip + clearance_mm * axis
    over = s_tip + clearance_mm * s_axis
    approach = [Move(LINE, up, axis, line=0, feed=feed), Move(RAPID, over, s_axis, line=0),
                Move(LINE, s_tip, s_axis, line=0, feed=feed)]
    a = (tip, axis)
    for m in approach:
        try:
            check_jog(machine, params, a[0], a[1], m.tip, m.axis)
        except LineError as e:
            raise ResumeRefused(f"the approach to line {line} is unreachable: {e}") from None
        a = (m.tip, m.axis)
    return Job(tuple(approach) + tuple(rest), job.source, job.points, job.point_lines, job.messages)
