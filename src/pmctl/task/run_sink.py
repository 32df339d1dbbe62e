"""The recording side of a one-shot run (``pmctl run``): per-tick record rows (layout R_* in
pmctl.motion.recorder, drained from the rt process's record ring by the supervisor, or from the
loop's own ring) converted to the recording's channels chunk by chunk, and the tool-tip error of
every tick kept compactly for the tracking figures at the end."""

from __future__ import annotations

AXES = ("L1", "L2", "L3", "X", "Y")
_TRUTH_NOTE = ("simulation: FK of the load-side joints (after drive lag and flexible mode); the tip of the "
               "machine config's reference tool (with a tool length offset d the cutting tip is tip - d * tool)")
_STRAIN_NOTE = "simulation: gravity strain of the true pose + flexible-mode spring strain + gauge noise"


def _held(samples, ticks, value):
    """Per-tick values of a device polled by its own thread: each sample ``(tick, ...)`` held from
    its tick until the next (NaN before the first), for the given (increasing) ticks."""
    import numpy as np
    snap = list(samples)                  # appended by the polling thread: a snapshot
    if not snap:
        return None
    tk = np.maximum(np.fromiter((s[0] for s in snap), np.int64, len(snap)), 0)
    idx = np.searchsorted(tk, ticks, side="right") - 1
    vals = np.array([value(s) for s in snap], float)
    out = vals[np.maximum(idx, 0)]
    out[idx < 0] = np.nan
    return out


class TrackingAccumulator:
    """The tool-tip and tool-axis error of every tick from the job's start, as two compact float32
    arrays indexed by tick (8 bytes a tick: a 10-minute job at 1 kHz holds 4.8 MB, the planner's
    longest job ~10 MB), so the figures of :func:`pmctl.motion.loop.tracking_stats` can be computed
    over a window known only at the end. A tick the recorder never saw (a dropped record) is -1;
    a failed FK is NaN; a non-finite load side is +inf (no figures, as tracking_stats)."""

    def __init__(self, job_start: int, expect: int = 0):
        import numpy as np
        self.j0 = int(job_start)
        self.n = 0
        self.tip = np.full(max(int(expect), 1024), -1.0, np.float32)
        self.ang = self.tip.copy()

    @property
    def nbytes(self) -> int:
        return self.tip.nbytes + self.ang.nbytes

    def add(self, ticks, e_tip, e_ang):
        import numpy as np
        keep = ticks >= self.j0
        if not keep.any():
            return
        i = ticks[keep] - self.j0
        end = int(i[-1]) + 1
        if end > len(self.tip):
            size = max(end, 2 * len(self.tip))
            for nm in ("tip", "ang"):
                a = np.full(size, -1.0, np.float32)
                a[:self.n] = getattr(self, nm)[:self.n]
                setattr(self, nm, a)
        self.tip[i] = e_tip[keep]
        self.ang[i] = e_ang[keep]
        self.n = max(self.n, end)

    def stats(self, i0: int, i1: int) -> dict:
        """tracking_stats over ticks [i0, i1): the same keys and formulas."""
        import numpy as np
        a, b = max(i0 - self.j0, 0), max(min(i1 - self.j0, self.n), 0)
        e = self.tip[a:b].astype(np.float64)
        ang = self.ang[a:b].astype(np.float64)
        seen = e != -1.0
        e, ang = e[seen], ang[seen]
        if len(e) == 0 or np.isinf(e).any():
            return {}
        ok = np.isfinite(e)
        if not ok.any():
            return {"samples": int(len(e)), "fk_failures": int(len(e))}
        return {"samples": int(len(e)), "tip_rms_um": float(np.sqrt(np.nanmean(e ** 2)) * 1e3),
                "tip_max_um": float(np.nanmax(e) * 1e3), "tip_p99_um": float(np.nanpercentile(e, 99) * 1e3),
                "axis_rms_urad": float(np.sqrt(np.nanmean(ang ** 2)) * 1e6),
                "axis_max_urad": float(np.nanmax(ang) * 1e6), "fk_failures": int(np.sum(~ok))}


