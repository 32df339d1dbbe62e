"""Homing (``$H``): a per-axis sequence against the home switches, one joint moving at a time.

Every home switch is a cam switch that closes when its joint moves in + past the switch's edge
([homing] in the service config gives the order, the speeds, the pull-off, the search distance and
the joint position of each edge). Per axis, as grbl and LinuxCNC do it:

1. if the switch is already closed: move off it (-) until it opens (ALARM 8 if it does not within
   the search distance);
2. seek (+) at the seek speed until it closes (ALARM 9 if not within the search distance), stop on
   the path;
3. back off (-) until it opens, then by the pull-off;
4. latch: approach (+) at the latch speed; the pulse counter of the tick the switch closes is taken
   (the rt side latches it, so the position is good to latch speed x tick + 1 pulse), stop;
5. back off (-) until it opens and by the pull-off;
6. re-reference: the counter becomes (reference + counted since the latch), at rest.

The moves are joint paths (q0 + e_i s(t), a trapezoidal s) streamed as pose samples (their FK) into
the one path the machine moves on; the NC's IK of those poses is the joint path. :class:`Sequence`
holds the logic against an abstract mover (so it can be checked without the rt side);
:class:`RtMover` moves the machine through the supervisor's channel; :class:`Homing` is the
supervisor's homing part: ``$H`` (``Supervisor.home``) runs its cycle, a soft reset or the session's
end aborts it (ALARM 6), a fault or a dead rt process forgets that the machine was homed (the
supervisor's events ``reset``, ``shutdown``, ``position_lost``).
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np

from pmctl.core import kinematics as K
from pmctl.core.errors import MotionRefused, PmctlError
from pmctl.hal.base import AXES
from pmctl.core.alarms import ALARM_HOMING_APPROACH, ALARM_HOMING_PULLOFF, ALARM_HOMING_RESET
from pmctl.motion import channel as C
from pmctl.motion.nc import RUN
from pmctl.motion.timescale import iter_job_rows, scaling_limits
from pmctl.motion.trajectory import Trajectory


class HomingFailed(PmctlError):
    """The homing cycle failed; ``code`` is grbl's alarm code (6 reset, 8 pull-off, 9 approach)."""

    def __init__(self, code, msg):
        super().__init__(msg)
        self.code = code


def joint_profile(dist: float, speed: float, accel: float, dt: float) -> np.ndarray:
    """s(t) sampled every ``dt`` from 0 to ``dist`` (signed): a trapezoid (a triangle when short) with
    |s'| <= speed and |s''| <= accel; starts and ends at rest, the last sample exactly ``dist``."""
    d = abs(float(dist))
    if d == 0.0:
        return np.zeros(1)
    v = min(float(speed), math.sqrt(d * accel))
    ta = v / accel
    tc = (d - v * ta) / v
    T = 2 * ta + tc
    n = max(2, int(math.ceil(T / dt)) + 1)
    t = np.minimum(np.arange(n) * dt, T)
    s = np.where(t < ta, 0.5 * accel * t ** 2,
                 np.where(t < ta + tc, 0.5 * v * ta + v * (t - ta),
                          d - 0.5 * accel * np.maximum(T - t, 0.0) ** 2))
    s[-1] = d
    return math.copysign(1.0, dist) * s


def joint_trajectory(q0, axis: int, dist: float, speed: float, accel: float, machine, dt: float):
    """The Trajectory (poses = FK of q0 + e_axis s(t)) of a single-joint move; PmctlError if any pose
    of it has no forward kinematics."""
    s = joint_profile(dist, speed, accel, dt)
    q = np.repeat(np.asarray(q0, float)[None], len(s), 0)
    q[:, axis] += s
    pose, ok = K.fk_batch(q, machine)
    if not np.all(ok):
        raise PmctlError(f"homing {AXES[axis]}: the move of {dist:+g} mm leaves the workspace")
    ax = pose.axis / np.linalg.norm(pose.axis, axis=1)[:, None]
    z = np.zeros_like(pose.tip)
    return Trajectory(dt, pose.tip, ax, z, z, np.zeros(len(s), int), np.zeros(len(s)), source="homing")


