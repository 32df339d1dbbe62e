"""`stepdir` backend: per-tick pulse counts to the step/dir bridge (firmware_bridge/) over a serial
link, with sequence numbers, acks and retransmit (the framing is pmctl.hal.bridge_protocol).

- ``port = "host-pty"`` (the shipped default) starts the bridge's host build as a child process on
  a pseudo-terminal (building it with ``make -C firmware_bridge`` when the binary is missing or
  older than its sources); ``port = "rp2040-emu"`` runs the RP2040 image in an emulated chip
  (:mod:`pmctl.hal.rp2040_emu`; ``make -C firmware_bridge rp2040``), and the backend then times its
  timeouts and retransmits in the chip's simulated time; any other value is a serial device opened
  with pyserial.
- ``open`` identifies the bridge (magic and protocol version: a host never drives a bridge it does
  not understand), configures it (tick, step width, direction set-up, watchdog, queue) and resets
  its counters to the controller's.
- ``write_pulses`` sends one TICK frame (tick index + signed pulses of the 5 axes) and returns.
- ``read`` takes what the bridge sent (acks, status), retransmits what was lost, waits (at most
  ``read_timeout_ms``) only while the bridge's tick queue is full, and returns the feedback:
  ``counts`` = the bridge's executed step counters; ``enc`` = those counters plus the pulses the
  bridge holds in its queue, i.e. the position the bridge is committed to. Every status sent at a
  tick start is checked against the commanded pulses *exactly*: a single lost or extra step is a
  fault, so the projection cannot drift silently. (An open-loop step/dir system has no encoder; a
  following-error check against the queue's latency would only trip on the queue itself.)
- Every fault ends in :class:`BridgeFault` (a HalError; HalTimeout for silence) with the reason
  and ``counts`` = what the bridge executed when it is known; the loop sets its counters to them.
"""

from __future__ import annotations

import collections
import os
import select
import shutil
import subprocess
import time
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from pmctl.core.errors import ConfigError
from pmctl.hal import bridge_protocol as bp
from pmctl.hal.base import Backend, Feedback, HalError, HalTimeout, Inputs, Status, switch_positions

FIRMWARE_DIR = Path(__file__).resolve().parents[3] / "firmware_bridge"
HOST_PTY = "host-pty"
EMU = "rp2040-emu"
# what the RP2040 port holds in the emulated chip (simulated time, 125 MHz; benchmarks/bench_rp2040.py):
# about 120 kstep/s on one axis and 150 k on the five together, so 20 k on each of the five at once
EMU_STEP_RATE_HZ = 20_000.0


class BridgeFault(HalError):
    """A controlled stop on the step/dir link. ``counts``: the bridge's executed counters when known
    (None when the bridge could not be reached to ask)."""

    def __init__(self, msg, counts=None):
        super().__init__(msg)
        self.counts = None if counts is None else np.array(counts, np.int64)


class BridgeTimeout(BridgeFault, HalTimeout):
    """The bridge did not answer in time."""


