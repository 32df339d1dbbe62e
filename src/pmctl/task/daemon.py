"""`pmctl serve`: the supervisor side of the daemon put together.

Start-up: read the counter file and the journal; decide where the machine is and whether that can
be trusted (a clean stop: yes; a periodic snapshot left by a crash or a power cut: Alarm 11 with the
age of the position, until ``$X`` confirms it or ``$H`` homes; a job the journal says was running is
kept as the interrupted job, which ``resume_job`` continues from its line once the alarm is cleared);
start the rt process there; open the
recording, the console and the control socket; tell systemd READY. Then watch: the watchdog is
pinged only while the rt side reports ticks on time; the journal follows the job and line.
Shutdown (SIGTERM, SIGINT): feed hold on the path, the rt process saves its counters and exits, the
recording and the journal are finalised.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np

from pmctl.core import kinematics as K
from pmctl.motion import channel as C


RT_FRESH_S = 0.5      # the rt status older than this (or than the ping period, if shorter) stops the pings


class Daemon:
    def __init__(self, *, config="prototype", service=None, backend=None, state_file="", record_dir=None,
                 console=None, realtime=True, rate_hz=None, socket_path=None, log=None):
        self.config, self.service, self.backend = config, service, backend
        self.state_file = state_file
        self.record_dir = record_dir
        self.console_spec = console
        self.realtime = realtime
        self.rate_hz = rate_hz
        self.socket_path = socket_path
        self.log = log or (lambda m: print(f"pmctl serve: {m}", file=sys.stderr, flush=True))
        self._stop = threading.Event()
        self.stop_reason = ""
        self.rec = None
        self.port = None
        self.console = None
        self.ctl = None
        self.sup = None
        self.lock = None
        self.interrupted = None            # (job file, line, start pose) of a job a crash interrupted
        self._rec_lock = threading.Lock()  # the record sink (monitor thread) vs record start/stop

    # ------------------------------------------------------------ start
    def start(self):
        from pmctl.motion.nc import counts_of
        from pmctl.motion.state_store import StateLock, load_counters
        from pmctl.task.journal import Journal, journal_path
        from pmctl.task.job import home_pose
        from pmctl.task.supervisor import ALARM_HOMING_REQUIRED, Supervisor

        sup = Supervisor(self.config, service=self.service, backend=self.backend, state_file=self.state_file,
                         realtime=self.realtime, rate_hz=self.rate_hz, log=self.log)
        self.sup = sup
        m = sup.machine
        if self.state_file:
            self.lock = StateLock(self.state_file)
        self.journal = Journal(journal_path(self.state_file) if self.state_file else None, m.name).load()
        saved = (load_counters(self.state_file, machine=m.name, pulses_per_mm=m.resolution.pulses_per_mm)
                 if self.state_file else None)
        alarm = None
        if saved is None:
            tip, axis = home_pose(m)
            counts = counts_of(K.ik(tip, axis, m).q, sup.params)
            self.position_note = "no saved position: starting at the home pose"
            if self.state_file and journal_path(self.state_file).exists():
                # a journal of an earlier session without its counters: the counter file was lost or
                # moved away, so the machine is anywhere; the home pose is only a placeholder
                self.position_note = (f"no saved position in {self.state_file}, but the journal of an earlier "
                                      f"session is there (the counter file was lost or moved): the position is "
                                      f"NOT known; home with $H (or confirm the home pose with $X)")
                alarm = ALARM_HOMING_REQUIRED
        else:
            counts = saved.counts
            age = max(0.0, time.time() - saved.wall_time)
            if saved.clean:
                self.position_note = f"position from {self.state_file}, saved at a clean stop {age:.0f} s ago: trusted"
            else:
                self.position_note = (f"position from {self.state_file} is {age:.0f} s old and NOT trusted (the last "
                                      f"write was a periodic snapshot: a crash or power cut may have lost up to one "
                                      f"persist interval of motion): confirm with $X or home with $H")
                alarm = ALARM_HOMING_REQUIRED
            if saved.note:
                self.position_note += f"; {saved.note}"
        job = self.journal.data.get("job")
        if self.journal.data.get("running") and job:
            self.position_note += f"; job {job} was interrupted at line {self.journal.data.get('line', 0)}"
            if job != "console":
                self.interrupted = (job, int(self.journal.data.get("line", 0)), self.journal.data.get("job_start"))
            if alarm is None:
                self.position_note += ": confirm the position with $X"
                alarm = ALARM_HOMING_REQUIRED
        if alarm:                          # the alarm's reason says all of it: age, trust, the job
            alarm = (alarm, self.position_note)
        for note in sup.nc_setup.notes:     # chain modes, K_theta (auto, or off), the shaper: as resolved
            self.log(note)
        self.log(self.position_note)
        if self.record_dir:
            sup.open_devices(at=counts)     # the DAQ connected first: the recording knows its channels
            self._open_recording()
        sup.start(counts)
        if alarm:
            sup.raise_alarm(*alarm)
            self.journal.data["homed"] = False          # the position is not trusted
        sup.homed = bool(self.journal.data.get("homed"))
        self.journal.save(running=False)
        if self.socket_path:
            from pmctl.interfaces.console.control import ControlServer
            self.ctl = ControlServer(self, self.socket_path)
            self.ctl.start()
        if self.console_spec:
            from pmctl.interfaces.console.grbl import GrblConsole
            from pmctl.interfaces.console.port import ConsolePort
            from pmctl.task.jog import make_jogger
            self.port = ConsolePort(self.console_spec)
            self.console = GrblConsole(sup, self.port.fd, self.journal, log=self.log, jogger=make_jogger(sup),
                                       homing=self.home, present=self.port.client_present)
            self.console.start()
            self.log(f"console on {self.port.device}" + (f" (link {self.port.link})" if self.port.link else ""))
        from pmctl.task.notify import sd_notify
        sd_notify(f"READY=1\nSTATUS={sup.state_name()}: {self.position_note}\nMAINPID={os.getpid()}")

    # ------------------------------------------------------------ homing, resume
    def home(self):
        """$H (console) / home (control socket): (ok, message); the journal records the homing."""
        ok, msg = self.sup.home()
        self.journal.save(homed=bool(ok))
        self.log(msg if ok else f"homing failed: {msg}")
        if ok and self.console is not None:
            self.console.interp.sync(*self.sup.pose())
        return ok, msg

    def resume_job(self, line=None, clearance_mm=None):
        """Queue the rest of the interrupted job from its line (or ``line``), with the safe approach of
        pmctl.task.resume from where the machine is. Refused in alarm (confirm with $X or home with
        $H first), while motion is queued, or when the approach is unreachable."""
        from pmctl.core.errors import PmctlError
        from pmctl.task.job import load_job
        from pmctl.task.resume import CLEARANCE_MM, resume_job
        from pmctl.task.supervisor import MotionRefused
        sup = self.sup
        if self.interrupted is None:
            raise PmctlError("no interrupted job to resume (the journal records none)")
        if sup.alarm or sup.rt_dead:
            raise MotionRefused(f"alarm {sup.alarm}: confirm the position ($X) or home ($H) first", 9)
        if sup.busy():
            raise MotionRefused("motion is queued or under way", 8)
        path, jline, start = self.interrupted
        line = jline if line is None else int(line)
        if start is not None:
            start = (np.asarray(start[:3], float), np.asarray(start[3:], float))
        from pmctl.task.gcode import reader_options
        offsets = self.console.interp.offsets() if getattr(self, "console", None) is not None else \
            self.journal.data.get("offsets")
        job = load_job(path, sup.machine, start=start, **reader_options(path, sup.svc.interpreter, offsets))
        tip, axis = sup.pose()
        rest = resume_job(job, line, tip, axis, sup.machine, sup.params,
                          CLEARANCE_MM if clearance_mm is None else float(clearance_mm))
        it = sup.submit(rest, kind="job", name=f"{os.path.basename(path)} from line {line}", source=path)
        it.start_pose = start              # the journal keeps the job's own start (G91 jobs need it)
        it.resume_line = line              # and, during the approach (line 0), the line it resumes
        self.interrupted = None
        self.log(f"resuming {path} from line {line}")
        return it

    # ------------------------------------------------------------ recording
    def record_start(self, folder):
        """Start recording the session into ``folder`` (control socket ``record start``)."""
        from pmctl.core.errors import PmctlError
        with self._rec_lock:
            if self.rec is not None:
                raise PmctlError(f"already recording into {self.record_dir}")
            before, self.record_dir = self.record_dir, str(folder)
        try:
            self._open_recording()
        except BaseException:
            self.record_dir = before        # refused (a folder or its .partial there): nothing changed
            raise
        return self.record_dir

    def record_stop(self):
        """Finalise the recording (control socket ``record stop``); returns its folder."""
        from pmctl.core.errors import PmctlError
        with self._rec_lock:
            if self.rec is None:
                raise PmctlError("not recording")
            self.sup.record_sink = None
            rec, self.rec = self.rec, None
            rec.__exit__(None, None, None)
        return self.record_dir

    def _open_recording(self):
        """The session recording: the channels of ``pmctl run``'s (pmctl.task.run_sink.RunSink, one
        piece for both) plus ``line`` and ``sigma``, the time running on across an rt restart."""
        from pmctl import hal
        from pmctl.core.recording import RecordingWriter
        from pmctl.hal.base import Backend
        from pmctl.task.run_sink import RunSink
        sup = self.sup
        from pmctl.motion.service_config import strain_in_loop
        cls = hal.backend_class(sup.backend)
        load = strain_in_loop(sup.backend)                  # gauges in the cyclic data
        rs = RunSink(sup.machine, sup.machine.resolution.pulses_per_mm, sup.rate_hz, cls.truth is not Backend.truth,
                     1 << 62, 0, None, sup.daq, load=load, strain=load, session=True,
                     spindle_of=lambda: sup.spindle, spindle_opt=sup.svc.spindle)
        chans, notes = rs.channels()
        folder = Path(self.record_dir)       # written into folder.partial, renamed on finishing
        machine_ref = str(self.config)
        if machine_ref.endswith(".toml"):
            from pmctl.core.config import CONFIG_DIR
            p = Path(machine_ref).resolve()
            machine_ref = p.stem if p.parent == CONFIG_DIR.resolve() else os.path.relpath(p, folder.resolve())
        rec = RecordingWriter(folder, chans, machine=machine_ref, sample_rate_hz=sup.rate_hz,
                              description=f"pmctl serve session on backend {sup.backend}", channel_notes=notes,
                              force_flag=None)
        rec.__enter__()                     # (refuses an existing folder.partial: then nothing is kept)
        self.rec = rec

        def sink(rows):
            with self._rec_lock:
                rs.writer = self.rec
                if self.rec is not None:
                    rs(rows)
        sup.record_sink = sink

    # ------------------------------------------------------------ run
    def catch_stop_signals(self):
        """SIGTERM, SIGINT and SIGHUP ask for a stop (feed hold, position saved). Called before
        ``start``: a signal during the start-up (the console link may already be there) is kept and
        acted on as soon as ``serve_forever`` runs, instead of killing the process unsaved."""
        for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
            signal.signal(sig, self._on_signal)

    def serve_forever(self):
        from pmctl.task.notify import watchdog_period_s
        self.catch_stop_signals()
        wd = watchdog_period_s()
        try:
            self._watch(wd)
        except Exception as e:             # a supervisor bug: stop the machine properly, say why
            self.log(f"supervisor error: {type(e).__name__}: {e}")
            self.stop_reason = f"supervisor error: {e}"
        return self.shutdown()

    def _watch(self, wd):
        from pmctl.task.notify import sd_notify
        last_ping = 0.0
        last_line = None
        last_status = ""
        last_save = 0.0
        while not self._stop.wait(0.05):
            sup = self.sup
            now = time.monotonic()
            if wd and now - last_ping >= wd and self.rt_on_time(min(RT_FRESH_S, wd)):
                sd_notify("WATCHDOG=1")
                last_ping = now
            if sup.homed != self.journal.data.get("homed"):
                try:
                    self.journal.save(homed=sup.homed)
                except OSError as e:
                    self.log(f"journal write failed: {e}")
            state = sup.state_name()
            if state != last_status:
                sd_notify(f"STATUS={state}" + (f" (alarm {sup.alarm}: {sup.alarm_msg})" if sup.alarm else ""))
                last_status = state
            running = bool(sup.busy()) and not sup.homing
            line = int(sup.current_line()) if running else 0
            if (running, line) != last_line and (last_line is None or running != last_line[0]
                                                  or now - last_save > 0.5):
                last_save = now
                job, start = None, None
                if running:
                    with sup._lock:
                        cur = sup.items[0] if sup.items else None
                    job = (cur.source or "console") if cur is not None else "console"
                    if line == 0 and cur is not None:
                        line = getattr(cur, "resume_line", 0)
                    if cur is not None and cur.source:
                        start = getattr(cur, "start_pose", None) or cur.start
                        start = [float(x) for x in np.concatenate([np.ravel(start[0]), np.ravel(start[1])])]
                try:
                    self.journal.save(running=running, line=line, job=job, job_start=start)
                except OSError as e:
                    self.log(f"journal write failed: {e}")
                last_line = (running, line)

    def rt_on_time(self, max_age_s: float = RT_FRESH_S) -> bool:
        """The rt side is alive and its last ticks were on time (the watchdog's condition): its status
        block written less than ``max_age_s`` ago (the watchdog passes 0.5 s, or its ping period when
        WatchdogSec is under 1 s, so a stalled rt side misses the next ping whatever the interval)."""
        sup = self.sup
        if sup.rt_dead or sup.ch is None:
            return False
        s = sup.raw()
        fresh = time.monotonic() - s[C.ST_MONO] < max_age_s
        return bool(fresh and (s[C.ST_ONTIME] > 0 or not self.realtime))

    def _on_signal(self, signum, frame):
        self.stop_reason = signal.Signals(signum).name
        self._stop.set()

    def request_stop(self, reason="stop requested"):
        self.stop_reason = reason
        self._stop.set()

    def shutdown(self) -> int:
        from pmctl.task.notify import sd_notify
        sd_notify("STOPPING=1")
        self.log(f"stopping ({self.stop_reason or 'shutdown'}): feed hold on the path, saving the position")
        if self.console is not None:
            self.console.stop()
        if self.ctl is not None:
            self.ctl.stop()
        counts = self.sup.shutdown(self.stop_reason)
        if self.rec is not None:
            try:
                self.rec.__exit__(None, None, None)
            except Exception as e:
                self.log(f"recording not finalised: {e}")
        self.journal.save(running=False)
        if self.port is not None:
            self.port.close()
        if self.lock is not None:
            self.lock.release(remove=True)
        self.log(f"stopped; counters {None if counts is None else counts.tolist()}")
        return 0
