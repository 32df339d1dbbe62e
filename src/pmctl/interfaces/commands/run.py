"""`pmctl run`: machine a job with the fixed-rate loop against a backend (the loopback sim by default).

    pmctl run --config config/prototype.toml --backend sim --job examples/jobs/<job> --record DIR
              [--force] [--rate HZ] [--no-realtime] [--service config/service.toml] [--state FILE]

Checks every input first (job, record target, backend, state file), then plans the job from where
the machine is (saved pulse counters, else home), runs the loop, shows progress, prints
tracking-error and timing statistics. With --record the run is written as a recording
(docs/recording.md) while it runs, chunk by chunk from the loop's bounded record ring, into
``<DIR>.partial/``, renamed to DIR at the end: memory does not grow with the job, and a run that
is killed (kill -9, power loss) leaves ``<DIR>.partial/`` with the samples up to the last chunk
drained (every 20 ms in real time), readable as an incomplete recording.

Ctrl-C, SIGTERM (``systemctl stop``) and SIGHUP all ask for a controlled stop: the machine
decelerates along its path, the counters are saved as a clean stop and the recording is written.
Output to a closed pipe (``pmctl run ... | head``) is dropped; the run goes on and is saved.

A probing move (G38.2/G38.3, the job's last motion) is stopped on contact by the strain monitor
(pmctl.motion.probe, [probe] in the service config); the contact point is printed as grbl's
``[PRB:x,y,z,a,b:1]`` and kept in recording.json's run block. Recordings of a backend with gauges in
its cyclic data carry load_fx/fy/fz (the tool-tip force estimated from the strains, per chunk).

Exit codes: 0 done; 3 controlled stop (soft limit, path error, missed deadlines, stall, Ctrl-C,
SIGTERM); 4 fault (following error, backend not answering, model pose lost, G38.2 without contact);
1 bad input.
"""

from __future__ import annotations

import math
import os
import signal
import sys
import threading
import time
from pathlib import Path

EXIT_DONE, EXIT_STOPPED, EXIT_FAULT = 0, 3, 4
STOP_SIGNALS = {"SIGINT": "interrupted by the operator (Ctrl-C)",
                "SIGTERM": "stop requested (SIGTERM, e.g. systemctl stop)",
                "SIGHUP": "stop requested (SIGHUP: the terminal went away)"}


def add_parser(sub):
    p = sub.add_parser("run", help="machine a job: the control loop against a backend (sim by default)",
                       description="Run a job through the closed-loop NC at a fixed tick rate and record it. "
                                   "Ctrl-C or SIGTERM stops the machine in a controlled way and saves the run. "
                                   "Exit status: 0 done, 3 controlled stop, 4 fault, 1 bad input.",
                       epilog="The recording format is described in docs/recording.md; the state file and "
                              "what stops a run in README.md; probing (G38.2/G38.3, stopped on contact by the "
                              "strain gauges) and the load_fx/fy/fz channels in docs/vibration.md section 4.")
    p.add_argument("--config", default="prototype", help="machine config (default: config/prototype.toml)")
    p.add_argument("--service", default=None, help="service config (default: config/service.toml)")
    p.add_argument("--backend", default=None, help="HAL backend, e.g. 'sim' (default: [hal] backend of the service config)")
    p.add_argument("--job", required=True, help="job file: G-code (.ngc .nc .gcode .tap) or CL data (.cl ...)")
    p.add_argument("--record", metavar="DIR", default=None,
                   help="write the run as a recording folder (must not exist yet; see --force)")
    p.add_argument("--force", action="store_true", help="replace an existing recording in --record DIR")
    p.add_argument("--rate", type=float, default=None, metavar="HZ", help="tick rate (default: service config)")
    p.add_argument("--no-realtime", action="store_true",
                   help="run ticks back to back, no sleeping and no real-time priority (offline simulation: "
                        "a slow tick is not a stall)")
    p.add_argument("--k-theta", default=None, metavar="PER_S|auto",
                   help="strain-gauge feedback gain per chain, 1/s (0 = off), or auto: per chain from the chain "
                        "mode (docs/vibration.md; default: service config)")
    p.add_argument("--shaper", default=None, metavar="TYPE|auto|none",
                   help="input shaper on the time law along the path (the tool stays on the path): ZV, MZV, ZVD, "
                        "EI, 2HUMP_EI, 3HUMP_EI, auto (from the chain modes) or none (default: [nc] shaper)")
    p.add_argument("--pulse-mode", choices=("multi", "single"), default=None,
                   help="V-F converters: integer pulses per tick (multi) or the original controller's one per tick (single; Kamiya et al. 2005)")
    p.add_argument("--state", default=None, metavar="FILE",
                   help="pulse-counter state file: where the machine is between runs (default: the service "
                        "config's state_file, per user); --state '' for none")
    p.add_argument("--feed-override", type=float, default=1.0, help="feed override factor (default 1)")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.set_defaults(func=run)


