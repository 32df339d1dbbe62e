"""The fixed-rate control loop: read feedback -> NC step -> write pulses, on absolute deadlines.

- Each tick runs as LinuxCNC's emcmotController, one method per phase of :class:`ControlLoop`,
  the loose values of the run in one :class:`Tick` context: read inputs (``_read_inputs``), model
  pose (``_model_pose``: the path follower's target, the probe monitor), NC (``_nc``), output
  (``_output``), record (``_record``; the hot path's compute time ends here), status (``_status``:
  the hook, the rt process's command/status exchange), supervise (``_supervise``: the stop rules,
  stalls) and wait (``_wait``: the overrun policy, the sleep to the next deadline).

- Fixed rate (default 1 kHz), deadlines on CLOCK_MONOTONIC, slept to with
  clock_nanosleep(TIMER_ABSTIME) (no drift); ``realtime=False`` runs the same ticks back to back
  (tests, CI, offline simulation).
- SCHED_FIFO and mlockall when permitted, with a clear message when not; the garbage collector is
  paused during the run (no collection pauses on the hot path).
- Targets come from a PathFollower (pmctl.motion.timescale): planned samples followed at a feed
  factor sigma limited in rate and jerk within the joint limits; feed hold stops on the path, feed
  and rapid overrides scale it, an empty queue decelerates along the path.
- Per-tick compute time and lateness in a bounded window; overruns counted, warned about
  (rate-limited), and N in a row stop the machine safely (decelerating stop).
- A tick longer than the stall timeout (in real time; offline, with ``realtime=False``, a slow tick
  is only counted and reported) while the path moves ends in a controlled stop with a reason, unless
  the backend can ride it out (``Backend.stall_hold``: the simulation) and the loop has an
  ``on_stall`` handler (the rt process: a feed hold on the path, resumed once the ticks are on time
  again); at rest (nothing commanded to move) a stall is only reported. A backend that does not
  answer ends in a controlled stop with a reason; any other exception inside the loop halts it with the reason, the counters true. The pulse counters are persisted by a writer thread every N ticks and at the
  stop (pmctl.motion.state_store).
- Per-tick records (commands, encoders, strain, the simulated load side, sigma, line) go into a
  bounded ring (pmctl.motion.recorder) that a recorder drains: the loop's memory does not grow
  with the job.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from pmctl.core import kinematics as K
from pmctl.core.config import Machine
from pmctl.core.errors import KinematicsError, PmctlError, UnreachablePose
from pmctl.hal import Backend, HalError, HalTimeout
from pmctl.motion.nc import HALTED, NCParams, NCState, RUN
from pmctl.motion.ncore import make_nc
from pmctl.motion.recorder import (REC_CAPACITY, REC_WIDTH, R_COUNTS, R_ENC, R_LINE, R_S, R_SIGMA, R_STRAIN,
                                   R_TARGET, R_TRUTH, Recorder)
from pmctl.motion.ring import ArraySource, Ring
from pmctl.motion.timescale import HOLDING, S_CAP, backward_pass, make_follower, make_rows, scaling_limits
from pmctl.motion.service_config import LoopConfig
from pmctl.motion.state_store import CounterWriter
from pmctl.motion.trajectory import Trajectory

# ---------------------------------------------------------------- real-time setup

_libc = None


def _get_libc():
    global _libc
    if _libc is None:
        _libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    return _libc


class _Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


CLOCK_MONOTONIC, TIMER_ABSTIME = 1, 1
MCL_CURRENT, MCL_FUTURE = 1, 2


class AbsoluteSleeper:
    """Sleep until an absolute CLOCK_MONOTONIC time in ns (time.monotonic_ns's clock)."""

    def __init__(self):
        self._ts = _Timespec()
        try:
            self._fn = _get_libc().clock_nanosleep
            self._fn.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.POINTER(_Timespec), ctypes.c_void_p]
            self._ref = ctypes.byref(self._ts)
        except (OSError, AttributeError):
            self._fn = None

    def until(self, t_ns: int) -> None:
        if self._fn is not None:
            self._ts.tv_sec, self._ts.tv_nsec = divmod(t_ns, 1_000_000_000)
            while self._fn(CLOCK_MONOTONIC, TIMER_ABSTIME, self._ref, None) == 4:   # EINTR: again
                pass
        else:
            d = t_ns - time.monotonic_ns()
            if d > 0:
                time.sleep(d / 1e9)


