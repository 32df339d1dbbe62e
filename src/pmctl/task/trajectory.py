"""The contract between the path planner and the controller: tool poses sampled at the tick rate.

The planner (pmctl.task.planner) produces a Trajectory from a job (G-code or CL data); the loop reads
one row per tick. All in the workpiece frame W: tip in mm, tool axis unit (tip -> spindle).

``tip`` is the tip of the machine config's reference tool (``geometry.tool_length``), the point the
machine's model and the rt side control: with a tool length offset d in force (Move.tool_offset, G43)
the cutting tip is ``tip - d * axis`` (pmctl.task.job.controlled_point). ``points`` are the programmed
(cutting) tip points.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Trajectory:
    dt: float                    # s, the tick period it was sampled at
    tip: np.ndarray              # (N, 3) mm, tip of the reference tool in W (the controlled point)
    axis: np.ndarray             # (N, 3) unit tool axis
    tip_vel: np.ndarray          # (N, 3) mm/s
    axis_vel: np.ndarray         # (N, 3) 1/s
    line: np.ndarray             # (N,) int, source line of the job each sample comes from (0: none)
    spindle_rpm: np.ndarray      # (N,) commanded spindle speed (0 = off)
    source: str = ""             # the job file
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # the job's programmed tip points in W
    # EVENT moves reached by this piece: ((sample index in this piece, line, events), ...) in order; the
    # sample is the exact stop where the events take effect (pmctl.task.job EVENT)
    marks: tuple = ()

    def __len__(self):
        return len(self.tip)

    @property
    def duration(self):
        return len(self.tip) * self.dt

    @classmethod
    def join(cls, pieces, max_len=None, too_long=None) -> "Trajectory":
        """One Trajectory of consecutive pieces (as the streaming planner yields them). With
        ``max_len``, ``too_long(n)`` (an exception) is raised once the pieces pass that many samples."""
        parts, n = [], 0
        for p in pieces:
            n += len(p)
            if max_len is not None and n > max_len:
                raise too_long(n)
            parts.append(p)
        first = parts[0]
        cat = {k: np.concatenate([getattr(p, k) for p in parts]) for k in
               ("tip", "axis", "tip_vel", "axis_vel", "line", "spindle_rpm")}
        marks, off = [], 0
        for p in parts:
            marks.extend((i + off, line, ev) for i, line, ev in p.marks)
            off += len(p)
        return cls(first.dt, source=first.source, points=first.points, marks=tuple(marks), **cat)