def _machine_ref(config_arg: str, machine, record_dir: Path) -> str:
    """How recording.json names the machine: a shipped config by name, else a path relative to the folder."""
    from pmctl.core.config import CONFIG_DIR
    p = Path(config_arg)
    if not p.suffix and not p.exists():
        return p.name
    p = p.resolve()
    if p.parent == CONFIG_DIR.resolve():
        return p.stem
    return os.path.relpath(p, record_dir.absolute())


class _Out:
    """stdout/stderr that never raise: output to a closed pipe (``pmctl run ... | head``) is
    dropped, so the loop, the saved counters and the recording never depend on a reader."""

    def __init__(self):
        self.lost = set()

    def write(self, text: str, err: bool = False):
        stream = sys.stderr if err else sys.stdout
        if stream is None or err in self.lost:
            return
        try:
            stream.write(text)
            stream.flush()
        except (BrokenPipeError, ValueError, OSError):
            self.lost.add(err)
            try:           # keep Python from failing again when it flushes the stream at exit
                os.dup2(os.open(os.devnull, os.O_WRONLY), stream.fileno())
            except (OSError, ValueError):
                pass

    def say(self, msg: str):
        self.write(msg + "\n")

    def log(self, msg: str):
        self.write(f"pmctl: {msg}\n", err=True)


class _Progress:
    def __init__(self, lp, job_name: str, dt: float, quiet: bool, out: _Out):
        self.lp, self.name, self.dt = lp, job_name, dt
        try:
            self.tty = sys.stderr.isatty()
        except (ValueError, AttributeError):
            self.tty = False
        self.quiet = quiet
        self.out = out
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True, name="pmctl-progress")

    def start(self):
        if not self.quiet:
            self._t.start()

    def _line(self):
        from pmctl.motion.nc import MODE_NAMES
        lp = self.lp
        k, n = lp.tick, max(lp.n_ticks, 1)
        frac = min(1.0, k / n)
        bar = "#" * int(frac * 24)
        return (f"{self.name}: [{bar:<24}] {100 * frac:5.1f}%  t = {k * self.dt:7.2f} / {n * self.dt:.2f} s  "
                f"{MODE_NAMES.get(lp.mode, '?')}")

    def _run(self):
        period = 0.2 if self.tty else 5.0
        while not self._stop.wait(period):
            if self.tty:
                self.out.write("\r" + self._line(), err=True)
            else:
                self.out.write(self._line() + "\n", err=True)

    def finish(self):
        self._stop.set()
        if self._t.is_alive():
            self._t.join()
            if self.tty:
                self.out.write("\r" + self._line() + "\n", err=True)