def setup_realtime(priority: int = 50, lock_memory: bool = True) -> list[str]:
    """Try SCHED_FIFO and mlockall; return one message per thing that was or was not granted."""
    msgs = []
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        msgs.append(f"real-time: SCHED_FIFO priority {priority}")
    except (PermissionError, OSError, AttributeError) as e:
        msgs.append(f"real-time: SCHED_FIFO not permitted ({getattr(e, 'strerror', None) or e}); running at normal "
                    f"priority, expect more lateness (grant CAP_SYS_NICE or an rtprio limit in "
                    f"/etc/security/limits.conf)")
    if lock_memory:
        try:
            libc = _get_libc()
            if libc.mlockall(MCL_CURRENT | MCL_FUTURE) != 0:
                err = ctypes.get_errno()
                raise OSError(err, os.strerror(err))
            msgs.append("memory: locked (mlockall)")
        except OSError as e:
            msgs.append(f"memory: mlockall not permitted ({e.strerror or e}); pages may be swapped out "
                        f"(raise RLIMIT_MEMLOCK / 'ulimit -l')")
    return msgs


def undo_realtime(lock_memory: bool) -> None:
    try:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (PermissionError, OSError, AttributeError):
        pass
    if lock_memory:
        try:
            _get_libc().munlockall()
        except OSError:
            pass


# ---------------------------------------------------------------- targets


@dataclass
class Targets:
    """Per-tick targets for the NC: (N, 12) = tip, axis, tip_vel, axis_vel, plus bookkeeping."""

    rows: np.ndarray
    q: np.ndarray             # (N, 5) joints of each target (IK), for the preflight and the start
    line: np.ndarray          # (N,) job line (0 = approach / none)
    job_start: int            # index of the first job sample (after any approach)


