"""`pmctl run`: machine a job with the fixed-rate loop against a backend (the loopback sim by default).

    pmctl run --config config/prototype.toml --backend sim --job examples/jobs/<job> --record DIR
              [--force] [--rate HZ] [--no-realtime] [--service config/service.toml] [--state FILE]
              [--backend stepdir --bridge host-pty|rp2040-emu]

Checks every input first (job, record target, backend, state file, and the whole job as ``pmctl
check`` does: every problem of the job, its poses and the path between them against the machine, the
whole job planned, so that it cannot stop midway for a planning reason; a tool change is refused
unless ``--tool`` says that tool is already in the spindle), then runs it through the daemon's machinery as a one-shot client: a
pmctl.task.supervisor.Supervisor starts the rt motion process (pmctl.motion.rtproc: the loop, the
NC and the backend in their own process) at the saved pulse counters (else home), the job is
submitted, planned window by window and streamed into the shared sample ring (memory bounded by a
window, whatever the job's length), the spindle VFD and the strain DAQ are run by the supervisor;
at the end the supervisor shuts the rt side down (it saves the counters and hands over its timing
figures) and the run prints tracking-error and timing statistics. ``--no-realtime``: the rt side
ticks back to back and waits for samples (an offline simulation of the same path). With --record
the run is written as a recording
(docs/recording.md) while it runs, chunk by chunk from the rt side's bounded record ring, into
``<DIR>.partial/``, renamed to DIR at the end: memory does not grow with the job, and a run that
is killed (kill -9, power loss) leaves ``<DIR>.partial/`` with the samples up to the last chunk
drained (every 20 ms in real time), readable as an incomplete recording.

Ctrl-C, SIGTERM (``systemctl stop``) and SIGHUP all ask for a controlled stop: the machine
decelerates along its path, the counters are saved as a clean stop and the recording is written.
Output to a closed pipe (``pmctl run ... | head``) is dropped; the run goes on and is saved.

A probing move (G38.2/G38.3) is stopped on contact by the strain monitor in the rt process
(pmctl.motion.probe, [probe] in the service config; the supervisor plans the rest of the job from
where the probe stopped, as the daemon does); the contact point is printed as grbl's
``[PRB:x,y,z,a,b:1]`` and kept in recording.json's run block. Recordings of a backend with gauges in
its cyclic data carry load_fx/fy/fz (the tool-tip force estimated from the strains, per chunk).

Exit codes: 0 done; 3 controlled stop (soft limit, path error, missed deadlines, stall, Ctrl-C,
SIGTERM, a spindle or DAQ fault); 4 fault (following error, backend not answering, model pose lost,
the rt process lost, G38.2 without contact); 1 bad input.
"""

from __future__ import annotations

import math
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from pmctl.core.errors import InputError, JobProblems, PmctlError

EXIT_DONE, EXIT_STOPPED, EXIT_FAULT = 0, 3, 4
STOP_SIGNALS = {"SIGINT": "interrupted by the operator (Ctrl-C)",
                "SIGTERM": "stop requested (SIGTERM, e.g. systemctl stop)",
                "SIGHUP": "stop requested (SIGHUP: the terminal went away)"}