AXES = ("L1", "L2", "L3", "X", "Y")
_TRUTH_NOTE = "simulation: FK of the load-side joints (after drive lag and flexible mode)"
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
    of a run is the ring, one chunk and the accumulator."""

    def __init__(self, machine, ppm, rate_hz: float, has_truth: bool, job_start: int, expect: int = 0,
                 spindle=None, daq=None, writer=None, load: bool = False, strain: bool = True):
        import numpy as np
        self.machine, self.ppm, self.rate_hz = machine, np.asarray(ppm, float), float(rate_hz)
        self.load = bool(load)        # load_fx/fy/fz from the gauges (a backend with strain in its cyclic data)
        self.strain = bool(strain)    # strain_* sampled (False: the backend has no gauges in its cyclic data)
        self.has_truth = bool(has_truth)
        self.spindle, self.daq, self.writer = spindle, daq, writer
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
        if self.spindle is not None:
            names.append("spindle_rpm")
            notes["spindle_rpm"] = {"source": f"VFD speed register polled every {self.spindle.opt.poll_ms:g} ms "
                                              f"by the supervisor, held between polls (negative: M4)"}
        if self.daq is not None:
            for i in range(3):
                names.append(f"daq_strain_{i + 1}")
                notes[f"daq_strain_{i + 1}"] = {"source": f"strain DAQ over Modbus TCP polled every "
                                                          f"{self.daq.opt.poll_ms:g} ms, held between polls, "
                                                          f"microstrain"}
        return names, notes

    def __call__(self, rows):
        import numpy as np

        from pmctl.core import kinematics as K
        from pmctl.motion.recorder import R_COUNTS, R_ENC, R_STRAIN, R_TARGET, R_TICK, R_TRUTH
        ticks = rows[:, R_TICK].astype(np.int64)
        n = len(ticks)
        cols = {"t": ticks / self.rate_hz}
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
        if self.spindle is not None:
            mon = self.spindle.monitor
            v = _held(mon.samples, ticks, lambda s: s[1]) if mon is not None else None
            cols["spindle_rpm"] = np.full(n, np.nan) if v is None else v * self.spindle.direction
        if self.daq is not None:
            d = self.daq.daq
            for i in range(3):
                v = _held(d.samples, ticks, lambda s, i=i: s[2][i]) if d is not None else None
                cols[f"daq_strain_{i + 1}"] = np.full(n, np.nan) if v is None else v
        if self.writer is not None:
            self.writer.append(cols)
        self.rows += n
        self.chunks += 1
        self.last_tick = int(ticks[-1])


def _plant_meta(backend) -> dict:
    """What a simulated plant put into the run that the nominal twin leaves out (its chain modes),
    so that ``pmctl twin diagnose`` can say a finding is the simulation's own physics."""
    opt = getattr(backend, "opt", None)
    hz = getattr(backend, "mode_hz", None)
    if opt is None or hz is None or not getattr(opt, "flex", False):
        return {}
    return {"kind": "simulation", "chain_mode_hz": [round(float(f), 4) for f in hz],
            "chain_mode_damping_ratio": [float(z) for z in getattr(opt, "mode_damping_ratio", [])]}


def tracking_window(res, stop_tick: int | None) -> tuple[int, int, str]:
    """Ticks over which the tool-tip error means something: (first, end, note).

    A run that ended done is tracked from the job's first point to its end. A run stopped by a
    signal is tracked up to the stop request: after it the machine decelerates off the path on
    purpose. A run the loop stopped on its own (stall, limit, path error) is not reported: the
    stopping ramp would dominate the figures. ``end <= first`` means nothing to report."""
    j0 = int(res.job_start)
    if res.status == "done":
        return j0, res.ticks, ""
    if stop_tick is not None:
        end = min(int(stop_tick), res.ticks)
        if end <= j0:
            return j0, j0, "the job was stopped before it started (during the approach to its first point)"
        return j0, end, f"over the {(end - j0) * res.dt:.2f} s machined before the stop request"
    return j0, j0, f"not reported: the run {res.status} ({res.reason}); the figures would measure the stop, not the tracking"


def _strain_of(backend):
    """The strain gauges the backend's last feedback holds (what a simulated DAQ serves)."""
    fb = getattr(backend, "_fb", None)
    return fb.strain.tolist() if fb is not None else [0.0, 0.0, 0.0]


