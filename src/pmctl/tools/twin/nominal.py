"""The nominal quasi-static twin (docs/diagnosis-report.md §1): what every channel of a recording should read.

- drives ideal: ``enc_*`` = ``cmd_*``;
- rigid links, nominal (config) geometry: platform pose = FK(chain lengths), tool tip in W and
  tool axis with the table at (X, Y). The joints used are ``enc_*`` where the recording has them
  (cell by cell: an empty enc cell falls back to ``cmd_*``), else ``cmd_*``;
- static strain: platform weight plus the known tip force ``load_f*`` (forward-filled over
  not-sampled cells, 0 when absent) held by the chains (:mod:`pmctl.core.statics`);
  ``strain_i`` = −k_ε·a_i.

API (pure; ``columns`` is any mapping channel -> 1-D array, e.g. ``Recording.columns``)
---
``PREDICTABLE``: the channels the twin predicts: enc_*, tip_*, tool_*, strain_*.
``joints_for_pose(columns) -> (n, 5)`` q = (L1, L2, L3, X, Y) the pose is computed from.
``tip_force(columns) -> (n, 3) | None`` the known tool-tip force (N).
``pose_of_joints(q, machine, guess=None) -> PoseBatch(tip, axis, P, R, ok)``: vectorised FK for a
    time series (n, 5), warm-started: anchors every 32 samples solved cold, the rest started from
    an interpolation between anchors (1–2 Newton steps); rows with NaN joints or failed FK are NaN
    with ok = False. Reuse it to evaluate perturbed joint series (effect models).
``nominal_state(columns, machine) -> NominalState``: q, P, R, tip, axis, ok, axial/lateral chain
    forces (N), strain (µε), tip_force.
``predict_columns(columns, machine, channels=None) -> dict[channel, (n,)]``: predictions of the
    channels present in ``columns`` (``channels="all"``: every PREDICTABLE channel; or a list).
``predict(recording, machine=None, channels=None)``: the same for a
    :class:`pmctl.core.recording.Recording` (machine defaults to the recording's).
``residuals(recording, machine=None, predicted=None) -> dict[channel, (n,)]``: measured −
    predicted, NaN where the channel was not sampled.
Linearisation for effect models: ``pmctl.core.kinematics.jacobian_tool(state.P, state.R, geom)`` gives
d(tip_W, axis)/dq (n, 6, 5) at every sample.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pmctl.core.config import Machine
from pmctl.core.kinematics import expm_so3, initial_guess, solve_platform, tool_of_platform
from pmctl.core.recording import AXES, ENC, LOAD, STRAIN, TIP, TOOL
from pmctl.core.statics import chain_forces, strain_of_axial

PREDICTABLE = ENC + TIP + TOOL + STRAIN
ANCHOR_EVERY = 32
CHUNK = 50_000


@dataclass
class PoseBatch:
    tip: np.ndarray     # (n, 3) tool tip in W, mm
    axis: np.ndarray    # (n, 3) tool axis
    P: np.ndarray       # (n, 3)
    R: np.ndarray       # (n, 3, 3)
    ok: np.ndarray      # (n,) FK converged on the assembly branch


@dataclass
class NominalState:
    q: np.ndarray           # (n, 5) joints the pose was computed from
    P: np.ndarray
    R: np.ndarray
    tip: np.ndarray
    axis: np.ndarray
    ok: np.ndarray
    axial: np.ndarray       # (n, 3) chain compression a_i, N
    lateral: np.ndarray     # (n, 3) b_i along n_i, N
    strain: np.ndarray      # (n, 3) µε
    tip_force: np.ndarray | None   # (n, 3) N or None

    @property
    def n_failed(self) -> int:
        return int(np.count_nonzero(~self.ok))


def ffill(x):
    """Forward-fill NaN (1-D); leading NaN take the first value; all-NaN stays NaN."""
    x = np.asarray(x, float)
    good = ~np.isnan(x)
    if good.all() or not good.any():
        return x.copy()
    idx = np.where(good, np.arange(len(x)), 0)
    np.maximum.accumulate(idx, out=idx)
    first = np.argmax(good)
    idx[:first] = first
    return x[idx]


def joints_for_pose(columns) -> np.ndarray:
    """q (n, 5): enc_* where present and sampled, else cmd_*."""
    out = []
    for a in AXES:
        c = np.asarray(columns[f"cmd_{a}"], float)
        e = columns.get(f"enc_{a}") if hasattr(columns, "get") else None
        if e is not None:
            e = np.asarray(e, float)
            c = np.where(np.isnan(e), c, e)
        out.append(c)
    return np.stack(out, -1)


def tip_force(columns) -> np.ndarray | None:
    if not any(c in columns for c in LOAD):
        return None
    n = len(columns["t"])
    cols = []
    for c in LOAD:
        v = columns[c] if c in columns else np.zeros(n)
        v = ffill(v)
        cols.append(np.where(np.isnan(v), 0.0, v))
    return np.stack(cols, -1)


def _rot_log(M):
    """Rotation vector of rotation matrices M (..., 3, 3) (angles < pi)."""
    c = np.clip((np.trace(M, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    th = np.arccos(c)
    v = np.stack([M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0], M[..., 1, 0] - M[..., 0, 1]], -1)
    s = np.sin(th)
    f = np.where(th < 1e-6, 0.5 + th**2 / 12.0, th / (2.0 * np.where(th < 1e-6, 1.0, s)))
    return f[..., None] * v


def _solve_chunked(L, geom, guess=None):
    n = L.shape[0]
    P = np.empty((n, 3))
    R = np.empty((n, 3, 3))
    ok = np.empty(n, bool)
    for s in range(0, n, CHUNK):
        sl = slice(s, s + CHUNK)
        g = None if guess is None else (guess[0][sl], guess[1][sl])
        sol = solve_platform(L[sl], geom, g)
        P[sl], R[sl], ok[sl] = sol.P, sol.R, sol.ok
    return P, R, ok


def pose_of_joints(q, machine: Machine, guess=None) -> PoseBatch:
    """Vectorised, warm-started FK of a joint time series q (n, 5) (see module docstring)."""
    q = np.asarray(q, float)
    geom = machine.geometry
    n = q.shape[0]
    P = np.full((n, 3), np.nan)
    R = np.full((n, 3, 3), np.nan)
    ok = np.zeros(n, bool)
    good = np.flatnonzero(np.all(np.isfinite(q), -1))
    m = good.size
    if m:
        L = q[good, :3]
        if guess is not None:
            Pg, Rg = np.asarray(guess[0], float)[good], np.asarray(guess[1], float)[good]
        elif m <= 2 * ANCHOR_EVERY:
            Pg = Rg = None
        else:
            anchors = np.unique(np.r_[np.arange(0, m, ANCHOR_EVERY), m - 1])
            PA, RA, okA = _solve_chunked(L[anchors], geom)
            i = np.arange(m)
            seg = np.clip(np.searchsorted(anchors, i, side="right") - 1, 0, len(anchors) - 2)
            a0, a1 = anchors[seg], anchors[seg + 1]
            frac = ((i - a0) / (a1 - a0))[:, None]
            w = _rot_log(RA[1:] @ np.swapaxes(RA[:-1], -1, -2))[seg]
            Pg = PA[seg] + frac * (PA[seg + 1] - PA[seg])
            Rg = expm_so3(frac * w) @ RA[seg]
            bad = ~(okA[seg] & okA[seg + 1]) | ~np.all(np.isfinite(Pg), -1)
            if bad.any():                        # never start from a failed anchor
                P0, R0 = initial_guess(L[bad], geom)
                Pg[bad], Rg[bad] = P0, R0
        Ps, Rs, oks = _solve_chunked(L, geom, None if Pg is None else (Pg, Rg))
        if guess is None and Pg is not None and not oks.all():   # retry cold where the warm start failed
            r = np.flatnonzero(~oks)
            Pr, Rr, okr = _solve_chunked(L[r], geom)
            Ps[r], Rs[r], oks[r] = Pr, Rr, okr
        P[good], R[good], ok[good] = Ps, Rs, oks
    P = np.where(ok[:, None], P, np.nan)
    R = np.where(ok[:, None, None], R, np.nan)
    tip, axis = tool_of_platform(P, R, q[:, 3:5], geom)
    return PoseBatch(tip, axis, P, R, ok)


def nominal_state(columns, machine: Machine, *, statics=True) -> NominalState:
    q = joints_for_pose(columns)
    pose = pose_of_joints(q, machine)
    f = tip_force(columns)
    n = q.shape[0]
    axial = lateral = strain = np.full((n, 3), np.nan)
    if statics:
        idx = np.flatnonzero(pose.ok)
        axial, lateral = np.full((n, 3), np.nan), np.full((n, 3), np.nan)
        if idx.size:
            cf = chain_forces(pose.P[idx], pose.R[idx], machine, None if f is None else f[idx])
            axial[idx], lateral[idx] = cf.axial, cf.lateral
        strain = strain_of_axial(axial, machine)
    return NominalState(q, pose.P, pose.R, pose.tip, pose.axis, pose.ok, axial, lateral, strain, f)


def _wanted(columns, channels):
    if channels is None:
        return [c for c in PREDICTABLE if c in columns]
    if channels == "all":
        return list(PREDICTABLE)
    bad = [c for c in channels if c not in PREDICTABLE]
    if bad:
        raise ValueError(f"the nominal twin does not predict {bad}")
    return list(channels)


def predict_columns(columns, machine: Machine, channels=None, state: NominalState | None = None):
    """Predicted value of each wanted channel (see module docstring)."""
    want = _wanted(columns, channels)
    out = {}
    for c in want:
        if c in ENC:
            out[c] = np.asarray(columns["cmd_" + c[4:]], float).copy()
    if any(c in want for c in TIP + TOOL + STRAIN):
        if state is None:
            state = nominal_state(columns, machine, statics=any(c in want for c in STRAIN))
        for j, c in enumerate(TIP):
            if c in want:
                out[c] = state.tip[:, j].copy()
        for j, c in enumerate(TOOL):
            if c in want:
                out[c] = state.axis[:, j].copy()
        for j, c in enumerate(STRAIN):
            if c in want:
                out[c] = state.strain[:, j].copy()
    return {c: out[c] for c in want}


def predict(recording, machine: Machine | None = None, channels=None):
    """Predictions for the channels a Recording carries (or ``channels``)."""
    return predict_columns(recording.columns, machine or recording.machine, channels)


def residuals(recording, machine: Machine | None = None, predicted=None):
    """Measured − predicted for every predicted channel the recording carries (NaN = not sampled)."""
    pred = predicted if predicted is not None else predict(recording, machine)
    return {c: np.asarray(recording.columns[c], float) - p for c, p in pred.items() if c in recording.columns}
