"""The rt motion process: the control loop, the NC step and the backend, fed through the channel.

Started by the supervisor (pmctl.task.supervisor) as a separate process; everything it needs comes
in ``spec`` (a dict of plain values). Per tick, after the NC step, its hook:
- applies the commands queued by the supervisor (hold, resume, overrides, soft reset, quit,
  E-stop, unlock, and for homing: arm a home-switch latch, re-reference a counter at rest) --
  reading a ring, never waiting;
- reads the backend's inputs: the E-stop halts; an armed home switch reaching its wanted state
  latches the counters of that tick and feed-holds on the path (the homing sequence, in the
  supervisor's pmctl.task.homing, plans the moves and reads the latch);
- probing (G38.2/G38.3): the loop's probe monitor (pmctl.motion.probe, the one ``pmctl run`` uses)
  takes the segment the supervisor announced in the channel's probe table once the follower is on
  ``FLAG_PROBE`` samples, and stops on contact; each ended probe's result (contact point, stop,
  tick, counters) goes into the status block under ``ST_PROBE_SEQ``;
- writes the status block (counters, model pose, sigma, line, phase, timing) under a sequence
  counter;
- every 50 ticks checks that the supervisor is still its parent: if it died, the machine is
  brought to a feed hold on the path, the counters are saved (clean) and the process exits;
- rides out a stall of the loop (a moment without ticks: a loaded computer) on a backend that allows
  it (``Backend.stall_hold``: the sim) with a feed hold on the path, released once ``STALL_RESUME_TICKS``
  ticks in a row were on time, unless the operator held meanwhile or the path waits at an event.
A fault (NC halt) or an NC stop drops the queued samples: motion resumes only after an unlock.
SIGTERM is a quit: hold on the path, save the counters, exit. As it exits, the rt side writes its
result into the channel (Channel.set_result: end status, reason, ticks, pulses sent, and the loop's
timing summary), which a one-shot client (``pmctl run``) reports and records.

``settings.offline`` (``pmctl run --no-realtime``): an offline simulation on the same path. Ticks
run back to back while the path moves, and the rt side waits for planned samples instead of
decelerating for an empty queue (starvation is a real-time matter: offline nothing is late), and
for room in the record ring instead of dropping records. With nothing to follow (idle, held, at a
job's end) the ticks are paced at the tick period.
"""

from __future__ import annotations

import copy
import math
import os
import signal
import sys
import time

import numpy as np

from pmctl import hal
from pmctl.core.errors import PmctlError
from pmctl.hal.base import as_inputs
from pmctl.hal.modbus_vfd import LOOKAHEAD_SAMPLES
from pmctl.motion import channel as C
from pmctl.motion.loop import ControlLoop, LoopParts
from pmctl.motion.nc import HALTED, RUN, STOPPING, initial_state
from pmctl.motion.probe import ProbeMonitor, ProbeSegment
from pmctl.motion.recorder import Recorder
from pmctl.motion.state_store import CounterWriter, load_counters, save_counters
from pmctl.motion.timescale import FLAG_END, FLAG_PROBE, S_FLAGS, full_speed_queue, make_follower


FINISHED = "finished: the job ran to its end"     # the quit of a run that is done (C_QUIT 1)
STALL_RESUME_TICKS = 200          # on-time ticks in a row after a stall before its feed hold is released


