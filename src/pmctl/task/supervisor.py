"""The supervisor: everything of the daemon except the loop (the rt process, pmctl.motion.rtproc).

It creates the channel (shared memory), starts the rt process and then, in its own threads:
- plans queued motion (jobs, console G-code, jogs) with the path planner, from where the previous
  item ends, and streams the samples (pmctl.motion.timescale rows) into the sample ring as room
  frees up -- the rt side never waits on it: an empty ring is a deceleration on the path;
- drains the per-tick record ring (into the recording, if one is open);
- watches the rt process: its status block and whether it is alive. If it dies, the supervisor
  raises an alarm, saves the last counters it reported (not trusted: the drives stopped on their
  own watchdog) and refuses motion until an unlock restarts it.

Probing (G38.2/G38.3) is planned in pieces around the probes (pmctl.task.probing); the results land
in ``Item.probe_results``; a G38.2 without contact raises ALARM 5 and drops the queue (grbl's probe
fail).

- acts on what happens where the path gets to it, in program order, as grbl's planner sync does:
  the EVENT moves of a job (pmctl.core.job: spindle, coolant, tool change, pause, outputs, messages),
  which the planner turns into exact stops marked in ``Trajectory.marks``, and the spindle speed
  changes of a job that carries its speed only per move (``Move.spindle_rpm``: CL data, the reader
  before EVENT moves). Each becomes a hold point: C_HOLD_AT at its sample, sent before that sample
  is queued, so the rt side holds on the path there; when it is reached the events thread performs
  the events (a spindle change waits until at speed) and releases the hold. A pause (M0, M1 with the
  optional stop on, M6 tool change) stays held until cycle start (``resume``). A job's first speed is
  such a point at its first sample. The state stays ``Run`` while the path waits for an event.
- sends the session's events (pmctl.task.events: an item done, the queue dropped, a stop, a reset,
  the records drained, ...) to its parts, which act on them: the spindle VFD (``[spindle]``,
  pmctl.task.spindle), the strain DAQ (``[daq]``, pmctl.task.daq), homing (pmctl.task.homing); a
  fault or lost link of a device is a controlled stop on the path with the reason (ALARM 3,
  ``controlled_stop``).

``pmctl run`` is a one-shot client of this class (start, submit one job, wait for its events, shutdown);
``offline=True`` (its --no-realtime) runs the rt side's ticks back to back, waiting for samples.

The machine state (grbl's: Idle, Run, Hold:0/1, Jog, Home, Alarm, Check) is derived here from
the rt status and the supervisor's own flags. Operator requests (hold, resume, overrides, soft
reset, E-stop, unlock) go to the rt side as commands on the channel's command ring.
"""

from __future__ import annotations

import collections
import json
import math
import os
import queue
import subprocess
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field

import numpy as np

from pmctl.core import kinematics as K
from pmctl.core.alarms import ALARM_ABORT, ALARM_ESTOP, ALARM_MOTOR_FAULT, ALARM_SOFT_LIMIT
from pmctl.core.errors import MotionRefused, PmctlError
from pmctl.core.job import DWELL, EVENT, RAPID
from pmctl.motion import channel as C
from pmctl.motion.nc import RUN
from pmctl.motion.recorder import R_TICK
from pmctl.motion.settings import resolve
from pmctl.motion.status import F_FAULT, RtStatus, read_status
from pmctl.motion.timescale import (HELD, HOLDING, MOVING, STARVED, S_LINE, RowStream, full_speed_queue,
                                    iter_stream_rows, shape_trajectory)
from pmctl.task.daq import Daq
from pmctl.task.events import EventHub
from pmctl.task.homing import Homing
from pmctl.task.interp import moves_job
from pmctl.task.jobcheck import machine_for_planning
from pmctl.task.planner import PlannerLimits, plan, plan_stream, validate
from pmctl.task.probing import Probing
from pmctl.task.spindle import Spindle, has_spindle_event
from pmctl.task.stream_planner import StreamPlanner

# the open stream of console blocks (Supervisor.stream, _stream_rows)
STREAM_REFILL_S = 1.0             # below this much motion queued ahead of the tool, every settled window is planned
STREAM_LOW_WATER_S = 0.5          # below this, with no block coming, the stream is planned to rest at its last block
STREAM_IDLE_S = 0.08              # no block for this long: the sender paused (a block may still come before)


@dataclass(eq=False)
class Item:
    """One planned piece of motion: a job file, a batch of console lines, a jog, a homing move. Items
    compare by identity (``it in sup.items``: the queue holds this very item)."""
    kind: str                       # "job" | "gcode" | "jog" | "home"
    job: object                     # pmctl.core.job.Job
    start: tuple                    # (tip, axis) it starts from
    end: tuple                      # (tip, axis) it ends at
    name: str = ""
    index: int = 0
    planned: bool = False
    error: str = ""
    lines: dict = field(default_factory=dict)    # sample line -> reported line (console N words)
    gen: int = 0                                 # queue generation: a reset or fault drops older items
    source: str = ""                             # a job file's path (the journal keeps it for a resume)
    probe_results: list = field(default_factory=list)   # pmctl.motion.probe.ProbeResult of each probe, in order
    parts: int = 1                               # pieces planned one after the other (probing splits an item)
    ends: int = 0                                # of which the rt side has passed the end
    pushed: int = 0                              # samples queued for the rt side so far
    pushed_line: int = 0                         # the job line of the last of them
    all_pushed: bool = False                     # every sample of it is queued (its length is known)
    path: object = None                          # the planner's checked path of its job (validate(full=True))
    stream: bool = False                         # a stream of console blocks (Supervisor.stream): it grows
    open: bool = False                           # a stream still taking blocks (``inbox``)
    inbox: list = field(default_factory=list)    # blocks' moves appended, not yet given to its planner
    last_in: float = 0.0                         # time.monotonic() of the last append
    waiting: bool = False                        # the sender waits for room in the queue (the console's)
    spindle_events: bool | None = None           # a spindle EVENT among its moves (None: look in job.moves)


