"""The nominal twin of a machine of independent axes (``"machine": "axes"``, pmctl.core.recording_axes)
and the diagnosis context built on it.

Nominal twin, per axis A (what an ideal, rigid, massless, frictionless drive would record):

- ``enc_<A>`` = ``cmd_<A>`` (the drive follows its command exactly);
- ``load_<A>`` = ``enc_<A>`` where it was sampled, else ``cmd_<A>`` (no play, no give between
  motor and load);
- ``effort_<A>`` = 0 (no mass, no friction, no load);
- ``acc_<A>`` = d²``cmd_<A>``/dt² (the commanded acceleration, central differences on the log's
  time stamps; no ringing).

Everything else is what the diagnosis finds (pmctl.tools.twin.drive and the catalogue of
pmctl.tools.twin.effects that applies to independent axes). Pure math; no I/O.
"""

from __future__ import annotations

import numpy as np

from pmctl.core.recording_axes import AxesMachine, axis_of, channel_kind
from pmctl.tools.twin import effects as fx
from pmctl.tools.twin.catalogue import DEFAULT_CAP
from pmctl.tools.twin.effects import Context

MEASURED = ("enc", "load", "effort", "acc")


def _second_derivative(t, x):
    return np.gradient(np.gradient(x, t), t) if len(x) > 2 else np.zeros_like(x)


def predict_columns(columns, machine: AxesMachine, names, rows=None, bounds=None) -> dict:
    """The nominal twin's value of each channel in ``names`` (at ``rows``; default all rows).
    ``bounds``: run bounds of a recording kept as runs (no derivative across a gap)."""
    t = np.asarray(columns["t"], float)
    n = len(t)
    rows = np.arange(n) if rows is None else np.asarray(rows, int)
    b = np.asarray([0, n] if bounds is None else bounds, int)
    out = {}
    for k in names:
        kind, A = channel_kind(k), axis_of(k)
        cmd = np.asarray(columns[f"cmd_{A}"], float)
        if kind == "enc":
            out[k] = cmd[rows]
        elif kind == "load":
            enc = columns.get(f"enc_{A}")
            src = cmd if enc is None else np.where(np.isfinite(enc), np.asarray(enc, float), cmd)
            out[k] = src[rows]
        elif kind == "effort":
            out[k] = np.zeros(len(rows))
        elif kind == "acc":
            c = fx.fill_gaps(t, cmd)
            acc = np.concatenate([_second_derivative(t[s:e], c[s:e]) for s, e in zip(b[:-1], b[1:]) if e > s])
            out[k] = acc[rows]
    return out


def _floor(name, columns):
    """Smallest credible noise of a channel: half the smallest step an encoder counts (sub-count
    structure is quantisation), else a tiny number."""
    if channel_kind(name) in ("enc", "load"):
        x = np.asarray(columns[name], float)
        x = x[np.isfinite(x)][:200_000]
        d = np.abs(np.diff(x))
        d = d[d > 1e-12 * max(float(np.max(np.abs(x))) if len(x) else 0.0, 1e-300)]
        if len(d):
            q = float(np.quantile(d, 0.01))
            return 0.5 * q
    return 1e-12


def build_context(columns: dict, machine: AxesMachine, *, cap=DEFAULT_CAP, bounds=None,
                  direction_before=None) -> Context:
    """The residuals of the nominal twin at the analysis rows, whitened and stacked (the same
    observations, runs and sample bookkeeping as the prototype's, pmctl.tools.twin.diagnose)."""
    from pmctl.tools.twin.diagnose import observations, record_runs, regular_times, settled_rows, uniform_step
    t = np.asarray(columns["t"], float)
    n = len(t)
    bounds = np.asarray([0, n] if bounds is None else bounds, int)
    runs = len(bounds) > 2
    if not runs:
        t = regular_times(t)
    columns = dict(columns, t=t)
    axes = list(machine.axes)
    q_cmd = np.stack([fx.fill_gaps(t, np.asarray(columns[f"cmd_{a}"], float)) for a in axes], 1)
    has_enc = np.array([f"enc_{a}" in columns and np.isfinite(np.asarray(columns[f"enc_{a}"], float)).any()
                        for a in axes])
    q_motor = q_cmd.copy()
    for i, a in enumerate(axes):
        if has_enc[i]:
            q_motor[:, i] = fx.fill_gaps(t, np.asarray(columns[f"enc_{a}"], float))
    temps = {k: fx.fill_gaps(t, np.asarray(v, float)) for k, v in columns.items()
             if channel_kind(k) == "temp" and np.isfinite(v).sum() >= 2}
    obs_names = [k for k in columns if channel_kind(k) in MEASURED]

    def predict_at(rows_all, names):
        sub = {k: np.asarray(columns[k], float)[rows_all] for k in names}
        return sub, predict_columns(columns, machine, names, rows_all, bounds)

    settled = settled_rows(t, bounds, runs)
    # the force model differentiates the filtered motor position: its first and last few filter
    # lengths of each run are edge transients, not motion; effort is analysed inside them
    from pmctl.tools.twin.drive import edge_rows
    inner = settled & ~edge_rows(t, bounds)
    settled_by = {k: (inner if channel_kind(k) == "effort" else settled) for k in obs_names}
    floors = {k: _floor(k, columns) for k in obs_names}
    obs, rows, _, sampled = observations(columns, obs_names, predict_at, settled_by, cap, floors.get)
    m = len(rows)
    ctx = Context(machine, t, q_cmd, q_motor, has_enc, temps, rows, np.zeros((m, 0, len(axes))), {},
                  np.zeros((m, 0)), obs, uniform_step(t, bounds))
    ctx.extra["axes"] = tuple(axes)
    ctx.extra["P"] = ctx.extra["R"] = None
    ctx.extra["effort"] = {k: fx.fill_gaps(t, np.asarray(columns[k], float)) for k in columns
                           if channel_kind(k) == "effort" and np.isfinite(np.asarray(columns[k], float)).any()}
    record_runs(ctx, bounds, sampled, direction_before)
    return ctx


def unit_of(machine: AxesMachine, channel: str) -> str:
    return machine.units.get(channel, "")