@dataclass
class StepDirOptions:
    port: str = HOST_PTY                 # "host-pty", "rp2040-emu" or a serial device (/dev/ttyACM0 ...)
    baud: int = 1_000_000                # serial devices only
    step_width_ns: int = 2500            # minimum step pulse high time
    dir_setup_ns: int = 5000             # direction set-up before the first step edge
    watchdog_ms: float = 100.0           # no valid tick for this long: the bridge stops and latches
    queue_ticks: int = 4                 # ticks the bridge may hold (2..4)
    prime_ticks: int = 2                 # ticks queued before stepping starts (1..queue_ticks)
    read_timeout_ms: float = 25.0        # read() blocks at most this long (only while the queue is full)
    link_timeout_ms: float = 50.0        # nothing valid from the bridge for this long: link lost
    retransmit_ms: float = 4.0           # unacknowledged frame resent after at most this long (sooner: 3 round trips)
    max_retransmits: int = 8             # and link_timeout_ms unacknowledged: the link is declared lost
    open_timeout_ms: float = 2000.0      # identify/configure/reset at open
    bridge_binary: str = ""              # host-pty: "" = firmware_bridge/build/bridge-host (made when stale)
    edge_log: str = ""                   # host-pty, rp2040-emu: file for the bridge's step-edge log ("" = none)
    control: str = ""                    # host-pty, rp2040-emu: FIFO for simulated inputs ("" = none)
    bridge_verbose: bool = False         # host-pty: let the bridge print its events on stderr
    bridge_rt_priority: int = 51         # host-pty: SCHED_FIFO priority asked for the bridge (0 = normal)
    home_switch_mm: tuple = ()           # host-pty, rp2040-emu: simulated home switches, closed at motor >= this (5 joint
                                         # positions, mm, in the counters' frame at start); () = none
    strain_ue_per_count: tuple = (0.01, 0.01, 0.01)   # strain ADC scale, microstrain per count
    strain_offset_counts: tuple = (0.0, 0.0, 0.0)     # ADC reading at zero strain
    max_step_rate_hz: float = 0.0        # steps per second per axis the bridge holds; the joints' speed is capped
                                         # to it (0: no cap, except rp2040-emu: EMU_STEP_RATE_HZ)

    def step_rate_cap(self) -> float:
        """The step rate per axis the run's joint speeds are capped to (0: none)."""
        if self.max_step_rate_hz:
            return float(self.max_step_rate_hz)
        return EMU_STEP_RATE_HZ if self.port == EMU else 0.0

    @classmethod
    def from_dict(cls, d: dict, where="hal.stepdir"):
        names = {f.name: f for f in fields(cls)}
        kw = {}
        for k, v in d.items():
            if k not in names:
                raise ConfigError(where, k, f"unknown stepdir option; known: {', '.join(names)}")
            kw[k] = v
        o = cls(**kw)
        for k in ("port", "bridge_binary", "edge_log", "control"):
            if not isinstance(getattr(o, k), str):
                raise ConfigError(where, k, f"must be a string, got {getattr(o, k)!r}")
        if not o.port:
            raise ConfigError(where, "port", 'must be "host-pty", "rp2040-emu" or a serial device path')
        if not isinstance(o.bridge_verbose, bool):
            raise ConfigError(where, "bridge_verbose", "must be true or false")

        def integer(k, lo, hi):
            v = getattr(o, k)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ConfigError(where, k, f"must be an integer within {lo} .. {hi}, got {v!r}")

        def number(k, lo, hi):
            v = getattr(o, k)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= v <= hi:
                raise ConfigError(where, k, f"must be a number within {lo:g} .. {hi:g}, got {v!r}")

        o.home_switch_mm = switch_positions(o.home_switch_mm, where, "home_switch_mm")
        integer("baud", 1200, 100_000_000)
        integer("step_width_ns", 100, 1_000_000)
        integer("dir_setup_ns", 0, 1_000_000)
        integer("queue_ticks", 2, 4)
        integer("prime_ticks", 1, o.queue_ticks)
        integer("max_retransmits", 1, 100)
        integer("bridge_rt_priority", 0, 99)
        number("watchdog_ms", 1.0, 10_000.0)
        number("read_timeout_ms", 0.1, 1000.0)
        number("link_timeout_ms", 1.0, 10_000.0)
        number("retransmit_ms", 0.1, 1000.0)
        number("open_timeout_ms", 10.0, 60_000.0)
        number("max_step_rate_hz", 0.0, 10_000_000.0)
        for k in ("strain_ue_per_count", "strain_offset_counts"):
            v = getattr(o, k)
            a = np.atleast_1d(np.asarray(v if not isinstance(v, bool) else [v], dtype=object))
            if a.ndim != 1 or len(a) not in (1, 3) or any(isinstance(x, bool) or not isinstance(x, (int, float))
                                                           for x in a):
                raise ConfigError(where, k, f"must be a number or a list of 3 numbers, got {v!r}")
            setattr(o, k, tuple(float(x) for x in np.broadcast_to(a.astype(float), (3,))))
        return o

    def check_tick(self, dt: float, where="hal.stepdir"):
        """The options against the tick period: a full-speed tick must fit the step width."""
        tick_ns = int(round(dt * 1e9))
        if 2 * self.step_width_ns + self.dir_setup_ns > tick_ns:
            raise ConfigError(where, "step_width_ns",
                              f"2 x {self.step_width_ns} ns + dir set-up {self.dir_setup_ns} ns does not fit "
                              f"in a {tick_ns} ns tick")
        if self.watchdog_ms * 1e6 < 2 * tick_ns:
            raise ConfigError(where, "watchdog_ms", f"{self.watchdog_ms:g} ms is shorter than two ticks")
        return tick_ns