def resample(traj: Trajectory, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tip, axis and line of ``traj`` at period dt (linear interpolation, axis renormalised)."""
    if abs(traj.dt - dt) <= 1e-12 * dt:
        return np.asarray(traj.tip, float), np.asarray(traj.axis, float), np.asarray(traj.line)
    n = len(traj)
    t0 = np.arange(n) * traj.dt
    t1 = np.arange(int(math.floor(t0[-1] / dt + 1e-9)) + 1) * dt
    tip = np.stack([np.interp(t1, t0, traj.tip[:, i]) for i in range(3)], -1)
    ax = np.stack([np.interp(t1, t0, traj.axis[:, i]) for i in range(3)], -1)
    ax /= np.linalg.norm(ax, axis=-1, keepdims=True)
    line = np.asarray(traj.line)[np.minimum(np.rint(t1 / traj.dt).astype(int), n - 1)]
    return tip, ax, line


def build_targets(tip, axis, line, dt: float, machine: Machine, params: NCParams) -> Targets:
    """Preflight (every sample reachable, joint speeds within limits) and the target rows.

    The feed-forward is the forward difference of the samples, so pulses over tick k carry the
    model exactly from sample k to sample k+1 (no lag, no velocity/position mismatch)."""
    tip = np.asarray(tip, float)
    axis = np.asarray(axis, float)
    n = len(tip)
    if n == 0:
        raise PmctlError("the trajectory is empty")
    if not (np.all(np.isfinite(tip)) and np.all(np.isfinite(axis))):
        raise PmctlError("the trajectory has non-finite samples")
    r = K.ik_batch(tip, axis, machine)
    if not np.all(r.ok):
        i = int(np.nonzero(~r.ok)[0][0])
        raise UnreachablePose(f"trajectory sample {i} (t = {i * dt:.3f} s, job line {int(line[i])}) is unreachable: "
                              f"{r.reason[i]}; nothing moved")
    q = r.q
    out = (q < params.lower - 1e-9) | (q > params.upper + 1e-9)
    if out.any():
        i, j = (int(x) for x in np.argwhere(out)[0])
        raise UnreachablePose(
            f"trajectory sample {i} (t = {i * dt:.3f} s, job line {int(line[i])}): "
            f"{('L1', 'L2', 'L3', 'X', 'Y')[j]} = {q[i, j]:.4f} mm outside the soft limits "
            f"[{params.lower[j]:g}, {params.upper[j]:g}] mm; nothing moved")
    if n > 1:
        qd = np.abs(np.diff(q, axis=0)) / dt
        over = qd > params.vmax * 1.02 + 0.5 / (params.pulses_per_mm * dt)
        if over.any():
            i, j = (int(x) for x in np.argwhere(over)[0])
            raise UnreachablePose(
                f"trajectory needs {('L1', 'L2', 'L3', 'X', 'Y')[j]} at {qd[i, j]:.2f} mm/s over the "
                f"{params.vmax[j]:.2f} mm/s limit at t = {i * dt:.3f} s (job line {int(line[i])}); nothing moved")
    rows = np.zeros((n, 12))
    rows[:, :3] = tip
    rows[:, 3:6] = axis
    if n > 1:
        rows[:-1, 6:9] = np.diff(tip, axis=0) / dt
        rows[:-1, 9:12] = np.diff(axis, axis=0) / dt
    return Targets(rows, q, np.asarray(line), 0)


def approach_path(q0, q1, dt, params: NCParams, machine: Machine, frac=0.5):
    """Joint-space move q0 -> q1 with a trapezoidal profile at ``frac`` of the joint limits, as tool
    poses (tip, axis). Used when the machine is not at the job start (restart from saved counters)."""
    d = np.asarray(q1, float) - np.asarray(q0, float)
    dist = np.abs(d)
    v = frac * params.vmax
    a = frac * params.amax
    # time per axis for a trapezoid (or triangle) over its distance; the slowest sets the time
    tri = dist <= v * v / a
    T_ax = np.where(tri, 2 * np.sqrt(dist / a), dist / v + v / a)
    T = float(T_ax.max())
    if T <= 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    # normalised trapezoid s(t) in [0, 1] with peak speed/accel scaled to the slowest axis
    i = int(np.argmax(T_ax))
    vs, as_ = (v[i] / dist[i], a[i] / dist[i])
    if tri[i]:
        vs = math.sqrt(as_)          # triangle: peak at half way, s'' = as_, T = 2 sqrt(1/as_)
    ta = vs / as_
    n = int(math.ceil(T / dt)) + 1
    t = np.minimum(np.arange(n) * dt, T)
    s = np.where(t < ta, 0.5 * as_ * t * t,
                 np.where(t > T - ta, 1.0 - 0.5 * as_ * (T - t) ** 2, vs * (t - 0.5 * ta)))
    s = np.clip(s, 0.0, 1.0)
    q = q0 + s[:, None] * d
    pose, ok = K.fk_batch(q, machine)
    if not np.all(ok):
        raise KinematicsError("approach move: forward kinematics failed on the way to the job start")
    return pose.tip, pose.axis


# ---------------------------------------------------------------- the loop

TIMING_WINDOW = 1 << 16          # ticks of timing kept (the last ~65 s at 1 kHz): bounded memory


@dataclass
class TimingStats:
    compute_ns: np.ndarray      # whole tick: read + NC + write (incl. the sim plant) + bookkeeping
    late_ns: np.ndarray         # wake-up time after the deadline (0 without real time)
    nc_ns: np.ndarray           # the NC step alone
    overruns: int
    max_overruns_in_row: int
    realtime: bool
    messages: list
    slow_ticks: int = 0         # ticks over the stall limit without real time (counted, not a stall)

    def summary(self) -> dict:
        c = self.compute_ns / 1e3
        lt = self.late_ns / 1e3
        if len(c) == 0:
            return {}
        nc = self.nc_ns / 1e3
        return {"ticks": int(len(c)),
                "nc_median_us": float(np.median(nc)), "nc_p99_us": float(np.percentile(nc, 99)),
                "compute_median_us": float(np.median(c)), "compute_p99_us": float(np.percentile(c, 99)),
                "compute_max_us": float(c.max()),
                "late_median_us": float(np.median(lt)), "late_p99_us": float(np.percentile(lt, 99)),
                "late_max_us": float(lt.max()), "overruns": int(self.overruns),
                "max_overruns_in_row": int(self.max_overruns_in_row), "realtime": bool(self.realtime),
                "slow_ticks": int(self.slow_ticks)}


@dataclass
class LoopResult:
    status: str                 # "done" | "stopped" (controlled stop) | "fault" (halted at once)
    reason: str
    ticks: int
    state: NCState
    timing: TimingStats
    dt: float
    counts: np.ndarray          # (ticks, 5) pulse counters at the start of each tick (commanded position)
    enc: np.ndarray             # (ticks, 5) motor-side feedback
    strain: np.ndarray          # (ticks, 3)
    truth: np.ndarray           # (ticks, 5) load-side joints (NaN without a simulation)
    target: np.ndarray          # (ticks, 6) target tip + axis
    pulses_sent: np.ndarray     # (5,) sum of all pulses written
    job_start: int = 0
    sigma: np.ndarray | None = None     # (ticks,) feed factor of the time-scaling
    path_s: np.ndarray | None = None    # (ticks,) path clock, samples passed
    line: np.ndarray | None = None      # (ticks,) job line of the target
    dropped: int = 0                    # records the recorder could not take (realtime only)

    @property
    def t(self):
        return np.arange(self.ticks) * self.dt

    @property
    def ok(self):
        return self.status == "done"


@dataclass
class LoopParts:
    """What a :class:`ControlLoop` is wired to besides the machine, the backend, the NC settings and
    its targets; every part optional.

    ``log``: callable(message) (default: stderr). ``writer``: the :class:`CounterWriter` that persists
    the pulse counters. ``follower``: the path follower (None: one made for the targets, followed at
    sigma = 1; a stream, the daemon's rt process, brings its own). ``records``: the per-tick record
    ring (default a private one of REC_CAPACITY rows); ``recorder`` drains it (default: one that
    keeps the rows for the LoopResult). ``hook(loop, k, state)`` runs at the end of every tick and
    returns the state (the daemon's command/status exchange). ``exit_when_done=False``: run until
    ``quit`` is set (halts and job ends do not end the loop). ``setup_rt``: SCHED_FIFO + mlockall
    (default: when the loop runs in real time). ``probe``: a
    :class:`pmctl.motion.probe.ProbeMonitor` that stops probing moves on contact (per tick)."""

    log: Callable[[str], None] | None = None
    writer: CounterWriter | None = None
    follower: object | None = None
    records: object | None = None
    recorder: object | None = None
    hook: Callable | None = None
    exit_when_done: bool = True
    setup_rt: bool | None = None
    probe: object | None = None


class ControlLoop:
    """Runs the NC against a backend, its targets taken from a :class:`PathFollower` that
    time-scales planned samples. ``run()`` returns a LoopResult.

    ``targets``: a :class:`Targets` (a one-shot job: followed at sigma = 1 and the loop ends when it
    is done), or None with a follower in ``parts`` (a stream: the daemon's rt process). ``parts``: a
    :class:`LoopParts`, or its fields as keywords (``log=..., hook=...``), not both.

    Attributes ``tick``, ``n_ticks`` and ``mode`` are updated every tick for a progress display
    running in another thread."""

    def __init__(self, machine: Machine, backend: Backend, params: NCParams, targets: Targets | None,
                 cfg: LoopConfig, state: NCState, parts: LoopParts | None = None, **part_fields):
        if parts is None:
            parts = LoopParts(**part_fields)       # an unknown keyword is a TypeError naming it
        elif part_fields:
            raise TypeError(f"ControlLoop: parts given, and also {', '.join(sorted(part_fields))}")
        self.machine, self.backend, self.params = machine, backend, params
        self.targets, self.cfg, self.state0 = targets, cfg, state
        self.log = parts.log or (lambda msg: print(f"pmctl: {msg}", file=sys.stderr))
        self.writer = parts.writer
        self.nc = make_nc(machine, params)      # params.implementation: "compiled" (C core) or "python"
        self.settle_ticks = int(round(cfg.settle_s * cfg.rate_hz))
        follower = parts.follower
        if follower is None:
            if targets is None:
                raise PmctlError("ControlLoop needs targets or a follower")
            follower = make_follower(ArraySource(target_samples(targets, cfg.dt, params)), params, cfg.dt)
            follower.scaler.sigma = 1.0       # a one-shot job is replayed as planned from its first sample
        self.follower = follower
        self.records = parts.records if parts.records is not None else Ring(REC_CAPACITY, REC_WIDTH)
        self.recorder = parts.recorder if parts.recorder is not None else Recorder(self.records)
        self.hook = parts.hook
        self.probe = parts.probe        # pmctl.motion.probe.ProbeMonitor: stop on contact (G38.2/G38.3), or None
        self.exit_when_done = parts.exit_when_done
        self.setup_rt = cfg.realtime if parts.setup_rt is None else bool(parts.setup_rt)   # SCHED_FIFO + mlockall
        self.last_late_ns = self.last_compute_ns = 0
        self.quit_reason = ""
        self.last_fb = None
        self.tick = 0
        self.n_ticks = (len(targets.rows) if targets is not None else 0) + self.settle_ticks
        self.mode = RUN
        self.stop_request = ""          # set from another thread: hold on the path, then stop
        self.quit = False
        self.dropped = 0
        self.stalls = 0               # stalls seen (in real time, beyond the stall limit)
        self.on_stall = None          # callable(reason): rides out a stall (Backend.stall_hold), else a stop
        self.sent = np.zeros(5, np.int64)
        self.chain_offset = None        # (3,) chain-length offset input, mm (the NC reads it each tick); None = none
        self._offset_refused = [False] * 3

    def set_chain_offset(self, chain: int, mm: float) -> bool:
        """Set the chain-length offset input of chain 0..2 (L1..L3), mm, added to the commanded
        length (pmctl.motion.nc: the NC slews to it at chain_offset_rate_mm_s). Any thread. A value
        beyond +-chain_offset_max_mm or not finite is refused, said in the log (once until a value
        is accepted again), and the previous input stays."""
        return self.set_chain_offsets({int(chain): mm})

    def set_chain_offsets(self, offsets_mm) -> bool:
        """Several chain-length offsets at once (a sequence of three, or {chain: mm}), each as
        :meth:`set_chain_offset`; the tick sees them together."""
        items = offsets_mm.items() if isinstance(offsets_mm, dict) else enumerate(offsets_mm)
        off = np.zeros(3) if self.chain_offset is None else self.chain_offset.copy()
        lim, ok = self.params.chain_offset_max_mm, True
        for chain, mm in items:
            if not 0 <= chain < 3:
                self.log(f"chain offset refused: chain {chain} is not 0, 1 or 2 (L1, L2, L3)")
                ok = False
                continue
            mm = float(mm)
            if not (math.isfinite(mm) and abs(mm) <= lim):
                if not self._offset_refused[chain]:
                    self.log(f"chain offset refused: L{chain + 1} {mm:+.4f} mm is beyond the bound +-{lim:g} mm "
                             f"(chain_offset_max_mm); the offset stays at {off[chain]:+.4f} mm")
                self._offset_refused[chain] = True
                ok = False
                continue
            self._offset_refused[chain] = False
            off[chain] = mm
        self.chain_offset = off           # one reference swap: the tick reads a whole vector
        return ok

    def run(self) -> LoopResult:
        """The ticks, each as LinuxCNC's emcmotController: read inputs, model pose, NC, output,
        record, status, supervise, wait; until the job is done, a stop, a fault or ``quit``."""
        c = self._start()
        read, pose, nc, output, record = self._read_inputs, self._model_pose, self._nc, self._output, self._record
        status, supervise, wait = self._status, self._supervise, self._wait
        try:
            self._sleep(c)
            while True:
                # ---- hot path (timed: compute_ns)
                if not read(c):
                    break
                pose(c)
                nc(c)
                if not output(c):
                    break
                record(c)
                # ---- end of hot path
                status(c)
                if supervise(c):
                    break
                wait(c)
        except Exception as e:        # anything else (a bug, an unexpected error of a backend): halt, say why
            c.status, c.reason = "fault", f"loop error at tick {c.k}: {type(e).__name__}: {e}"
            st = c.st
            if c.pending is not None:  # not known to be taken by the backend: the counters must not claim them
                st = st.uncounted(c.pending)
            c.st = _halt(st, c.reason)
        finally:
            self._finish(c)
        return self._result(c)

    # ---- setting up and ending a run

    def _start(self) -> Tick:
        """The run's context; real-time scheduling (when asked), the recorder started, the garbage
        collector paused (no collection pauses on the hot path)."""
        cfg, p, be = self.cfg, self.params, self.backend
        c = Tick()
        c.realtime = cfg.realtime
        c.has_truth = be.truth() is not None
        c.positions, c.ppm = be.accepts == "positions", p.pulses_per_mm     # CSP drives take joint targets, mm
        c.nan5 = [math.nan] * 5
        c.zero3 = [0.0] * 3
        c.period = int(round(1e9 / cfg.rate_hz))
        c.stall_ns = int(max(cfg.stall_timeout_s, be.stall_tolerance_s) * 1e9)
        c.spin_ns = int(cfg.spin_us * 1e3)
        # timing statistics in a bounded window (the last TIMING_WINDOW ticks)
        c.comp = np.zeros(TIMING_WINDOW, np.int64)
        c.late = np.zeros(TIMING_WINDOW, np.int64)
        c.ncns = np.zeros(TIMING_WINDOW, np.int64)
        c.msgs = []
        if cfg.realtime:
            if self.setup_rt:
                c.msgs = setup_realtime(cfg.rt_priority, cfg.lock_memory)
                for m in c.msgs:
                    self.log(m)
            self.recorder.start()
        c.sleeper = AbsoluteSleeper()
        c.st = self.nc.load(self.state0)
        c.status, c.reason = "done", ""
        c.overruns = c.in_row = c.max_in_row = c.slow = 0
        c.pending = None                # pulses computed but not yet taken by the backend
        c.last_warn = 0
        c.persist_every = cfg.persist_every_ticks
        c.gc_was = gc.isenabled()
        gc.collect()
        gc.disable()
        c.switch = sys.getswitchinterval()
        if cfg.realtime:
            # a helper thread (progress, counter writer, recorder) holding the GIL when the tick
            # wakes is asked to let go after 100 us instead of 5 ms
            sys.setswitchinterval(1e-4)
        c.mono = mono = time.monotonic_ns
        c.k = 0
        c.done_at = -1
        c.stop_from_hold = False
        c.held_at = -1                  # tick at which a stop's feed hold reached sigma = 0
        # held on the path, the NC's rest deadband zeroes the rates within half a pulse of the target;
        # K_theta answering the chains' ringing may still ask for a pulse or two's worth (K_v x a
        # pulse's worth of error): that is at rest too
        c.rest_rate = (2.0 * p.kv / p.pulses_per_mm).tolist()
        c.deadline = mono() + c.period
        c.t1_prev = c.deadline - c.period   # end of the previous tick: the last command sent
        return c

    def _finish(self, c: Tick) -> None:
        """Whatever the run ended with: the final state kept, scheduling, the switch interval and the
        garbage collector as they were, the recorder stopped."""
        cfg = self.cfg
        self.state = c.st
        sys.setswitchinterval(c.switch)
        if c.gc_was:
            gc.enable()
        if cfg.realtime and self.setup_rt:
            undo_realtime(cfg.lock_memory)
        self.recorder.stop()

    def _result(self, c: Tick) -> LoopResult:
        cfg, recorder = self.cfg, self.recorder
        n = c.k
        m = min(n, TIMING_WINDOW)
        order = np.arange(n - m, n) % TIMING_WINDOW
        if c.slow:
            self.log(f"{c.slow} ticks took longer than the stall limit ({cfg.stall_timeout_s * 1e3:g} ms); "
                     f"not a stall without real time")
        timing = TimingStats(c.comp[order].copy(), c.late[order].copy(), c.ncns[order].copy(), c.overruns,
                             c.max_in_row, cfg.realtime, c.msgs, c.slow)
        a = recorder.arrays() if recorder.keep else np.zeros((0, self.records.width))
        return LoopResult(c.status, c.reason, n, c.st.snapshot(), timing, 1.0 / cfg.rate_hz,
                          a[:, R_COUNTS:R_COUNTS + 5].astype(np.int64), a[:, R_ENC:R_ENC + 5],
                          a[:, R_STRAIN:R_STRAIN + 3], a[:, R_TRUTH:R_TRUTH + 5], a[:, R_TARGET:R_TARGET + 6],
                          self.sent.copy(), self.targets.job_start if self.targets is not None else 0,
                          a[:, R_SIGMA], a[:, R_S], a[:, R_LINE].astype(int), self.dropped)

    # ---- the phases of a tick, in order

    def _read_inputs(self, c: Tick) -> bool:
        """Read inputs: the backend's feedback, and the tick's start as the record will hold it
        (copies: the backend reuses its feedback object). False: the backend failed, halted."""
        be = self.backend
        c.t0 = c.mono()                 # the hot path's start: its compute time runs from here
        try:
            fb = be.read()
        except HalTimeout as e:
            return self._backend_lost(c, f"backend not answering: {e}", e)
        except HalError as e:
            return self._backend_lost(c, f"backend fault: {e}", e)
        c.fb = fb
        row = c.st.counts.tolist()
        row += fb.enc.tolist()
        row += fb.strain.tolist()
        row += be.truth().tolist() if c.has_truth else c.nan5
        c.row = row
        return True

    def _backend_lost(self, c: Tick, reason: str, e: HalError) -> bool:
        c.status, c.reason = "fault", reason
        c.st = _halt(_executed(c.st, e), reason)
        c.comp[c.w] = c.mono() - c.t0
        return False

    def _model_pose(self, c: Tick) -> None:
        """Model pose: the pose the model is to reach this tick, the path follower's next target (a
        stop request turns into a feed hold on the path first); the probe monitor watches it."""
        fol = self.follower
        if self.stop_request and c.st.mode == RUN and not c.stop_from_hold:
            fol.scaler.hold = True          # a stop is a feed hold on the path, then a halt
            c.stop_from_hold = True
        c.tg = tg = fol.next_target()
        if self.probe is not None:
            self.probe.tick(fol, tg, c.fb.strain, c.k)      # strain as read: the plant at this target

    def _nc(self, c: Tick) -> None:
        """NC: this tick's pulses and the next state (the one NC call site, compiled or Python)."""
        mono = c.mono
        t_nc = mono()
        pulses, c.st = self.nc.step(c.st, c.tg, c.fb, self.chain_offset)
        c.ncns[c.w] = mono() - t_nc
        c.pulses = c.pending = pulses

    def _output(self, c: Tick) -> bool:
        """Output: the pulses (or, to a CSP drive, the joint positions) to the backend. False: it did
        not take them, halted, and the counters do not claim them."""
        pulses = c.pulses
        try:
            if c.positions:
                self.backend.write_positions(c.st.counts / c.ppm)
            else:
                self.backend.write_pulses(pulses)
        except HalError as e:
            c.status, c.reason = "fault", f"backend fault: {e}"
            c.st = _halt(_executed(c.st.uncounted(pulses), e), c.reason)
            c.pending = None
            return False
        sent = self.sent
        sent += pulses
        c.pending = None
        return True

    def _record(self, c: Tick) -> None:
        """Record: the tick's row into the record ring, the counters offered to the writer every
        persist_every ticks; the end of the hot path (its compute time)."""
        st, w = c.st, c.w
        s_total, sigma, line, state = self.follower.progress()
        row = [c.k, s_total, sigma, line, st.mode, state] + c.row
        row += c.tg.tolist()[:6]
        row.append(c.late_ns)
        row.append(self.last_compute_ns)
        row += c.zero3 if st.offset is None else st.offset.tolist()
        if not self.records.push_row(row):
            recorder = self.recorder
            if c.realtime or not getattr(recorder, "inline", True):
                self.dropped += 1
            else:
                recorder.drain()
                self.records.push_row(row)
        if writer := self.writer:
            if c.k % c.persist_every == 0:
                writer.offer(st.counts, c.k)
        c.t1 = t1 = c.mono()
        c.comp[w] = t1 - c.t0
        self.last_compute_ns = t1 - c.t0
        self.last_late_ns = c.late_ns
        self.last_fb = c.fb

    def _status(self, c: Tick) -> None:
        """Status: the tick and mode for a progress display, then the hook (the rt process's
        command/status exchange), which may change the state."""
        self.tick = c.k
        self.mode = c.st.mode
        c.k += 1
        if self.hook is not None:
            c.st = self.hook(self, c.k, c.st)

    def _supervise(self, c: Tick) -> bool:
        """Supervise, the stop rules: quit; with exit_when_done a halt, a stop's hold come to rest,
        the job's end after settling; a stall. True: the run ends."""
        st, fol = c.st, self.follower
        k = c.k
        if self.quit:
            c.status, c.reason = ("stopped" if st.mode != HALTED or _was_stop(st) else "fault"), \
                (self.quit_reason or st.reason or "quit")
            return True
        if self.exit_when_done:
            if st.mode == HALTED:
                c.status, c.reason = ("stopped" if _was_stop(st) else "fault"), st.reason
                return True
            if c.stop_from_hold and st.mode == RUN and fol.sigma == 0.0:
                # held on the path: halt once the joints are at rest (rates within a pulse
                # or two's worth), or at the latest after the settling time
                if c.held_at < 0:
                    c.held_at = k
                if all(abs(v) <= r for v, r in zip(st.qdot.tolist(), c.rest_rate)) \
                        or k - c.held_at >= self.settle_ticks:
                    c.st = _halt(st, self.stop_request)
                    c.status, c.reason = "stopped", self.stop_request
                    return True
            if st.mode == RUN and fol.at_end and fol.src.count() <= 1 and fol.state != HOLDING:
                if c.done_at < 0:
                    c.done_at = k
                if k - c.done_at >= self.settle_ticks:
                    c.st = _done(st)
                    c.status, c.reason = "done", ""
                    return True
        self._check_stall(c)
        c.t1_prev = c.t1
        return False

    def _check_stall(self, c: Tick) -> None:
        """A tick that left the device too long without a command: in real time, while the path
        moves, a stop with the reason (or a hold that rides it out); offline only counted."""
        t0, t1, stall_ns = c.t0, c.t1, c.stall_ns
        if not c.realtime:
            if t1 - t0 > stall_ns:
                c.slow += 1      # offline simulation: a slow tick harms nothing; counted, reported
        elif t1 - c.t1_prev > stall_ns and c.st.mode == RUN:
            # the device went this long without a command: a slow tick, or a late wake-up
            # (the process descheduled), both count
            gap = t1 - c.t1_prev
            why = (f"loop stalled: {gap / 1e6:.1f} ms between two commands, "
                   f"{(t1 - t0) / 1e6:.1f} ms of it computing "
                   f"(limit {stall_ns / 1e6:g} ms){stall_hint(gap, t1 - t0)}")
            self.stalls += 1
            fol = self.follower
            if fol.sigma == 0.0 and fol.state != HOLDING:
                self.log(f"warning: {why}; at rest, nothing was commanded to move: no stop")
            elif self.backend.stall_hold and self.on_stall is not None:
                self.on_stall(why)      # a feed hold on the path, resumed when on time again
            else:
                c.st = _stopping(c.st, why)

    def _wait(self, c: Tick) -> None:
        """Wait: in real time the next deadline and the overrun policy (missed deadlines counted,
        warned about, N in a row stop the machine), then sleep to it."""
        if c.realtime:
            self._pace(c)
        self._sleep(c)

    def _pace(self, c: Tick) -> None:
        cfg, period, t1 = self.cfg, c.period, c.t1
        c.deadline += period
        if t1 > c.deadline:
            missed = (t1 - c.deadline) // period + 1
            c.overruns += 1
            c.in_row += 1
            c.max_in_row = max(c.max_in_row, c.in_row)
            c.deadline += missed * period
            if t1 - c.last_warn > 1_000_000_000:
                c.last_warn = t1
                self.log(f"warning: tick {c.k} overran its deadline by {(t1 - c.deadline + missed * period) / 1e3:.0f} us "
                         f"({c.overruns} overruns so far)" + ("" if c.overruns > 1 else
                         f": the computer is too busy for {cfg.rate_hz:g} Hz; stop other work, give the "
                         f"loop real-time priority and a core of its own (docs/service.md: PREEMPT_RT, "
                         f"isolcpus) or lower [loop] rate_hz"))
            if c.in_row >= cfg.max_overruns_in_row and c.st.mode == RUN:
                c.st = _stopping(c.st, f"{c.in_row} deadlines missed in a row at {cfg.rate_hz:g} Hz")
        else:
            c.in_row = 0

    def _sleep(self, c: Tick) -> None:
        """Until the tick's deadline (real time; ``spin_us`` of it busy-waiting), and the lateness of
        the wake-up; offline the tick starts at once."""
        c.w = w = c.k % TIMING_WINDOW
        if c.realtime:
            mono = c.mono
            deadline = c.deadline
            if c.spin_ns:
                c.sleeper.until(deadline - c.spin_ns)
                while mono() < deadline:
                    pass
            else:
                c.sleeper.until(deadline)
            c.late[w] = c.late_ns = mono() - deadline
        else:
            c.late_ns = 0


class Tick:
    """The loose values of a run that travel from phase to phase and from tick to tick: the NC state,
    this tick's feedback, target and pulses, the deadline, the timing window, the stop rules' memory."""

    __slots__ = ("realtime", "has_truth", "positions", "ppm", "nan5", "zero3", "period", "stall_ns", "spin_ns",
                 "comp", "late", "ncns", "msgs", "sleeper", "st", "status", "reason", "overruns", "in_row",
                 "max_in_row", "slow", "pending", "last_warn", "persist_every", "gc_was", "switch", "mono", "k",
                 "w", "done_at", "stop_from_hold", "held_at", "rest_rate", "deadline", "t0", "t1", "t1_prev",
                 "fb", "tg", "pulses", "row", "late_ns")


def _executed(st: NCState, e: HalError) -> NCState:
    """A backend that knows what the device executed (a step/dir bridge's counters) puts it on the
    error as ``counts``: the controller's counters follow the device, not the commands."""
    c = getattr(e, "counts", None)
    return st if c is None else st.with_counts(c)


def _halt(st: NCState, reason: str) -> NCState:
    return st.halted(reason)


def stall_hint(gap_ns: int, compute_ns: int) -> str:
    """What a stall reason adds when the time went to the scheduler, not to computing: the process
    was not running (a loaded machine, no real-time priority); empty when computing took most of it."""
    if compute_ns * 2 >= gap_ns:
        return ""
    return (f"; the process was not scheduled for {(gap_ns - compute_ns) / 1e6:.0f} ms: a loaded machine or no "
            f"real-time priority (--no-realtime runs offline, ticks back to back)")


def _stopping(st: NCState, reason: str) -> NCState:
    return st.stopping(reason)


def _done(st: NCState) -> NCState:
    return st.done()


def _was_stop(st: NCState) -> bool:
    r = st.reason
    return not (r.startswith("following error") or r.startswith("model pose lost"))


# ---------------------------------------------------------------- convenience


def target_samples(tg: Targets, dt: float, params: NCParams, *, rapid=None, rapid_mm_s: float = 50.0):
    """Sample rows (pmctl.motion.timescale) of preflighted targets: their joint rates come from the
    IK the preflight already did; caps looked ahead by the backward pass; the last row ends the job."""
    rows = make_rows(tg.rows[:, :3], tg.rows[:, 3:6], tg.q, tg.line, dt, params, rapid=rapid,
                     rapid_mm_s=rapid_mm_s, end=True)
    rows[:, S_CAP] = backward_pass(rows[:, S_CAP], dt, 0.5 * scaling_limits(params)[0])
    return rows


def prepare(machine: Machine, params: NCParams, traj: Trajectory, dt: float, counts0=None) -> Targets:
    """Preflight the trajectory at tick period dt and prepend an approach move from counts0."""
    tip, axis, line = resample(traj, dt)
    tg = build_targets(tip, axis, line, dt, machine, params)
    if counts0 is None:
        return tg
    q0 = np.asarray(counts0) / params.pulses_per_mm
    q1 = tg.q[0]
    if np.all(np.abs(np.rint(q1 * params.pulses_per_mm) - counts0) <= 1):
        return tg
    a_tip, a_axis = approach_path(q0, q1, dt, params, machine)
    hold = int(round(0.02 / dt))
    a_tip = np.concatenate([a_tip, np.repeat(tip[:1], hold, 0)])
    a_axis = np.concatenate([a_axis, np.repeat(axis[:1], hold, 0)])
    full = build_targets(np.concatenate([a_tip, tip]), np.concatenate([a_axis, axis]),
                         np.concatenate([np.zeros(len(a_tip), int), line]), dt, machine, params)
    full.job_start = len(a_tip)
    return full


def tracking_stats(res: LoopResult, machine: Machine, from_tick: int | None = None) -> dict:
    """Tool-tip error of the load-side pose (FK of the simulated load side) against the target."""
    i0 = res.job_start if from_tick is None else from_tick
    tr = res.truth[i0:]
    if len(tr) == 0 or not np.all(np.isfinite(tr)):
        return {}
    pose, ok = K.fk_batch(tr, machine)
    e = np.linalg.norm(pose.tip - res.target[i0:, :3], axis=-1)
    ang = np.arccos(np.clip(np.sum(pose.axis * res.target[i0:, 3:6], -1), -1.0, 1.0))
    e = np.where(ok, e, np.nan)
    return {"samples": int(len(e)), "tip_rms_um": float(np.sqrt(np.nanmean(e ** 2)) * 1e3),
            "tip_max_um": float(np.nanmax(e) * 1e3), "tip_p99_um": float(np.nanpercentile(e, 99) * 1e3),
            "axis_rms_urad": float(np.sqrt(np.nanmean(ang ** 2)) * 1e6),
            "axis_max_urad": float(np.nanmax(ang) * 1e6), "fk_failures": int(np.sum(~ok))}
