"""`pmctl run`: machine a job with the fixed-rate loop against a backend (the loopback sim by default).

    pmctl run --config config/prototype.toml --backend sim --job examples/jobs/<job> --record DIR
              [--rate HZ] [--no-realtime] [--service config/service.toml]

Plans the job from where the machine is (saved pulse counters, else home), runs the loop, shows
progress, prints tracking-error and timing statistics, and writes the run as a recording
(RECORDING.md). Exit codes: 0 done; 3 controlled stop (soft limit, path error, missed deadlines,
stall, Ctrl-C); 4 fault (following error, backend not answering, model pose lost); 1 bad input.
"""

from __future__ import annotations

import math
import os
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np

from pmctl import hal
from pmctl.core import kinematics as K
from pmctl.core.config import CONFIG_DIR, load_machine
from pmctl.core.errors import PmctlError
from pmctl.motion.loop import ControlLoop, LoopResult, prepare, tracking_stats
from pmctl.motion.service_config import load_service_config
from pmctl.motion.nc import counts_of, initial_state
from pmctl.motion.state_store import CounterWriter, StateLock, load_counters

EXIT_DONE, EXIT_STOPPED, EXIT_FAULT = 0, 3, 4


def add_parser(sub):
    p = sub.add_parser("run", help="machine a job: the control loop against a backend (sim by default)",
                       description="Run a job through the closed-loop NC at a fixed tick rate and record it.")
    p.add_argument("--config", default="prototype", help="machine config (default: config/prototype.toml)")
    p.add_argument("--service", default=None, help="service config (default: config/service.toml)")
    p.add_argument("--backend", default=None, help="HAL backend (default: from the service config; 'sim')")
    p.add_argument("--job", required=True, help="job file: G-code (.ngc .nc .gcode .tap) or CL data (.cl ...)")
    p.add_argument("--record", metavar="DIR", default=None, help="write the run as a recording folder")
    p.add_argument("--rate", type=float, default=None, metavar="HZ", help="tick rate (default: service config)")
    p.add_argument("--no-realtime", action="store_true",
                   help="run ticks back to back, no sleeping and no real-time priority (offline simulation)")
    p.add_argument("--k-theta", type=float, default=None, metavar="PER_S",
                   help="strain-gauge feedback gain per chain, 1/s (0 = off; default: service config)")
    p.add_argument("--pulse-mode", choices=("multi", "single"), default=None,
                   help="V-F converters: integer pulses per tick (multi) or the seed's one per tick (single)")
    p.add_argument("--state", default=None, metavar="FILE",
                   help="pulse-counter state file (default: service config); --state '' disables it")
    p.add_argument("--feed-override", type=float, default=1.0, help="feed override factor (default 1)")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.set_defaults(func=run)


def _machine_ref(config_arg: str, machine, record_dir: Path) -> str:
    """How recording.json names the machine: a shipped config by name, else a path relative to the folder."""
    p = Path(config_arg)
    if not p.suffix and not p.exists():
        return p.name
    p = p.resolve()
    if p.parent == CONFIG_DIR.resolve():
        return p.stem
    return os.path.relpath(p, record_dir.resolve())


class _Progress:
    def __init__(self, lp: ControlLoop, job_name: str, dt: float, quiet: bool):
        self.lp, self.name, self.dt = lp, job_name, dt
        self.tty = sys.stderr.isatty()
        self.quiet = quiet
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True, name="pmctl-progress")

    def start(self):
        if not self.quiet:
            self._t.start()

    def _line(self):
        lp = self.lp
        k, n = lp.tick, max(lp.n_ticks, 1)
        frac = min(1.0, k / n)
        bar = "#" * int(frac * 24)
        from pmctl.motion.nc import MODE_NAMES
        return (f"{self.name}: [{bar:<24}] {100 * frac:5.1f}%  t = {k * self.dt:7.2f} / {n * self.dt:.2f} s  "
                f"{MODE_NAMES.get(lp.mode, '?')}")

    def _run(self):
        period = 0.2 if self.tty else 5.0
        while not self._stop.wait(period):
            if self.tty:
                sys.stderr.write("\r" + self._line())
                sys.stderr.flush()
            else:
                print(self._line(), file=sys.stderr, flush=True)

    def finish(self):
        self._stop.set()
        if self._t.is_alive():
            self._t.join()
            if self.tty:
                sys.stderr.write("\r" + self._line() + "\n")


