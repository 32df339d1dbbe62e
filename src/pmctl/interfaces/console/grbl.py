"""The operator console: grbl 1.1's serial protocol on a pty or a serial device.

Two threads:
- the reader takes bytes as they come. Realtime bytes act at once, also in the middle of a line:
  ``?`` status report, ``!`` feed hold, ``~`` cycle start, 0x18 soft reset, 0x85 jog cancel,
  0x90-0x94 feed override (100 %, +10, -10, +1, -1; 10-200 %), 0x95-0x97 rapid override (100, 50,
  25 %), 0x99-0x9D spindle override (100 %, +10, -10, +1, -1; 10-200 %: the VFD's set-point when a
  ``[spindle]`` is configured), 0x9E spindle stop in a hold. Other bytes collect into
  lines (``\\n`` or ``\\r`` ends one); a line longer than ``LINE_MAX`` is dropped whole with error:11.
- the worker executes lines in order and answers each with ``ok`` or ``error:N``. A motion line is
  answered once it is checked (reader, reachability of its poses and of the path to them) and its
  blocks have entered the planner queue: ``PLANNER_BLOCKS`` blocks (moves) accepted and not yet
  executed, the depth ``[OPT:]`` and ``Bf:`` advertise. It counts every block from its ``ok`` until
  the rt side has run past it: the ones waiting for the look-ahead that settles them, the ones being
  planned and the ones whose samples wait in the sample ring ahead of the tool (the look-ahead the
  time-scaling needs to stop on the path). When it is full the answer waits (grbl's full planner
  buffer), so a character-counting sender is paced by the motion.
  Accepted blocks go at once into the supervisor's open stream (Supervisor.stream): one job that
  grows as they come, planned window by window once the blocks after a window settle it
  (pmctl.task.stream_planner), so a streamed program runs as ``pmctl run`` runs the same file,
  without stops between lines. The stream is planned to rest at its last block at M2/M30 (whose
  ``ok`` comes when the program's end is queued; ``[MSG:Pgm End]`` follows when the machine gets
  there), at a G4 and a probe, and when the sender starves the queue (the supervisor decides:
  little motion left queued and no block coming).
- a probing line (G38.2/G38.3) is executed as grbl does: the queued motion is sent, the probe goes
  alone, and the line is answered once the probe has ended -- ``[PRB:x,y,z,a,b:1]`` (``:0``
  without contact; after ``ALARM:5`` for a G38.2 without contact) then ``ok`` -- and the lines after
  it are read from where the probe stopped. The answer comes once the probe has come to rest, so a
  jog or a ``$`` command that needs Idle may follow at once.
- M-codes take effect in program order where the stream gets to them: a line's spindle (M3 M4 M5 S),
  coolant (M7 M8 M9), tool change (M6), pause (M0 M1), output and message words come from the
  interpreter as EVENT moves (pmctl.core.job) queued with the motion; the supervisor holds the path
  where each takes effect (a lone one at once when idle).

A bad line changes nothing: not the queued motion, not the parser state, not the next line.
"""

from __future__ import annotations

import collections
import copy
import math
import os
import queue
import select
import threading
import time

import numpy as np

from pmctl import __version__
from pmctl.motion.probe import check_probe_feeds
from pmctl.task.interp import AXES, WCS_NAMES, LineError, LineInterpreter, moves_job
from pmctl.core.job import DWELL, EVENT, Job
from pmctl.task.planner import PlannerLimits, _PathBuilder, check_segments
from pmctl.task.supervisor import roll_pitch_deg
from pmctl.core.errors import InputError, MotionRefused

RX_BUFFER = 128
LINE_MAX = 256
PLANNER_BLOCKS = 128              # the planner queue's depth in blocks (moves): [OPT:VN,128,128], Bf:
MAX_QUEUED_ITEMS = 3              # items queued before a probe is queued (it waits for room)
BANNER = "Grbl 1.1h ['$' for help]"
HELP = "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $C $X $H ~ ! ? ctrl-x]"

RT_STATUS, RT_HOLD, RT_START, RT_RESET = 0x3F, 0x21, 0x7E, 0x18
RT_DOOR, RT_JOG_CANCEL = 0x84, 0x85