class Sequence:
    """The homing cycle against a mover with ``switch(i) -> bool``, ``count(i) -> int``,
    ``move(i, dist, speed, want=None) -> latched counter or None`` (``want``: stop at the first tick
    the switch reads ``want``) and ``set_count(i, n)``."""

    def __init__(self, cfg, ppm):
        self.cfg = cfg
        self.ppm = np.asarray(ppm, float)

    def home_axis(self, mv, i: int) -> int:
        """Home axis ``i``; returns the counter shift applied (pulses)."""
        c, name = self.cfg, AXES[i]
        if mv.switch(i):
            if mv.move(i, -c.search_mm, c.seek_mm_s, want=False) is None:
                raise HomingFailed(ALARM_HOMING_PULLOFF, f"homing {name}: the switch did not open within "
                                                         f"{c.search_mm:g} mm moving off it")
        if mv.move(i, c.search_mm, c.seek_mm_s, want=True) is None:
            raise HomingFailed(ALARM_HOMING_APPROACH, f"homing {name}: switch not found within the search "
                                                      f"distance {c.search_mm:g} mm")
        edge = self._clear(mv, i)
        dist = (edge - mv.count(i)) / self.ppm[i] + 2 * c.pull_off_mm      # to the edge and a pull-off beyond
        latched = mv.move(i, dist, c.latch_mm_s, want=True)
        if latched is None:
            raise HomingFailed(ALARM_HOMING_APPROACH, f"homing {name}: switch not found on the latch approach "
                                                      f"({dist:.3f} mm)")
        self._clear(mv, i)
        shift = int(round(c.reference_mm[i] * self.ppm[i])) - int(latched)
        mv.set_count(i, mv.count(i) + shift)
        return shift

    def _clear(self, mv, i) -> int:
        """Back off (-) until the switch opens, then by the pull-off; returns the counter at the edge."""
        c = self.cfg
        edge = mv.move(i, -c.search_mm, c.seek_mm_s, want=False)
        if edge is None:
            raise HomingFailed(ALARM_HOMING_PULLOFF, f"homing {AXES[i]}: the switch did not open pulling off")
        mv.move(i, -c.pull_off_mm, c.seek_mm_s)
        return edge

    def run(self, mv) -> dict:
        return {AXES.index(a): self.home_axis(mv, AXES.index(a)) for a in self.cfg.order}


class RtMover:
    """Moves for :class:`Sequence` through the supervisor: samples into the channel's sample ring,
    the switch latch and the re-reference as commands to the rt side."""

    def __init__(self, sup, abort):
        self.sup = sup
        self.abort = abort                 # threading.Event: a reset aborts the cycle (ALARM 6)
        self.ppm = np.asarray(sup.machine.resolution.pulses_per_mm, float)
        self.accel = [0.25 * float(a) for a in sup.params.amax]
        self.scaling = scaling_limits(sup.params)

    def _s(self):
        return self.sup.status()

    def _check(self, latch_seq=None):
        sup = self.sup
        if latch_seq is not None and self._s().latch_seq != latch_seq:
            raise _Latched()
        if self.abort.is_set() or sup._stop.is_set():
            raise HomingFailed(ALARM_HOMING_RESET, "homing aborted by a reset")
        if sup.rt_dead or sup.alarm:
            raise MotionRefused(sup.alarm_msg or "the rt motion process is down", 9)

    def count(self, i):
        return int(self._s().counts[i])

    def switch(self, i):
        bits = self._s().home_in
        if bits < 0:
            raise HomingFailed(ALARM_HOMING_APPROACH, "this backend reports no home switches")
        return bool(bits >> i & 1)

    def move(self, i, dist, speed, want=None):
        sup = self.sup
        s = self._s()
        q0 = s.counts / self.ppm
        traj = joint_trajectory(q0, i, dist, speed, self.accel[i], sup.machine, sup.dt)
        seq0, ended0 = s.latch_seq, s.ended
        if want is not None:
            if not sup.wait_ack(sup.command(C.C_HOME_ARM, float(i), 1.0 if want else 0.0), 10.0):
                raise HomingFailed(ALARM_HOMING_APPROACH, "the rt side did not take the switch latch")
        latched = None
        try:
            for rows in iter_job_rows(traj, sup.machine, sup.params, rapid=np.ones(len(traj), bool),
                                      rapid_mm_s=1e3):
                sup.stream_rows(rows, lambda: self._check(seq0))
            while True:
                self._check()
                st = self._s()
                if st.latch_seq != seq0 or st.ended > ended0:
                    break
                time.sleep(0.002)
        except _Latched:
            pass
        if want is not None:
            sup.wait_ack(sup.command(C.C_HOME_ARM, -1.0), 10.0)
        st = self._s()
        if st.latch_seq != seq0:
            latched = int(st.latch[i])
        sup._stop_queue()                   # at rest on the path, the rest of the move dropped
        self._check()
        return latched

    def set_count(self, i, n):
        """Re-reference counter ``i`` to ``n`` (at rest). The rt side takes the command only at rest with
        nothing queued (a tick after a stop may still be settling) and then moves its start counters by
        the shift (``counts0`` of its status): unchanged after the ack, it was not taken and goes again. Afterwards the
        NC, restarted from the new counters, may close a pulse or two of sub-pulse residue (or, on
        drives, what the position feedback moved while the reference was taken), counted like any motion."""
        sup = self.sup
        c0 = int(self._s().counts0[i])
        t0 = time.monotonic()
        while True:
            if self.count(i) == n:
                return
            sup.wait_ack(sup.command(C.C_SET_COUNTS, float(i), float(n)), 10.0)
            if int(self._s().counts0[i]) != c0:
                return
            self._check()
            if time.monotonic() - t0 > 10.0:
                s = self._s()
                raise HomingFailed(ALARM_HOMING_APPROACH, f"homing {AXES[i]}: the rt side did not re-reference "
                                                          f"the counter in 10 s (not at rest: sigma {s.sigma:g}, "
                                                          f"{s.queued} samples queued, mode {s.mode})")
            time.sleep(0.02)