def add_parser(sub):
    p = sub.add_parser("run", help="machine a job: the control loop against a backend (sim by default)",
                       description="Run a job through the closed-loop NC at a fixed tick rate and record it. "
                                   "Like pmctl serve, it starts the real-time motion process and streams the "
                                   "job to it as it is planned (memory does not grow with the job); the "
                                   "supervisor side runs the spindle and the strain DAQ. "
                                   "Ctrl-C or SIGTERM stops the machine in a controlled way and saves the run. "
                                   "Exit status: 0 done, 3 controlled stop, 4 fault, 1 bad input.",
                       epilog="The recording format is described in docs/recording.md; the state file and "
                              "what stops a run in README.md; probing (G38.2/G38.3, stopped on contact by the "
                              "strain gauges) and the load_fx/fy/fz channels in docs/vibration.md section 4.")
    p.add_argument("--config", default="prototype", help="machine config (default: config/prototype.toml)")
    p.add_argument("--service", default=None, help="service config (default: config/service.toml)")
    p.add_argument("--backend", default=None, help="HAL backend, e.g. 'sim' (default: [hal] backend of the service config)")
    p.add_argument("--bridge", choices=("host-pty", "rp2040-emu"), default=None,
                   help="with --backend stepdir: the bridge's host build on a pty (host-pty), or its RP2040 image "
                        "in an emulated chip (rp2040-emu: needs --no-realtime and make -C firmware_bridge rp2040; "
                        "docs/stepdir.md) (default: [hal.stepdir] port)")
    p.add_argument("--job", required=True, help="job file: G-code (.ngc .nc .gcode .tap) or CL data (.cl ...)")
    p.add_argument("--record", metavar="DIR", default=None,
                   help="write the run as a recording folder (must not exist yet; see --force)")
    p.add_argument("--force", action="store_true", help="replace an existing recording in --record DIR")
    p.add_argument("--rate", type=float, default=None, metavar="HZ", help="tick rate (default: service config)")
    p.add_argument("--no-realtime", action="store_true",
                   help="run ticks back to back, no sleeping and no real-time priority (offline simulation of "
                        "the same path: a slow tick is not a stall, and the motion process waits for planned "
                        "samples instead of slowing down)")
    p.add_argument("--k-theta", default=None, metavar="PER_S|auto",
                   help="strain-gauge feedback gain per chain, 1/s (0 = off), or auto: designed per chain from "
                        "its chain mode with margins kept for the mode 20 %% off (docs/vibration.md; default: "
                        "service config)")
    p.add_argument("--shaper", default=None, metavar="TYPE|auto|none",
                   help="input shaper on the time law along the path (the tool stays on the path): ZV, MZV, ZVD, "
                        "EI, 2HUMP_EI, 3HUMP_EI, MA, types joined by '*' (ZV*MA), auto (per chain from its mode) "
                        "or none (default: [nc] shaper)")
    p.add_argument("--pulse-mode", choices=("multi", "single"), default=None,
                   help="V-F converters: integer pulses per tick (multi) or the original controller's one per tick (single; Kamiya et al. 2005)")
    p.add_argument("--state", default=None, metavar="FILE",
                   help="pulse-counter state file: where the machine is between runs (default: the service "
                        "config's state_file, per user); --state '' for none")
    p.add_argument("--feed-override", type=float, default=1.0, help="feed override factor (default 1)")
    p.add_argument("--tool", type=int, default=None, metavar="N",
                   help="the tool in the spindle at the start: a tool change (M6) to it goes on, a change to "
                        "another tool is refused on a real machine (pmctl run has no operator to change "
                        "tools); on --backend sim the simulation's operator changes tools and answers M0")
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


def run(args) -> int:
    """args -> Settings -> the job, checked whole -> run it -> print the result (its exit code)."""
    from pmctl.motion.state_store import StateLock
    out = _Out()
    # every input is checked before anything is said about the machine or anything moves
    settings = _settings_of(args)
    state_file = settings.svc.loop.state_file if args.state is None else args.state
    lock = StateLock(state_file) if state_file else None      # noqa: F841 (held until the process exits)
    counts0, where = _start_position(settings, state_file)
    job, path = _checked_job(args, out, settings, counts0)
    return _run_client(_RunContext(args, out, settings, state_file, counts0, job, path=path), where)


