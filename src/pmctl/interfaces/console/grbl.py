"""The operator console: grbl 1.1's serial protocol on a pty or a serial device.

Two threads:
- the reader takes bytes as they come. Realtime bytes act at once, also in the middle of a line:
  ``?`` status report, ``!`` feed hold, ``~`` cycle start, 0x18 soft reset, 0x85 jog cancel,
  0x90-0x94 feed override (100 %, +10, -10, +1, -1; 10-200 %), 0x95-0x97 rapid override (100, 50,
  25 %), 0x99-0x9D spindle override (100 %, +10, -10, +1, -1; 10-200 %: the VFD's set-point when a
  ``[spindle]`` is configured), 0x9E spindle stop in a hold. Other bytes collect into
  lines (``\\n`` or ``\\r`` ends one); a line longer than ``LINE_MAX`` is dropped whole with error:11.
- the worker executes lines in order and answers each with ``ok`` or ``error:N``. A motion line is
  answered once it is checked (reader, reachability) and queued; when the motion queue is full the
  answer waits (grbl's full planner buffer), so a character-counting sender with its 128-byte budget
  is paced by the machine. Motion lines are collected into batches that the supervisor plans as one
  job (a batch goes when it is large, when the sender pauses, or at M2/M30).
- a probing line (G38.2/G38.3) is executed as grbl does: the queued motion is sent, the probe goes
  alone, and the line is answered once the probe has ended -- ``[PRB:x,y,z,a,b:1]`` (``:0``
  without contact; after ``ALARM:5`` for a G38.2 without contact) then ``ok`` -- and the lines after
  it are read from where the probe stopped.

A bad line changes nothing: not the queued motion, not the parser state, not the next line.
"""

from __future__ import annotations

import copy
import math
import os
import queue
import select
import threading
import time

import numpy as np

from pmctl import __version__
from pmctl.motion import channel as C
from pmctl.task.interp import AXES, WCS_NAMES, LineError, LineInterpreter, moves_job
from pmctl.task.job import DWELL
from pmctl.task.supervisor import MotionRefused, roll_pitch_deg

RX_BUFFER = 128
LINE_MAX = 256
BATCH_MOVES = 200
BATCH_IDLE_S = 0.08
MAX_QUEUED_ITEMS = 3
BANNER = "Grbl 1.1h ['$' for help]"
HELP = "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $C $X $H ~ ! ? ctrl-x]"

RT_STATUS, RT_HOLD, RT_START, RT_RESET = 0x3F, 0x21, 0x7E, 0x18
RT_DOOR, RT_JOG_CANCEL = 0x84, 0x85