class _Latched(Exception):
    pass


class Homing:
    """The homing part of a :class:`pmctl.task.supervisor.Supervisor` (``sup``): whether a cycle is
    under way (``active``: the machine state ``Home``, motion refused) and whether the machine is
    homed (``homed``: the journal keeps it)."""

    def __init__(self, sup):
        self.sup = sup
        self.active = False
        self.homed = False
        self.abort = threading.Event()     # a reset during homing aborts the cycle (ALARM 6)
        sup.events.register("reset", self._reset)
        sup.events.register("shutdown", self.abort.set)
        sup.events.register("position_lost", self._lost)

    def _reset(self):
        if self.active:
            self.abort.set()

    def _lost(self):
        self.homed = False                 # following error / lost backend / dead rt side: not trusted

    def run(self):
        """The cycle with the [homing] settings; blocks until it ends. Returns (True, message) when
        homed (the alarm is cleared), (False, reason) when it failed (an alarm says why);
        MotionRefused when it cannot start (busy, no switches)."""
        sup = self.sup
        if self.active:
            raise MotionRefused("homing is already under way", 8)
        if not (sup.alarm or sup.rt_dead) and sup.busy():
            raise MotionRefused("$H only when idle: motion is queued or under way", 8)
        if sup.rt_dead or sup.status().mode != RUN:
            sup.unlock()                  # restart / re-arm the rt side first (refused while an E-stop holds)
        if sup.status().home_in < 0:
            raise MotionRefused(f"backend {sup.backend!r} reports no home switches", 5)
        self.abort.clear()
        sup._drop_queue()
        sup.alarm, sup.alarm_msg = 0, ""
        self.active = True
        sup._emit("homing", {})
        try:
            shifts = Sequence(sup.svc.homing, sup.machine.resolution.pulses_per_mm).run(RtMover(sup, self.abort))
        except (HomingFailed, MotionRefused, PmctlError) as e:
            self.active = False
            code = getattr(e, "code", 9) if isinstance(e, HomingFailed) else 9
            if sup.ch is not None and not sup.rt_dead:
                sup._stop_queue()
            if not sup.alarm:
                sup.raise_alarm(code, f"homing failed: {e}")
            self.homed = False
            return False, str(e)
        finally:
            self.active = False
        self.homed = True
        ppm = sup.machine.resolution.pulses_per_mm
        msg = "homed; counter corrections " + ", ".join(f"{AXES[i]} {d / ppm[i]:+.4f} mm" for i, d in shifts.items())
        sup._emit("homed", {"shifts": {AXES[i]: int(d) for i, d in shifts.items()}, "msg": msg})
        return True, msg