def run(args) -> int:
    import numpy as np

    from pmctl import hal
    from pmctl.core import kinematics as K
    from pmctl.core.config import load_machine
    from pmctl.core.errors import PmctlError
    from pmctl.core.recording import check_target, partial_path
    from pmctl.motion.loop import ControlLoop, prepare
    from pmctl.motion.nc import counts_of, initial_state
    from pmctl.motion.service_config import load_service_config
    from pmctl.motion.state_store import CounterWriter, StateLock, load_counters
    from pmctl.task.planner import load_job

    out = _Out()
    log = out.log

    # ---- every input is checked before anything is said about the machine or anything moves
    if args.rate is not None and not (math.isfinite(args.rate) and 10 <= args.rate <= 20000):
        raise PmctlError(f"--rate must be within 10 .. 20000 Hz, got {args.rate:g}")
    from pmctl.motion.service_config import parse_k_theta_flag, parse_shaper_flag
    k_theta_arg = parse_k_theta_flag(args.k_theta)
    shaper_arg = parse_shaper_flag(getattr(args, "shaper", None))
    if not (math.isfinite(args.feed_override) and 0 < args.feed_override <= 10):
        raise PmctlError(f"--feed-override must be within (0, 10], got {args.feed_override:g}")
    if args.backend is not None and args.backend not in hal.BACKENDS:
        raise PmctlError(f"--backend {args.backend!r}: unknown backend; known: {', '.join(sorted(hal.BACKENDS))}")
    if args.force and not args.record:
        raise PmctlError("--force replaces an existing --record folder; there is no --record")
    if args.record:               # find out now, not after the run, that the recording cannot be written
        folder = Path(args.record)
        check_target(folder, overwrite=args.force)
        part = partial_path(folder)
        if part.exists() and not args.force:
            raise PmctlError(f"--record {folder}: {part} exists (a run that was killed left it; it reads as an "
                             f"incomplete recording); move it away, or --force to replace it")
    machine = load_machine(args.config)
    svc = load_service_config(args.service)
    cfg = svc.loop
    if args.rate is not None:
        cfg.rate_hz = float(args.rate)
    if args.no_realtime:
        cfg.realtime = False
    if k_theta_arg is not None:
        svc.nc.k_theta_auto = k_theta_arg == "auto"
        svc.nc.k_theta_per_s = (0.0,) * 3 if svc.nc.k_theta_auto else (k_theta_arg,) * 3
    if shaper_arg is not None:
        svc.nc.shaper = shaper_arg
    if args.pulse_mode:
        svc.nc.pulse_mode = args.pulse_mode
    backend_name = args.backend or svc.backend
    state_file = cfg.state_file if args.state is None else args.state
    dt = cfg.dt
    from pmctl.motion.service_config import nc_setup
    setup = nc_setup(svc, machine, dt, backend_name)     # chain modes, K_theta auto, shaper
    from pmctl.hal.modbus_daq import check_k_theta_source
    check_k_theta_source(svc.daq, svc.nc.k_theta_per_s, machine, f"{svc.source}: daq")
    strain_in_loop = getattr(hal.backend_class(backend_name), "strain_in_loop", True)
    if not strain_in_loop and any(svc.nc.k_theta_per_s):
        log(f"K_theta off: backend {backend_name} carries no strain gauges in its cyclic data")
        svc.nc.k_theta_per_s = (0.0,) * 3
    params = svc.nc.params(machine, dt, where=svc.source, modes=setup.modes)

    # Where the machine is: saved counters, else home (said only once everything has been checked).
    lock = StateLock(state_file) if state_file else None      # noqa: F841 (held until the process exits)
    saved = load_counters(state_file, machine=machine.name) if state_file else None
    if saved is not None:
        counts0 = saved.counts
        where = (f"position from {state_file} (tick {saved.tick}"
                 + (", clean stop)" if saved.clean else "; NOT a clean stop: re-home if in doubt)"))
    else:
        from pmctl.task.planner import home_pose
        h_tip, h_axis = home_pose(machine)
        counts0 = counts_of(K.ik(h_tip, h_axis, machine).q, params)
        where = "position: home" + (f" (no saved counters in {state_file})" if state_file else " (--state '')")
    st = initial_state(machine, counts0)

    job = load_job(args.job, machine, start=(st.tip, st.axis))
    if not job.moves:                 # nothing to run (an empty file, only comments and M30): say so
        from pmctl.core.errors import InputError
        raise InputError(args.job, None, "no motion in the job (no move and no dwell): nothing to run")
    for line, text in job.messages:                  # G-code (MSG, ...): for the operator, before it runs
        log(f"message from {Path(args.job).name} line {line}: {text}")
    probe_segs = []
    if any(m.probe for m in job.moves):
        from pmctl.motion.probe import check_probe_job, probe_segments
        check_probe_job(job, svc.probe, args.job, args.feed_override)
        probe_segs = probe_segments(job, machine, st.tip)
    plan_machine = machine
    notes = []
    if np.any(params.vmax < machine.limits.joint_speed - 1e-9):
        # the V-F converters cap the joint speed below the machine's (seed mode: one pulse per
        # tick): plan within what they can emit
        from dataclasses import replace
        lim = replace(machine.limits, chain_speed=float(params.vmax[:3].min()), table_speed=float(params.vmax[3:].min()))
        plan_machine = replace(machine, limits=lim)
        notes.append(f"V-F converters limit the joints to {params.vmax.min():.3g} mm/s at {cfg.rate_hz:g} Hz: "
                     f"planning with that")
    traj = _plan(job, plan_machine, dt, args.feed_override, (st.tip, st.axis))
    from pmctl.motion.timescale import shape_trajectory
    traj = shape_trajectory(traj, setup.shaper)
    notes += setup.notes
    targets = prepare(machine, params, traj, dt, counts0)
    backend = hal.create(backend_name, machine, dt, svc.backend_tables.get(backend_name, {}))

    # From here on a stop signal is a controlled stop: before the loop exists it is remembered and
    # the loop stops at its first tick (nothing moves), after that it asks the loop to decelerate.
    stop_tick, pending, holder = [], [], {}

    def _stop(signum, frame):
        # runs in the main thread between two bytecodes (of the loop, once it runs): flags only
        reason = STOP_SIGNALS.get(signal.Signals(signum).name, f"signal {signum}")
        lp_ = holder.get("lp")
        if lp_ is None:
            pending.append(reason)
        elif not lp_.stop_request:
            stop_tick.append(lp_.tick)
            lp_.stop_request = reason
    old = {}
    if threading.current_thread() is threading.main_thread():
        for name in STOP_SIGNALS:
            sig = getattr(signal, name, None)
            if sig is not None:
                old[sig] = signal.signal(sig, _stop)
    from pmctl.hal.modbus_daq import DaqSession
    from pmctl.hal.modbus_vfd import SpindleSession, job_speed
    rpm_job, spindle, daq = job_speed(traj.spindle_rpm), None, None
    if rpm_job and svc.spindle is None:
        notes.append(f"no [spindle] in {svc.source}: the job's S{abs(rpm_job):g} M{3 if rpm_job > 0 else 4} "
                     f"is not executed")
    try:
        log(where)
        for m in notes:
            log(m)
        try:
            if rpm_job and svc.spindle is not None:
                spindle = SpindleSession(svc.spindle, log).connect()   # the link answers before the drives enable
            backend.open(counts0)
            if svc.daq is not None:       # the simulated DAQ serves the backend's (plant's) strain gauges
                daq = DaqSession(svc.daq, lambda: _strain_of(backend), log).connect()
            if spindle is not None:
                spindle.start(rpm_job)    # cutting waits for at speed
        except BaseException:
            backend.close()
            for dev in (spindle, daq):
                if dev is not None:
                    dev.close()
            raise
        writer = CounterWriter(state_file, machine=machine.name) if state_file else None
        # the records stream out of the loop's bounded ring chunk by chunk: into the recording
        # (written as it goes, so a killed run leaves <DIR>.partial) and into the tracking figures
        from pmctl.motion.recorder import REC_CAPACITY, REC_WIDTH, Recorder
        from pmctl.motion.ring import Ring
        sink = RunSink(machine, params.pulses_per_mm, cfg.rate_hz, backend.truth() is not None,
                       targets.job_start, len(targets.rows) - targets.job_start, spindle, daq,
                       load=strain_in_loop, strain=strain_in_loop)
        probe = None
        if probe_segs:
            from pmctl.motion.probe import ProbeMonitor
            probe = ProbeMonitor(machine, probe_segs, svc.probe, dt, params)
        rec_writer = None
        if args.record:
            rec_writer = _open_recording(args, machine, backend, backend_name, cfg, sink, targets.job_start)
            sink.writer = rec_writer
        try:
            ring = Ring(REC_CAPACITY, REC_WIDTH)
            lp = ControlLoop(machine, backend, params, targets, cfg, st, log=log, writer=writer, records=ring,
                             recorder=Recorder(ring, keep=False, sink=sink), probe=probe)
        except BaseException:
            if rec_writer is not None:
                rec_writer._discard()       # nothing ran: nothing is left under any name
            raise
        holder["lp"] = lp
        if spindle is not None:           # S changes inside the job: the path waits at each for the speed
            spindle.follow(lp, targets, traj.spindle_rpm)
        if pending:
            stop_tick.append(0)
            lp.stop_request = pending[0]
        mode = "multi-pulse" if params.max_pulses_per_tick > 1 else "one pulse per tick (as in Kamiya et al. 2005)"
        log(f"{Path(args.job).name}: {len(targets.rows) * dt:.2f} s at {cfg.rate_hz:g} Hz, backend {backend_name}, "
            f"V-F {mode}, K_theta {'/'.join(f'{k:.4g}' for k in sorted(set(svc.nc.k_theta_per_s)))}/s, "
            f"{'real-time' if cfg.realtime else 'no real-time (ticks back to back)'}")
        prog = _Progress(lp, Path(args.job).name, dt, args.quiet, out)
        return _run_and_report(args, lp, prog, backend, writer, state_file, machine, params, cfg, dt,
                               counts0, backend_name, stop_tick, out, spindle, daq, sink, rec_writer)
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