def _settings_of(args):
    """The run's flags checked (PmctlError naming the flag) and the settings resolved once for the
    whole run (pmctl.motion.settings: the supervisor and the rt process get these)."""
    from pmctl import hal
    from pmctl.core.recording import check_target
    from pmctl.motion.service_config import parse_k_theta_flag, parse_shaper_flag
    from pmctl.motion.settings import resolve
    if args.rate is not None and not (math.isfinite(args.rate) and 10 <= args.rate <= 20000):
        raise PmctlError(f"--rate must be within 10 .. 20000 Hz, got {args.rate:g}")
    k_theta_arg = parse_k_theta_flag(args.k_theta)
    shaper_arg = parse_shaper_flag(getattr(args, "shaper", None))
    if not (math.isfinite(args.feed_override) and 0 < args.feed_override <= 10):
        raise PmctlError(f"--feed-override must be within (0, 10], got {args.feed_override:g}")
    if args.backend is not None and args.backend not in hal.BACKENDS:
        raise PmctlError(f"--backend {args.backend!r}: unknown backend; known: {', '.join(sorted(hal.BACKENDS))}")
    if args.bridge == "rp2040-emu" and not args.no_realtime:
        raise PmctlError("--bridge rp2040-emu: the emulated chip runs slower than real time; add --no-realtime "
                         "(the host then waits for the chip)")
    if args.force and not args.record:
        raise PmctlError("--force replaces an existing --record folder; there is no --record")
    if args.record:               # find out now, not after the run, that the recording cannot be written
        folder = Path(args.record)
        check_target(folder, overwrite=args.force)          # (and its .partial, which a killed run left)
    nc_over = {}                          # what the flags change in the service config's [nc]
    if k_theta_arg is not None:
        auto = k_theta_arg == "auto"
        nc_over.update(k_theta_auto=auto, k_theta_per_s=(0.0,) * 3 if auto else (k_theta_arg,) * 3)
    if shaper_arg is not None:
        nc_over["shaper"] = shaper_arg
    if args.pulse_mode:
        nc_over["pulse_mode"] = args.pulse_mode
    settings = resolve(args.config, args.service, backend=args.backend, rate_hz=args.rate,
                       realtime=False if args.no_realtime else None, nc=nc_over,
                       hal={"stepdir": {"port": args.bridge}} if args.bridge else None)
    if args.bridge is not None and settings.backend != "stepdir":
        raise PmctlError(f"--bridge {args.bridge} is the step/dir bridge's: it needs --backend stepdir")
    return settings


def _start_position(settings, state_file: str):
    """Where the machine is: (pulse counters, what to say about them): the saved counters, else home
    (said only once everything has been checked)."""
    from pmctl.core import kinematics as K
    from pmctl.motion.nc import counts_of
    from pmctl.motion.state_store import load_counters
    from pmctl.task.planner import home_pose
    machine = settings.machine
    saved = (load_counters(state_file, machine=machine.name, pulses_per_mm=machine.resolution.pulses_per_mm)
             if state_file else None)
    if saved is not None:
        where = (f"position from {state_file} (tick {saved.tick}"
                 + (", clean stop)" if saved.clean else "; NOT a clean stop: re-home if in doubt)")
                 + (f"; {saved.note}" if saved.note else ""))
        return saved.counts, where
    h_tip, h_axis = home_pose(machine)
    counts0 = counts_of(K.ik(h_tip, h_axis, machine).q, settings.params)
    return counts0, "position: home" + (f" (no saved counters in {state_file})" if state_file else " (--state '')")


def _checked_job(args, out, settings, counts0):
    """(the job, its checked path): the job read and parsed (every problem the reader finds), then
    checked whole against the machine and planned before anything moves (pmctl check's check, with
    the V-F cap on the joint speeds the supervisor plans with); the supervisor's queue samples the
    windows this check settled instead of planning them again. An input shaper plans the job whole:
    the batch planner's bounds."""
    from pmctl.motion.nc import initial_state
    from pmctl.task.gcode import reader_options
    from pmctl.task.job import parse_job
    from pmctl.task.jobcheck import check_job, machine_for_planning
    machine, svc = settings.machine, settings.svc
    st = initial_state(machine, counts0)
    job, problems = parse_job(args.job, machine, start=(st.tip, st.axis),
                              **reader_options(args.job, svc.interpreter))    # tool table, search path...
    if problems:
        raise JobProblems(problems)
    if settings.backend != "sim":      # the simulation's stand-in operator changes tools and answers pauses
        _refuse_operator_waits(job, args.tool)
    if not job.moves:                 # nothing to run (an empty file, only comments and M30): say so
        raise InputError(args.job, None, "no motion in the job (no move and no dwell): nothing to run")
    for line, text in job.messages:                  # G-code (MSG, ...): for the operator, before it runs
        out.log(f"message from {Path(args.job).name} line {line}: {text}")
    if any(m.probe for m in job.moves):
        from pmctl.motion.probe import check_probe_job
        check_probe_job(job, svc.probe, args.job, args.feed_override)
    rep = check_job(job, machine_for_planning(machine, settings.params), settings.dt,
                    feed_override=args.feed_override, start=(st.tip, st.axis), batch=settings.setup.shaper is not None)
    if not rep.ok:
        raise JobProblems(rep.problems)
    return job, rep.path