class GrblConsole:
    def __init__(self, sup, fd: int, journal, *, log=None, homing=None, jogger=None, present=None):
        self.sup = sup
        self.fd = fd
        self.present = present or (lambda: True)   # a sender has the port open (a pty can tell)
        self.connected = False
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
        # a soft reset drops the line being executed: it queues no motion (the check of its reset
        # generation and its submit are one step against the reset's increment, _queue_motion) and
        # leaves the parser as the reset sets it (the reset waits for the line to end: _line_lock)
        self._queue_lock = threading.Lock()
        self._line_lock = threading.RLock()   # (RLock: $C's automatic reset runs inside its line)
        self._line_gen = 0                    # the reset generation of the line being executed
        self.blocks = collections.deque()     # [console line, blocks, item] accepted, not run
        self._blocks_lock = threading.Lock()  # the reader (Bf:) and the worker both take run blocks off its front
        self._rx_lock = threading.Lock()
        self._rx_pending = 0                  # bytes of lines received and not yet answered (Bf:'s second field)
        self._line_bytes = 0
        self._pgm_end = []                    # items ending with M2/M30: [MSG:Pgm End] when they have run
        self._last_item = None                # the last item the console queued
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
        if not self.present():
            return                         # nobody on the pty: it would wait there for the next sender
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
        elif event in ("error", "pause", "message"):
            self.write(f"[MSG:{one_line(detail['msg'])}]")

    # ------------------------------------------------------------ life
    def start(self):
        if self.present():                 # a serial device (or a sender already on the pty)
            self.connected = True
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
            if not self._check_client():
                time.sleep(0.05)
                continue
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
                if self.connected:
                    self.connected = False
                    self.log("console: the sender closed the port")
                time.sleep(0.005)
                continue
            if not data:
                time.sleep(0.05)
                continue
            self.feed(data)

    def _check_client(self) -> bool:
        """Whether a sender is there; one that has just opened the pty is greeted as a grbl board
        greets when its port is opened (the banner; nothing is reset: queued motion goes on)."""
        present = self.present()
        if present and not self.connected:
            self.connected = True
            self.log("console: a sender opened the port")
            self.welcome()
        elif not present and self.connected:
            self.connected = False
            self.log("console: the sender closed the port")
        return present

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
                self._line_bytes += 1
                if self._overflow or self._buf or b == 0x0A:
                    n, self._line_bytes = self._line_bytes, 0
                    with self._rx_lock:
                        self._rx_pending += n
                    # (None: error:11 in order with the others)
                    self.lines.put((self._reset_gen, None if self._overflow else bytes(self._buf), n))
                self._buf.clear()
                self._overflow = False
            else:
                self._line_bytes += 1
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
        with self._queue_lock:                # the line in execution queues nothing from here on
            self._reset_gen += 1
        self._buf.clear()
        self._overflow = False
        self._line_bytes = 0
        while True:                           # drop the queued lines, to the last (the worker may take it first)
            try:
                self.lines.get_nowait()
            except queue.Empty:
                break
        with self._rx_lock:
            self._rx_pending = 0              # the unanswered lines are dropped (grbl clears its RX buffer)
        with self._blocks_lock:
            self.blocks.clear()
        self._pgm_end.clear()
        self.sup.soft_reset()
        with self._line_lock:                 # (its waits see the new generation and end it at once)
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
        """The machine state as the sender sees it: Run as soon as a motion line is accepted (its
        stream is queued, planned or not)."""
        return self.sup.state_name()

    def n_word(self) -> int:
        """The N word of the line being executed (0: the line had none; grbl reports Ln only then)."""
        sup = self.sup
        line = sup.status().line
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
        acc = accessories(sup)
        if acc:
            parts.append(f"A:{acc}")
        if self.settings[10] & 2:
            parts.append(f"Bf:{max(0, PLANNER_BLOCKS - self.queued_blocks())},{max(0, RX_BUFFER - self._rx_pending)}")
        line = self.n_word()
        if line > 0 and state not in ("Idle", "Alarm", "Jog"):
            parts.append(f"Ln:{line}")
        rt = sup.status()
        fo = int(round(rt.feed_override * 100)) or self.feed_ov
        ro = int(round(rt.rapid_override * 100)) or self.rapid_ov
        parts.append(f"Ov:{fo},{ro},{self.spindle_ov}")
        parts.append("WCO:" + mm3(wco))
        return "<" + "|".join(parts) + ">"

    # ------------------------------------------------------------ the planner queue
    def queued_blocks(self) -> int:
        """Blocks in the planner queue: accepted (answered) and not yet run past by the rt side; the
        ones run past are dropped from its front (they complete in order)."""
        with self._blocks_lock:
            return self._queued_blocks()

    def _queued_blocks(self) -> int:
        sup, blocks = self.sup, self.blocks
        line = None
        while blocks:
            seq, _n, it = blocks[0]
            if not sup.retired(it):
                with sup._lock:
                    head = sup.items[0] if sup.items else None
                if head is not it:
                    break
                if line is None:
                    line = sup.status().line
                if line <= seq:                  # the tool is on this block (or before it)
                    break
            blocks.popleft()
            it.lines.pop(seq, None)          # (the stream's map of N words: what is still to run)
        return sum(n for _, n, _ in blocks)

    def _wait_room(self, n: int, gen) -> bool:
        """grbl's full planner buffer: wait until ``n`` more blocks fit (or the queue is empty); the
        open stream knows meanwhile that no block comes before the tool runs past one. False: a
        reset or an alarm ended it."""
        if self.queued_blocks() + n <= PLANNER_BLOCKS or not self.blocks:
            return True
        self.sup.stream_waiting(True)
        try:
            while self.queued_blocks() + n > PLANNER_BLOCKS and self.blocks:
                if gen != self._reset_gen or self._stop.is_set() or self.sup.alarm or self.sup.rt_dead:
                    return False
                time.sleep(0.005)
        finally:
            self.sup.stream_waiting(False)
        return True

    def _announce_ends(self):
        """[MSG:Pgm End] for the programs whose M2/M30 the machine has reached."""
        while self._pgm_end and self.sup.retired(self._pgm_end[0]):
            self._pgm_end.pop(0)
            self.write("[MSG:Pgm End]")

    # ------------------------------------------------------------ lines
    def _worker(self):
        while not self._stop.is_set():
            try:
                gen, raw, nbytes = self.lines.get(timeout=0.02)
            except queue.Empty:
                self._announce_ends()
                continue
            if gen != self._reset_gen:
                continue
            answer = None
            if raw is None:
                answer = "error:11"
            else:
                try:
                    text = raw.decode("ascii")
                except UnicodeDecodeError:
                    answer = "error:1"
            if answer is None:
                with self._line_lock:
                    try:
                        self.execute(text.strip(), gen)
                        answer = "ok"
                    except LineError as e:
                        answer = f"error:{e.code}"
                    except MotionRefused as e:
                        answer = f"error:{e.code}"
                    except Exception as e:              # a bug must not kill the console
                        self.log(f"console: {type(e).__name__}: {e}")
                        answer = "error:20"
            with self._queue_lock:        # (the answer comes before the reset's banner, or not at all)
                if gen != self._reset_gen:
                    continue              # a soft reset dropped the line meanwhile: no answer (grbl's)
                with self._rx_lock:
                    self._rx_pending = max(0, self._rx_pending - nbytes)
                if answer is not None:
                    self.write(answer)
            self._announce_ends()

    def execute(self, text: str, gen: int = 0):
        self._line_gen = gen
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
        # motion from elsewhere (a jog, a job from the control socket, a hold) may have moved the
        # machine: the parser continues from where the queued motion ends
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
        # grbl synchronises on G4 (mc_dwell): the answer comes once all queued motion has run and the
        # dwell elapsed -- a sender's way to know the buffer is empty. M2/M30 are answered when the
        # program's end is queued; [MSG:Pgm End] when the machine gets there
        sync = not self.sup.check_mode and any(m.kind == DWELL for m in moves)
        if moves and not self.sup.check_mode:
            self._check_path(st0, moves)
            n = sum(1 for m in moves if m.kind != DWELL)
            if n and not self._wait_room(n, gen):
                if gen != self._reset_gen:
                    return                # a soft reset dropped the line: no answer
                raise MotionRefused("an alarm stopped the motion this line waited for", 9)
            try:
                it = self._queue_motion(gen, lambda: self.sup.stream(moves, {self.seq: n_word}))
            except MotionRefused:
                self.interp.st = st0
                raise
            if it is None:
                return                    # a soft reset dropped the line: no answer
            self._last_item = it
            if n:
                with self._blocks_lock:
                    self.blocks.append([self.seq, n, it])
        if flags.get("end") or sync:
            it = self.sup.stream_close()
            if flags.get("end") and not self.sup.check_mode:
                if it is None and self.sup.busy():
                    it = self._last_item      # an end line without motion: the end is where the queued motion ends
                if it is not None:
                    self._pgm_end.append(it)
                elif not self.sup.busy():
                    self.write("[MSG:Pgm End]")
        if sync and not self._synchronize(gen):
            return                    # a soft reset dropped the line: no answer

    def _queue_motion(self, gen, submit):
        """``submit()`` (queue a line's motion) unless a soft reset dropped the line (reset generation
        ``gen``): then None. One step against the reset's increment, so a line the reset dropped never
        moves, not even once the reset is over."""
        with self._queue_lock:
            if gen != self._reset_gen:
                return None
            return submit()

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

    def _check_path(self, st0, moves):
        """The path of a line's moves from where the queued motion ends (where the line starts),
        checked before its ``ok`` as the planner checks it (every grid step reachable: an arc or a
        tilt may leave the workspace between reachable ends): error:33 naming what is unreachable,
        and the parser state back to ``st0`` (before the line)."""
        moving = [m for m in moves if m.kind not in (DWELL, EVENT)]
        if not moving:
            return
        tip, axis = self.sup.end_pose()
        start = (np.array(tip, float), np.array(axis, float))
        lim = PlannerLimits()
        pb = _PathBuilder(start, lim, 1.0, self.sup.dt, "console")
        try:
            for m in moving:
                pb.add(m)
            check_segments(pb.path(), Job((), "console"), self.sup.plan_machine, lim)
        except InputError as e:
            self.interp.st = st0
            raise LineError(33, f"path unreachable: {e.reason}") from None

    def _queue_alone(self, moves, lines, gen=None):
        """A probe's moves as an item of their own (after the open stream, which is closed)."""
        self.sup.stream_close()
        while self.sup.queued_items() >= MAX_QUEUED_ITEMS:
            if (gen is not None and gen != self._reset_gen) or self._stop.is_set() or self.sup.alarm:
                return None
            time.sleep(0.01)
        try:
            it = self._queue_motion(self._line_gen if gen is None else gen, lambda: self.sup.submit(
                moves_job(moves, "console"), kind="gcode", name="console", lines=lines))
        except MotionRefused:
            return None
        if it is not None:
            self._last_item = it
        return it

    def _probe(self, moves, n_word, st0, gen):
        """A G38.2/G38.3 line, as grbl runs it: the motion queued before it goes first, the probe is
        planned alone, and the line is answered when the probe has ended ([PRB:...] then ok); the
        parser continues from where the probe stopped."""
        try:
            check_probe_feeds(moves_job(moves), self.sup.svc.probe, "console", self.sup.plan_feed_override)
        except InputError as e:
            self.interp.st = st0
            self.write(f"[MSG:{e.reason}]")
            raise LineError(20, e.reason) from None
        it = self._queue_alone(list(moves), {self.seq: n_word}, gen)
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
        while not self.sup.retired(it):   # grbl answers once the probe cycle has come to rest (Idle)
            if gen != self._reset_gen or self._stop.is_set() or it.gen != self.sup._gen or self.sup.rt_dead \
                    or self.sup.alarm:
                break
            time.sleep(0.005)
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
            self.write(f"[OPT:VN,{PLANNER_BLOCKS},{RX_BUFFER}]")
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
            self._queue_motion(self._line_gen, lambda: self.jogger(cmd[3:], self.interp))
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
        switches = self.sup.ch is not None and self.sup.status().home_in >= 0
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




def accessories(sup) -> str:
    """grbl's ``A:`` field: S spindle clockwise, C counter-clockwise, F flood, M mist ("" when none)."""
    rpm = spindle_rpm(sup, signed=True)
    out = "S" if rpm > 0 else "C" if rpm < 0 else ""
    return out + ("F" if "flood" in sup.coolant else "") + ("M" if "mist" in sup.coolant else "")





def spindle_rpm(sup, signed=False) -> float:
    """The speed the spindle VFD is commanded to (the programmed S with the spindle override; 0:
    stopped or no ``[spindle]``), as grbl's ``FS:`` reports it. No Modbus request: the last command."""
    sp = sup.spindle
    vfd = getattr(sp, "vfd", None)
    rpm = float(vfd.rpm_cmd) if vfd is not None else 0.0
    return rpm if signed else abs(rpm)


def one_line(text) -> str:
    """A message as one line (a ``[MSG:...]`` may not break the line protocol)."""
    return " ".join(str(text).split())


def mm3(values) -> str:
    """Numbers as grbl prints positions: 3 decimals, comma separated, never ``-0.000``."""
    return ",".join(f"{round(float(v), 3) + 0.0:.3f}" for v in values)


def axis_index(letter: str) -> int:
    return AXES.index(letter)