class Supervisor:
    def __init__(self, config="prototype", *, service=None, backend=None, state_file="", realtime=False,
                 rate_hz=None, log=None, sample_capacity=C.SAMPLE_CAPACITY, offline=False, nc=None, hal=None,
                 settings=None):
        # the settings, resolved once (pmctl run resolves them and passes them in); the rt process gets
        # them as data and never reads a config file
        if settings is None:
            settings = resolve(config, service, backend=backend, rate_hz=rate_hz, realtime=realtime,
                               offline=offline, nc=nc, hal=hal)
        self.settings = settings
        self.config = config
        self.service = service
        self.machine = settings.machine
        self.nc_overrides = settings.nc_overrides  # e.g. pmctl run --k-theta --shaper --pulse-mode
        self.hal_overrides = settings.hal_overrides   # e.g. pmctl run --bridge rp2040-emu
        self.svc = settings.svc
        self.offline = settings.offline           # rt ticks back to back, waiting for samples
        self.backend = settings.backend
        self.rate_hz = settings.rate_hz
        self.dt = settings.dt
        self.nc_setup = settings.setup
        self.params = settings.params
        # the V-F converters may cap the joint speed below the machine's (seed mode: one pulse per
        # tick): plan within what they can emit
        self.plan_machine = machine_for_planning(self.machine, self.params)
        self.state_file = state_file
        self.realtime = settings.realtime
        self.log = log or (lambda m: None)
        self.sample_capacity = sample_capacity
        self.ch: C.Channel | None = None
        self.proc = None
        self.alarm = 0
        self.alarm_msg = ""
        self.check_mode = False
        self.rt_dead = False
        self._quitting = False
        self.items: collections.deque[Item] = collections.deque()   # submitted, not finished
        self.n_submitted = 0
        self._gen = 0
        self._plan_q: queue.Queue = queue.Queue()
        self._abort = threading.Event()
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._threads = []
        self.record_sink = None           # callable(rows) for drained records
        self.events = EventHub()          # the session's events (pmctl.task.events): the parts act on them
        self.listeners = self.events.listeners     # callables(event: str, detail: dict): the outside's
        self._last_status = None
        self._fault_seen = 0.0
        self.started_at = time.time()
        self.counts0 = None
        self.exited_reason = ""
        self.plan_feed_override = 1.0     # the planner's feed factor (pmctl run --feed-override)
        self.final_status = None          # the rt side's last status block, kept at shutdown
        self.rt_result = None             # what the rt side reported as it exited (Channel.result)
        self._stream_wake = threading.Event()     # a block appended to the open stream, or it closed
        self._hold_points = collections.deque()    # (ring row, events) of queued C_HOLD_AT points, in row order
        self._hold_at_seen = 0
        self._events_q: queue.Queue = queue.Queue()   # (queue generation, events) of the points reached
        self._auto_hold = False           # the path holds at a point while its events are performed
        self.paused = ""                  # a pause (M0, M1, M6) waiting for cycle start: what to do
        self.optional_stop = False        # M1 pauses only with this switch on (pmctl ctl optional-stop on)
        # who answers a tool change or a pause when no operator is at a console: None (they wait for
        # cycle start), or a callable(what) that performs it and logs (pmctl run on the simulation)
        self.stand_in_operator = None
        self.tool = None                  # the tool in the spindle, once a tool change was confirmed (None: not known)
        self._pause_tool = None           # the tool a waiting tool-change pause asks for
        self.coolant = set()              # "mist" (M7), "flood" (M8); M9 clears
        self.outputs = {}                 # M62-M68: "name index" -> value, as last set
        self.device_fault = ""            # the spindle's or the DAQ's fault that stopped motion
        # the parts out of the tick, driven by the events: the spindle VFD and the strain DAQ (opened
        # by open_devices())
        self._spindle = Spindle(self)
        self._daq = Daq(self)
        self._probing = Probing(self)      # items with probing moves (G38.x), from the planner thread
        self._homing = Homing(self)        # $H

    @property
    def homing(self) -> bool:
        """A homing cycle is under way (pmctl.task.homing: the state Home, motion refused)."""
        return self._homing.active

    @property
    def homed(self) -> bool:
        """The machine was homed since its position was last lost (the daemon's journal keeps it)."""
        return self._homing.homed

    @homed.setter
    def homed(self, yes: bool):
        self._homing.homed = bool(yes)

    @property
    def spindle(self):
        """The spindle VFD's session (pmctl.hal.modbus_vfd.SpindleSession; None until connected)."""
        return self._spindle.session

    @property
    def daq(self):
        """The strain DAQ's session (pmctl.hal.modbus_daq.DaqSession; None without ``[daq]``)."""
        return self._daq.session

    @property
    def spindle_ov(self) -> float:
        """grbl's spindle speed override, 0.1 .. 2.0 (:meth:`spindle_override`)."""
        return self._spindle.ov

    @property
    def spindle_off_at_job_end(self) -> bool:
        """M5 when a job ends with the spindle off (pmctl run turns it off: M5 at the shutdown)."""
        return self._spindle.off_at_job_end

    @spindle_off_at_job_end.setter
    def spindle_off_at_job_end(self, on: bool):
        self._spindle.off_at_job_end = bool(on)

    @property
    def generation(self) -> int:
        """The queue's generation: a reset or a fault that drops the queue starts a new one."""
        return self._gen

    # ------------------------------------------------------------ lifecycle
    def start(self, counts0, timeout_s: float = 60.0):
        """Create the channel, start the rt process at pulse counters ``counts0`` and the threads."""
        self.counts0 = np.asarray(counts0, np.int64)
        self.open_devices(at=self.counts0)   # a device that does not answer: refused before the drives enable
        try:
            self.ch = C.Channel(create=True, sample_capacity=self.sample_capacity)
            self._spawn(self.counts0, timeout_s)
        except BaseException:
            self.close_devices()
            raise
        for name, fn in (("pmctl-planner", self._planner), ("pmctl-monitor", self._monitor),
                         ("pmctl-events", self._events_loop)):
            t = threading.Thread(target=fn, name=name, daemon=True)
            t.start()
            self._threads.append(t)

    def _spawn(self, counts, timeout_s):
        ch = self.ch
        ch.reset_status(counts)           # nothing of a previous rt process's status may count
        ch.samples.clear()
        ch.records.clear()
        ch.commands.clear()
        ch.clear_result()
        self._hold_points.clear()
        self._hold_at_seen = 0
        spec = {"shm": ch.name, "state_file": self.state_file, "counts": [int(c) for c in counts],
                "ppid": os.getpid()}
        # the settings go as data over the spawn pipe (stdin): the rt process reads no config file
        p = subprocess.Popen([sys.executable, "-m", "pmctl.motion.rtproc", json.dumps(spec)], stdin=subprocess.PIPE)
        try:
            p.stdin.write(self.settings.to_bytes())
            p.stdin.close()
        except BrokenPipeError:
            pass                          # it died at once: said below
        self.proc = _RtProc(p)
        t0 = time.monotonic()
        while not self.status().running:
            if not self.proc.is_alive():
                raise PmctlError(f"the rt motion process failed to start (exit code {self.proc.exitcode})")
            if time.monotonic() - t0 > timeout_s:
                self.proc.kill()
                raise PmctlError(f"the rt motion process did not start within {timeout_s:g} s")
            time.sleep(0.01)
        while self.status().tick < 2 and self.proc.is_alive():
            time.sleep(0.005)
        self.rt_dead = False
        self._ended_base = 0
        self._fault_seen = self.status().reason_seq

    @property
    def rt_pid(self):
        return self.proc.pid if self.proc is not None else None

    def shutdown(self, reason="stopped", timeout_s=30.0) -> np.ndarray:
        """Hold on the path, let the rt side save its counters and exit; returns the final counters."""
        self.events.send("shutdown")
        self._abort.set()
        self._quitting = True         # the rt side's exit from here on is the asked-for one, not a death (ALARM 17)
        counts = None
        if self.proc is not None and self.proc.is_alive():
            self.ch.command(C.C_QUIT, 1.0 if reason == "done" else 0.0)
            self.proc.join(timeout_s)
            if self.proc.is_alive():
                self.proc.terminate()
                self.proc.join(5)
        if self.ch is not None:
            self.final_status = self.status()
            counts = self.final_status.counts.copy()
            self.exited_reason = self.ch.reason()
            self.rt_result = self.ch.result()
        self._stop.set()
        for t in self._threads:
            t.join(2.0)
        self._drain_records()
        self.close_devices()
        if self.ch is not None:
            self.ch.close(unlink=True)
            self.ch = None
        return counts

    # ------------------------------------------------------------ devices out of the tick
    def open_devices(self, spindle: bool = False, at=None):
        """Connect the strain DAQ (and, with ``spindle``, the spindle VFD now rather than at the first
        job that needs it); ``start`` calls it. pmctl run calls it before ``start`` so that the
        recording knows its channels and the spindle is at speed at the first tick. ``at``: the pulse
        counters the machine starts at (a simulated DAQ serves the plant's strain at rest there until
        the first record: its weight, not a zero that a slow estimate would take for the truth)."""
        if at is not None:
            self._daq.at_rest(at)
        if spindle and self.spindle is None and self.svc.spindle is not None:
            self._spindle.connect()
        self._daq.open()

    def spindle_start(self, rpm: float):
        """M3/M4 S``rpm`` (0: M5) and wait until at speed (the path waits: call between jobs); the
        spindle is watched from then on (pmctl.task.spindle)."""
        self._spindle.start(rpm)

    def close_devices(self):
        """M5 and disconnect the spindle, stop polling the DAQ (each whatever the other does)."""
        for name, part in (("spindle", self._spindle), ("daq", self._daq)):
            try:
                part.close()
            except Exception as e:        # noqa: BLE001 (reported; the counters are the rt side's)
                self.log(f"warning: closing the {name}: {e}")

    def rt_tick(self) -> int:
        """The rt side's tick now (0 before the channel exists): what polled devices stamp samples with."""
        ch = self.ch
        return read_status(ch).tick if ch is not None else 0

    def controlled_stop(self, why: str):
        """The spindle's or the DAQ's polling thread saw a fault or a lost link: a controlled stop
        on the path (the queue is dropped), ALARM 3 with the reason."""
        if self.device_fault:
            return
        self.device_fault = why
        self.log(f"controlled stop: {why}")
        self.events.send("device_fault", {"msg": why}, msg=why)
        if not self.alarm:
            self.raise_alarm(ALARM_ABORT, why)

        def stop():
            try:
                if self.ch is not None and not self.rt_dead and not self._quitting:
                    self._stop_queue()
            except Exception as e:        # noqa: BLE001 (a shutdown meanwhile closed the channel: it stops anyway)
                if not self._quitting:
                    self.log(f"stopping after {why}: {type(e).__name__}: {e}")
        threading.Thread(target=stop, daemon=True, name="pmctl-device-stop").start()

    # ------------------------------------------------------------ events where the path gets to them
    def _hold_point(self, row: int, rest: bool, events: tuple, it=None):
        """Hold the path at sample ``row`` of the ring and perform ``events`` there (sent before that
        sample is queued); item ``it`` is not done before they are."""
        with self._lock:
            if it is not None:
                self._check_going(it)     # a point of a dropped item never reaches the rt side (after its reset)
            self._hold_points.append((row, tuple(events), it))
            seq = self.command(C.C_HOLD_AT, float(row), 1.0 if rest else 0.0)
        # the rt side takes commands after its path step: the point must be there before the sample
        self.wait_ack(seq, 1.0)
        for name, value in events:
            if name == "spindle":
                self._spindle.plan_rpm = float(value)

    def _events_of(self, it, pieces, row0, per_move=True):
        """The planner's pieces, passed through; before each piece's samples are queued, its hold
        points are sent: the marks of its EVENT moves (on their exact stops), and for a job that
        carries the spindle speed only per move, its first speed and its speed changes
        (pmctl.task.spindle: ``Spindle.speed_points``)."""
        speeds = self._spindle.speed_points(it.job.moves, per_move)
        n0 = 0                         # samples before this piece
        for tr in pieces:
            points = [(row0 + n0 + i, True, tuple(ev)) for i, _line, ev in tr.marks]
            if speeds is not None:
                first, changes = speeds.of(tr, row0, row0 + n0)
                points = first + points + changes
            for row, rest, ev in sorted(points, key=lambda p: p[0]):
                self._hold_point(row, rest, ev, it)
            n0 += len(tr)
            yield tr

    def _drop_hold_points(self):
        """A soft reset, an E-stop or a fault dropped the queue: no event is waited for (the rt side
        dropped its points too)."""
        with self._lock:
            self._hold_points.clear()
            self._spindle.plan_rpm = None
            self._auto_item = None
            self._auto_hold = False         # nothing waits at an event any more: the state is no longer Run for it
        self.paused = ""

    def _follow_hold_points(self, s):
        """(monitor thread) The rt side reached C_HOLD_AT points and holds: their events go to the
        events thread, which performs them and releases the hold."""
        seq = s.hold_at_seq
        while self._hold_at_seen < seq:
            self._hold_at_seen += 1
            with self._lock:
                if not self._hold_points:
                    continue
                _row, events, it = self._hold_points.popleft()
                self._auto_hold = True
                self._auto_item = it
                self._events_q.put((self._gen if it is None else it.gen, events, it))

    def _events_loop(self):
        """Performs the events of the hold points the path reached, one point after the other, then
        releases the hold (unless a pause waits for cycle start, or the operator holds)."""
        while not self._stop.is_set():
            try:
                gen, events, it = self._events_q.get(timeout=0.1)
            except queue.Empty:
                continue
            self._auto_item = it
            try:
                for name, value in events:
                    if gen != self._gen:
                        break
                    self._perform(name, value, gen)
            except Exception as e:           # noqa: BLE001 (a device that failed: a controlled stop)
                self._auto_hold = False
                self._auto_item = None
                if gen == self._gen:
                    self.controlled_stop(f"{name} {value}: {e}")
                continue
            if gen == self._gen and not self.paused and not self.operator_hold and self._events_q.empty():
                self.command(C.C_RESUME)
            self._auto_hold = False
            if not self.paused:
                self._auto_item = None

    _auto_item = None                     # the item whose events are performed (or whose pause waits)

    def _perform(self, name, value, gen):
        """One event, where the path holds for it."""
        if name == "spindle":
            self._spindle.set(float(value), gen)
        elif name == "coolant":
            if value == "off":
                self.coolant.clear()
            else:
                self.coolant.add(str(value))
            self._emit("coolant", {"coolant": sorted(self.coolant)})
        elif name == "output":
            out_name, index, v = value
            self.outputs[f"{out_name} {index}"] = v
            self._emit("output", {"name": out_name, "index": index, "value": v})
        elif name == "message":
            self._emit("message", {"msg": str(value)})
        elif name in ("tool_change", "pause"):
            if name == "pause" and value == "M1" and not self.optional_stop:
                self.log("M1 optional stop: not taken (the optional-stop switch is off)")
                return
            what = (f"tool change: load tool {value}" if name == "tool_change" else
                    f"program paused ({value})")
            if self.stand_in_operator is not None:
                self.stand_in_operator(what)
                if name == "tool_change":
                    self.tool = int(value)
                return
            self._pause_tool = int(value) if name == "tool_change" else None
            self.paused = f"{what}; then cycle start (~ on the console, or pmctl ctl resume)"
            self.log(self.paused)
            self._emit("pause", {"msg": self.paused})
        elif name == "tool_offset":
            pass                           # the planner put the offset into the poses after it
        else:
            self.log(f"event {name} {value!r}: nothing here performs it")

    def spindle_override(self, f: float):
        """grbl's spindle speed override: the programmed speed x ``f`` (0.1 .. 2.0); pmctl.task.spindle."""
        self._spindle.override(f)

    # ------------------------------------------------------------ status
    def status(self) -> RtStatus:
        """A fresh snapshot of the rt side's status (pmctl.motion.status: named fields)."""
        return read_status(self.ch)

    def raw(self) -> np.ndarray:
        """The status block as the rt side wrote it (a copy; diagnostics and tests: read :meth:`status`)."""
        return self.ch.status()

    def counts(self) -> np.ndarray:
        return self.status().counts

    def pose(self):
        """Tool tip and axis in W of the pulse counters (FK; the status block's model pose is the
        one at the start of the rt side's last tick, one tick behind the counters)."""
        s = self.status()
        counts = s.counts.astype(float)
        key = counts.tobytes()
        if self._pose_cache is not None and self._pose_cache[0] == key:
            return self._pose_cache[1][0].copy(), self._pose_cache[1][1].copy()
        pose, ok = K.fk_batch((counts / self.machine.resolution.pulses_per_mm)[None], self.machine)
        if not ok[0]:
            return s.tip_mm.copy(), s.axis.copy()
        out = (pose.tip[0].copy(), pose.axis[0] / np.linalg.norm(pose.axis[0]))
        self._pose_cache = (key, out)
        return out[0].copy(), out[1].copy()

    _pose_cache = None

    def busy(self) -> bool:
        """Motion queued or under way (items not finished, samples queued, or moving)."""
        with self._lock:
            if self.items:
                return True
        s = self.status()
        return s.queued > 1 or s.follow in (MOVING, HOLDING, STARVED) or s.sigma > 0

    def state_name(self) -> str:
        """grbl machine state: Idle Run Hold:0 Hold:1 Jog Home Alarm Check."""
        if self.alarm or self.rt_dead:
            return "Alarm"
        if self.homing:
            return "Home"
        s = self.status()
        fol = s.follow
        if s.hold and self._auto_hold and not self.operator_hold and not self.paused:
            return "Run"                 # the path waits where an event takes effect (a spindle speed...)
        if s.hold and (self.busy() or fol in (HOLDING, HELD)):
            return "Hold:0" if (fol == HELD or (s.sigma == 0 and fol != HOLDING)) else "Hold:1"
        if self.check_mode:
            return "Check"
        if self.busy():
            with self._lock:
                cur = self.items[0] if self.items else None
            return "Jog" if cur is not None and cur.kind == "jog" else "Run"
        return "Idle"

    def current_line(self) -> int:
        line = self.status().line
        with self._lock:
            for it in self.items:
                if line in it.lines:
                    return it.lines[line]
        return line

    # ------------------------------------------------------------ motion requests
    def _check_not_stopping(self):
        """(under ``_lock``) A reset, an E-stop or a shutdown is dropping the queue: an item queued now
        would be neither planned nor dropped (it would stay queued for ever, the state Run at rest)."""
        if self._abort.is_set():
            raise MotionRefused("a reset or stop is dropping the queue: nothing is queued meanwhile", 9)

    def _check_motion_allowed(self):
        if self.homing:
            raise MotionRefused("homing is under way", 8)
        if self.rt_dead:
            raise MotionRefused("the rt motion process is down: unlock ($X) or reset to restart it", 9)
        if self.alarm:
            raise MotionRefused(f"alarm {self.alarm} active: unlock ($X) or home ($H)", 9)

    def end_pose(self):
        """Where the last submitted motion ends (the current pose when nothing is queued)."""
        with self._lock:
            if self.items:
                return self.items[-1].end
        return self.pose()

    def submit(self, job, kind="job", name="", lines=None, source="", path=None, stream=False) -> Item:
        """Queue a Job (planned from where the previous item ends). Raises MotionRefused in alarm.
        ``path``: the job already checked in full from that start (pmctl.task.jobcheck: the path of
        ``validate(full=True)`` with its settled windows), which the planner then samples instead of
        planning the job again. ``stream``: the first blocks of a stream (use ``stream``)."""
        self._check_motion_allowed()
        moves = [m for m in job.moves if m.kind not in ("dwell", "event")]     # those do not move
        with self._lock:
            self._check_not_stopping()
            self.stream_close()           # what comes after it goes after it
            start = self.end_pose()
            end = (np.asarray(moves[-1].tip, float), np.asarray(moves[-1].axis, float)) if moves else start
            it = Item(kind, job, start, end, name, self.n_submitted, lines=dict(lines or {}), gen=self._gen,
                      source=str(source), path=path, stream=stream, open=stream,
                      inbox=list(job.moves) if stream else [], last_in=time.monotonic())
            if self._probing.wanted(job):
                self._probing.prepare(it, source or name or job.source)
            self.n_submitted += 1
            self.items.append(it)
        self._plan_q.put(it)
        return it

    def stream(self, moves, lines=None, name="console") -> Item:
        """Append the moves of accepted blocks (a console line's) to the open stream: one job that
        grows as blocks arrive, planned by pmctl.task.stream_planner as they come -- windows of it
        are handed to the rt side as soon as the blocks known beyond them settle them, so a program
        streamed line by line runs as one job, without stops between the lines. A new stream (an
        Item of kind "gcode") starts where the queue ends when none is open (the first block, after a
        close, after an item of another kind). ``lines``: {stream line: reported line (N word)}.
        MotionRefused in alarm."""
        moving = [m for m in moves if m.kind not in (DWELL, EVENT)]
        spindle = has_spindle_event(moves)
        with self._lock:
            self._check_not_stopping()
            it = self._stream_item
            if it is None or not it.open or it.gen != self._gen or it not in self.items:
                it = self.submit(moves_job(list(moves), name), kind="gcode", name=name, lines=lines, stream=True)
                it.spindle_events = spindle
                self._stream_item = it
            else:
                self._check_motion_allowed()
                it.inbox.extend(moves)
                it.lines.update(lines or {})
                it.spindle_events = it.spindle_events or spindle
                if moving:            # (the job of a stream: its last moves, for the spindle at its end)
                    it.job = moves_job(list(moves), name)
                    it.end = (np.asarray(moving[-1].tip, float), np.asarray(moving[-1].axis, float))
            it.last_in = time.monotonic()
        self._stream_wake.set()
        return it

    def stream_close(self):
        """End the open stream at its last block: its planner plans the rest to rest there (M2/M30,
        G4, a probe, a job queued after it). Returns the stream's Item (None: none open)."""
        with self._lock:
            it, self._stream_item = self._stream_item, None
            if it is not None and it.open:
                it.open = False
                self._stream_wake.set()
                return it
        return None

    def stream_waiting(self, waiting: bool):
        """The console waits for room in its queue (True) or not any more: the open stream cannot
        get a block before the tool runs past one."""
        it = self._stream_item
        if it is not None:
            it.waiting = bool(waiting)
            self._stream_wake.set()

    _stream_item = None

    def stream_rows(self, rows, cancelled) -> None:
        """Push sample rows into the ring as room frees up; raises ``cancelled()``'s exception (the
        callable raises to stop) between pushes."""
        i = 0
        while i < len(rows):
            with self._lock:              # (see _push_rows)
                cancelled()
                n = self.ch.samples.push(rows[i:])
            i += n
            if n == 0:
                time.sleep(0.005)

    def retired(self, it) -> bool:
        """Whether item ``it`` has left the queue: every piece of it ran to its end (or it was dropped)."""
        with self._lock:
            return it not in self.items

    def queued_items(self) -> int:
        with self._lock:
            return len(self.items)

    def command(self, code, a1=0.0, a2=0.0) -> int:
        """Queue a command for the rt side; returns its sequence number (see wait_ack)."""
        with self._lock:
            self.ch.command(code, a1, a2)
            return self.ch._cmd_seq

    def wait_ack(self, seq, timeout_s=5.0) -> bool:
        """Wait until the rt side has applied command ``seq`` (it acknowledges in its status)."""
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout_s and not self.rt_dead:
            if self.status().cmd_ack >= seq:
                return True
            time.sleep(0.002)
        return False

    def hold(self):
        self.operator_hold = True
        self.command(C.C_HOLD)

    operator_hold = False                # a feed hold asked for (console !, socket hold), until resumed

    def resume(self):
        if self.homing:                  # the homing cycle's stops are its own
            return
        self.operator_hold = False
        if self.paused:                  # cycle start after M0, M1 or a tool change: the program goes on
            self.log(f"resumed after: {self.paused}")
            self.paused = ""
            if self._pause_tool is not None:      # the operator confirmed the tool change
                self.tool, self._pause_tool = self._pause_tool, None
            self._auto_item = None
            self._emit("resumed", {})
        elif self._auto_hold:            # the path waits for an event: the events thread releases it
            return
        if self._spindle.resume():       # stopped in the hold: the path goes on once it is back at speed
            return
        self.command(C.C_RESUME)

    def spindle_stop_toggle(self) -> bool:
        """grbl's 0x9E: the spindle stopped in a completed hold, or started again (pmctl.task.spindle)."""
        return self._spindle.stop_toggle()

    def feed_override(self, f: float):
        self.command(C.C_FEED_OV, float(f))

    def rapid_override(self, r: float):
        self.command(C.C_RAPID_OV, float(r))

    def set_chain_offset(self, chain: int, mm: float) -> bool:
        """The chain-length offset input of chain 0..2 (L1..L3), mm, added to the commanded length by
        the rt side's NC at its slew rate (the strain DAQ's slow compensation). Refused (False, the
        reason in the log) beyond the NC's bound or when not finite."""
        lim = self.params.chain_offset_max_mm
        refused = getattr(self, "_offset_refused", set())
        self._offset_refused = refused
        if not (0 <= int(chain) < 3 and math.isfinite(mm) and abs(mm) <= lim):
            if chain not in refused:          # said once until a value of that chain is accepted again
                self.log(f"chain offset refused: chain {chain} {mm:+.4f} mm (chains 0-2, bound +-{lim:g} mm "
                         f"chain_offset_max_mm); the previous offset stays")
            refused.add(chain)
            return False
        refused.discard(chain)
        if self.ch is None or self.rt_dead:
            return False
        self.command(C.C_CHAIN_OFFSET, float(int(chain)), float(mm))
        return True

    def soft_reset(self, timeout_s=10.0):
        """Stop now on the path, drop everything queued, keep the position (grbl ctrl-X). During
        homing it aborts the cycle (ALARM 6)."""
        self.events.send("reset")         # (a homing cycle aborts)
        self._stop_queue(timeout_s)
        self.events.send("reset_done")    # (the spindle stops)

    def _stop_queue(self, timeout_s=10.0):
        """Stop on the path, drop every queued item and sample, wait until at rest."""
        self._abort.set()
        self.operator_hold = False
        self._drop_queue()
        self._drop_hold_points()
        # the planner thread drops what it holds once it sees the abort
        while not self._plan_q.empty():
            try:
                self._plan_q.get_nowait()
            except queue.Empty:
                break
        if self.ch is not None and not self.rt_dead:
            seq = self.command(C.C_RESET)
            t0 = time.monotonic()
            self.wait_ack(seq, timeout_s)
            while time.monotonic() - t0 < timeout_s and not self.rt_dead:
                s = self.status()
                if s.queued == 0 and s.sigma == 0 and not s.hold:
                    break
                time.sleep(0.005)
            self._ended_base = self.status().ended
        self._abort.clear()

    def estop(self, reason="E-stop"):
        self._abort.set()
        self._drop_queue()
        if self.ch is not None and not self.rt_dead:
            self.command(C.C_ESTOP)
            self._ended_base = self.status().ended
        self.raise_alarm(ALARM_ESTOP, reason)
        self._drop_hold_points()
        self.events.send("estop")
        self._abort.clear()

    def unlock(self):
        """$X: clear the alarm; restart the rt process if it died; re-arm the NC after a fault."""
        if self.rt_dead:
            counts = self.status().counts.copy()
            self._spawn(counts, 60.0)
        elif self.ch is not None:
            self.wait_ack(self.command(C.C_UNLOCK))
            t0 = time.monotonic()
            while time.monotonic() - t0 < 1.0 and self.status().mode != RUN:
                time.sleep(0.005)
            if self.status().mode != RUN:
                raise MotionRefused(f"cannot unlock: {self.ch.reason() or 'the rt side stays halted'}", 9)
        self.alarm, self.alarm_msg = 0, ""

    def home(self):
        """``$H``: the homing cycle (pmctl.task.homing) with the [homing] settings; blocks until it
        ends. Returns (True, message) when homed (the alarm is cleared), (False, reason) when it
        failed (an alarm says why); MotionRefused when it cannot start (busy, no switches)."""
        return self._homing.run()

    def raise_alarm(self, code: int, msg: str):
        first = not self.alarm
        self.alarm, self.alarm_msg = code, msg
        if first:
            self._emit("alarm", {"code": code, "msg": msg})

    def _emit(self, event, detail):
        self.events.send(event, detail)

    def _drop_queue(self, ended=None):
        """Drop every queued item (a reset, an E-stop, a fault, homing, a failed probe or plan): a new
        queue generation, so that nothing planned for the old one goes on; ``ended``: the rt side's
        count of passed job ends the new queue counts from."""
        with self._lock:
            dropped = list(self.items)
            self.items.clear()
            self._gen += 1
            if ended is not None:
                self._ended_base = ended
        self.events.send("queue_dropped", items=dropped)

    def _check_going(self, it):
        """Raise _Aborted when item ``it`` is to be planned no further (a reset, a dropped queue, the end)."""
        if self._abort.is_set() or self._stop.is_set() or self.rt_dead or it.gen != self._gen:
            raise _Aborted()

    def _starts_after(self, it, start):
        """Item ``it`` ends at ``start`` (tip, axis) (a probe stopped there): the item queued after it
        starts from there."""
        with self._lock:
            it.end = start
            if it in self.items:
                i = self.items.index(it)
                if i + 1 < len(self.items):
                    self.items[i + 1].start = start

    def wait_idle(self, timeout_s=600.0, poll=0.01) -> bool:
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout_s:
            if not self.busy() or self.alarm or self.rt_dead:
                return True
            time.sleep(poll)
        return False

    # ------------------------------------------------------------ threads
    def _planner(self):
        """Plans queued items one after the other with the streaming planner: the whole item is
        validated first (reachability, feeds, bounds: nothing of a bad item reaches the rt side),
        then planned window by window and pushed as room frees up in the sample ring, so memory is
        bounded by a window, not by the job. An item with probing moves goes piece by piece
        (:meth:`_plan_probing`)."""
        while not self._stop.is_set():
            try:
                it = self._plan_q.get(timeout=0.05)
            except queue.Empty:
                continue
            if self._abort.is_set() or it.gen != self._gen:
                continue
            try:
                if it.parts > 1 or self._probing.wanted(it.job):
                    self._probing.plan(it)
                    continue
                rows_iter = self._stream_rows(it) if it.stream else self._rows_of(it.job, it.start, it)
                it.planned = True
                if self._push_rows(rows_iter, it) == 0:
                    self._ended_without_samples(it)
                it.all_pushed = True
            except _Aborted:
                continue
            except PmctlError as e:
                it.error = str(e)
                with self._lock:
                    if it in self.items:
                        self.items.remove(it)
                self.events.send("item_failed", item=it)
                self.log(f"planning {it.name or it.kind} failed: {e}")
                self._emit("error", {"msg": f"planning failed: {e}"})
                if it.planned:
                    self._planning_failed_midway(it, e)
            except Exception as e:           # a bug: never a silent dead planner with motion queued
                self._planner_crashed(it, e)

    def _ended_without_samples(self, it):
        """An item (or a piece of one) planned to no samples at all (a job with no motion): the rt
        side will never pass its end, so it counts as passed now; the item retires in its turn."""
        with self._lock:
            it.ends += 1

    def _planner_crashed(self, it, e):
        """An unexpected exception while planning: log it with its traceback, stop on the path, drop
        the queue and raise an alarm saying why; the planner thread goes on (``$X`` unlocks)."""
        self.log(f"planner error on {it.name or it.kind}: {''.join(traceback.format_exception(e)).rstrip()}")
        it.error = f"internal error: {type(e).__name__}: {e}"      # (pmctl run waits on it)
        self._drop_queue()
        self.events.send("item_failed", item=it)
        if self.ch is not None and not self.rt_dead:
            self.command(C.C_RESET)
        self.raise_alarm(ALARM_ABORT, f"internal error planning {it.name or it.kind}: {type(e).__name__}: {e}; "
                                      f"motion stopped, queue dropped")

    def _rows_of(self, job, start, it=None):
        """Sample rows of ``job`` planned from ``start`` (validated first), an iterator of chunks.
        With the item ``it``: its spindle start speed is set (or a hold queued) before its first
        sample, and its speed changes inside the job become C_HOLD_AT points."""
        rapid_mm_s = PlannerLimits().rapid_mm_s
        rapid_lines = {m.line for m in job.moves if m.kind == RAPID}
        pm = self.plan_machine
        if self.nc_setup.shaper is None:
            # the whole job planned first (pmctl check's planning, with its fallback): nothing of it
            # moves unless all of it can be planned, and the stream cannot fail midway. A job checked
            # so before it was queued (pmctl run) brings that path: its settled windows are sampled,
            # not planned again
            path = it.path if it is not None and job is it.job and _path_starts_at(it.path, start) else None
            if path is None:
                path = validate(job, pm, self.dt, feed_override=self.plan_feed_override, start=start, full=True)
            pieces = plan_stream(job, pm, self.dt, feed_override=self.plan_feed_override, start=start, path=path)
        else:
            # an input shaper reshapes the time law over whole segments: planned whole (memory
            # grows with the job; a streaming shaper is not built yet)
            pieces = [shape_trajectory(plan(job, pm, self.dt, feed_override=self.plan_feed_override, start=start),
                                       self.nc_setup.shaper)]
        if it is not None:
            pieces = self._events_of(it, pieces, self.ch.samples.written)   # (the ring row of its first sample)
        return iter_stream_rows(pieces, self.machine, self.params, rapid_lines=rapid_lines,
                                rapid_mm_s=rapid_mm_s)

    def _queued_s(self) -> float:
        """Seconds of samples queued ahead of the tool (at 100 % feed)."""
        return self.status().queued * self.dt

    def _low_water_s(self) -> float:
        """Below this much motion queued ahead of the tool the open stream is planned to rest at its
        last block unless a block comes (offline the rt side waits for a queue it can stop within:
        that is low water there)."""
        if not self.offline:
            return STREAM_LOW_WATER_S
        return max(STREAM_LOW_WATER_S, (full_speed_queue(self.params, self.dt, self.sample_capacity) + 20) * self.dt)

    def _stream_rows(self, it):
        """Sample rows of a stream item (``stream``): its blocks planned as they come by a
        StreamPlanner (pmctl.task.stream_planner), each window's samples handed out once the blocks
        after it settle it, the rows taken as they are final (pmctl.motion.timescale.RowStream). While
        more than ``STREAM_REFILL_S`` is queued ahead of the tool only whole windows are planned
        (fewer, larger windows); below it, whatever the blocks settle. The stream is planned to rest
        at its last block when it is closed (M2/M30, G4, a probe, a job after it), or when less than
        the low water (``_low_water_s``) is queued, nothing more settles and no block is coming
        (the sender paused for ``STREAM_IDLE_S``, or it waits for room in the queue): then the machine
        stops on the path at the last block it has, and the blocks after start a new stream there.
        Before that, when the console waits for room while a merged run of lines waits for its end,
        the run is cut at its last block (StreamPlanner.cut_run) and the stream goes on."""
        if self.nc_setup.shaper is not None:
            return self._stream_batch_rows(it)
        return self._stream_planned_rows(it)

    def _stream_inbox(self, it):
        """(the moves appended to the stream item since the last call, whether it is closed); raises
        _Aborted when the queue was dropped."""
        self._check_going(it)
        self._stream_wake.clear()
        with self._lock:
            new, it.inbox = it.inbox, []
            return new, not it.open

    def _stream_starved(self, it, low) -> bool:
        """Close the stream when it starves: less than ``low`` s queued ahead of the tool and no block
        coming (the sender paused for ``STREAM_IDLE_S``, or the console waits for room). True: it did
        (unless a block came meanwhile)."""
        if self._queued_s() < low and (it.waiting or time.monotonic() - it.last_in > STREAM_IDLE_S):
            with self._lock:
                if not it.inbox:
                    it.open = False
                    if self._stream_item is it:
                        self._stream_item = None
            return True
        return False

    def _stream_batch_rows(self, it):
        """A stream with an input shaper configured: the shaper plans whole jobs (``_rows_of``), so the
        blocks are collected until the stream closes (as ``_stream_planned_rows`` closes it) and then
        planned from rest to rest: a streamed program stops where a batch ends."""
        low = self._low_water_s()
        moves = []
        while True:
            new, closing = self._stream_inbox(it)
            moves += new
            if closing:
                break
            if not self._stream_starved(it, low):
                self._stream_wake.wait(0.005)
        it.job = moves_job(moves, it.name or "console")
        return self._rows_of(it.job, it.start, it)

    def _stream_planned_rows(self, it):
        limits = PlannerLimits()
        sp = StreamPlanner(self.plan_machine, self.dt, start=it.start, feed_override=self.plan_feed_override,
                           limits=limits, source=it.name or "console")
        rs = RowStream(self.dt, self.machine, self.params, rapid_mm_s=limits.rapid_mm_s)
        rapid = set()
        low = self._low_water_s()

        def pieces():
            while True:
                new, closing = self._stream_inbox(it)
                if new:
                    rapid.update(m.line for m in new if m.kind == RAPID)
                    sp.extend(new)
                got = False
                for piece in sp.settled(eager=self._queued_s() < STREAM_REFILL_S):
                    got = True
                    yield piece
                if closing:
                    yield from sp.close()
                    return
                if got or new:
                    continue
                if it.waiting and sp.pending and self._queued_s() < STREAM_REFILL_S:
                    # the queue is full of blocks a merged run of lines waits on (a straight run of short
                    # lines): the run ends at its last block, the stream goes on
                    sp.cut_run()
                    continue
                if not self._stream_starved(it, low):     # (starved: planned to rest at the last block)
                    self._stream_wake.wait(0.005)

        for piece in self._events_of(it, pieces(), self.ch.samples.written, per_move=False):
            rs.add(piece.tip, piece.axis, piece.line, np.isin(piece.line, list(rapid)) if rapid else None)
            yield from rs.take()
        yield from rs.take(end=True)

    def _push_rows(self, rows_iter, it) -> int:
        """Push the rows as room frees up; returns how many were pushed."""
        total = 0
        for rows in rows_iter:
            total += len(rows)
            i = 0
            while i < len(rows):
                with self._lock:          # (a drop's new generation, then its C_RESET: no sample after them)
                    self._check_going(it)
                    n = self.ch.samples.push(rows[i:])
                i += n
                if n == 0:
                    time.sleep(0.005)
                else:
                    it.pushed += n
                    it.pushed_line = int(rows[i - 1, S_LINE])
        return total

    def _planning_failed_midway(self, it, e):
        """A window of an item failed after its first samples were queued (validation passed, so
        rare): stop on the path now, drop everything queued after it and raise an alarm; nothing
        may continue from a pose the machine is not at."""
        self._drop_queue()
        if self.ch is not None and not self.rt_dead:
            self.command(C.C_RESET)
        self.raise_alarm(ALARM_ABORT, f"planning of {it.name or it.kind} failed during the job: {e}")

    def _drain_records(self):
        if self.ch is None:
            return
        rows = self.ch.records.pop()
        if len(rows) and self.record_sink is not None:
            try:
                self.record_sink(rows)
            except Exception as e:
                self.log(f"recording failed: {e}")
                self.record_sink = None
        if len(rows):
            self.events.send("records", rows=rows, tick=int(rows[-1, R_TICK]))

    def _take_fault(self, ch, s):
        """A fault the rt side reported (status ``s``) and not yet taken: the queue dropped, the alarm
        raised with its reason."""
        if s.reason_seq == self._fault_seen or not s.stopped:
            return
        self._fault_seen = s.reason_seq
        reason = ch.reason()
        self._drop_queue(ended=s.ended)
        self._drop_hold_points()
        code = ALARM_SOFT_LIMIT if reason.startswith(("soft limit", "path error")) else (
            ALARM_ESTOP if reason.startswith("E-stop") else ALARM_MOTOR_FAULT)
        if code == ALARM_MOTOR_FAULT:
            self.events.send("position_lost")     # following error / lost backend: the position may be wrong
        if not self.alarm:
            self.raise_alarm(code, reason)
        self.events.send("stopped", reason=reason, fault=s.fault == F_FAULT)

    def _monitor(self):
        while not self._stop.wait(0.01):
            ch = self.ch
            if ch is None:
                continue
            self._drain_records()
            s = read_status(ch)
            self._last_status = s
            if s.hold_at_seq != self._hold_at_seen:
                self._follow_hold_points(s)
            self._take_fault(ch, s)
            if self.proc is not None and not self.proc.is_alive() and not self.rt_dead and not self._stop.is_set() \
                    and not self._quitting:
                self._take_fault(ch, read_status(ch))     # its last word: a fault it stopped on, written before it left
                r = ch.result()
                if not self.alarm and r and r.get("status") == "fault" and r.get("reason"):
                    self.events.send("position_lost")
                    self.raise_alarm(ALARM_MOTOR_FAULT, str(r["reason"]))
                self.rt_dead = True
                self.events.send("position_lost")     # the counters are kept, but not trusted
                self._drop_queue()
                code = self.proc.exitcode
                died = (f"rt motion process died (exit code {code}); last counters kept, not trusted until "
                        f"homed or confirmed")
                if self.alarm:                # it stopped on a fault it reported (read above): that is the reason
                    self.log(f"{died} (after: {self.alarm_msg})")
                else:
                    self.raise_alarm(ALARM_MOTOR_FAULT, died)
                self.events.send("rt_dead", {"exitcode": code}, exitcode=code)
                continue
            # retire finished items: the rt side counts the job ends it passed
            ended = s.ended
            with self._lock:
                while self.items and self.items[0].planned:
                    head = self.items[0]
                    if self._auto_item is head or any(p[2] is head for p in self._hold_points):
                        break                   # its events first (the rt side may hold on its last sample)
                    if head.ends < head.parts:      # items planned to no samples have all their ends
                        if self._ended_base + 1 > ended:
                            break
                        self._ended_base += 1
                        head.ends += 1
                        if head.ends < head.parts:  # a piece of an item planned in pieces (probing)
                            continue
                    done = self.items.popleft()
                    self.events.send("item_done", {"kind": done.kind, "name": done.name, "index": done.index},
                                     item=done)

    _ended_base = 0