def _refuse_operator_waits(job, tool):
    """What pmctl run on a real machine cannot do, refused before anything moves (InputError naming
    the line): a tool change (M6) to any tool but ``tool``, the one already in the spindle (--tool),
    and a program pause (M0, M60) that waits for a cycle start no one can give here. (M1 is not
    taken: the optional-stop switch is off in pmctl run.)"""
    from pmctl.core.job import EVENT
    for m in job.moves:
        if m.kind != EVENT:
            continue
        for name, value in m.events:
            if name == "tool_change" and (tool is None or int(value) != int(tool)):
                have = "no tool is known to be loaded (--tool)" if tool is None else f"tool {tool} is loaded (--tool)"
                raise InputError(m.file or job.source, m.line or None,
                                 f"tool change to T{int(value)}: pmctl run cannot change tools and {have}; load "
                                 f"tool {int(value)} and run with --tool {int(value)}, split the job at the change, "
                                 "or queue it in pmctl serve where the operator changes tools")
            if name == "pause" and value != "M1":
                raise InputError(m.file or job.source, m.line or None,
                                 f"{value} program pause: pmctl run has no cycle start to continue after it; "
                                 "queue the job in pmctl serve (cycle start: ~ on the console or pmctl ctl "
                                 f"resume), or remove the {value}")


def _catch_stop_signals(handler) -> dict:
    """SIGINT, SIGTERM and SIGHUP to ``handler`` (main thread only); returns the handlers to restore."""
    old = {}
    if threading.current_thread() is threading.main_thread():
        for name in STOP_SIGNALS:
            sig = getattr(signal, name, None)
            if sig is not None:
                old[sig] = signal.signal(sig, handler)
    return old


class _RunView:
    """What the progress display reads of a job streamed to the rt process: ticks since the job
    was submitted, an estimate of its length, and the NC mode. The length is the ticks so far plus
    the samples planned and not yet run (the rt side runs one a tick at 100 % feed); while the
    planner is still ahead of the machine (a job longer than the sample ring), the samples not yet
    planned are extrapolated from the job line the planned ones reached."""

    def __init__(self, sup, last_line: int, job=None):
        self.sup, self.last_line = sup, max(int(last_line), 1)
        self.tick0 = None
        self.item = None                 # the job's supervisor Item, once submitted
        self.s0 = 0.0                    # the rt side's path clock (samples run) when it was submitted
        self.lines, self.share = _nominal_shares(job) if job is not None else (None, None)

    def _planned_share(self, line: int) -> float:
        """The share of the job planned once its samples reached ``line``: by the moves' nominal
        times (length / feed, rapids at the planner's rapid speed, dwells), else by lines."""
        if self.lines is None or not len(self.lines):
            return min(1.0, line / self.last_line)
        import numpy as np
        k = int(np.searchsorted(self.lines, line, "right"))
        return float(self.share[k - 1]) if k else 0.0

    def _st(self):
        from pmctl.motion.status import read_status
        ch = self.sup.ch
        return read_status(ch) if ch is not None else None

    @property
    def tick(self):
        st = self._st()
        if st is None or self.tick0 is None:
            return 0
        return max(st.tick - self.tick0, 0)

    @property
    def n_ticks(self):
        st, it = self._st(), self.item
        if st is None or it is None or not it.pushed:
            return self.tick
        total = float(it.pushed)
        if not it.all_pushed:
            total /= max(self._planned_share(it.pushed_line), 1e-3)
        return self.tick + int(max(0.0, total - (st.path_s - self.s0)))

    @property
    def mode(self):
        st = self._st()
        return st.mode if st is not None else 0


