"""The spindle of a session: the VFD (``[spindle]``, pmctl.hal.modbus_vfd) as the supervisor's
events drive it.

- M3/M4/M5 where the path holds for them (the supervisor's hold points: :meth:`Spindle.set`): the
  VFD gets the speed with the spindle override and the path waits until it is at speed;
- a job that carries its speed only per move (CL data): its first speed and its speed changes
  become hold points (:meth:`Spindle.speed_points`), and M5 when it ends with the spindle off
  (``item_done``);
- grbl's spindle speed override (0.1 .. 2.0) and its spindle stop in a hold (0x9E), restored at
  cycle start before the path goes on;
- M5 at a soft reset and an E-stop (``reset_done``, ``estop``); the monitor's polled samples
  trimmed to the records drained (``records``); a fault or lost link of the VFD is the
  supervisor's controlled stop (``Supervisor.controlled_stop``).

Every VFD write happens off the caller's thread where the caller is the console's reader or the
monitor, and the override's writes exclude a stop's (``_ov_lock``): a reset's M5 always wins.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np

from pmctl.core import kinematics as K
from pmctl.core.job import DWELL, EVENT
from pmctl.hal import HalTimeout
from pmctl.hal.base import trim_polled
from pmctl.hal.modbus_vfd import REST_STEP_MM, SpindleSession, job_speed
from pmctl.motion import channel as C


class Spindle:
    """The spindle part of a :class:`pmctl.task.supervisor.Supervisor` (``sup``): it reads the
    supervisor's settings, log, rt tick and queue generation, and acts on its events."""

    def __init__(self, sup):
        self.sup = sup
        self.opt = sup.svc.spindle        # None: no [spindle] (the speeds are kept, not executed)
        self.session = None               # pmctl.hal.modbus_vfd.SpindleSession, once connected
        self.prog = 0.0                   # the programmed speed (signed rpm; 0: M5), before the override
        self.ov = 1.0                     # grbl's spindle speed override, 0.1 .. 2.0
        self.off_at_job_end = True        # M5 when a job ends with the spindle off (pmctl run: at shutdown)
        self.stopped_in_hold = False      # stopped by 0x9E in a hold: cycle start restores it
        self.plan_rpm = None              # the speed at the end of what is planned (None: as commanded)
        self._noted = False               # "no [spindle]: not executed" said once
        self._ov_lock = threading.Lock()  # the override's set-point writes vs a stop's
        self._ov_wake = None
        self._m5 = None                   # the thread writing an M5
        hub = sup.events
        hub.register("item_done", self._at_item_done)
        hub.register("reset_done", lambda: self.off("at the soft reset"))
        hub.register("estop", lambda: self.off("at the E-stop"))
        hub.register("records", self._trim)

    # ------------------------------------------------------------ connection
    def connect(self):
        self.session = SpindleSession(self.opt, self.sup.log).connect()
        return self.session

    def close(self):
        if self.session is not None:
            self.session.close()

    def _trim(self, rows, tick):
        if self.session is not None and self.session.monitor is not None:
            trim_polled(self.session.monitor.samples, tick)

    def _watch(self, sp):
        sp.watch(self.sup.rt_tick, self.sup.controlled_stop)

    # ------------------------------------------------------------ between jobs
    def start(self, rpm: float):
        """M3/M4 S``rpm`` (0: M5) and wait until at speed (the path waits: call between jobs); the
        spindle is watched from then on."""
        sp = self.session or self.connect()
        self._m5_written()
        self.prog = float(rpm)
        if rpm == 0:
            with self._ov_lock:
                sp.vfd.stop()
            return
        sp.start(self.rpm_for(rpm))
        self._apply_ov()                  # an override changed during the spin-up
        if sp.monitor is None:
            self._watch(sp)
            if self.sup.ch is not None and sp.monitor.samples:      # at speed now, not at the rt side's tick 0
                sp.monitor.samples[0] = (self.sup.rt_tick(), sp.monitor.samples[0][1])

    # ------------------------------------------------------------ where the path holds
    def now(self) -> float:
        """The speed (signed programmed rpm) when the path reaches the end of what is planned."""
        if self.plan_rpm is not None:
            return self.plan_rpm
        return float(self.prog)

    def note_not_executed(self, rpm: float, what: str = ""):
        """Say once that a programmed speed is not executed (no ``[spindle]``)."""
        if rpm and not self._noted:
            self._noted = True
            self.sup.log(f"no [spindle] in {self.sup.svc.source}: {what}S{abs(rpm):g} M{3 if rpm > 0 else 4} "
                         f"is not executed")

    def set(self, rpm: float, gen):
        """M3/M4 S (``rpm`` signed; 0: M5) where the path holds: the VFD gets the speed (with the
        spindle override) and the path waits until it is at speed (a stop: until it turns no more
        than the tolerance). A reset meanwhile wins: its M5 is written after this start, or this
        start not at all (both hold ``_ov_lock``). ``gen``: the queue generation of the hold point."""
        if self.opt is None:
            self.prog = rpm
            self.note_not_executed(rpm)
            return
        sp = self.session or self.connect()
        self._m5_written()
        want = self.rpm_for(rpm)
        with self._ov_lock:
            if gen != self.sup.generation:
                return
            self.prog = rpm
            if want == sp.vfd.rpm_cmd:
                return
            _patient(sp.vfd, lambda: sp.vfd.start(want))
        t0 = time.monotonic()
        got = _patient(sp.vfd, sp.vfd.wait_at_speed)
        if rpm and sp.monitor is not None:
            # the reading that releases the path is the spindle's speed from here on: the monitor's
            # next poll may come after the path has moved on (offline, ticks run back to back)
            sp.monitor.samples.append((self.sup.rt_tick(), -got if sp.vfd.rpm_cmd < 0 else got))
        self.sup.log(f"spindle {'M5' if not rpm else ('M3' if rpm > 0 else 'M4') + f' S{abs(rpm):g}'}: "
                     f"{'stopped' if not rpm else 'at speed'} after {time.monotonic() - t0:.2f} s")
        if rpm and sp.monitor is None:
            self._watch(sp)

    def speed_points(self, moves, per_move: bool):
        """The hold points of a job that carries its speed only per move (``Move.spindle_rpm``: no
        spindle EVENT among ``moves``), or None: a :class:`_SpeedPoints` that the supervisor asks
        piece by piece as it plans them."""
        on_lines = [] if has_spindle_event(moves) or not per_move else [m.line for m in moves if getattr(m, "spindle_rpm", 0.0)]
        if on_lines and self.opt is None:
            self.note_not_executed(job_speed([getattr(m, "spindle_rpm", 0.0) for m in moves]), "the job's ")
            on_lines = []
        return _SpeedPoints(self, max(on_lines)) if on_lines else None

    # ------------------------------------------------------------ stops
    def _at_item_done(self, item):
        """M5 when a job that carries its speed per move (no spindle EVENT: those took effect where
        the path got to them) ended with the spindle off and nothing queued needs it running."""
        if not self.sup.items:
            self.plan_rpm = None          # nothing planned ahead: the speed is the commanded one
        sp = self.session
        if item.spindle_events or (item.spindle_events is None and has_spindle_event(item.job.moves)):
            return
        moves = [m for m in item.job.moves if m.kind not in (DWELL, EVENT)] \
            or [m for m in item.job.moves if m.kind == DWELL]       # (EVENT moves carry no speed)
        if not self.off_at_job_end or sp is None or not sp.vfd.rpm_cmd or not moves \
                or getattr(moves[-1], "spindle_rpm", 0.0) or self.sup.items:
            return
        self.off("at the job's end")

    def off(self, when: str):
        """M5 from a thread of its own (a Modbus write is no business of the caller's thread)."""
        sp = self.session
        self.prog = 0.0                   # before the write: an override must not start it again
        self.stopped_in_hold = False
        if sp is None or sp.vfd is None or not sp.vfd.rpm_cmd:
            return
        self._stop_vfd(sp, f"M5 {when}")

    def _stop_vfd(self, sp, what: str):
        """Stop the VFD from a thread of its own (``_m5``, which ``_m5_written`` waits for); the
        write excludes the override's (``_ov_lock``)."""
        def stop():
            try:
                with self._ov_lock:
                    sp.vfd.stop()
            except Exception as e:            # noqa: BLE001 (the monitor reports a lost link)
                self.sup.log(f"warning: {what}: {e}")
        self._m5 = threading.Thread(target=stop, daemon=True, name="pmctl-m5")
        self._m5.start()

    def _m5_written(self):
        """Wait for an M5 under way in its thread: until it is written, the VFD's last command still
        says running, and a job queued meanwhile at the same speed would skip its M3 and then run
        with the spindle stopped by that late M5."""
        t = self._m5
        if t is not None and t is not threading.current_thread():
            t.join()

    # ------------------------------------------------------------ override
    def rpm_for(self, rpm: float) -> float:
        """The speed sent to the VFD for the programmed ``rpm``: scaled by the spindle override, which
        never takes it past the VFD's maximum (grbl: ``$30``; a programmed S beyond it stays the VFD's
        error), signed as ``rpm``."""
        if not rpm or self.ov == 1.0:
            return float(rpm)
        v = abs(float(rpm)) * self.ov
        if self.opt is not None:
            v = min(v, max(float(self.opt.max_rpm), abs(float(rpm))))
        return math.copysign(v, rpm)

    def override(self, f: float):
        """grbl's spindle speed override: the programmed speed x ``f`` (0.1 .. 2.0). A running spindle
        gets the new set-point at once, from a thread of its own (a Modbus write is no business of
        the caller's); a stopped one starts with it at its next M3/M4. Without ``[spindle]``: kept only."""
        self.ov = min(2.0, max(0.1, float(f)))
        if self.opt is None:
            return
        with self.sup._lock:
            if self._ov_wake is None:
                self._ov_wake = threading.Event()
                threading.Thread(target=self._ov_loop, daemon=True, name="pmctl-spindle-ov").start()
        self._ov_wake.set()

    def _ov_loop(self):
        stop = self.sup._stop
        while not stop.is_set():
            if not self._ov_wake.wait(0.2):
                continue
            self._ov_wake.clear()
            t_end = time.monotonic() + self.opt.spinup_timeout_s
            try:                          # a speed change the path waits for goes first (scaled already)
                while not self._apply_ov() and time.monotonic() < t_end and not stop.is_set():
                    time.sleep(0.01)
            except Exception as e:        # noqa: BLE001 (the monitor reports a lost link)
                self.sup.log(f"warning: spindle override: {e}")

    def _apply_ov(self) -> bool:
        """The running spindle's set-point to the programmed speed with the current override; False:
        not now, a speed change inside the job is under way. Never starts a stopped spindle: a stop
        clears ``prog`` before its write, and every write holds ``_ov_lock``."""
        with self._ov_lock:
            sp = self.session
            vfd = sp.vfd if sp is not None else None
            if vfd is None or vfd.client is None or not self.prog or not vfd.rpm_cmd:
                return True
            want = self.rpm_for(self.prog)
            if want != vfd.rpm_cmd and (want > 0) == (vfd.rpm_cmd > 0):
                vfd.start(want)
            return True

    # ------------------------------------------------------------ stop in a hold
    def stop_toggle(self) -> bool:
        """grbl's 0x9E: in a completed hold (Hold:0) with the spindle running, stop it; again (still in
        the hold), start it back at its speed. Cycle start restores it and waits until it is at speed
        before the path goes on. Anywhere else, and without a spindle VFD, nothing happens (False)."""
        sup = self.sup
        if self.opt is None or self.session is None or not sup.operator_hold or sup.state_name() != "Hold:0":
            return False                 # (a hold of the path for a spindle speed change is not one)
        if self.stopped_in_hold:
            threading.Thread(target=self._restore, args=(False,), daemon=True,
                             name="pmctl-spindle-restore").start()
            return True
        if not self.prog or not self.session.vfd.rpm_cmd:
            return False
        self.stopped_in_hold = True
        self._stop_vfd(self.session, "spindle stop in the hold")   # prog stays: the speed to come back to
        return True

    def resume(self) -> bool:
        """Cycle start: True when the spindle was stopped in the hold. Then grbl brings it back to its
        speed first and the path goes on once it is there (a thread: the Modbus writes and the
        spin-up wait are no business of the caller's, the console's reader)."""
        if not self.stopped_in_hold:
            return False
        threading.Thread(target=self._restore, args=(True,), daemon=True, name="pmctl-spindle-restore").start()
        return True

    def _restore(self, then_resume: bool):
        """The spindle back at its speed after a stop in the hold. 0x9E again (``then_resume`` False):
        the start is written and the spindle counts as running at once, so a further 0x9E during the
        spin-up stops it again. Cycle start (True): the path goes on once it is at speed."""
        self._m5_written()
        sp, rpm = self.session, self.prog
        try:
            if sp is not None and rpm and self.stopped_in_hold:
                with self._ov_lock:
                    sp.vfd.start(self.rpm_for(rpm))
                    if not then_resume:
                        self.stopped_in_hold = False
                sp.vfd.wait_at_speed()
                if sp.vfd.rpm_cmd:
                    self.sup.log(f"spindle back at speed after the stop in the hold ({abs(sp.vfd.rpm_cmd):g} rpm)")
        except Exception as e:            # noqa: BLE001
            self.sup.controlled_stop(f"spindle VFD: restoring the speed after a stop in the hold: {e}")
            return
        if then_resume:
            self.stopped_in_hold = False
            self.sup.command(C.C_RESUME)