class GrblConsole:
    def __init__(self, sup, fd: int, journal, *, log=None, homing=None, jogger=None):
        self.sup = sup
        self.fd = fd
        self.journal = journal
        self.log = log or (lambda m: None)
        self.homing = homing                  # callable() -> (ok, msg) for $H, or None
        self.jogger = jogger
        tip, axis = sup.pose()
        self.interp = LineInterpreter(sup.machine, tip, axis, journal.data.get("offsets"),
                                      config=getattr(getattr(sup, "svc", None), "interpreter", None))
        self.last_prb = None                  # the last probe's ProbeResult ($# reports it)
        self.settings = {10: int(journal.data.get("settings", {}).get("10", 1))}
        self.lines: queue.Queue = queue.Queue()
        self._wlock = threading.Lock()
        self._stop = threading.Event()
        self._reset_gen = 0
        self.batch: list = []
        self.batch_lines: dict = {}
        self.batch_t = 0.0
        self.seq = 0
        self.spindle_ov = 100
        self.feed_ov = 100
        self.rapid_ov = 100
        self._buf = bytearray()
        self._overflow = False
        self._last_tip = None
        self._last_t = 0.0
        self.speed = 0.0
        self.threads = []
        sup.listeners.append(self._on_event)

    # ------------------------------------------------------------ output
    def write(self, text: str):
        data = (text + "\r\n").encode("ascii", "replace")
        with self._wlock:
            try:
                while data:
                    n = os.write(self.fd, data)
                    data = data[n:]
            except (BlockingIOError, OSError):
                pass                       # nobody listening (a disconnected sender): drop it

    def _on_event(self, event, detail):
        if event == "alarm":
            self.write(f"ALARM:{detail['code']}")
            self.write(f"[MSG:{one_line(detail['msg'])}]")
        elif event == "error":
            self.write(f"[MSG:{one_line(detail['msg'])}]")

    # ------------------------------------------------------------ life
    def start(self):
        self.welcome()
        for name, fn in (("pmctl-console-rx", self._reader), ("pmctl-console-lines", self._worker)):
            t = threading.Thread(target=fn, name=name, daemon=True)
            t.start()
            self.threads.append(t)

    def stop(self):
        self._stop.set()
        for t in self.threads:
            t.join(2.0)

    def welcome(self):
        """grbl's start-up message (at start and after a soft reset). In alarm, as grbl: the unlock
        reminder right after the banner; then the alarm itself, ``ALARM:n`` and ``[MSG:reason]``:
        an alarm raised before the console started (the daemon's start-up alarm: the saved position
        not trusted, a job interrupted) or before the reset is said, not only hinted at."""
        sup = self.sup
        self.write("")
        self.write(BANNER)
        if sup.alarm or sup.rt_dead:
            self.write("[MSG:'$H'|'$X' to unlock]")
            if sup.alarm:
                self.write(f"ALARM:{sup.alarm}")
                if sup.alarm_msg:
                    self.write(f"[MSG:{one_line(sup.alarm_msg)}]")

    # ------------------------------------------------------------ reader
    def _reader(self):
        while not self._stop.is_set():
            try:
                r, _, _ = select.select([self.fd], [], [], 0.05)
            except (OSError, ValueError):
                time.sleep(0.05)
                continue
            if not r:
                continue
            try:
                data = os.read(self.fd, 4096)
            except BlockingIOError:
                continue
            except OSError:                 # the sender closed the port: wait for the next one
                time.sleep(0.05)
                continue
            if not data:
                time.sleep(0.05)
                continue
            self.feed(data)

    def feed(self, data: bytes):
        """Bytes from the sender (the reader thread; tests may call it directly)."""
        for b in data:
            if b == RT_STATUS:
                self.write(self.status_report())
            elif b == RT_HOLD:
                state = self.state()
                if state in ("Run", "Idle"):  # grbl 1.1: a hold while idle is a hold too (Hold:0)
                    self.sup.hold()
                elif state == "Jog":          # grbl: a feed hold during a jog cancels the jog
                    self.jog_cancel()
                # Alarm, Check, Hold: nothing to hold
            elif b == RT_START:
                self.sup.resume()
            elif b == RT_RESET:
                self.soft_reset()
            elif b == RT_JOG_CANCEL:
                self.jog_cancel()
            elif b >= 0x80:
                self._override(b)
            elif b in (0x0A, 0x0D):
                if self._overflow:
                    self.lines.put((self._reset_gen, None))      # error:11 in order with the others
                elif self._buf or b == 0x0A:
                    self.lines.put((self._reset_gen, bytes(self._buf)))
                self._buf.clear()
                self._overflow = False
            else:
                if len(self._buf) >= LINE_MAX:
                    self._overflow = True
                    self._buf.clear()
                elif not self._overflow:
                    self._buf.append(b)

    def _override(self, b):
        if 0x90 <= b <= 0x94:
            f = self.feed_ov
            f = {0x90: 100, 0x91: f + 10, 0x92: f - 10, 0x93: f + 1, 0x94: f - 1}[b]
            self.feed_ov = min(200, max(10, f))
            self.sup.feed_override(self.feed_ov / 100.0)
        elif 0x95 <= b <= 0x97:
            self.rapid_ov = {0x95: 100, 0x96: 50, 0x97: 25}[b]
            self.sup.rapid_override(self.rapid_ov / 100.0)
        elif 0x99 <= b <= 0x9D:
            s = self.spindle_ov
            s = {0x99: 100, 0x9A: s + 10, 0x9B: s - 10, 0x9C: s + 1, 0x9D: s - 1}[b]
            self.spindle_ov = min(200, max(10, s))
            self.sup.spindle_override(self.spindle_ov / 100.0)
        elif b == 0x9E:
            self.sup.spindle_stop_toggle()    # only in Hold:0 with a running spindle VFD (else ignored)
        # 0x84 door, 0xA0/0xA1 coolant: no such hardware here; others: not commands

    def soft_reset(self):
        self._reset_gen += 1
        self._buf.clear()
        self._overflow = False
        while not self.lines.empty():
            try:
                self.lines.get_nowait()
            except queue.Empty:
                break
        self.batch, self.batch_lines = [], {}
        self.sup.soft_reset()
        self.interp.reset_modal()
        self.interp.sync(*self.sup.pose())
        if self.interp.changed:
            self._persist()
        self.feed_ov = self.rapid_ov = self.spindle_ov = 100
        self.sup.feed_override(1.0)
        self.sup.rapid_override(1.0)
        self.sup.spindle_override(1.0)
        self.welcome()

    def jog_cancel(self):
        if self.sup.state_name() == "Jog":
            self.sup.soft_reset()
            self.interp.sync(*self.sup.pose())

    # ------------------------------------------------------------ status
    def state(self) -> str:
        """The machine state as the sender sees it: Run as soon as a motion line is accepted (it
        may still wait in the batch that goes to the supervisor)."""
        state = self.sup.state_name()
        return "Run" if state == "Idle" and self.batch else state

    def n_word(self) -> int:
        """The N word of the line being executed (0: the line had none; grbl reports Ln only then)."""
        sup = self.sup
        line = int(sup.raw()[C.ST_LINE])
        with sup._lock:
            for it in sup.items:
                if line in it.lines:
                    return int(it.lines[line] or 0)
        return 0

    def status_report(self) -> str:
        sup = self.sup
        state = self.state()
        tip, axis = sup.pose()
        a, b = roll_pitch_deg(axis)
        m = [float(tip[0]), float(tip[1]), float(tip[2]), a, b]
        now = time.monotonic()
        if self._last_tip is not None and now - self._last_t > 1e-3:
            self.speed = float(np.linalg.norm(tip - self._last_tip)) / (now - self._last_t) * 60.0
        self._last_tip, self._last_t = tip, now
        if state in ("Idle", "Hold:0", "Alarm"):
            self.speed = 0.0
        wco = self.interp.wco()
        if self.settings[10] & 1:
            pos = "MPos:" + mm3(m)
        else:
            pos = "WPos:" + mm3(m[i] - wco[i] for i in range(5))
        parts = [state, pos, f"FS:{self.speed:.0f},{spindle_rpm(sup):.0f}"]
        if self.settings[10] & 2:
            parts.append(f"Bf:{max(0, 15 - sup.queued_items())},{RX_BUFFER}")
        line = self.n_word()
        if line > 0 and state not in ("Idle", "Alarm", "Jog"):
            parts.append(f"Ln:{line}")
        raw = sup.raw()
        fo = int(round(raw[C.ST_FEED_OV] * 100)) or self.feed_ov
        ro = int(round(raw[C.ST_RAPID_OV] * 100)) or self.rapid_ov
        parts.append(f"Ov:{fo},{ro},{self.spindle_ov}")
        parts.append("WCO:" + mm3(wco))
        return "<" + "|".join(parts) + ">"

    # ------------------------------------------------------------ lines
    def _worker(self):
        while not self._stop.is_set():
            try:
                gen, raw = self.lines.get(timeout=0.02)
            except queue.Empty:
                if self.batch and time.monotonic() - self.batch_t > BATCH_IDLE_S:
                    self._flush()
                continue
            if gen != self._reset_gen:
                continue
            if raw is None:
                self.write("error:11")
                continue
            try:
                text = raw.decode("ascii")
            except UnicodeDecodeError:
                self.write("error:1")
                continue
            try:
                self.execute(text.strip(), gen)
                if gen == self._reset_gen:
                    self.write("ok")
            except LineError as e:
                self.write(f"error:{e.code}")
            except MotionRefused as e:
                self.write(f"error:{e.code}")
            except Exception as e:              # a bug must not kill the console
                self.log(f"console: {type(e).__name__}: {e}")
                self.write("error:20")

    def execute(self, text: str, gen: int = 0):
        if not text:
            return
        if "".join(text.split()).startswith("$"):
            return self._system("".join(text.split()).upper())
        if any(ord(c) < 0x20 and c != "\t" for c in text):
            raise LineError(1, "control characters in the line")
        state = self.sup.state_name()
        if state == "Alarm":
            raise LineError(9, "G-code locked out during alarm")
        if state == "Jog":
            raise LineError(9, "G-code locked out while jogging")
        self.seq += 1
        if not self.batch:
            # motion from elsewhere (a jog, a job from the control socket, a hold) may have moved
            # the machine: the parser continues from where the queued motion ends
            with self.sup._lock:
                last = self.sup.items[-1].kind if self.sup.items else None
            if last != "gcode":
                self.interp.sync(*self.sup.end_pose())
        st0 = copy.deepcopy(self.interp.st)     # a refused probe line changes nothing
        moves, n_word, flags = self.interp.execute(text, self.seq)
        if any(m.probe for m in moves) and not self.sup.check_mode:
            return self._probe(moves, n_word, st0, gen)
        if flags.get("sync"):
            self._persist()
        # grbl synchronises on G4 (mc_dwell) and M2/M30: the answer comes once all queued motion
        # has run (and the dwell elapsed) -- a sender's way to know the buffer is empty
        sync = not self.sup.check_mode and (flags.get("end") or any(m.kind == DWELL for m in moves))
        if moves and not self.sup.check_mode:
            if not self.batch:
                self.batch_t = time.monotonic()
            self.batch.extend(moves)
            self.batch_lines[self.seq] = n_word
            self.batch_t = time.monotonic()
        if len(self.batch) >= BATCH_MOVES or flags.get("end") or sync:
            self._flush(gen)          # waits (the answer with it) while the motion queue is full
        if sync and not self._synchronize(gen):
            return                    # a soft reset dropped the line: no answer
        if flags.get("end"):
            self.write("[MSG:Pgm End]")

    def _synchronize(self, gen) -> bool:
        """grbl's protocol_buffer_synchronize: wait until every queued item has run and the machine
        is at rest. The reader goes on meanwhile (status, hold, resume, overrides); a soft reset ends
        the wait (False: the line is dropped unanswered); an alarm answers it with error:9."""
        while not self._stop.is_set():
            if gen != self._reset_gen:
                return False
            if self.sup.alarm or self.sup.rt_dead:
                raise MotionRefused("an alarm stopped the motion this line waited for", 9)
            if not self.sup.busy():
                return True
            time.sleep(0.005)
        return False

    def _flush(self, gen=None):
        if not self.batch:
            return None
        while self.sup.queued_items() >= MAX_QUEUED_ITEMS:
            if (gen is not None and gen != self._reset_gen) or self._stop.is_set() or self.sup.alarm:
                self.batch, self.batch_lines = [], {}
                return None
            time.sleep(0.01)
        batch, lines = self.batch, self.batch_lines
        try:                          # the batch stays visible (state Run) until the item is queued
            return self.sup.submit(moves_job(batch, "console"), kind="gcode", name="console", lines=lines)
        except MotionRefused:
            return None
        finally:
            self.batch, self.batch_lines = [], {}

    def _probe(self, moves, n_word, st0, gen):
        """A G38.2/G38.3 line, as grbl runs it: the motion queued before it goes first, the probe is
        planned alone, and the line is answered when the probe has ended ([PRB:...] then ok); the
        parser continues from where the probe stopped."""
        from pmctl.core.errors import InputError
        from pmctl.motion.probe import check_probe_feeds
        try:
            check_probe_feeds(moves_job(moves), self.sup.svc.probe, "console", self.sup.plan_feed_override)
        except InputError as e:
            self.interp.st = st0
            self.write(f"[MSG:{e.reason}]")
            raise LineError(20, e.reason) from None
        self._flush(gen)
        self.batch, self.batch_lines, self.batch_t = list(moves), {self.seq: n_word}, time.monotonic()
        it = self._flush(gen)
        if it is None:
            self.interp.st = st0
            raise MotionRefused("the probe could not be queued", 9)
        while not it.probe_results:
            if gen != self._reset_gen or self._stop.is_set() or it.gen != self.sup._gen or self.sup.rt_dead:
                break                     # a soft reset, an alarm or a fault dropped it
            time.sleep(0.005)
        if not it.probe_results:
            self.interp.sync(*self.sup.pose())
            return
        r = it.probe_results[-1]
        t0 = time.monotonic()
        while r.error and not self.sup.alarm and time.monotonic() - t0 < 2.0:
            time.sleep(0.002)             # ALARM:5 first (the supervisor raises it right after the result)
        self.last_prb = r
        self.write(r.prb())
        self.interp.sync(r.stop, it.end[1])

    def _persist(self):
        self.interp.changed = False
        self.journal.save(offsets=self.interp.offsets(), settings={str(k): v for k, v in self.settings.items()})

    # ------------------------------------------------------------ $ commands
    def _system(self, cmd: str):
        sup = self.sup
        idle_like = self.state() in ("Idle", "Alarm", "Check")
        if cmd == "$":
            self.write(HELP)
        elif cmd == "$$":
            for k, v in self._settings_list():
                self.write(f"${k}={v}")
        elif cmd == "$#":
            for n in WCS_NAMES:
                self.write(f"[{n}:" + mm3(self.interp.wcs[n]) + "]")
            z = ",".join(["0.000"] * 5)
            offsets = self.interp.offsets()
            self.write("[G28:" + mm3(offsets["g28"]) + "]")
            self.write("[G30:" + mm3(offsets["g30"]) + "]")
            self.write("[G92:" + mm3(self.interp.g92) + "]")
            self.write(f"[TLO:{mm3([self.interp.tlo()])}]")
            self.write(self.last_prb.prb() if self.last_prb is not None else f"[PRB:{z}:0]")
        elif cmd == "$G":
            self.write(f"[GC:{self.interp.parser_state()}]")
        elif cmd == "$I":
            self.write(f"[VER:1.1h.pmctl-{__version__}:{sup.machine.name}]")
            self.write(f"[OPT:VN,15,{RX_BUFFER}]")
        elif cmd == "$N":
            self.write("$N0=")
            self.write("$N1=")
        elif cmd == "$X":
            if sup.alarm or sup.rt_dead:
                try:
                    sup.unlock()
                except MotionRefused as e:     # say why before the error code (the rt side stays down)
                    self.write(f"[MSG:{e}]")
                    self.log(f"$X refused: {e}")
                    raise
                self.interp.sync(*sup.pose())
                self.write("[MSG:Caution: Unlocked]")
        elif cmd == "$C":
            if sup.check_mode:
                sup.check_mode = False
                self.write("[MSG:Disabled]")
                self.write("ok")               # the answer to $C, then grbl's automatic reset
                self.soft_reset()
            elif not idle_like or sup.alarm:
                raise LineError(8, "$C only when idle")
            else:
                sup.check_mode = True
                self.write("[MSG:Enabled]")
        elif cmd == "$H":
            if self.homing is None:
                raise LineError(5, "homing is not available on this backend")
            if self.state() not in ("Idle", "Alarm"):
                raise LineError(8, "$H only when idle")
            ok, msg = self.homing()
            if not ok:
                return
            self.interp.sync(*sup.pose())
            self._persist()
        elif cmd.startswith("$J="):
            if self.state() not in ("Idle", "Jog"):
                raise LineError(8 if not sup.alarm else 9, "jog only when idle or jogging")
            if self.jogger is None:
                raise LineError(3, "jogging not available")
            self.jogger(cmd[3:], self.interp)
        elif cmd.startswith("$") and "=" in cmd:
            k, _, v = cmd[1:].partition("=")
            try:                            # grbl: a setting number or value that is no number
                k, v = int(k), float(v)
            except ValueError:
                raise LineError(2, "bad number format in a $ setting") from None
            if not math.isfinite(v):
                raise LineError(2, "bad number format in a $ setting")
            if k != 10:
                raise LineError(3, f"${k} is read-only on pmctl")
            if v != int(v) or not 0 <= v <= 255:
                raise LineError(4, "$10 is a mask 0..255")
            self.settings[10] = int(v)
            self._persist()
        elif cmd in ("$SLP", "$RST=$", "$RST=#", "$RST=*"):
            raise LineError(3, "not supported")
        else:
            raise LineError(3, "unknown $ command")

    def _settings_list(self):
        m, p = self.sup.machine, self.sup.params
        switches = self.sup.ch is not None and self.sup.raw()[C.ST_HOME_IN] >= 0
        out = [(10, self.settings[10]), (13, 0), (20, 1), (21, 0), (22, 1 if self.homing and switches else 0)]
        ppm = m.resolution.pulses_per_mm
        for i in range(5):
            out.append((100 + i, f"{ppm[i]:.3f}"))
        for i in range(5):
            out.append((110 + i, f"{p.vmax[i] * 60:.3f}"))
        for i in range(5):
            out.append((120 + i, f"{p.amax[i]:.3f}"))
        for i in range(5):
            out.append((130 + i, f"{p.upper[i] - p.lower[i]:.3f}"))
        return out


def spindle_rpm(sup) -> float:
    """The speed the spindle VFD is commanded to (the programmed S with the spindle override; 0:
    stopped or no ``[spindle]``), as grbl's ``FS:`` reports it. No Modbus request: the last command."""
    sp = sup.spindle
    vfd = getattr(sp, "vfd", None)
    return abs(float(vfd.rpm_cmd)) if vfd is not None else 0.0


def one_line(text) -> str:
    """A message as one line (a ``[MSG:...]`` may not break the line protocol)."""
    return " ".join(str(text).split())


def mm3(values) -> str:
    """Numbers as grbl prints positions: 3 decimals, comma separated, never ``-0.000``."""
    return ",".join(f"{round(float(v), 3) + 0.0:.3f}" for v in values)


def axis_index(letter: str) -> int:
    return AXES.index(letter)