def _plan(job, machine, dt, feed_override, start):
    """The job planned by the streaming planner the daemon uses: validated whole first (nothing
    moves on a bad line), then planned window by window and joined, since the in-process loop
    replays a whole preflighted trajectory (bounded as the batch planner is: MAX_SAMPLES ticks)."""
    from pmctl.core.errors import InputError
    from pmctl.task.planner import MAX_SAMPLES, plan_stream, validate
    from pmctl.task.trajectory import Trajectory
    path = validate(job, machine, dt, feed_override=feed_override, start=start, batch=True)

    def too_long(n):
        return InputError(job.source, None, f"the planned job takes more than {MAX_SAMPLES} ticks "
                                            f"({MAX_SAMPLES * dt / 60:.0f} min at {1 / dt:g} Hz), what a one-shot "
                                            f"run holds; run longer jobs through pmctl serve")
    return Trajectory.join(plan_stream(job, machine, dt, feed_override=feed_override, start=start, path=path),
                           MAX_SAMPLES, too_long)


def _open_recording(args, machine, backend, backend_name, cfg, sink, job_start):
    """The recording, opened before the loop starts: ``<DIR>.partial/`` marked incomplete, with the
    run's metadata as far as it is known (status "running"; the rest is written at the end)."""
    from pmctl.core.recording import RecordingWriter
    folder = Path(args.record)
    names, notes = sink.channels()
    run_meta = {"job": str(args.job), "status": "running", "reason": "", "job_start_row": int(job_start),
                "backend": backend_name}
    plant = _plant_meta(backend)
    if plant:
        run_meta["plant"] = plant
    desc = f"pmctl run {Path(args.job).name} on backend {backend_name} at {cfg.rate_hz:g} Hz: running"
    w = RecordingWriter(folder, names, machine=_machine_ref(args.config, machine, folder),
                        sample_rate_hz=cfg.rate_hz, description=desc, channel_notes=notes,
                        extra_meta={"run": run_meta}, overwrite=args.force)
    return w.__enter__()


