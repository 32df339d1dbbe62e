"""The post-processor (seed 000 ch. 7): a job's tool poses converted to the machine's actuator
coordinates, q = (L1, L2, L3, X, Y): the chain lengths and the table position, mm.

- ``per_move(job, machine)``: one row per move that moves (RAPID, LINE, ARC), its end pose in program
  order: (line, q). The CL data's post-processor of the seed, for G-code jobs too.
- ``per_step(job, machine, dt, every, ...)``: the job as the planner plans it for the run (the whole job
  checked and planned first, then streamed: bounded memory), every ``every``-th tick and the last:
  (t, line, q) rows, chunk by chunk.

Poses are of the controlled point (pmctl.task.job.controlled_point: with a tool length offset the IK is
that of the longer tool), so the joints are what the machine's model (the reference tool) commands.
"""

from __future__ import annotations

import numpy as np

from pmctl.task.job import DWELL, EVENT, Job, check_reach, controlled_point

COLUMNS = ("L1", "L2", "L3", "X", "Y")


def per_move(job: Job, machine):
    """(lines (N,), q (N, 5)) of the end pose of every move that moves; InputError at the first
    unreachable one."""
    moving = [m for m in job.moves if m.kind not in (DWELL, EVENT)]
    if not moving:
        return np.zeros(0, int), np.zeros((0, 5))
    tips = np.array([m.tip for m in moving], float)
    axes = np.array([m.axis for m in moving], float)
    axes = axes / np.linalg.norm(axes, axis=1, keepdims=True)
    lines = np.array([m.line for m in moving], int)
    off = np.array([m.tool_offset for m in moving], float)
    r = check_reach(controlled_point(tips, axes, off), axes, lines, machine, job.source)
    return lines, r.q


def per_step(job: Job, machine, dt, every=1, *, start=None, feed_override=1.0, limits=None):
    """Chunks (t (n,), line (n,), q (n, 5)) of the planned job every ``every`` ticks of ``dt`` (and its
    last sample), planned as pmctl run plans it (validate(full=True), then plan_stream)."""
    from pmctl.core import kinematics as K
    from pmctl.task.planner import plan_stream, validate
    path = validate(job, machine, dt, feed_override=feed_override, limits=limits, start=start, full=True)
    total = path.planned_samples
    k0 = 0
    for piece in plan_stream(job, machine, dt, feed_override=feed_override, limits=limits, start=start, path=path):
        n = len(piece)
        k = np.arange(k0, k0 + n)
        sel = (k % every == 0) | (k == total - 1)
        if np.any(sel):
            tip, axis = np.asarray(piece.tip)[sel], np.asarray(piece.axis)[sel]
            q = K.ik_batch(tip, axis, machine, check_limits=False).q
            yield k[sel] * dt, np.asarray(piece.line)[sel], q
        k0 += n