def ensure_built(firmware_dir: Path = FIRMWARE_DIR) -> Path:
    """The host build of the bridge, made with ``make -C firmware_bridge`` if missing or stale."""
    d = Path(firmware_dir)
    binary = d / "build" / "bridge-host"
    if not (d / "Makefile").is_file():
        raise HalError(f"step/dir bridge: {d}/Makefile not found; the host-pty bridge needs the firmware_bridge "
                       f"folder of a source checkout (or set [hal.stepdir] bridge_binary)")
    sources = [p for p in d.iterdir() if p.suffix in (".c", ".h") or p.name == "Makefile"]
    if binary.is_file() and all(p.stat().st_mtime <= binary.stat().st_mtime for p in sources):
        return binary
    make = shutil.which("make")
    if make is None:
        raise HalError(f"step/dir bridge: 'make' not found; building {binary} needs make and a C compiler "
                       f"(Debian/Ubuntu: apt-get install build-essential)")
    cc = os.environ.get("CC", "cc")
    if shutil.which(cc) is None:
        raise HalError(f"step/dir bridge: C compiler '{cc}' not found; building {binary} needs one "
                       f"(Debian/Ubuntu: apt-get install build-essential)")
    r = subprocess.run([make, "-C", str(d)], capture_output=True, text=True)
    if r.returncode != 0 or not binary.is_file():
        tail = "\n".join((r.stderr or r.stdout).strip().splitlines()[-8:])
        raise HalError(f"step/dir bridge: 'make -C {d}' failed (exit {r.returncode}):\n{tail}")
    return binary


class _Out:
    __slots__ = ("seq", "data", "t", "t0", "tries", "type", "tick", "pulses")

    def __init__(self, seq, data, t, type_, tick=-1, pulses=None):
        self.seq, self.data, self.t, self.t0, self.tries, self.type = seq, data, t, t, 0, type_
        self.tick, self.pulses = tick, pulses