def record_columns(res: LoopResult, machine, ppm) -> tuple[dict, dict]:
    """Recording channels of a run: commands (pulse counters), encoders, the simulated load-side
    tool pose, and the strain gauges as read."""
    cols = {"t": res.t}
    names = ("L1", "L2", "L3", "X", "Y")
    q_cmd = res.counts / ppm
    for i, a in enumerate(names):
        cols[f"cmd_{a}"] = q_cmd[:, i]
    for i, a in enumerate(names):
        cols[f"enc_{a}"] = res.enc[:, i]
    notes = {f"cmd_{a}": {"source": "pulse counter x resolution at the tick start"} for a in names}
    if np.all(np.isfinite(res.truth)) and len(res.truth):
        pose, ok = K.fk_batch(res.truth, machine)
        tip = np.where(ok[:, None], pose.tip, np.nan)
        axis = np.where(ok[:, None], pose.axis, np.nan)
        for i, c in enumerate(("tip_x", "tip_y", "tip_z")):
            cols[c] = tip[:, i]
        for i, c in enumerate(("tool_i", "tool_j", "tool_k")):
            cols[c] = axis[:, i]
        for c in ("tip_x", "tip_y", "tip_z", "tool_i", "tool_j", "tool_k"):
            notes[c] = {"source": "simulation: FK of the load-side joints (after drive lag and flexible mode)"}
        for i in range(3):
            notes[f"strain_{i + 1}"] = {"source": "simulation: gravity strain of the true pose + "
                                                  "flexible-mode spring strain + gauge noise"}
    for i in range(3):
        cols[f"strain_{i + 1}"] = res.strain[:, i]
    return cols, notes


def _strain_of(backend):
    """The strain gauges the backend's last feedback holds (what a simulated DAQ serves)."""
    fb = getattr(backend, "_fb", None)
    return fb.strain.tolist() if fb is not None else [0.0, 0.0, 0.0]


