"""Measured poses from a recording: static rows, or the dwells of a longer recording.

A *pose* is a run of consecutive rows with the same joints (to ``tol_mm``). When no two consecutive
rows share their joints, every row is one static pose. Otherwise only runs of at least ``min_rows``
rows are poses (dwells; rows in motion are skipped), and the measured channels are averaged over the
second half of the run (the tool has settled). Joints: ``enc_*`` where every one of the five is
recorded over the run (what the motors really reached), else ``cmd_*`` (``joints="cmd"|"enc"`` forces one).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pmctl.core.errors import InputError
from pmctl.core.recording import CMD, ENC, TIP, TOOL, read_recording


@dataclass
class Poses:
    q: np.ndarray              # (n, 5)
    tip: np.ndarray            # (n, 3)
    axis: np.ndarray | None    # (n, 3) or None when the recording has no tool axis
    rows: np.ndarray           # (n,) first data row of each pose (0-based)
    joints_from: str           # "cmd" or "enc"
    dwells: bool               # True when the poses are dwells of a longer recording
    machine: object            # the recording's machine


def poses_of(rec, *, joints="auto", tol_mm=1e-6, min_rows=3) -> Poses:
    path = rec.path
    for c in TIP:
        if c not in rec:
            raise InputError(path, None, f"no measured tool tip channel {c}: nothing to calibrate against")
    use_enc = joints == "enc" or (joints == "auto" and all(c in rec for c in ENC))
    if joints == "enc" and not all(c in rec for c in ENC):
        raise InputError(path, None, "--joints enc: the recording lacks some enc_* channels")
    qcols = ENC if use_enc else CMD
    q = np.stack([rec[c] for c in qcols], 1)
    if use_enc and joints == "auto" and not np.all(np.isfinite(q)):
        use_enc, qcols = False, CMD
        q = np.stack([rec[c] for c in CMD], 1)
    tip = np.stack([rec[c] for c in TIP], 1)
    has_axis = all(c in rec for c in TOOL)
    ax = np.stack([rec[c] for c in TOOL], 1) if has_axis else None
    n = len(q)
    if n == 0:
        raise InputError(path, None, "the recording has no rows")
    same = np.all(np.abs(np.diff(q, axis=0)) <= tol_mm, axis=1) if n > 1 else np.zeros(0, bool)
    starts = np.concatenate([[0], np.nonzero(~same)[0] + 1])
    ends = np.concatenate([starts[1:], [n]])
    dwells = bool(np.any(ends - starts > 1))
    Q, T, A, R = [], [], [], []
    for s, e in zip(starts, ends):
        if dwells and e - s < min_rows:
            continue
        h = s + (e - s) // 2 if dwells else s
        sl = slice(h, e)
        tip_s = tip[sl]
        good = np.all(np.isfinite(tip_s), 1)
        if not good.any() or not np.all(np.isfinite(q[s])):
            continue
        Q.append(q[s])
        T.append(tip_s[good].mean(0))
        if has_axis:
            a = ax[sl][np.all(np.isfinite(ax[sl]), 1)]
            A.append(a.mean(0) if len(a) else np.full(3, np.nan))
        R.append(s)
    if not Q:
        raise InputError(path, None, "no static pose with a measured tool tip "
                                     + ("(no dwell of at least %d rows)" % min_rows if dwells else ""))
    A = np.array(A) if has_axis else None         # NaN rows: axis not measured at that pose
    if A is not None and not np.any(np.isfinite(A)):
        A = None
    return Poses(np.array(Q), np.array(T), A, np.array(R), "enc" if use_enc else "cmd", dwells, rec.machine)


def read_poses(folder, **kw) -> Poses:
    return poses_of(read_recording(folder), **kw)