def _nominal_shares(job):
    """(lines, share of the job's nominal time up to and including each line), lines increasing."""
    import numpy as np

    from pmctl.core.job import ARC, DWELL, RAPID
    from pmctl.task.planner import PlannerLimits
    rapid = PlannerLimits().rapid_mm_s
    t, lines, prev = [], [], None
    for m in job.moves:
        tip = np.asarray(m.tip, float)
        if m.kind == DWELL:
            dt = float(m.dwell)
        elif prev is None:
            dt = 0.0
        else:
            if m.kind == ARC and m.center is not None:
                r = float(np.hypot(*(tip[:2] - np.asarray(m.center, float)[:2])))
                length = float(np.hypot(abs(m.sweep) * r, tip[2] - prev[2]))
            else:
                length = float(np.linalg.norm(tip - prev))
            dt = length / (rapid if m.kind == RAPID or not m.feed else min(float(m.feed), rapid))
        if m.kind != DWELL:
            prev = tip
        t.append(dt)
        lines.append(int(m.line))
    if not t or sum(t) <= 0:
        return None, None
    order = np.argsort(lines, kind="stable")
    ls, share = np.asarray(lines)[order], np.cumsum(np.asarray(t)[order]) / sum(t)
    keep = np.r_[ls[1:] != ls[:-1], True]                 # the last entry of each line
    return ls[keep], share[keep]


@dataclass(eq=False)
class _RunContext:
    """One ``pmctl run`` in flight: what its wait, its recording and its report need."""
    args: object                     # the parsed command line
    out: _Out
    settings: object                 # pmctl.motion.settings.Settings, resolved once
    state_file: str
    counts0: object                  # the pulse counters it starts at
    job: object                      # pmctl.core.job.Job, checked whole
    path: object = None              # its checked path (the settled windows the queue samples)
    sup: object = None               # pmctl.task.supervisor.Supervisor
    sink: object = None              # pmctl.task.run_sink.RunSink: the records' tracking and recording
    rec: object = None               # the RecordingWriter (--record), or None
    rec_err: list = field(default_factory=list)   # the recorder's error, if it stopped
    stop_req: list = field(default_factory=list)  # [(reason, tick)] of a stop signal
    job_tick: int | None = None      # the first tick following the job's samples: its tracking starts
    s0: float | None = None          # the rt side's path clock when the job was submitted
    item: object = None              # the job's supervisor Item, once submitted

    @property
    def cfg(self):
        return self.settings.svc.loop

    @property
    def dt(self) -> float:
        return self.settings.dt


@dataclass(eq=False)
class _RunResult:
    """How a run ended and what it measured: the recording's run block and the report say it."""
    status: str = ""                 # done | stopped | fault
    reason: str = ""
    stop_tick: int | None = None     # the tick of a stop request (a signal)
    ticks: int = 0
    dt: float = 0.0
    wall: float = 0.0                # s, from the submission to the rt side's exit
    job_start: int = 0               # the tick the job's tracking starts at
    sent_ok: bool = False            # pulses sent = pulse counters
    clean: bool = False              # the counters saved as a clean stop
    dropped: int = 0                 # records the recorder missed
    tracking: dict = field(default_factory=dict)
    track_note: str = ""
    timing: dict = field(default_factory=dict)
    realtime: bool = False
    probes: list = field(default_factory=list)
    rec_error: str = ""
    rec_rows: int | None = None      # rows of the finished recording (None: no recording)

    @property
    def exit_code(self) -> int:
        return {"done": EXIT_DONE, "stopped": EXIT_STOPPED}.get(self.status, EXIT_FAULT)