def run(args) -> int:
    from pmctl.task.planner import load_job, plan

    machine = load_machine(args.config)
    svc = load_service_config(args.service)
    cfg = svc.loop
    if args.rate is not None:
        if not 10 <= args.rate <= 20000:
            raise PmctlError(f"--rate must be within 10 .. 20000 Hz, got {args.rate:g}")
        cfg.rate_hz = float(args.rate)
    if args.no_realtime:
        cfg.realtime = False
    if args.k_theta is not None:
        if not (math.isfinite(args.k_theta) and args.k_theta >= 0):
            raise PmctlError(f"--k-theta must be >= 0 1/s, got {args.k_theta:g}")
        svc.nc.k_theta_per_s = (args.k_theta,) * 3
    if not (math.isfinite(args.feed_override) and 0 < args.feed_override <= 10):
        raise PmctlError(f"--feed-override must be within (0, 10], got {args.feed_override:g}")
    if args.pulse_mode:
        svc.nc.pulse_mode = args.pulse_mode
    backend_name = args.backend or svc.backend
    state_file = cfg.state_file if args.state is None else args.state
    dt = cfg.dt
    log = lambda m: print(f"pmctl: {m}", file=sys.stderr)  # noqa: E731
    from pmctl.hal.modbus_daq import DaqSession, check_k_theta_source
    check_k_theta_source(svc.daq, svc.nc.k_theta_per_s, machine, f"{svc.source}: daq")
    strain_in_loop = getattr(hal.backend_class(backend_name), "strain_in_loop", True)
    if not strain_in_loop and any(svc.nc.k_theta_per_s):
        log(f"K_theta off: backend {backend_name} carries no strain gauges in its cyclic data")
        svc.nc.k_theta_per_s = (0.0,) * 3
    params = svc.nc.params(machine, dt, where=svc.source)

    # Where the machine is: saved counters, else home.
    lock = StateLock(state_file) if state_file else None      # held until the process exits
    saved = load_counters(state_file, machine=machine.name) if state_file else None
    if saved is not None:
        counts0 = saved.counts
        log(f"position from {state_file} (tick {saved.tick}"
            + (", clean stop)" if saved.clean else "; NOT a clean stop: re-home if in doubt)"))
    else:
        from pmctl.task.planner import home_pose
        h_tip, h_axis = home_pose(machine)
        counts0 = counts_of(K.ik(h_tip, h_axis, machine).q, params)
    st = initial_state(machine, counts0)

    if args.record:               # find out now, not after the run, that the recording cannot be written
        folder = Path(args.record)
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise PmctlError(f"--record {folder}: cannot create the folder: {e.strerror or e}") from None
        if not os.access(folder, os.W_OK):
            raise PmctlError(f"--record {folder}: folder is not writable")
    job = load_job(args.job, machine, start=(st.tip, st.axis))
    plan_machine = machine
    if np.any(params.vmax < machine.limits.joint_speed - 1e-9):
        # the V-F converters cap the joint speed below the machine's (seed mode: one pulse per
        # tick): plan within what they can emit
        from dataclasses import replace
        lim = replace(machine.limits, chain_speed=float(params.vmax[:3].min()), table_speed=float(params.vmax[3:].min()))
        plan_machine = replace(machine, limits=lim)
        log(f"V-F converters limit the joints to {params.vmax.min():.3g} mm/s at {cfg.rate_hz:g} Hz: planning with that")
    traj = plan(job, plan_machine, dt, feed_override=args.feed_override, start=(st.tip, st.axis))
    targets = prepare(machine, params, traj, dt, counts0)

    from pmctl.hal.modbus_vfd import SpindleSession, job_speed
    rpm_job, spindle = job_speed(traj.spindle_rpm), None
    if rpm_job and svc.spindle is not None:
        spindle = SpindleSession(svc.spindle, log).connect()       # the link answers before the drives enable
    elif rpm_job:
        log(f"no [spindle] in {svc.source}: the job's S{abs(rpm_job):g} M{3 if rpm_job > 0 else 4} is not executed")
    backend = hal.create(backend_name, machine, dt, svc.hal_options.get(backend_name, {}))
    daq = None
    try:
        backend.open(counts0)
        if svc.daq is not None:           # the simulated DAQ serves the backend's (plant's) strain gauges
            daq = DaqSession(svc.daq, lambda: _strain_of(backend),
                             log).connect()
        if spindle is not None:
            spindle.start(rpm_job)        # cutting waits for at speed
    except BaseException:
        backend.close()
        for dev in (spindle, daq):
            if dev is not None:
                dev.close()
        raise
    writer = CounterWriter(state_file, machine=machine.name) if state_file else None
    lp = ControlLoop(machine, backend, params, targets, cfg, st, log=log, writer=writer)
    mode = "multi-pulse" if params.max_pulses_per_tick > 1 else "one pulse per tick (seed)"
    log(f"{Path(args.job).name}: {len(targets.rows) * dt:.2f} s at {cfg.rate_hz:g} Hz, backend {backend_name}, "
        f"V-F {mode}, K_theta {svc.nc.k_theta_per_s[0]:g}/s, "
        f"{'real-time' if cfg.realtime else 'no real-time (ticks back to back)'}")

    prog = _Progress(lp, Path(args.job).name, dt, args.quiet)
    old = signal.getsignal(signal.SIGINT)

    def _sigint(signum, frame):
        lp.stop_request = "interrupted by the operator (Ctrl-C)"
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, _sigint)
    prog.start()
    t_wall = time.monotonic()
    for dev in (spindle, daq):            # polled by their own threads; a fault or lost link stops the run
        if dev is not None:
            dev.watch(lambda: lp.tick, lambda why: setattr(lp, "stop_request", why))
    try:
        res = lp.run()
    finally:
        prog.finish()
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, old)
        backend.close()
        for dev in (spindle, daq):
            if dev is not None:
                dev.close()               # the spindle: M5
        if writer is not None:
            writer.stop()          # on a crash the last periodic snapshot (clean = false) stays
    wall = time.monotonic() - t_wall
    if writer is not None and writer.error:
        log(f"warning: periodic writes of {state_file} failed during the run ({writer.error}); "
            f"a crash would have lost the position")
    if writer is not None:
        from pmctl.motion.state_store import save_counters
        # clean: the counters are exactly what was sent and the machine did what they say; after a
        # fault (following error, lost backend) the position is in doubt: the next start says so
        save_counters(state_file, res.state.counts, machine=machine.name, clean=res.status != "fault",
                      tick=res.ticks)

    # ---- the recording first (the run's data must not depend on stdout staying open), then the report
    sent_ok = bool(np.all(counts0 + res.pulses_sent == res.state.counts))
    ts = tracking_stats(res, machine)
    tm = res.timing.summary()
    if args.record:
        from pmctl.core.recording import write_recording
        folder = Path(args.record)
        cols, notes = record_columns(res, machine, params.pulses_per_mm)
        if spindle is not None:
            cols["spindle_rpm"] = spindle.per_tick(res.ticks)
            notes["spindle_rpm"] = {"source": f"VFD speed register polled every {svc.spindle.poll_ms:g} ms by "
                                              f"the supervisor, held between polls (negative: M4)"}
        if daq is not None:
            ds = daq.per_tick(res.ticks)
            for i in range(3):
                cols[f"daq_strain_{i + 1}"] = ds[:, i]
                notes[f"daq_strain_{i + 1}"] = {"source": f"strain DAQ over Modbus TCP polled every "
                                                          f"{svc.daq.poll_ms:g} ms, held between polls, microstrain"}
        desc = (f"pmctl run {Path(args.job).name} on backend {backend_name} at {cfg.rate_hz:g} Hz: {res.status}"
                + (f" ({res.reason})" if res.reason else ""))
        write_recording(folder, cols, machine=_machine_ref(args.config, machine, folder),
                        sample_rate_hz=cfg.rate_hz, description=desc, channel_notes=notes,
                        extra_meta={"run": {"job": str(args.job), "status": res.status, "reason": res.reason,
                                            "tracking": ts, "timing": tm, "job_start_row": res.job_start}})
    print(f"result: {res.status}" + (f" ({res.reason})" if res.reason else ""))
    print(f"  ticks {res.ticks} ({res.ticks * dt:.2f} s machine time, {wall:.2f} s wall), "
          f"pulses sent = pulse counters: {'yes' if sent_ok else 'NO'}")
    if ts:
        print(f"  tool-tip error (load side vs target, job part): RMS {ts['tip_rms_um']:.3f} um, "
              f"p99 {ts['tip_p99_um']:.3f} um, max {ts['tip_max_um']:.3f} um; tool axis RMS "
              f"{ts['axis_rms_urad']:.2f} urad, max {ts['axis_max_urad']:.2f} urad")
    if tm:
        print(f"  timing: tick compute median {tm['compute_median_us']:.0f} us, p99 {tm['compute_p99_us']:.0f} us, "
              f"max {tm['compute_max_us']:.0f} us (NC step median {tm['nc_median_us']:.0f} us, "
              f"p99 {tm['nc_p99_us']:.0f} us; period {dt * 1e6:.0f} us)"
              + (f"; lateness p99 {tm['late_p99_us']:.0f} us, max {tm['late_max_us']:.0f} us; "
                 f"overruns {tm['overruns']} (max {tm['max_overruns_in_row']} in a row)" if cfg.realtime
                 else "; lateness n/a (--no-realtime)"))
    if args.record:
        print(f"  recording: {args.record} ({res.ticks} rows)")
    return {"done": EXIT_DONE, "stopped": EXIT_STOPPED}.get(res.status, EXIT_FAULT)