class _Aborted(Exception):
    pass


def _path_starts_at(path, start, tol_mm=1e-9) -> bool:
    """Whether a checked path (validate(full=True)) starts at ``start`` (tip, axis): the pose the
    check took for the machine's (the two computations of the pose from the counters agree to
    ~1e-12 mm), so that it plans the job the queue would plan."""
    if path is None or getattr(path, "settled", None) is None:
        return False
    return (float(np.abs(np.asarray(path.start_tip, float) - np.asarray(start[0], float)).max()) <= tol_mm
            and float(np.abs(np.asarray(path.start_axis, float) - np.asarray(start[1], float)).max()) <= tol_mm * 1e-2)


class _RtProc:
    """The rt process as a child (subprocess.Popen) with multiprocessing.Process's few methods."""

    def __init__(self, popen):
        self.popen = popen
        self.pid = popen.pid

    def is_alive(self):
        return self.popen.poll() is None

    @property
    def exitcode(self):
        return self.popen.poll()

    def join(self, timeout=None):
        try:
            self.popen.wait(timeout)
        except subprocess.TimeoutExpired:
            pass

    def terminate(self):
        if self.is_alive():
            self.popen.terminate()

    def kill(self):
        if self.is_alive():
            self.popen.kill()


def roll_pitch_deg(axis) -> tuple[float, float]:
    a, b = K.roll_pitch_from_axis(np.asarray(axis, float))
    return math.degrees(float(a)), math.degrees(float(b))