def _run_client(ctx: _RunContext, where: str) -> int:
    """The job through the machinery of the daemon: a Supervisor starts the rt motion process (its
    own process: loop, NC, backend), the job is submitted with its checked ``path`` (the check's
    settled windows are sampled, not planned again), planned window by window and streamed into
    the sample ring (memory bounded by a window, whatever the job's length), the records stream back
    into the recording; then the supervisor shuts the rt side down and the run is reported with the
    timing figures the rt side hands over as it exits (Channel.result)."""
    from pmctl import hal
    from pmctl.hal.base import Backend
    from pmctl.hal.modbus_vfd import job_speed
    from pmctl.task.supervisor import Supervisor
    args, job, settings = ctx.args, ctx.job, ctx.settings
    log = ctx.out.log
    svc, params, backend_name, cfg = settings.svc, settings.params, settings.backend, ctx.cfg
    sup = ctx.sup = Supervisor(args.config, service=args.service, state_file=ctx.state_file or "", log=log,
                               settings=settings)
    if backend_name == "sim":                # the simulation's stand-in operator: tool changes and pauses
        sup.stand_in_operator = lambda what: log(f"{what}: done by the simulation's operator, the job goes on")
    notes = list(settings.setup.notes)     # chain modes, K_theta auto, shaper, joint caps: as resolved
    rpm0 = job_speed([m.spindle_rpm for m in job.moves])
    if rpm0 and svc.spindle is None:
        notes.append(f"no [spindle] in {svc.source}: the job's S{abs(rpm0):g} M{3 if rpm0 > 0 else 4} "
                     f"is not executed")

    # From here on a stop signal is a controlled stop: before the rt side runs the job it is remembered
    # and nothing is submitted; after that the supervisor holds on the path and stops.
    stop_req = ctx.stop_req

    def _stop(signum, frame):
        if not stop_req:
            stop_req.append((STOP_SIGNALS.get(signal.Signals(signum).name, f"signal {signum}"),
                             sup.status().tick if sup.ch is not None else 0))
    old = _catch_stop_signals(_stop)
    try:
        cls = hal.backend_class(backend_name)
        has_truth = cls.truth is not Backend.truth          # a simulation knows its load side
        log(where)
        for m in notes:
            log(m)
        # the VFD link answers (and the DAQ) before the drives enable
        sup.open_devices(spindle=bool(rpm0), at=ctx.counts0)
        try:
            _open_sink(ctx, hal, has_truth)
            if rpm0 and sup.spindle is not None:
                sup.spindle_start(rpm0)        # cutting waits for at speed
            sup.spindle_off_at_job_end = False     # M5 at the shutdown, after the last recorded tick
            sup.plan_feed_override = args.feed_override
            sup.start(ctx.counts0)
        except BaseException:
            sup.close_devices()
            if ctx.rec is not None:
                ctx.rec._discard()             # nothing ran: nothing is left under any name
            raise
        mode = "multi-pulse" if params.max_pulses_per_tick > 1 else "one pulse per tick (as in Kamiya et al. 2005)"
        log(f"{Path(args.job).name}: streamed to the rt motion process (pid {sup.rt_pid}) at {cfg.rate_hz:g} Hz, "
            f"backend {backend_name}, V-F {mode}, K_theta "
            f"{'/'.join(f'{k:.4g}' for k in sorted(set(sup.svc.nc.k_theta_per_s)))}/s, "
            f"{'real-time' if cfg.realtime else 'no real-time (ticks back to back, waiting for samples)'}")
        res = _run_job(ctx)
        _finish_recording(ctx, res)
        _report(ctx, res)
        return res.exit_code
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


def _open_sink(ctx: _RunContext, hal, has_truth: bool):
    """Where the supervisor's drained records go: the RunSink (tracking figures; the spindle's and the
    DAQ's samples per tick) and, with --record, the recording opened as ``<DIR>.partial/``."""
    import numpy as np

    from pmctl.motion.recorder import R_S, R_TICK
    from pmctl.motion.service_config import strain_in_loop as carries_strain
    from pmctl.task.run_sink import RunSink
    sup, settings, cfg = ctx.sup, ctx.settings, ctx.cfg
    machine, backend_name = settings.machine, settings.backend
    strain_in_loop = carries_strain(backend_name)
    sink = ctx.sink = RunSink(machine, settings.params.pulses_per_mm, cfg.rate_hz, has_truth, 1 << 62, 0,
                              sup.spindle, sup.daq, load=strain_in_loop, strain=strain_in_loop)
    if ctx.args.record:
        plant = hal.create(backend_name, machine, ctx.dt, settings.svc.backend_tables.get(backend_name, {})) \
            if has_truth else None          # not opened: its options describe the simulated plant
        ctx.rec = _open_recording(ctx.args, machine, plant, backend_name, cfg, sink, 0)
        sink.writer = ctx.rec

    def feed(rows):            # the supervisor's monitor thread, every drained chunk of records
        if ctx.job_tick is None and ctx.s0 is not None:
            moved = np.flatnonzero(rows[:, R_S] > ctx.s0)
            if len(moved):     # the first tick following the job's samples: its tracking starts
                ctx.job_tick = int(rows[moved[0], R_TICK])
                if sink.track is not None:
                    sink.track.j0 = ctx.job_tick
        try:
            sink(rows)
        except Exception as e:
            ctx.rec_err.append(f"{type(e).__name__}: {e}")
            raise
    sup.record_sink = feed