class RtHook:
    def __init__(self, ch: C.Channel, machine, params, ppid: int, log, offline: bool = False):
        self.ch, self.machine, self.params = ch, machine, params
        self.offline = bool(offline)
        self.hold_at = []                           # [(ring row, at rest)] queued by C_HOLD_AT, in order
        self.hold_at_seq = 0
        self.need = None                            # offline: samples queued before the path moves on
        self._sent_prev = None                      # pulses sent as of the previous tick
        self.ppid = ppid
        self.log = log
        self.resetting = False
        self.quitting = ""
        self.last_ack = 0.0
        self.ontime = 0
        self.period_ns = int(round(params.dt * 1e9))
        self.st = ch.st
        self.faulted = False
        self.term = False
        self.rest_ticks = 0
        self.arm_axis, self.arm_want = -1, True     # the armed home switch (C_HOME_ARM)
        self.arm_edges = None                       # the device latch's transition count at arming
        self.latch_seq = 0
        self.latch = [0.0] * 5
        self.shift = np.zeros(5, np.int64)          # re-references (C_SET_COUNTS) since the start
        self.probe = None                           # the loop's ProbeMonitor (rt_main sets it)
        self.probe_seen = float(ch.probe[0])        # the probe table's last announcement taken
        self.probe_seq = 0
        self.probe_row = [float("nan")] * C.PROBE_RESULT_WIDTH
        self.op_hold = False                        # the supervisor asked for a hold (C_HOLD) not yet resumed
        self.event_hold = False                     # held at a C_HOLD_AT point until C_RESUME
        self.rest_hold = False                      # ... a point at rest (a planned stop), held on its sample
        self.stall_hold = False                     # held after a stall; released when on time again
        self.stall_ok = 0

    def probe_fetch(self, fol):
        """ProbeMonitor's ``fetch``: the segment newly announced in the probe table, once the follower
        is on a sample flagged FLAG_PROBE of its line (one float compare per tick otherwise)."""
        tab = self.ch.probe
        if tab[0] == self.probe_seen or fol.line != int(tab[1]):
            return None
        src = fol.src
        if src.count() == 0 or not int(src.row(0)[S_FLAGS]) & FLAG_PROBE:
            return None
        self.probe_seen = float(tab[0])
        return ProbeSegment.from_row(tab[1:])

    def __call__(self, lp, k, st):
        ch, fol = self.ch, lp.follower
        sc = fol.scaler
        cmds = ch.commands
        while cmds.count():
            seq, code, a1, a2 = cmds.row(0).tolist()
            cmds.advance(1)
            code = int(code)
            self.last_ack = seq
            if code == C.C_HOLD:
                sc.hold = True
                self.op_hold = True
            elif code == C.C_RESUME:
                self.op_hold = self.event_hold = self.stall_hold = False
                if not (self.resetting or self.quitting):
                    sc.hold = False
                    if self.rest_hold:
                        fol.rest_here()       # leaves the planned stop on its samples' own acceleration
                self.rest_hold = False
            elif code == C.C_FEED_OV:
                sc.set_feed_override(a1)
            elif code == C.C_RAPID_OV:
                sc.set_rapid_override(a1)
            elif code == C.C_RESET:
                self.resetting = True
                self.op_hold = self.event_hold = self.stall_hold = self.rest_hold = False
                self.hold_at.clear()
                sc.hold = True
                if self.probe is not None:
                    self.probe.cancel(fol)
            elif code == C.C_QUIT:       # a1 = 1: the job ran to its end (pmctl run), else a stop
                self.quitting = FINISHED if a1 == 1.0 else "stopped by the supervisor"
                sc.hold = True
            elif code == C.C_ESTOP:
                st = _halt(st, "E-stop (software)")
            elif code == C.C_UNLOCK:
                if as_inputs(lp.backend.inputs()).estop:
                    continue                  # latched: the E-stop input must clear first
                if st.mode != RUN:
                    st = _restart(st, self.machine, lp)
                    self.faulted = False
                if self.probe is not None:
                    self.probe.cancel(fol)
                fol.clear()
                fol._rest = st.tip.tolist() + st.axis.tolist()
                sc.hold = False
            elif code == C.C_HOME_ARM:
                self.arm_axis, self.arm_want = int(a1), bool(a2)
                dev = as_inputs(lp.backend.inputs()).latch
                self.arm_edges = dev[self.arm_axis][0] if dev is not None and self.arm_axis >= 0 else None
            elif code == C.C_CHAIN_OFFSET:
                lp.set_chain_offset(int(a1), a2)      # bounded there (refused with a reason in the log)
            elif code == C.C_HOLD_AT:
                self.hold_at.append((float(a1), bool(a2)))
            elif code == C.C_SET_COUNTS:
                # at rest with nothing queued only (the supervisor checks the counters after the ack)
                if st.mode == RUN and sc.sigma == 0.0 and fol.src.count() == 0 and 0 <= int(a1) < 5:
                    st = self._rereference(lp, st, int(a1), int(a2))
        inp = as_inputs(lp.backend.inputs())
        if st.mode != HALTED and inp.estop:
            st = _halt(st, "E-stop input pressed")
        home = inp.home if lp.backend.can_rereference else None      # homing needs the re-reference
        if self.arm_axis >= 0 and home is not None:
            i, dev = self.arm_axis, inp.latch
            if dev is not None and self.arm_edges is not None and dev[i][0] != self.arm_edges:
                # the device latched a transition since arming: its counter at the switch edge
                if bool(dev[i][1]) == self.arm_want:
                    self._latch(st.counts.tolist(), i, int(dev[i][2]), sc)
                else:
                    self.arm_edges = dev[i][0]       # a transition the other way: keep waiting
            elif bool(home[i]) == self.arm_want:
                self._latch(st.counts.tolist(), i, None, sc)
        if self.term and not self.quitting:
            self.quitting = "SIGTERM"
            sc.hold = True
        if k % 50 == 0 and os.getppid() != self.ppid and not self.quitting:
            self.quitting = "the supervisor died: feed hold on the path, counters saved"
            self.log(self.quitting)
            sc.hold = True
        if self.hold_at:
            self._check_hold_at(fol, sc)
        if st.mode in (STOPPING, HALTED):
            if not self.faulted:
                self.faulted = True
                if self.probe is not None:
                    self.probe.cancel(fol)
                self.hold_at.clear()
                fol.clear()
                ch.set_reason(st.reason)
                ch.st[C.ST_FAULT] = C.F_FAULT if st.mode == HALTED and not _was_stop(st) else C.F_STOP
        # at rest: the path clock stopped (not still braking) for 50 ticks; the NC then holds each
        # joint within half a pulse of its target (its rest deadband) and sends no pulses unless a
        # disturbance pushes a joint out of it
        self.rest_ticks = self.rest_ticks + 1 if (sc.sigma == 0.0 and fol.state != 2) else 0     # 2 = HOLDING
        at_rest = self.rest_ticks >= 50
        if self.resetting and at_rest:
            fol.clear()
            sc.hold = False
            self.resetting = False
        # quit on a tick that sent no pulse: the last record's counters are the ones saved
        sent = lp.sent.tolist()
        quiet = sent == self._sent_prev
        self._sent_prev = sent
        if self.quitting and ((at_rest and quiet) or st.mode == HALTED):
            lp.quit = True
            lp.quit_reason = self.quitting
        mon = self.probe
        if mon is not None and mon.results:
            r = mon.results.pop(0)              # one probe at a time: the supervisor waits for each
            r.counts = tuple(int(c) for c in st.counts.tolist())
            self.probe_row = r.to_row()
            self.probe_seq += 1
        late = getattr(lp, "last_late_ns", 0)
        comp = getattr(lp, "last_compute_ns", 0)
        self.ontime = self.ontime + 1 if (late + comp) < self.period_ns else 0
        if self.stall_hold:
            self.stall_ok = self.stall_ok + 1 if (late + comp) < self.period_ns else 0
            if self.op_hold or self.event_hold or self.resetting or self.quitting:
                self.stall_hold = False          # a hold of its own takes over: its resume releases it
            elif self.stall_ok >= STALL_RESUME_TICKS:
                self.stall_hold = False
                sc.hold = False
                self.log(f"resumed after the stall ({STALL_RESUME_TICKS} ticks on time)")
        s = self.st
        s[C.ST_SEQ] += 1.0
        s[C.ST_TICK:C.ST_COUNTS] = (k, _wall(), st.mode, fol.state, sc.sigma, fol.line, fol.s_total,
                                     sc.feed_override, sc.rapid_override, 1.0 if sc.hold else 0.0)
        s[C.ST_COUNTS:C.ST_ENDED] = st.counts.tolist() + st.tip.tolist() + st.axis.tolist()
        s[C.ST_ENDED] = fol.ended_jobs
        s[C.ST_DROPPED] = lp.dropped
        s[C.ST_LATE_NS] = late
        s[C.ST_COMPUTE_NS] = comp
        s[C.ST_LATCH_SEQ] = self.latch_seq
        s[C.ST_LATCH:C.ST_LATCH + 5] = self.latch
        s[C.ST_HOME_IN] = -1.0 if home is None else float(sum(1 << i for i in range(5) if home[i]))
        s[C.ST_CMD_ACK] = self.last_ack
        s[C.ST_ONTIME] = self.ontime
        s[C.ST_QUEUED] = fol.src.count()
        s[C.ST_MONO] = _mono()
        s[C.ST_SENT:C.ST_SENT + 5] = lp.sent.tolist()
        fb = lp.last_fb
        if fb is not None and fb.counts is not None:
            s[C.ST_DEV_COUNTS:C.ST_DEV_COUNTS + 5] = fb.counts.tolist()
        s[C.ST_PROBE_SEQ] = self.probe_seq
        s[C.ST_PROBE:C.ST_PROBE + C.PROBE_RESULT_WIDTH] = self.probe_row
        s[C.ST_HOLD_AT_SEQ] = self.hold_at_seq
        s[C.ST_SEQ] += 1.0
        if self.offline:
            be = lp.backend
            # a simulation waits as long as it takes; a device keeps its watchdog fed (CANopen: the
            # host heartbeat the ticks carry; a step/dir bridge: its command watchdog)
            self._offline_wait(fol, sc, math.inf if be.truth() is not None else
                               (0.4 * be.stall_tolerance_s if be.stall_tolerance_s > 0 else 0.05))
        return st

    def _latch(self, counts, axis, dev_count, sc):
        """The armed switch reached its state: latch the counters (the device's own latch of that
        axis when it has one), disarm, feed hold on the path (the supervisor drops the rest)."""
        if dev_count is not None:
            counts[axis] = dev_count
        self.latch = counts
        self.latch_seq += 1
        self.arm_axis = -1
        sc.hold = True

    def _check_hold_at(self, fol, sc):
        """Hold on the path at the first queued C_HOLD_AT row: once the next ticks would reach it
        (at most LOOKAHEAD_SAMPLES short of it, as pmctl.hal.modbus_vfd.SpeedChanger does in one process)."""
        row, rest = self.hold_at[0]
        at = fol.src.consumed + fol.frac
        if fol.at_end:
            at += 1.0                 # resting on a job's last sample: the next one starts the next job
        # a planned stop (rest): the path holds on its very sample, where the samples are at rest; on
        # the move (a speed change inside a run of samples): the hold starts a little before the point
        if (at >= row - 1e-9) if rest else (at + LOOKAHEAD_SAMPLES * sc.sigma * fol.k >= row):
            sc.hold = True
            self.event_hold = True
            self.rest_hold = bool(rest)
            if rest:                  # on a planned stop the path is at rest: sigma means nothing there
                sc.sigma = sc.dsigma = 0.0
            self.hold_at.pop(0)
            self.hold_at_seq += 1

    def _offline_wait(self, fol, sc, max_wait_s=math.inf):
        """Offline (no real time): before the next tick, wait until the path can go on at full speed
        (enough samples queued for a stop from SIGMA_MAX, or the job's end among them) and the
        record ring has room; pace the tick when there is nothing to follow. Commands, a quit and
        a dead supervisor end the wait at once; a device's watchdog bounds it (``max_wait_s``):
        then the tick runs, and the path may slow down for want of samples as in real time."""
        src, ch = fol.src, self.ch
        t_end = time.monotonic() + max_wait_s
        if self.need is None:
            # the queue the starvation limit of the path follower lets run at SIGMA_MAX, in samples
            self.need = full_speed_queue(self.params, self.params.dt / fol.k, src.capacity)
        while True:
            if self.quitting or self.resetting or self.term or ch.commands.count() or os.getppid() != self.ppid \
                    or time.monotonic() > t_end:
                return
            if ch.records.free() < 2:
                time.sleep(0.0005)
                continue
            n = src.count()
            end = n > 0 and int(src.row(n - 1)[S_FLAGS]) & FLAG_END
            if n == 0 or (n == 1 and end) or (sc.hold and sc.sigma == 0.0):
                time.sleep(self.params.dt)        # nothing to follow: paced
                return
            if end or n >= self.need:
                return
            time.sleep(0.0005)                    # the planner is behind: wait, do not decelerate


    def _rereference(self, lp, st, axis, count):
        """Set one axis's pulse counter (homing): the NC restarts from the new counters (its model pose
        is their FK), the backend's device counters follow, and the start counters move with it so
        that counters = start + pulses sent still holds."""
        counts = np.array(st.counts, np.int64)
        d = count - int(counts[axis])
        counts[axis] = count
        lp.backend.rereference(counts)
        off = lp.backend.reference_offset()
        if off is not None and lp.writer is not None:
            lp.writer.offer(counts, lp.tick, off)      # the new offset is saved with the counters it belongs to
        st = _restart(st, self.machine, lp, counts)
        self.shift[axis] += d
        self.ch.st[C.ST_COUNTS0 + axis] += d
        lp.follower.clear()
        lp.follower._rest = st.tip.tolist() + st.axis.tolist()
        return st