def has_spindle_event(moves) -> bool:
    """Whether a spindle EVENT (M3/M4/M5 in program order) is among ``moves``: then the speed takes
    effect where the path gets to it, not per move."""
    return any(m.kind == EVENT and any(n == "spindle" for n, _ in m.events) for m in moves)


class _SpeedPoints:
    """The spindle hold points of one job that carries its speed per move, piece by piece of its
    plan: its first speed (at the item's first sample, unless the spindle runs at it already) and
    the speed changes inside it (at the last sample of the old speed, as
    pmctl.hal.modbus_vfd.speed_changes finds them in a whole plan; at rest there when the joints
    stand still)."""

    def __init__(self, spindle, last_on: int):
        self.spindle = spindle
        self.machine = spindle.sup.machine
        self.last_on = last_on            # the last line that turns the spindle on
        self.prev = None                  # the speed of the sample before
        self.cur = None                   # the speed the spindle runs at (after the first on)
        self.tail = (np.zeros((0, 3)), np.zeros((0, 3)))

    def of(self, tr, row0: int, row: int):
        """(points before the piece's marks, points after them) of piece ``tr`` whose first sample is
        ring row ``row`` (``row0``: the item's first), each (row, at rest, events)."""
        first, changes = [], []
        v = np.asarray(tr.spindle_rpm, float)
        line = np.asarray(tr.line)
        tips = np.concatenate([self.tail[0], np.asarray(tr.tip, float)])
        axes = np.concatenate([self.tail[1], np.asarray(tr.axis, float)])
        off = len(self.tail[0])
        for i in range(len(v)):
            x = float(v[i])
            if self.cur is None:
                if x:
                    self.cur = x
                    if x != self.spindle.now():     # the job's first speed, before its first sample
                        first.append((row0, True, (("spindle", x),)))
            elif x != self.prev and x != self.cur and (x or int(line[i]) < self.last_on):
                self.cur = x
                j = off + i                       # index of sample c in tips: the stop is c - 1
                lo = max(0, j - 1 - 2)
                q = K.ik_batch(tips[lo:j + 1], axes[lo:j + 1], self.machine, check_limits=False).q
                rest = len(q) > 1 and float(np.abs(np.diff(q, axis=0)).max()) <= REST_STEP_MM
                changes.append((row + i - 1, bool(rest), (("spindle", x),)))
            self.prev = x
        self.tail = (tips[-3:], axes[-3:])
        return first, changes


def _patient(vfd, request):
    """A VFD request (idempotent: a start, a wait at speed) tried again after an unanswered Modbus
    request, up to the ``max_missed_polls`` the spindle monitor allows in a row (a busy computer or
    link can miss one); then the link counts as lost."""
    missed = 0
    while True:
        try:
            return request()
        except HalTimeout:
            missed += 1
            if missed >= vfd.opt.max_missed_polls:
                raise