def _run_and_report(args, lp, prog, backend, writer, state_file, machine, params, cfg, dt, counts0,
                    backend_name, stop_tick, out, spindle, daq, sink, rec) -> int:
    try:
        return _run_and_report_1(args, lp, prog, backend, writer, state_file, machine, params, cfg, dt,
                                 counts0, backend_name, stop_tick, out, spindle, daq, sink, rec)
    except BaseException as e:
        # whatever went wrong after the loop ended, the rows written so far are kept, marked incomplete
        if rec is not None and not rec._done and rec.rows:
            try:
                rec.finish(complete=False, reason=f"pmctl run ended by {type(e).__name__}: {e}")
            except Exception:
                pass
        raise


def _run_and_report_1(args, lp, prog, backend, writer, state_file, machine, params, cfg, dt, counts0,
                      backend_name, stop_tick, out, spindle, daq, sink, rec) -> int:
    import numpy as np
    log = out.log
    prog.start()
    t_wall = time.monotonic()
    for dev in (spindle, daq):            # polled by their own threads; a fault or lost link stops the run
        if dev is not None:
            dev.watch(lambda: lp.tick, lambda why: setattr(lp, "stop_request", why))
    close_errors = []
    try:
        res = lp.run()                    # its recorder has drained the last rows into the sink
    finally:
        prog.finish()
        # each device is closed whatever the others do: the spindle first (M5), then the drives
        for dev in (spindle, daq, backend):
            if dev is not None:
                try:
                    dev.close()
                except Exception as e:    # noqa: BLE001 (kept, reported, the run ends as a fault)
                    close_errors.append((dev, e))
        if writer is not None:
            writer.stop()          # on a crash the last periodic snapshot (clean = false) stays
    if close_errors:
        # e.g. a step/dir bridge whose final counters disagree: the device's counters are the truth
        from dataclasses import replace
        st = res.state
        for dev, e in close_errors:
            if dev is backend and getattr(e, "counts", None) is not None:
                st = st.with_counts(e.counts)
        why = "; ".join(f"closing {getattr(d, 'name', type(d).__name__)}: {e}" for d, e in close_errors)
        res = replace(res, status="fault", state=st, reason=(res.reason + "; " if res.reason else "") + why)
    wall = time.monotonic() - t_wall
    if writer is not None and writer.error:
        log(f"warning: periodic writes of {state_file} failed during the run ({writer.error}); "
            f"a crash would have lost the position")
    if writer is not None:
        from pmctl.motion.state_store import save_counters
        # clean: the counters are exactly what was sent and the machine did what they say (a
        # controlled stop included); after a fault (following error, lost backend) the position is
        # in doubt: the next start says so
        save_counters(state_file, res.state.counts, machine=machine.name, clean=res.status != "fault",
                      tick=res.ticks)

    probes = [r for r in lp.probe.results] if lp.probe is not None else []
    probe_err = next((r.error for r in probes if r.error), "")
    if probe_err and res.status == "done":     # G38.2 without contact: grbl's probe-fail alarm
        from dataclasses import replace
        res = replace(res, status="fault", reason=probe_err)

    # ---- the recording first (the run's data must not depend on stdout staying open), then the report
    sent_ok = bool(np.all(counts0 + res.pulses_sent == res.state.counts))
    rec_error = lp.recorder.error
    if rec_error:
        log(f"warning: the recorder stopped at row {sink.rows}: {rec_error}")
    i0, i1, track_note = tracking_window(res, stop_tick[0] if stop_tick else None)
    ts = {}
    if i1 > i0 and sink.track is not None and not rec_error:
        ts = sink.track.stats(i0, i1)
    tm = res.timing.summary()
    dropped = int(res.dropped)
    rec_rows = None
    if rec is not None:
        desc = (f"pmctl run {Path(args.job).name} on backend {backend_name} at {cfg.rate_hz:g} Hz: {res.status}"
                + (f" ({res.reason})" if res.reason else ""))
        run_meta = dict(rec.meta.get("run", {}))
        run_meta.update({"status": res.status, "reason": res.reason, "tracking": ts, "timing": tm})
        if track_note:
            run_meta["tracking_note"] = track_note
        if dropped:
            run_meta["dropped_rows"] = dropped
        if probes:
            run_meta["probe"] = [r.as_dict() for r in probes]
        # a stopped run is a complete recording of what happened: "complete" is about the file;
        # rows the recorder missed (dropped, or a recording error) make it incomplete
        missing = dropped or rec_error or rec.rows != res.ticks
        why = (f"{dropped} rows dropped (the recorder fell behind the loop)" if dropped
               else f"recording error: {rec_error}" if rec_error
               else f"{rec.rows} rows for {res.ticks} ticks")
        if rec._done:
            log(f"warning: the recording {args.record} was abandoned during the run ({rec_error})")
        else:
            try:
                rec_rows = rec.rows
                rec.finish(complete=not missing, reason=why if missing else "",
                           extra_meta={"description": desc, "run": run_meta})
            except Exception as e:
                log(f"warning: the recording {args.record} could not be finished: {e}")
                rec_rows = None
    say = out.say
    say(f"result: {res.status}" + (f" ({res.reason})" if res.reason else ""))
    say(f"  ticks {res.ticks} ({res.ticks * dt:.2f} s machine time, {wall:.2f} s wall), "
        f"pulses sent = pulse counters: {'yes' if sent_ok else 'NO'}")
    if dropped:
        say(f"  records dropped: {dropped} (the recorder fell behind the loop; the recording and the "
            f"tracking figures miss those ticks)")
    if ts:
        say(f"  tool-tip error (load side vs target, job part{', ' + track_note if track_note else ''}): "
            f"RMS {ts['tip_rms_um']:.3f} um, p99 {ts['tip_p99_um']:.3f} um, max {ts['tip_max_um']:.3f} um; "
            f"tool axis RMS {ts['axis_rms_urad']:.2f} urad, max {ts['axis_max_urad']:.2f} urad")
    elif track_note:
        say(f"  tool-tip error: {track_note}")
    for r in probes:
        if r.contact:
            say(f"  probe G38.{r.mode} (line {r.line}): contact at X{r.point[0]:.4f} Y{r.point[1]:.4f} "
                f"Z{r.point[2]:.4f} mm (tool tip in W); stopped {r.overtravel_mm * 1e3:.1f} um past it, "
                f"{r.after_trigger_mm * 1e3:.1f} um past the trigger (bound {r.bound_mm * 1e3:.1f} um)")
        else:
            say(f"  probe G38.{r.mode} (line {r.line}): no contact; at the target X{r.stop[0]:.4f} "
                f"Y{r.stop[1]:.4f} Z{r.stop[2]:.4f} mm")
        say(f"  {r.prb()}")
    if tm:
        say(f"  timing: tick compute median {tm['compute_median_us']:.0f} us, p99 {tm['compute_p99_us']:.0f} us, "
            f"max {tm['compute_max_us']:.0f} us (NC step median {tm['nc_median_us']:.0f} us, "
            f"p99 {tm['nc_p99_us']:.0f} us; period {dt * 1e6:.0f} us)"
            + (f"; lateness p99 {tm['late_p99_us']:.0f} us, max {tm['late_max_us']:.0f} us; "
               f"overruns {tm['overruns']} (max {tm['max_overruns_in_row']} in a row)" if cfg.realtime
               else "; lateness n/a (--no-realtime)"))
    if state_file:
        say(f"  counters: {state_file} ({'clean stop' if res.status != 'fault' else 'NOT a clean stop'})")
    if rec_rows is not None:
        say(f"  recording: {args.record} ({rec_rows} rows)")
    return {"done": EXIT_DONE, "stopped": EXIT_STOPPED}.get(res.status, EXIT_FAULT)