def _run_job(ctx: _RunContext) -> _RunResult:
    """Submit the job, wait for how it ends (the supervisor's events), shut the rt side down and
    gather what it measured; PmctlError when the job was refused before any of it moved."""
    from pmctl.task.job_watch import JobWatch
    sup, cfg = ctx.sup, ctx.cfg
    view = _RunView(sup, max((m.line for m in ctx.job.moves), default=1), ctx.job)
    prog = _Progress(view, Path(ctx.args.job).name, ctx.dt, ctx.args.quiet, ctx.out)
    watch = JobWatch(sup)
    t_wall = time.monotonic()
    end = None
    try:
        s = sup.status()
        view.tick0 = s.tick
        ended0 = s.ended
        if not ctx.stop_req:
            ctx.s0 = s.path_s
            watch.item = ctx.item = sup.submit(ctx.job, kind="job", name=Path(ctx.args.job).name,
                                               source=str(ctx.args.job), path=ctx.path)
            view.item, view.s0 = ctx.item, ctx.s0
        prog.start()
        end = watch.wait(ended0, int(round(cfg.settle_s * cfg.rate_hz)),
                         lambda: ctx.stop_req[0] if ctx.stop_req else None)
    finally:
        watch.close()
        prog.finish()
        # hold on the path; the rt side saves its counters and exits
        sup.shutdown((end.reason if end is not None else "") or "done")
    res = _RunResult(end.status, end.reason, end.stop_tick, dt=ctx.dt, realtime=bool(cfg.realtime),
                     wall=time.monotonic() - t_wall)
    if end.bad_input:
        if ctx.rec is not None:
            ctx.rec._discard()
        raise PmctlError(end.bad_input)
    _gather(ctx, res)
    return res


def _gather(ctx: _RunContext, res: _RunResult):
    """What the rt side handed over as it exited (Channel.result), the probe results and the tracking
    figures, into ``res``."""
    sup = ctx.sup
    r = sup.rt_result
    fs = sup.final_status
    if r is None:
        res.status = "fault"
        res.reason = "the rt motion process ended without its result" + (f" ({res.reason})" if res.reason else "")
        r = {"ticks": fs.tick if fs is not None else 0, "sent_ok": False, "clean": False, "timing": {},
             "dropped": fs.dropped if fs is not None else 0}
    elif r.get("status") == "fault" and res.status != "fault":      # e.g. a following error while stopping
        res.status, res.reason = "fault", r.get("reason", "")
    res.ticks = int(r["ticks"])
    res.sent_ok, res.clean = bool(r.get("sent_ok")), bool(r.get("clean"))
    if ctx.state_file and r.get("clean") is False and res.status != "fault":
        ctx.out.log(f"warning: the rt side did not save {ctx.state_file} as a clean stop: the position may be off "
                    f"by the motion of the last persist interval; home the machine (or check it) before the next job")

    res.probes = list(getattr(ctx.item, "probe_results", None) or []) if ctx.item is not None else []
    probe_err = next((p.error for p in res.probes if p.error), "")
    if probe_err and res.status == "done":         # G38.2 without contact: grbl's probe-fail alarm
        res.status, res.reason = "fault", probe_err

    res.rec_error = ctx.rec_err[0] if ctx.rec_err else ""
    if res.rec_error:
        ctx.out.log(f"warning: the recorder stopped at row {ctx.sink.rows}: {res.rec_error}; the recording ends there "
                    f"(marked incomplete): check the disk (space, permissions) and run the job again to record all "
                    f"of it")
    res.job_start = ctx.job_tick if ctx.job_tick is not None else (
        res.stop_tick if res.stop_tick is not None else res.ticks)
    i0, i1, res.track_note = tracking_window(res, res.stop_tick)
    if i1 > i0 and ctx.sink.track is not None and not res.rec_error:
        res.tracking = ctx.sink.track.stats(i0, i1)
    res.timing = r.get("timing") or {}
    res.dropped = int(r.get("dropped", 0))


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