def _restore_offset(be, state_file, machine_name, log, pulses_per_mm=None):
    """A backend that keeps a reference offset (homing on drives that keep their positions) gets the one
    saved with the counters it starts from (at the same resolution: offsets in counts of another one
    are not restored)."""
    if not state_file or be.reference_offset() is None:
        return
    try:
        saved = load_counters(state_file, machine=machine_name, pulses_per_mm=pulses_per_mm)
    except PmctlError as e:
        log(f"reference offsets not restored: {e}")
        return
    if saved is not None and saved.offsets is not None:
        be.set_reference_offset(saved.offsets)


def _wall():
    return time.time()


def _mono():
    return time.monotonic()


def _halt(st, reason):
    return st.halted(reason)          # NCState or the compiled core's state handle


def _was_stop(st) -> bool:
    r = st.reason
    return not (r.startswith("following error") or r.startswith("model pose lost") or r.startswith("backend"))


def _restart(st, machine, lp, counts=None):
    off = getattr(st, "offset", None)          # the applied chain-length offset stays through a restart
    return lp.nc.load(initial_state(machine, st.counts if counts is None else counts,
                                    offset=None if off is None else np.array(off, float)))


def rt_main(spec: dict, settings) -> int:
    """Entry point of the rt process (spawned by the supervisor): ``spec`` says where (the shared
    channel, the counters, the state file, the supervisor's pid); ``settings``
    (pmctl.motion.settings.Settings, resolved by the supervisor) says with what. No config file is
    read here."""

    signal.signal(signal.SIGINT, signal.SIG_IGN)          # the supervisor handles Ctrl-C
    log = lambda m: print(f"pmctl rt: {m}", file=sys.stderr, flush=True)  # noqa: E731
    ch = C.Channel(spec["shm"])
    ch.st[C.ST_PID] = os.getpid()
    ch.st[C.ST_COUNTS0:C.ST_COUNTS0 + 5] = [float(c) for c in spec["counts"]]
    ch.st[C.ST_DEV_COUNTS:C.ST_DEV_COUNTS + 5] = float("nan")
    machine, svc, params = settings.machine, settings.svc, settings.params
    cfg = copy.copy(svc.loop)
    cfg.rate_hz = settings.rate_hz
    realtime = settings.realtime
    offline = settings.offline
    cfg.realtime = not offline            # the daemon always keeps time (deadlines); offline: back to back
    if not realtime:
        cfg.lock_memory = False
        cfg.stall_timeout_s = max(cfg.stall_timeout_s, 5.0)
        cfg.max_overruns_in_row = 1 << 30
    dt = cfg.dt
    counts = np.array(spec["counts"], np.int64)
    be = hal.create(settings.backend, machine, dt, svc.backend_tables.get(settings.backend, {}))
    state_file = spec.get("state_file") or ""
    _restore_offset(be, state_file, machine.name, log, machine.resolution.pulses_per_mm)
    be.open(counts)
    st = initial_state(machine, counts)
    fol = make_follower(ch.samples, params, dt, pose=st.tip.tolist() + st.axis.tolist())
    ppm = machine.resolution.pulses_per_mm                # the counters' resolution, saved with them
    writer = CounterWriter(state_file, machine=machine.name, pulses_per_mm=ppm) if state_file else None

    class _Null(Recorder):           # the supervisor drains the record ring
        inline = False

        def drain(self):
            return 0

        def start(self, period_s=0.02):
            pass

        def stop(self):
            pass

    hook = RtHook(ch, machine, params, int(spec["ppid"]), log, offline=offline)

    def on_stall(why):                    # Backend.stall_hold: ride it out on the path (loop.py)
        hook.stall_hold, hook.stall_ok = True, 0
        lp.follower.scaler.hold = True
        log(f"warning: {why}: feed hold on the path, resumed once the ticks are on time again")
    hook.probe = ProbeMonitor(machine, [], svc.probe, dt, params, fetch=hook.probe_fetch)

    def _term(signum, frame):
        hook.term = True
    signal.signal(signal.SIGTERM, _term)
    lp = ControlLoop(machine, be, params, None, cfg, st,
                     LoopParts(log=log, writer=writer, follower=fol, records=ch.records,
                               recorder=_Null(ch.records, keep=False), hook=hook, exit_when_done=False,
                               setup_rt=realtime and not offline, probe=hook.probe))
    lp.on_stall = on_stall
    ch.st[C.ST_PHASE] = C.PH_RUNNING
    res = None
    try:
        res = lp.run()
    finally:
        final = lp.state if hasattr(lp, "state") else st
        clean = res is not None and final.mode != HALTED or (res is not None and _was_stop(final))
        try:
            be.close()
        finally:
            if writer is not None:
                writer.stop()
                save_counters(state_file, final.counts, machine=machine.name, clean=bool(clean), tick=lp.tick,
                              offsets=be.reference_offset(), pulses_per_mm=ppm)
            ch.st[C.ST_COUNTS:C.ST_COUNTS + 5] = final.counts.tolist()
            ch.set_reason(getattr(lp, "quit_reason", "") or (res.reason if res else "rt process error"))
            fb = lp.last_fb
            sent_ok = bool(np.array_equal(counts + hook.shift + lp.sent, final.counts))
            ch.set_result({"status": res.status if res else "fault", "reason": res.reason if res else "rt process error",
                           "ticks": int(res.ticks if res else lp.tick), "counts": final.counts.tolist(),
                           "sent": lp.sent.tolist(), "shift": hook.shift.tolist(), "sent_ok": sent_ok,
                           "dropped": int(lp.dropped), "clean": bool(clean), "realtime": bool(cfg.realtime),
                           "timing": res.timing.summary() if res else {}})
            ch.st[C.ST_PHASE] = C.PH_EXITED
            if os.getppid() != int(spec["ppid"]):
                ch.close(unlink=True)             # the supervisor died: nobody else removes the segment
            why = getattr(lp, 'quit_reason', '') or (res.reason if res else '')
            log(f"{why if why == FINISHED else 'stopped: ' + why}; counters "
                f"{final.counts.tolist()} saved; pulses sent = counter change: {'yes' if sent_ok else 'NO'}; "
                + device_agreement(fb, final.counts, ppm))
    return 0


def device_agreement(fb, counts, ppm) -> str:
    """What the devices said last against the counters saved: a backend with pulse counters (the
    bridge, the sim) must hold exactly the saved ones; drives without counters (canopen) report their
    positions, which must be within a pulse of them (at rest). No feedback read: said so."""
    if fb is None:
        return "device counters: none read"
    if fb.counts is not None:
        return f"device counters = counters: {'yes' if np.array_equal(fb.counts, counts) else 'NO'}"
    off = np.rint(np.asarray(fb.enc, float) * np.asarray(ppm, float)) - np.asarray(counts, float)
    if not np.all(np.isfinite(off)):
        return "drive positions = counters: unknown (no position read)"
    if np.all(np.abs(off) <= 1):
        return "drive positions = counters: yes (within a pulse)"
    i = int(np.argmax(np.abs(off)))
    return (f"drive positions = counters: NO ({('L1', 'L2', 'L3', 'X', 'Y')[i]} {int(off[i]):+d} pulses: "
            f"the drive stopped elsewhere, or was still moving)")


if __name__ == "__main__":
    import json

    from pmctl.motion.settings import Settings
    sys.exit(rt_main(json.loads(sys.argv[1]), Settings.from_bytes(sys.stdin.buffer.read())))