class StepDirBackend(Backend):
    name = "stepdir"
    accepts = "pulses"
    can_rereference = True        # a RESET at rest sets the bridge's counters (homing)

    @classmethod
    def validate_options(cls, table: dict, where: str) -> StepDirOptions:
        try:
            return StepDirOptions.from_dict(table, where)
        except TypeError as e:
            raise ConfigError(where, "-", str(e)) from None

    def __init__(self, machine, dt: float, options=None, *, tx_filter=None, rx_filter=None, clock=None):
        """``tx_filter``/``rx_filter`` (tests): callables applied to each outgoing frame / each
        received chunk (bytes -> bytes), to inject line noise, drops, duplicates and corruption.
        ``clock``: the time source of every timeout, s (default time.monotonic; an emulated chip's
        simulated clock, :meth:`pmctl.hal.rp2040_emu.Emulator.sim_time`, for a chip slower than real time)."""
        o = options if isinstance(options, StepDirOptions) else StepDirOptions.from_dict(options or {})
        self.opt = o
        self.dt = float(dt)
        self.tick_ns = o.check_tick(dt)
        self.ppm = np.asarray(machine.resolution.pulses_per_mm, float)
        self.max_step = bp.max_pulses(self.tick_ns, o.step_width_ns, o.dir_setup_ns, False)
        self.max_step_rev = bp.max_pulses(self.tick_ns, o.step_width_ns, o.dir_setup_ns, True)
        self.tx_filter, self.rx_filter = tx_filter, rx_filter
        self._fb = Feedback()
        self._fb.counts = np.zeros(5, np.int64)
        self._gain = np.asarray(o.strain_ue_per_count, float)
        self._offset = np.asarray(o.strain_offset_counts, float)
        self.proc = None
        self.emu = None                  # rp2040-emu: the emulated chip (pmctl.hal.rp2040_emu.Emulator)
        self._clock = clock or time.monotonic
        self._now = self._clock          # the clock of every timeout: the chip's simulated one for rp2040-emu
        self.emu_figures = {}            # rp2040-emu: what the emulator reported when it stopped
        self._t_call = 0.0               # the host's previous read() (its own lateness: _link_diagnosis)
        self._host_gap = self._host_gap_at = self._send_gap = self._send_gap_at = 0.0
        self.fd = None
        self._ser = None
        self.port = o.port
        self._open = False
        self.status_last: bp.BridgeStatus | None = None
        self.ident: bp.Ident | None = None
        self.stats = collections.Counter()

    # ---------------------------------------------------------------- link
    def _start_host_bridge(self):
        o = self.opt
        binary = Path(o.bridge_binary) if o.bridge_binary else ensure_built()
        if not binary.is_file():
            raise HalError(f"step/dir bridge: {binary} not found")
        cmd = [str(binary), "--orphan-exit-ms", "2000", "--rt-priority", str(o.bridge_rt_priority)]
        if o.edge_log:
            cmd += ["--edge-log", o.edge_log]
        if o.control:
            cmd += ["--control", o.control]
        for i, mm in enumerate(o.home_switch_mm):
            cmd += ["--home-at", f"{i}:{int(round(mm * self.ppm[i]))}"]
        if not o.bridge_verbose:
            cmd.append("--quiet")
        self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=None)
        r, _, _ = select.select([self.proc.stdout], [], [], 5.0)
        line = self.proc.stdout.readline().decode(errors="replace").strip() if r else ""
        if not line.startswith("PTY "):
            self._kill_bridge()
            raise HalError(f"step/dir bridge: {binary} did not report its pty within 5 s (got {line!r})")
        return line[4:]

    def _start_emulated_chip(self):
        from pmctl.hal.rp2040_emu import Emulator
        o = self.opt
        self.emu = Emulator(edge_log=o.edge_log or None, control=o.control or None, host_paced_ms=5.0,
                            home_at=[(i, int(round(mm * self.ppm[i]))) for i, mm in enumerate(o.home_switch_mm)])
        self._now = self.emu.sim_time
        return self.emu.port

    def _open_port(self, path: str):
        import serial
        try:
            self._ser = serial.Serial(path, baudrate=self.opt.baud, timeout=0, write_timeout=0)
        except (serial.SerialException, OSError) as e:
            raise HalError(f"step/dir bridge: cannot open {path}: {e}") from None
        self.fd = self._ser.fileno()
        os.set_blocking(self.fd, False)

    def _kill_bridge(self):
        if self.emu is not None:
            emu, self.emu = self.emu, None
            self.emu_figures = emu.stop()
            self._now = self._clock
        p = self.proc
        self.proc = None
        if p is None:
            return
        if p.poll() is None:
            p.terminate()
            try:
                p.wait(2.0)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        if p.stdout:
            p.stdout.close()

    def _write(self, data: bytes):
        if self.tx_filter is not None:
            data = self.tx_filter(data)
        mv = memoryview(data)
        t_end = self._now() + self.opt.link_timeout_ms / 1e3
        while mv:
            try:
                n = os.write(self.fd, mv)
                mv = mv[n:]
            except BlockingIOError:
                if self._now() > t_end:
                    raise self._host_fault(f"cannot write to {self.port} for {self.opt.link_timeout_ms:g} ms "
                                           f"(link blocked)")
                select.select([], [self.fd], [], 0.001)
            except OSError as e:
                raise self._host_fault(f"write to {self.port} failed: {e.strerror or e}")

    def _send(self, type_, payload=b"", *, tick=-1, pulses=None, sequenced=True):
        if not sequenced:
            self._write(bp.frame(0, type_, payload))
            return None
        seq = self.seq
        self.seq = (seq + 1) & 0xFF
        data = bp.frame(seq, type_, payload)
        out = _Out(seq, data, self._now(), type_, tick, pulses)
        self.unacked.append(out)
        self._write(data)
        return out

    def _retransmit(self, now, why):
        for o in self.unacked:
            o.tries += 1
            if o.tries > self.opt.max_retransmits and now - o.t0 > self.opt.link_timeout_ms / 1e3:
                raise self._host_fault(f"frame {o.seq} ({_TYPE_NAMES.get(o.type, o.type)}"
                                       + (f", tick {o.tick}" if o.tick >= 0 else "")
                                       + f") not acknowledged after {o.tries - 1} retransmits over "
                                       f"{(now - o.t0) * 1e3:.0f} ms ({why}): {self._link_diagnosis(now)}")
            o.t = now
            self.stats["retransmits"] += 1
            self._write(o.data)
        self._last_retx = now

    def _pump(self, wait_s: float = 0.0) -> int:
        """Reads what is there (waiting up to wait_s for the first bytes) and handles every frame;
        returns the number of frames handled."""
        try:
            if wait_s > 0:
                r, _, _ = select.select([self.fd], [], [], wait_s)
                if not r:
                    return 0
            data = os.read(self.fd, 65536)
        except BlockingIOError:
            return 0
        except OSError as e:
            raise self._host_fault(f"read from {self.port} failed: {e.strerror or e}")
        if not data:
            return 0
        if self.rx_filter is not None:
            data = self.rx_filter(data)
        frames = self.parser.feed(data)
        for f in frames:
            self._handle(f)
        return len(frames)

    def _handle(self, f: bp.Frame):
        now = self._now()
        self.t_rx = now
        if f.type == bp.T_ACK:
            try:
                a = bp.decode_ack(f)
            except ValueError:
                self.stats["bad_payload"] += 1
                return
            self._acked(a.next_seq, now)
            if a.flags & bp.ACK_DUP:
                self.stats["dup_acks"] += 1
            if a.flags & bp.ACK_REJECT:
                self.rejects.append(a)
            if a.flags & (bp.ACK_NAK | bp.ACK_FULL) and self.unacked and self.unacked[0].seq == a.next_seq:
                self.stats["naks" if a.flags & bp.ACK_NAK else "queue_full"] += 1
                if now - self._last_retx >= self.opt.retransmit_ms / 4e3:
                    self._retransmit(now, "the bridge asked for it" if a.flags & bp.ACK_NAK else "queue full")
        elif f.type == bp.T_STATUS:
            try:
                s = bp.decode_status(f)
            except ValueError:
                self.stats["bad_payload"] += 1
                return
            self._acked(s.next_seq, now)
            self._status(s)
        elif f.type == bp.T_IDENT_REPLY:
            self._ident_frame = f
        else:
            self.stats["unknown_frames"] += 1

    def _acked(self, next_seq, now):
        u = self.unacked
        while u and 0 < ((next_seq - u[0].seq) & 0xFF) <= 128:
            o = u.popleft()
            if o.tries == 0:
                rtt = now - o.t
                self.srtt = rtt if self.srtt is None else 0.875 * self.srtt + 0.125 * rtt

    def _status(self, s: bp.BridgeStatus):
        self.status_last = s
        fb = self._fb
        fb.seq += 1
        fb.counts[:] = s.counters
        fb.strain[:] = (np.asarray(s.adc, float) - self._offset) * self._gain
        if s.why == bp.WHY_TICK and s.state != bp.S_FAULT and self.base is not None and s.started >= 1:
            k = s.started - 1            # tick k just started: the counters hold ticks 0 .. k-1
            if self.next_tick - k <= len(self.cum) - 2 and k <= self.next_tick:
                exp = self.cum[k % len(self.cum)]
                if not np.array_equal(exp, fb.counts):
                    d = fb.counts - exp
                    self.mismatch = (f"bridge counters differ from the commanded pulses at the start of tick {k} "
                                     f"by {_axes(d)} steps")
        if s.state == bp.S_FAULT and self.fault is None:
            self.fault = s

    # ---------------------------------------------------------------- faults
    def _host_fault(self, why: str) -> BridgeFault:
        """A fault the host detected: ask the bridge to stop (STOP is honoured even out of sequence)
        and read its final counters, so the controller's counters equal what it executed."""
        if self._stopping:
            return BridgeFault(f"step/dir bridge: {why}")
        self._stopping = True
        self._dead = True
        counts = None
        try:
            self.tx_filter = None         # the injected faults apply to the job, not to the stop
            self.rx_filter = None
            self.unacked.clear()          # abandoned: the bridge's counters will say what ran
            t_end = self._now() + max(self.opt.link_timeout_ms, 20.0) / 1e3
            data = bp.frame(self.seq, bp.T_STOP)
            last = 0.0
            while self._now() < t_end:
                if self._now() - last > 0.005:
                    os.write(self.fd, data)
                    last = self._now()
                self._pump(0.002)
                if self.fault is not None and self.status_last is not None and self.status_last.state == bp.S_FAULT:
                    counts = self.status_last.counters
                    break
        except (OSError, HalError):
            pass
        if counts is None:
            last = self.status_last
            known = f"; last counters heard at tick {last.done}: {_axes(last.counters)}" if last else ""
            return BridgeTimeout(f"step/dir bridge: {why}; the bridge did not answer a stop, so what it executed "
                                 f"is unknown (its watchdog stops it within {self.opt.watchdog_ms:g} ms){known}")
        s = self.status_last
        return BridgeFault(f"step/dir bridge: {why}; stopped the bridge: it executed {s.done} ticks, "
                           f"not executed {_axes(s.not_executed)} pulses", counts)

    def _bridge_fault(self, s: bp.BridgeStatus) -> BridgeFault:
        self._dead = True
        in_flight = self.next_tick - s.next_tick
        extra = ""
        if s.faults & bp.F_WATCHDOG:
            quiet = self._now() - self.t_send
            late = ""
            if quiet * 1e3 > 0.5 * self.opt.watchdog_ms:
                late = ": the host was late (not scheduled, or stopped)"
            elif self._send_gap * 1e3 > 0.5 * self.opt.watchdog_ms:
                late = f", {self._send_gap * 1e3:.0f} ms after the one before: the host was late (not scheduled)"
            extra = (f" [the bridge had no valid tick for {((s.fault_us - s.last_tick_rx_us) % 2**32) / 1e3:.1f} ms; the host "
                     f"sent its last tick frame {quiet * 1e3:.1f} ms ago{late}]")
        return BridgeFault(
            f"step/dir bridge stopped: {s.fault_text()}{extra} (tick {s.done} of {self.next_tick} sent); not executed: "
            f"{_axes(s.not_executed)} pulses over {s.dropped_ticks} ticks"
            + (f", plus {in_flight} ticks still in flight (refused)" if in_flight > 0 else ""), s.counters)

    # ---------------------------------------------------------------- Backend API
    def open(self, counts):
        o = self.opt
        counts = np.asarray(counts, np.int64)
        if np.any(np.abs(counts) > 2**31 - 1 - 10**6):
            raise HalError(f"step/dir bridge: counters {counts.tolist()} do not fit the bridge's int32 counters")
        self.parser = bp.Parser()
        self.unacked = collections.deque()
        self.rejects = []
        self.seq = 0
        self.srtt = None
        self._last_retx = 0.0
        self._stopping = False
        self._dead = False
        self.fault = None
        self.mismatch = ""
        self.base = None
        self.next_tick = 0
        self.cum = np.zeros((64, 5), np.int64)
        self._dir = np.ones(5, np.int64)          # direction per axis as the bridge will have it (RESET: +)
        self._ident_frame = None
        self._fb.seq = 0
        try:
            if o.port == HOST_PTY:
                self.port = self._start_host_bridge()
            elif o.port == EMU:
                self.port = self._start_emulated_chip()
            self._open_port(self.port)
            self._handshake(counts)
        except BaseException:
            self.close()
            raise
        self.t_rx = self.t_send = self._t_call = self._now()
        self._host_gap = self._host_gap_at = self._send_gap = self._send_gap_at = 0.0
        self._open = True

    def _handshake(self, counts):
        o = self.opt
        t_end = self._now() + o.open_timeout_ms / 1e3
        # identify: any SEQ; the bridge restarts its expected sequence from ours
        while self._ident_frame is None:
            if self._now() > t_end:
                raise HalTimeout(f"step/dir bridge at {self.port}: no answer to IDENTIFY within "
                                 f"{o.open_timeout_ms:g} ms (is it a pmctl bridge, and the baud rate {o.baud}?)")
            self._write(bp.frame(self.seq, bp.T_IDENT))
            t_try = self._now() + 0.1
            while self._ident_frame is None and self._now() < t_try:
                self._pump(0.01)
        try:
            self.ident = bp.decode_ident(self._ident_frame)
        except ValueError as e:
            raise HalError(f"step/dir bridge at {self.port}: {e}; not driving it") from None
        if self.ident.naxes != 5:
            raise HalError(f"step/dir bridge at {self.port} has {self.ident.naxes} axes; pmctl needs 5")
        if self.ident.queue_max < o.queue_ticks:
            raise HalError(f"step/dir bridge at {self.port} queues at most {self.ident.queue_max} ticks; "
                           f"queue_ticks = {o.queue_ticks}")
        self.seq = (self.seq + 1) & 0xFF
        self.unacked.clear()
        # a bridge still moving for a previous host is stopped first
        self._pump(0.02)
        s = self.status_last
        if s is not None and s.state in (bp.S_RUNNING, bp.S_DRAINING, bp.S_ARMED):
            self._command(bp.T_STOP, b"", t_end, "STOP")
        self._command(bp.T_CONFIG, bp.config_payload(self.tick_ns, o.step_width_ns, o.dir_setup_ns,
                                                     int(o.watchdog_ms * 1000), o.queue_ticks, o.prime_ticks),
                      t_end, "CONFIG")
        self.fault = None
        self._command(bp.T_RESET, bp.reset_payload(counts), t_end, "RESET")
        self.base = counts.copy()
        self.cum[0] = counts
        self.fault = None
        self._fb.counts[:] = counts
        self._fb.enc[:] = counts / self.ppm

    def _command(self, type_, payload, t_end, name):
        self.rejects.clear()
        out = self._send(type_, payload)
        while out in self.unacked:
            now = self._now()
            if now > t_end:
                raise HalTimeout(f"step/dir bridge at {self.port}: {name} not acknowledged")
            if now - out.t > self.opt.retransmit_ms / 1e3 * 5:
                self._retransmit(now, name)
            self._pump(0.005)
        for a in self.rejects:
            if a.type == type_:
                s = self.status_last
                extra = f": {s.fault_text()}" if s is not None and a.code == bp.E_FAULT else ""
                raise HalError(f"step/dir bridge at {self.port} refused {name}: "
                               f"{bp.REJECT_TEXT.get(a.code, a.code)}{extra}")

    def read(self):
        if not self._open:
            raise HalError("step/dir bridge: read before open")
        if self._dead:
            raise BridgeFault("step/dir bridge: already stopped after a fault")
        o = self.opt
        t0 = self._now()
        if t0 - self._t_call > self._host_gap or t0 - self._host_gap_at > o.link_timeout_ms / 1e3:
            self._host_gap = t0 - self._t_call  # the longest the host was away between two reads, recently
            self._host_gap_at = t0
        self._t_call = t0
        t_end = t0 + o.read_timeout_ms / 1e3
        self._pump()
        while True:
            self._check()
            now = self._now()
            if self.unacked and now - self.unacked[0].t > self._rto():
                self._retransmit(now, f"no ack within {self._rto() * 1e3:.1f} ms")
            s = self.status_last
            started = s.started if s is not None else 0
            if self.next_tick - started < o.queue_ticks and len(self.unacked) < 32:
                break                                        # room for this tick's frame
            if now >= t_end and self._pump() == 0:      # a last look: the host may have been descheduled
                if self.unacked:
                    u = self.unacked[0]
                    why = (f"{len(self.unacked)} frames not acknowledged (the oldest, tick {u.tick}, sent "
                           f"{u.tries + 1} times; the bridge counted {s.rx_bad if s else '?'} bad frames): "
                           + self._link_diagnosis(now))
                else:
                    why = (f"the bridge's tick queue stayed full for {o.read_timeout_ms:g} ms "
                           f"(state {bp.STATE_NAMES.get(s.state, s.state) if s else '?'}, "
                           f"{self.next_tick - started} ticks waiting)")
                    if now - self.t_rx >= 0.5 * o.read_timeout_ms / 1e3:
                        why += f": {self._link_diagnosis(now, since=self.t_rx)}"
                raise self._timeout(why)
            if now >= t_end:
                continue
            self._pump(min(t_end - now, self._rto() / 2))
        if self._now() - self.t_rx > o.link_timeout_ms / 1e3:
            raise self._timeout(f"nothing from the bridge for {o.link_timeout_ms:g} ms (link lost)")
        self._fb.enc[:] = self.cum[self.next_tick % len(self.cum)] / self.ppm
        return self._fb

    def _link_diagnosis(self, now, since=None) -> str:
        """Why frames went unacknowledged, from what the host saw: the host itself away (not scheduled),
        the bridge silent (a host-pty bridge is a process on this computer: not scheduled, or dead), or
        the bridge answering while frames were lost (the line)."""
        silent = now - self.t_rx
        limit = self.opt.link_timeout_ms / 1e3
        oldest = since if since is not None else self.unacked[0].t0 if self.unacked else now
        if self._host_gap > limit and self._host_gap_at >= oldest:
            return (f"the host was late: {self._host_gap * 1e3:.0f} ms passed between two of its ticks (it was not "
                    f"scheduled: CPU load), longer than link_timeout_ms {self.opt.link_timeout_ms:g}")
        if self.t_rx <= oldest + 0.002:              # nothing heard since (about) the oldest frame went out
            who = ("the host-pty bridge is a process on this computer: not scheduled (CPU load) or dead"
                   if self.opt.port == HOST_PTY else "the bridge stopped answering (power, cable, reset?)")
            return f"nothing from the bridge for {silent * 1e3:.0f} ms ({who}); link lost"
        return (f"the bridge answered {silent * 1e3:.0f} ms ago but did not take these frames: link corrupted "
                f"(bad CRCs, lost bytes)")

    def _rto(self) -> float:
        """Retransmit timeout, s: 3 smoothed round trips + 0.5 ms, within 1 ms .. retransmit_ms."""
        cap = self.opt.retransmit_ms / 1e3
        if self.srtt is None:
            return cap
        return min(cap, max(0.001, 3 * self.srtt + 0.0005))

    def _timeout(self, why) -> BridgeFault:
        e = self._host_fault(why)
        if isinstance(e, HalTimeout):
            return e
        return BridgeTimeout(str(e), e.counts)

    def _check(self):
        if self.fault is not None:
            raise self._bridge_fault(self.fault)
        if self.mismatch:
            raise self._host_fault(self.mismatch)
        for a in self.rejects:
            if a.type == bp.T_TICK and a.code != bp.E_FAULT:
                raise self._host_fault(f"the bridge refused a tick: {bp.REJECT_TEXT.get(a.code, a.code)}")

    def write_pulses(self, pulses):
        if self._dead or not self._open:
            raise HalError("step/dir bridge: not running")
        p = np.asarray(pulses, np.int64)
        a = np.abs(p)
        sg = np.sign(p)
        # the bridge's limit: one pulse fewer when the direction changes (set-up time)
        rev = (sg != 0) & (sg != self._dir)
        lim = np.where(rev, self.max_step_rev, self.max_step)
        if np.any(a > lim):
            i = int(np.argmax(a - lim))
            raise self._host_fault(f"{abs(int(p[i]))} pulses on {bp.AXES[i]} in one tick exceed the "
                                   f"{int(lim[i])} a {self.tick_ns} ns tick holds at a {self.opt.step_width_ns} ns "
                                   f"step width" + (" after a direction change" if rev[i] else "") + "; not sent")
        self._dir = np.where(sg != 0, sg, self._dir)
        k = self.next_tick
        n = len(self.cum)
        self.cum[(k + 1) % n] = self.cum[k % n] + p
        self._send(bp.T_TICK, bp.tick_payload(k, p), tick=k, pulses=p)
        self.next_tick = k + 1
        now = self._now()
        if now - self.t_send > self._send_gap or now - self._send_gap_at > 1.0:
            self._send_gap = now - self.t_send     # the longest gap between two tick frames, in the last second
            self._send_gap_at = now
        self.t_send = now

    def status(self):
        if self.fault is not None:
            return Status(False, self.fault.fault_text())
        return Status(not self._dead, "")

    def inputs(self) -> Inputs:
        """The bridge's inputs as last reported: home switches (bits 0-4), E-stop (bit 5), and the
        bridge's own latch of each home switch's last transition (the counter at that step, exact)."""
        s = self.status_last
        if s is None:
            return Inputs((False,) * 5, False)
        return Inputs(tuple(bool(s.inputs >> i & 1) for i in range(5)), bool(s.inputs & bp.IN_ESTOP), s.latches())

    def rereference(self, counts):
        """Homing, at rest: the bridge runs out its queue (END), checks that it executed exactly what was
        commanded, and a RESET sets its counters to ``counts`` (the motors do not move). Takes a few
        ticks of the link; the next tick starts the bridge's tick index at 0 again."""
        counts = np.asarray(counts, np.int64)
        err = self._finish()                  # END, wait for idle, counters = commanded
        if err is not None:
            self._dead = True
            raise err
        t_end = self._now() + self.opt.open_timeout_ms / 1e3
        try:
            self.fault = None
            self._command(bp.T_RESET, bp.reset_payload(counts), t_end, "RESET")
        except HalError as e:
            self._dead = True
            raise BridgeFault(f"step/dir bridge: re-reference: {e}", self.status_last.counters
                              if self.status_last is not None else None) from None
        # every frame after the RESET's ack is from after it: wait for a status of the new counters
        # (the queue accounting and the latches must not read the old one)
        self.status_last = None
        self._send(bp.T_STATUS_REQ, sequenced=False)
        while self.status_last is None:
            if self._now() > t_end:
                self._dead = True
                raise BridgeTimeout("step/dir bridge: no status after the re-reference's RESET")
            self._pump(0.005)
        self.base = counts.copy()
        self.next_tick = 0
        self.cum[0] = counts
        self._dir[:] = 1                      # RESET sets every direction output to +
        self._fb.counts[:] = counts
        self._fb.enc[:] = counts / self.ppm
        self.t_rx = self.t_send = self._t_call = self._now()

    def close(self):
        """Runs out the bridge's queue (END), checks that it executed exactly what was commanded,
        and closes the link (stopping the host bridge process it started). Raises BridgeFault if the
        final counters differ from the commanded ones (the position would be wrong)."""
        err = None
        try:
            if self._open and not self._dead and self.fd is not None:
                err = self._finish()
        finally:
            self._open = False
            if self._ser is not None:
                try:
                    self._ser.close()
                except Exception:        # noqa: BLE001 - closing a dead port must not mask the result
                    pass
                self._ser = None
                self.fd = None
            self._kill_bridge()
        if err:
            raise err

    def _finish(self):
        o = self.opt
        try:
            self._send(bp.T_END)
            t_end = self._now() + (o.queue_ticks + 2) * self.dt + o.link_timeout_ms / 1e3
            while self._now() < t_end:
                now = self._now()
                if self.unacked and now - self.unacked[0].t > o.retransmit_ms / 1e3:
                    self._retransmit(now, "END")
                self._pump(0.002)
                s = self.status_last
                if not self.unacked and s is not None and s.state in (bp.S_IDLE, bp.S_FAULT) \
                        and (s.state == bp.S_FAULT or s.done >= self.next_tick):
                    break
            self._send(bp.T_STATUS_REQ, sequenced=False)
            self._pump(0.01)
        except HalError as e:
            return e
        s = self.status_last
        want = self.cum[self.next_tick % len(self.cum)]
        # a bridge whose watchdog tripped after it had executed every tick (the host slow to say END:
        # a loaded computer shutting down) lost nothing: its counters are the commanded ones
        benign = (s is not None and s.state == bp.S_FAULT and s.faults == bp.F_WATCHDOG
                  and not any(s.not_executed) and s.done >= self.next_tick)
        if s is None or (s.state != bp.S_IDLE and not benign) or not np.array_equal(np.asarray(s.counters), want):
            got = "nothing" if s is None else (f"{bp.STATE_NAMES.get(s.state)} ({s.fault_text()}), counters "
                                              f"{_axes(s.counters)}")
            return BridgeFault(f"step/dir bridge: at the end it reports {got}; commanded {_axes(want)}",
                               None if s is None else s.counters)
        return None


_TYPE_NAMES = {bp.T_IDENT: "IDENT", bp.T_CONFIG: "CONFIG", bp.T_RESET: "RESET", bp.T_TICK: "TICK",
               bp.T_END: "END", bp.T_STOP: "STOP"}


def _axes(v) -> str:
    return "(" + ", ".join(f"{a} {int(x)}" for a, x in zip(bp.AXES, v)) + ")"