def _finish_recording(ctx: _RunContext, res: _RunResult):
    """Write the run's end into the recording (recording.json's ``run`` block: status, reason,
    tracking, timing, probe results) and rename ``<DIR>.partial`` to DIR; its rows go to
    ``res.rec_rows`` (None: no recording, or it could not be finished)."""
    rec, args, log = ctx.rec, ctx.args, ctx.out.log
    if rec is None:
        return
    status, reason, dropped, rec_error = res.status, res.reason, res.dropped, res.rec_error
    run_meta = dict(rec.meta.get("run", {}))
    run_meta.update({"job_start_row": int(res.job_start), "rt_pid": ctx.sup.rt_pid})
    desc = (f"pmctl run {Path(args.job).name} on backend {ctx.settings.backend} at {ctx.cfg.rate_hz:g} Hz: {status}"
            + (f" ({reason})" if reason else ""))
    run_meta.update({"status": status, "reason": reason, "tracking": res.tracking, "timing": res.timing})
    if res.track_note:
        run_meta["tracking_note"] = res.track_note
    if dropped:
        run_meta["dropped_rows"] = dropped
    if res.probes:
        run_meta["probe"] = [r.as_dict() for r in res.probes]
    # a stopped run is a complete recording of what happened: "complete" is about the file;
    # rows the recorder missed (dropped, or a recording error) make it incomplete
    missing = dropped or rec_error or rec.rows != res.ticks
    why = (f"{dropped} rows dropped (the recorder fell behind the loop)" if dropped
           else f"recording error: {rec_error}" if rec_error
           else f"{rec.rows} rows for {res.ticks} ticks")
    if rec._done:
        log(f"warning: the recording {args.record} was abandoned during the run ({rec_error}); nothing of it was "
            f"kept: check the disk (space, permissions) and run the job again to record it")
    else:
        try:
            res.rec_rows = rec.rows
            rec.finish(complete=not missing, reason=why if missing else "",
                       extra_meta={"description": desc, "run": run_meta})
        except Exception as e:
            log(f"warning: the recording {args.record} could not be finished: {e}; what was written "
                f"may be left in {args.record}.partial (it reads as an incomplete recording)")
            res.rec_rows = None


def _report(ctx: _RunContext, res: _RunResult):
    """The run's report on stdout (outside checks parse these lines: keep their wording)."""
    out, args, dt = ctx.out, ctx.args, res.dt
    status, reason, ticks, tm = res.status, res.reason, res.ticks, res.timing
    ts, track_note = res.tracking, res.track_note
    say = out.say
    say(f"result: {status}" + (f" ({reason})" if reason else ""))
    say(f"  ticks {ticks} ({ticks * dt:.2f} s machine time, {res.wall:.2f} s wall), "
        f"pulses sent = pulse counters: {'yes' if res.sent_ok else 'NO'}")
    if res.dropped:
        say(f"  records dropped: {res.dropped} (the recorder fell behind the loop; the recording and the "
            f"tracking figures miss those ticks)")
    if ts:
        say(f"  tool-tip error (load side vs target, job part{', ' + track_note if track_note else ''}): "
            f"RMS {ts['tip_rms_um']:.3f} um, p99 {ts['tip_p99_um']:.3f} um, max {ts['tip_max_um']:.3f} um; "
            f"tool axis RMS {ts['axis_rms_urad']:.2f} urad, max {ts['axis_max_urad']:.2f} urad")
    elif track_note:
        say(f"  tool-tip error: {track_note}")
    for r in res.probes:
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
               f"overruns {tm['overruns']} (max {tm['max_overruns_in_row']} in a row)" if res.realtime
               else "; lateness n/a (--no-realtime)"))
    if ctx.state_file:
        say(f"  counters: {ctx.state_file} ({'clean stop' if res.clean else 'NOT a clean stop'})")
    if res.rec_rows is not None:
        say(f"  recording: {args.record} ({res.rec_rows} rows)")