class RunSink:
    """What ``pmctl run`` does with every chunk of record rows the recorder drains (layout R_* in
    pmctl.motion.recorder): converts it to the recording's channels, vectorised (one fk_batch a
    chunk for the load-side tool pose), appends them to a RecordingWriter (when recording), and
    adds the chunk's tool-tip errors to a TrackingAccumulator. Nothing else is kept: the memory
    of a run is the ring, one chunk and the accumulator.

    ``session=True`` (a ``pmctl serve`` session recording): the channels ``line`` and ``sigma`` too, and
    the time runs on across a restarted rt process (whose ticks count from 0 again). ``spindle_of``:
    a callable returning the spindle session, for one that is connected later (the daemon's, at the
    first M3/M4); ``spindle_opt`` then gives its options (the channel exists from the start)."""

    def __init__(self, machine, ppm, rate_hz: float, has_truth: bool, job_start: int, expect: int = 0,
                 spindle=None, daq=None, writer=None, load: bool = False, strain: bool = True,
                 session: bool = False, spindle_of=None, spindle_opt=None):
        import numpy as np
        self.session = bool(session)
        self._t_off, self._t_last = 0.0, -np.inf
        self.spindle_of = spindle_of if spindle_of is not None else (lambda: self.spindle)
        self.spindle_opt = spindle.opt if spindle is not None else spindle_opt
        self.machine, self.ppm, self.rate_hz = machine, np.asarray(ppm, float), float(rate_hz)
        self.load = bool(load)        # load_fx/fy/fz from the gauges (a backend with strain in its cyclic data)
        self.strain = bool(strain)    # strain_* sampled (False: the backend has no gauges in its cyclic data)
        self.has_truth = bool(has_truth)
        self.spindle, self.daq, self.writer = spindle, daq, writer
        self._comp = daq is not None and daq.opt.compensate      # comp_L1..3: the applied chain offsets
        self.track = TrackingAccumulator(job_start, expect) if has_truth else None
        self.rows = 0
        self.chunks = 0
        self.last_tick = -1

    def channels(self) -> tuple[list, dict]:
        """Channel names and notes of the recording (as record_columns, plus the devices)."""
        names = ["t"] + [f"cmd_{a}" for a in AXES] + [f"enc_{a}" for a in AXES]
        notes = {f"cmd_{a}": {"source": "pulse counter x resolution at the tick start"} for a in AXES}
        if self.has_truth:
            names += ["tip_x", "tip_y", "tip_z", "tool_i", "tool_j", "tool_k"]
            for c in ("tip_x", "tip_y", "tip_z", "tool_i", "tool_j", "tool_k"):
                notes[c] = {"source": _TRUTH_NOTE}
            for i in range(3):
                notes[f"strain_{i + 1}"] = {"source": _STRAIN_NOTE}
        names += [f"strain_{i + 1}" for i in range(3)]
        if self.load:
            from pmctl.core.strain_sensing import LOAD_CHANNELS, LOAD_NOTE
            names += list(LOAD_CHANNELS)
            for c in LOAD_CHANNELS:
                notes[c] = {"source": LOAD_NOTE}
        if self.session:
            names += ["line", "sigma"]
            notes["line"] = {"source": "line of the job or console stream being executed (console lines are counted)"}
            notes["sigma"] = {"source": "feed factor of the time-scaling (1 = as planned)"}
        if self.spindle_opt is not None:
            names.append("spindle_rpm")
            notes["spindle_rpm"] = {"source": f"VFD speed register polled every {self.spindle_opt.poll_ms:g} ms "
                                              f"by the supervisor, held between polls (negative: M4)"}
        if self.daq is not None:
            for i in range(3):
                names.append(f"daq_strain_{i + 1}")
                notes[f"daq_strain_{i + 1}"] = {"source": f"strain DAQ over Modbus TCP polled every "
                                                          f"{self.daq.opt.poll_ms:g} ms, held between polls, "
                                                          f"microstrain"}
        if self._comp:
            for i in range(3):
                names.append(f"comp_L{i + 1}")
                notes[f"comp_L{i + 1}"] = {"source": "chain-length offset the NC applied (slow compensation from "
                                                     "the strain DAQ: -deflection, slew-limited), mm"}
        return names, notes

    def __call__(self, rows):
        import numpy as np

        from pmctl.core import kinematics as K
        from pmctl.motion.recorder import R_COUNTS, R_ENC, R_STRAIN, R_TARGET, R_TICK, R_TRUTH
        ticks = rows[:, R_TICK].astype(np.int64)
        n = len(ticks)
        t = ticks / self.rate_hz
        if self.session:
            if t[0] + self._t_off <= self._t_last:     # a restarted rt process counts from 0 again
                self._t_off = self._t_last + 1.0 / self.rate_hz - t[0]
            t = t + self._t_off
            self._t_last = float(t[-1])
        cols = {"t": t}
        q_cmd = np.rint(rows[:, R_COUNTS:R_COUNTS + 5]) / self.ppm
        for i, a in enumerate(AXES):
            cols[f"cmd_{a}"] = q_cmd[:, i]
            cols[f"enc_{a}"] = rows[:, R_ENC + i]
        if self.has_truth:
            truth = rows[:, R_TRUTH:R_TRUTH + 5]
            fin = np.all(np.isfinite(truth), axis=1)
            tip = np.full((n, 3), np.nan)
            axis = np.full((n, 3), np.nan)
            ok = np.zeros(n, bool)
            if fin.any():
                pose, ok_f = K.fk_batch(truth[fin], self.machine)
                tip[fin], axis[fin], ok[fin] = pose.tip, pose.axis, ok_f
            tip[~ok] = np.nan
            axis[~ok] = np.nan
            for i, c in enumerate(("tip_x", "tip_y", "tip_z")):
                cols[c] = tip[:, i]
            for i, c in enumerate(("tool_i", "tool_j", "tool_k")):
                cols[c] = axis[:, i]
            tg = rows[:, R_TARGET:R_TARGET + 6]
            e = np.linalg.norm(tip - tg[:, :3], axis=-1)
            ang = np.arccos(np.clip(np.sum(axis * tg[:, 3:6], -1), -1.0, 1.0))
            e[~fin] = np.inf
            self.track.add(ticks, e.astype(np.float32), ang.astype(np.float32))
        for i in range(3):            # a backend without gauges in its cyclic data: not sampled (NaN), not 0
            cols[f"strain_{i + 1}"] = rows[:, R_STRAIN + i] if self.strain else np.full(n, np.nan)
        if self.load:
            from pmctl.core.strain_sensing import load_columns
            cols.update(load_columns(rows[:, R_STRAIN:R_STRAIN + 3], q_cmd, self.machine))
        if self.session:
            from pmctl.motion.recorder import R_LINE, R_SIGMA
            cols["line"] = rows[:, R_LINE]
            cols["sigma"] = rows[:, R_SIGMA]
        if self.spindle_opt is not None:
            sp = self.spindle_of()
            mon = sp.monitor if sp is not None else None
            v = _held(mon.samples, ticks, lambda s: s[1]) if mon is not None else None
            cols["spindle_rpm"] = np.full(n, np.nan) if v is None else v * sp.direction
        if self.daq is not None:
            d = self.daq.daq
            for i in range(3):
                v = _held(d.samples, ticks, lambda s, i=i: s[2][i]) if d is not None else None
                cols[f"daq_strain_{i + 1}"] = np.full(n, np.nan) if v is None else v
        if self._comp:
            from pmctl.motion.recorder import R_CHAIN_OFFSET
            for i in range(3):
                cols[f"comp_L{i + 1}"] = rows[:, R_CHAIN_OFFSET + i]
        if self.writer is not None:
            self.writer.append(cols)
        self.rows += n
        self.chunks += 1
        self.last_tick = int(ticks[-1])
