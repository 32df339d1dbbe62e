"""The spindle inverter (VFD) over Modbus TCP or RTU (a serial line), with a pymodbus client.

- ``M3``/``M4 S..`` -> set-point and run forward / reverse; ``M5`` -> stop (function codes 06 and 03).
- ``wait_at_speed``: the measured speed within ``at_speed_tolerance`` (2 %) of the command, as
  LinuxCNC's spindle-at-speed; cutting starts only then.
- ``SpindleMonitor``: polls speed and fault in its own thread (never in the tick), keeps the samples
  stamped with the loop's tick, and calls ``on_fault(reason)`` on a VFD fault or a lost link (the
  run turns that into a controlled, decelerating stop).
- The register map is config (``[spindle.registers]``); the default is the Huanyang GT map that
  LinuxCNC's ``hy_gt_vfd`` speaks: 0x1000 command (1 forward, 2 reverse, 5 stop), 0x2000 set-point
  0 .. 10000 of the maximum frequency, 0x3000 output frequency (0.01 Hz), 0x3005 speed (rpm),
  0x5000 fault.
Every error names the device (host:port, unit) and the register.
"""

from __future__ import annotations

import threading
import time
from dataclasses import asdict, dataclass, field, fields, replace

import numpy as np

from pmctl.core.errors import ConfigError
from pmctl.core.strict_toml import Table
from pmctl.hal.base import HalError, HalTimeout
from pmctl.hal.devsim import start_simulated, stop_simulated
from pmctl.hal.vfd_registers import VfdRegisters


BAUDS = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200)


@dataclass
class VfdOptions:
    enabled: bool = True
    transport: str = "tcp"           # "tcp" (Modbus TCP) or "rtu" (Modbus RTU on a serial line)
    host: str = "127.0.0.1"          # tcp
    port: int = 502                  # tcp; 0 with simulate = true: any free loopback port
    serial_port: str = ""            # rtu: the serial device; "devsim" with simulate = true
    baud: int = 19200                # rtu
    parity: str = "N"                # rtu: N, E or O
    stop_bits: int = 1               # rtu
    device_id: int = 1
    timeout_ms: float = 200.0
    max_rpm: float = 24000.0         # speed at set-point 10000 (maximum frequency)
    max_hz: float = 400.0
    at_speed_tolerance: float = 0.02
    spinup_timeout_s: float = 10.0
    poll_ms: float = 50.0
    max_missed_polls: int = 3        # consecutive unanswered polls before the link counts as lost
    simulate: bool = False           # serve a simulated VFD on host:port (loopback only)
    sim_ramp_rpm_per_s: float = 12000.0
    registers: VfdRegisters = field(default_factory=VfdRegisters)

    @classmethod
    def from_dict(cls, d: dict, where="spindle") -> "VfdOptions":
        """The ``[spindle]`` table (and ``[spindle.registers]``) read strictly
        (pmctl.core.strict_toml.Table: every key known, every value of its exact type and range);
        ConfigError(where, key, reason)."""
        t = Table(where, d, "")
        b = cls()
        pos = dict(positive=True, hi=1e15)
        _, regs = t._get("registers", {}, False)
        rt = Table(where, regs, "registers")
        rb = VfdRegisters()
        registers = VfdRegisters(**{f.name: rt.integer(f.name, default=getattr(rb, f.name), lo=0, hi=0xFFFF)
                                    for f in fields(VfdRegisters)})
        rt.finish()
        o = cls(
            enabled=t.boolean("enabled", default=b.enabled),
            transport=t.string("transport", default=b.transport, choices=("tcp", "rtu")),
            host=t.string("host", default=b.host),
            port=t.integer("port", default=b.port, lo=0, hi=65535),
            serial_port=t.string("serial_port", default=b.serial_port),
            baud=t.integer("baud", default=b.baud, lo=0, hi=10**7),
            parity=t.string("parity", default=b.parity, choices=("N", "E", "O")),
            stop_bits=t.integer("stop_bits", default=b.stop_bits, lo=1, hi=2),
            device_id=t.integer("device_id", default=b.device_id, lo=0, hi=247),
            timeout_ms=t.number("timeout_ms", default=b.timeout_ms, **pos),
            max_rpm=t.number("max_rpm", default=b.max_rpm, **pos),
            max_hz=t.number("max_hz", default=b.max_hz, **pos),
            at_speed_tolerance=t.number("at_speed_tolerance", default=b.at_speed_tolerance, **pos),
            spinup_timeout_s=t.number("spinup_timeout_s", default=b.spinup_timeout_s, **pos),
            poll_ms=t.number("poll_ms", default=b.poll_ms, **pos),
            max_missed_polls=t.integer("max_missed_polls", default=b.max_missed_polls, lo=1, hi=100),
            simulate=t.boolean("simulate", default=b.simulate),
            sim_ramp_rpm_per_s=t.number("sim_ramp_rpm_per_s", default=b.sim_ramp_rpm_per_s, **pos),
            registers=registers,
        )
        t.finish()
        if o.at_speed_tolerance >= 0.5:
            raise ConfigError(where, "at_speed_tolerance", "a fraction of the speed, e.g. 0.02 for 2 %")
        if o.transport == "tcp" and o.port == 0 and not o.simulate:
            raise ConfigError(where, "port", "0 (any free port) only with simulate = true")
        if o.baud not in BAUDS:
            raise ConfigError(where, "baud", f"must be one of {', '.join(map(str, BAUDS))}, got {o.baud!r}")
        if o.transport == "rtu":
            if o.simulate and o.serial_port != "devsim":
                raise ConfigError(where, "serial_port", f"a simulated RTU VFD is the device simulator's: "
                                                        f"serial_port = \"devsim\", not {o.serial_port!r}")
            if o.simulate and o.parity != "N":
                raise ConfigError(where, "parity", f"the simulated RTU line is a pty, which has no parity bit: "
                                                   f"parity = \"N\", not {o.parity!r}")
            if not o.simulate and not o.serial_port.startswith("/"):
                raise ConfigError(where, "serial_port", f"must be a serial device (e.g. /dev/ttyUSB0), "
                                                        f"got {o.serial_port!r}")
            if not 1 <= o.device_id <= 247:
                raise ConfigError(where, "device_id", f"an RTU unit address is 1 .. 247, got {o.device_id}")
        if not o.host:
            raise ConfigError(where, "host", "must be a host name or address")
        if o.simulate and not (o.host.startswith("127.") or o.host == "localhost"):
            raise ConfigError(where, "host", f"a simulated VFD listens on a loopback address, not {o.host}")
        r = o.registers
        addrs = [r.command, r.setpoint, r.output_freq, r.speed_rpm, r.fault]
        if len(set(addrs)) != len(addrs):
            raise ConfigError(where, "registers", f"two roles share a register: {[hex(a) for a in addrs]}")
        if len({r.run_forward, r.run_reverse, r.stop}) != 3:
            raise ConfigError(where, "registers", "run_forward, run_reverse and stop codes must differ")
        return o


class SpindleVFD:
    """Client of one inverter. Thread-safe (one request at a time)."""

    def __init__(self, opt: VfdOptions):
        self.opt = opt
        self.r = opt.registers
        self.client = None
        self._lock = threading.Lock()
        self.rpm_cmd = 0.0

    @property
    def device(self):
        o = self.opt
        if o.transport == "rtu":
            return f"spindle VFD {o.serial_port} RTU {o.baud} {o.parity}{o.stop_bits} (unit {o.device_id})"
        return f"spindle VFD {o.host}:{o.port} (unit {o.device_id})"

    def connect(self):
        o = self.opt
        if o.transport == "rtu":
            from pymodbus import FramerType  # lazy: pymodbus loads only when a Modbus device is used
            from pymodbus.client import ModbusSerialClient
            self.client = ModbusSerialClient(o.serial_port, framer=FramerType.RTU, baudrate=o.baud, bytesize=8,
                                             parity=o.parity, stopbits=o.stop_bits, timeout=o.timeout_ms / 1e3,
                                             retries=0, reconnect_delay=0)
        else:
            from pymodbus.client import ModbusTcpClient  # lazy: pymodbus loads only when a Modbus device is used
            self.client = ModbusTcpClient(o.host, port=o.port, timeout=o.timeout_ms / 1e3,
                                          retries=0, reconnect_delay=0)
        if not self.client.connect():
            raise HalError(f"{self.device}: cannot connect")
        self.read_fault()              # the link answers and the inverter is healthy, before any command
        return self

    def close(self):
        if self.client is not None:
            self.client.close()
            self.client = None

    def _read(self, addr):
        from pymodbus.exceptions import ModbusException  # lazy: pymodbus loads only when a Modbus device is used
        with self._lock:
            try:
                rr = self.client.read_holding_registers(addr, count=1, device_id=self.opt.device_id)
            except (ModbusException, OSError) as e:
                raise HalTimeout(f"{self.device}: {self.r.name(addr)}: link lost ({e})") from None
        if rr.isError():
            raise HalError(f"{self.device}: {self.r.name(addr)}: exception response {rr}")
        return rr.registers[0]

    def _write(self, addr, value):
        from pymodbus.exceptions import ModbusException  # lazy: pymodbus loads only when a Modbus device is used
        with self._lock:
            try:
                rr = self.client.write_register(addr, int(value), device_id=self.opt.device_id)
            except (ModbusException, OSError) as e:
                raise HalTimeout(f"{self.device}: {self.r.name(addr)} = {value}: link lost ({e})") from None
        if rr.isError():
            raise HalError(f"{self.device}: {self.r.name(addr)} = {value}: exception response {rr}")

    def read_fault(self):
        code = self._read(self.r.fault)
        if code:
            raise HalError(f"{self.device}: fault code {code} in {self.r.name(self.r.fault)}")
        return code

    def read_rpm(self) -> float:
        return float(self._read(self.r.speed_rpm))

    def start(self, rpm: float):
        """Positive rpm: forward (M3); negative: reverse (M4); 0: stop (M5)."""
        if rpm == 0:
            return self.stop()
        if abs(rpm) > self.opt.max_rpm:
            raise HalError(f"{self.device}: S{abs(rpm):g} exceeds the spindle's {self.opt.max_rpm:g} rpm")
        self.read_fault()
        if self.rpm_cmd and (rpm > 0) != (self.rpm_cmd > 0):
            # reversing: the speed register has no sign, so stop and see zero before the other way
            self.stop()
            t_end = time.monotonic() + self.opt.spinup_timeout_s
            while self.read_rpm() > 0:
                if time.monotonic() > t_end:
                    raise HalError(f"{self.device}: not at rest {self.opt.spinup_timeout_s:g} s after stop "
                                   f"(reversing), {self.r.name(self.r.speed_rpm)}")
                time.sleep(self.opt.poll_ms / 1e3)
        sp = self._setpoint(rpm)
        self._write(self.r.setpoint, sp)
        self._write(self.r.command, self.r.run_forward if rpm > 0 else self.r.run_reverse)
        self.rpm_cmd = float(rpm)

    def stop(self):
        self._write(self.r.command, self.r.stop)
        self.rpm_cmd = 0.0

    def _setpoint(self, rpm: float) -> int:
        """The set-point register's value for ``rpm``: 0 .. 10000 of max_rpm."""
        return int(round(abs(rpm) / self.opt.max_rpm * 10000))

    def at_speed(self, rpm_meas: float) -> bool:
        """Within at_speed_tolerance of the speed the set-point commands: the set-point has 10000 steps
        of max_rpm (S1 on a 24000 rpm spindle commands 0) and the speed register whole rpm, so the
        tolerance is never below one step of either."""
        want = self._setpoint(self.rpm_cmd) / 10000 * self.opt.max_rpm
        return abs(rpm_meas - want) <= max(self.opt.at_speed_tolerance * want, self.opt.max_rpm / 10000, 1.0)

    def wait_at_speed(self, sleep=time.sleep) -> float:
        t_end = time.monotonic() + self.opt.spinup_timeout_s
        while True:
            self.read_fault()
            rpm = self.read_rpm()
            if self.at_speed(rpm):
                return rpm
            if time.monotonic() > t_end:
                raise HalError(f"{self.device}: not at speed after {self.opt.spinup_timeout_s:g} s: "
                               f"{rpm:g} rpm of {abs(self.rpm_cmd):g} (tolerance "
                               f"{self.opt.at_speed_tolerance * 100:g} %) in {self.r.name(self.r.speed_rpm)}")
            sleep(self.opt.poll_ms / 1e3)


class SpindleMonitor:
    """Polls a running spindle in its own thread: rpm samples tagged with ``tick()`` (the loop's tick
    when sampled), and ``on_fault(reason)`` once on a fault or a lost link."""

    def __init__(self, vfd: SpindleVFD, tick, on_fault):
        self.vfd, self.tick, self.on_fault = vfd, tick, on_fault
        self.changer = None              # a SpeedChanger: speed changes inside the job
        self.samples: list[tuple[int, float]] = []  # (tick, signed rpm)
        self.fault = ""
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True, name="pmctl-spindle")

    def start(self):
        self._t.start()
        return self

    def _run(self):
        period = self.vfd.opt.poll_ms / 1e3
        missed = 0
        while not self._stop.is_set():
            try:
                self.vfd.read_fault()
                rpm = self.vfd.read_rpm()
                # signed like the command: negative = M4
                self.samples.append((int(self.tick()), -rpm if self.vfd.rpm_cmd < 0 else rpm))
                missed = 0
                if self.changer is not None:
                    self.changer.poll(rpm)
            except HalTimeout as e:          # one unanswered poll is no lost link yet
                missed += 1
                if missed < self.vfd.opt.max_missed_polls:
                    self._stop.wait(period)
                    continue
                self.fault = f"{e} ({missed} polls in a row)"
                self.on_fault(self.fault)
                return
            except HalError as e:
                self.fault = str(e)
                self.on_fault(self.fault)
                return
            self._stop.wait(period)

    def stop(self):
        self._stop.set()
        if self._t.is_alive():
            self._t.join(5.0)

    def per_tick(self, n_ticks: int):
        """rpm per tick 0 .. n-1, holding each sample until the next (NaN before the first)."""
        out = np.full(n_ticks, np.nan)
        for k, (tk, rpm) in enumerate(self.samples):
            out[max(0, tk):] = rpm
        return out


def sim_spec(opt: VfdOptions) -> dict:
    """What the device simulator (pmctl.hal.devsim) needs to serve a VFD for ``opt``."""
    spec = {"registers": asdict(opt.registers), "max_hz": opt.max_hz, "max_rpm": opt.max_rpm,
            "ramp_rpm_per_s": opt.sim_ramp_rpm_per_s, "host": opt.host, "port": opt.port,
            "device_id": opt.device_id}
    if opt.transport == "rtu":
        spec["rtu"] = {"baudrate": opt.baud, "parity": opt.parity, "stopbits": opt.stop_bits}
    return spec


def simulated(opt: VfdOptions):
    """Start a simulated VFD for ``opt`` in this process (tests); returns (server, device). The
    chosen port is written back to ``opt.port`` when it was 0."""
    # lazy: pymodbus loads only when a Modbus device is simulated
    from pmctl.hal.modbus_sim import ModbusSimServer, SimVFD
    dev = SimVFD(opt.registers, max_hz=opt.max_hz, rpm_per_hz=opt.max_rpm / opt.max_hz,
                 ramp_hz_per_s=opt.sim_ramp_rpm_per_s * opt.max_hz / opt.max_rpm)
    srv = ModbusSimServer(dev, opt.host, opt.port, opt.device_id).start()
    opt.port = srv.port
    return srv, dev


def job_speed(spindle_rpm) -> float:
    """The spindle speed a job starts with (signed: negative = M4): its first non-zero one, 0 when
    the spindle stays off. Later changes are ``speed_changes``."""
    v = np.asarray(spindle_rpm, float)
    on = v[v != 0]
    return float(on[0]) if len(on) else 0.0


REST_STEP_MM = 1e-3     # joint motion per sample below which a planned stop counts as at rest
LOOKAHEAD_SAMPLES = 2   # the wait starts this many ticks' worth of path before the stop, at most


def speed_changes(spindle_rpm, q, job_start: int = 0) -> list[tuple[int, float, bool]]:
    """The spindle speed changes inside a job, after it started at ``job_speed``: (the sample of
    the loop's targets where the motion waits, the new signed speed, whether the path is at rest
    there). The planner stops the path exactly on the last sample of the old speed (``q``: the
    targets' joints, ``job_start``: the first job sample among them); it is at rest when the
    joints move less than ``REST_STEP_MM`` per sample around it. Trailing zeros (the M5 at the end)
    are no change."""
    v = np.asarray(spindle_rpm, float)
    q = np.asarray(q, float)
    on = np.flatnonzero(v)
    if not len(on):
        return []
    out = []
    cur = v[on[0]]
    for c in np.flatnonzero(np.diff(v)) + 1:
        if c <= on[0] or c > on[-1] or v[c] == cur:
            continue
        cur = v[c]
        p = int(c) + job_start - 1                  # the last sample at the old speed: the stop
        steps = [np.abs(q[i + 1] - q[i]).max() for i in range(p - LOOKAHEAD_SAMPLES, p + 1)
                 if 0 <= i and i + 1 < len(q)]
        out.append((p, float(cur), bool(steps) and bool(max(steps) <= REST_STEP_MM)))
    return out


class SpeedChanger:
    """Speed changes inside a job. In the loop's thread (``hook``, each tick): when the path
    reaches a change, the loop's path follower holds there (at a planned stop, where the path is
    at rest, at once). In the monitor's thread (``poll``, at each poll): the new speed goes to the
    VFD, and once it is within ``at_speed_tolerance`` the hold is released. A change that does not
    reach its speed within ``spinup_timeout_s`` is a fault (a controlled stop)."""

    def __init__(self, vfd: SpindleVFD, loop, changes):
        self.vfd, self.loop, self.changes = vfd, loop, list(changes)
        self.next = 0
        self.pending = None             # the speed asked for, while the path waits for it
        self.sent = False
        self.t_sent = 0.0
        self.held_ticks = []            # [from tick, to tick] of each wait

    def hook(self, lp, k, st):
        if self.pending is None and self.next < len(self.changes):
            b, rpm, rest = self.changes[self.next]
            fol = lp.follower
            sc = fol.scaler
            # where the next ticks will take the path (sigma samples per tick): wait before the
            # stop is passed, i.e. at most LOOKAHEAD_SAMPLES short of it, where the path is at rest
            if fol.s_total + LOOKAHEAD_SAMPLES * sc.sigma * fol.k >= b:
                sc.hold = True
                if rest:                # on a planned stop the path is at rest: sigma means nothing there
                    sc.sigma = sc.dsigma = 0.0
                self.next += 1
                self.sent = False
                self.held_ticks.append([k, None])
                self.pending = rpm
        return st

    def poll(self, rpm_meas: float):
        """In the monitor's thread; raises HalError when a change does not come to speed."""
        want = self.pending
        if want is None:
            return
        if not self.sent:
            self.vfd.start(want)        # M3/M4 S.. (or M5); reversing waits for rest inside
            self.sent, self.t_sent = True, time.monotonic()
            return
        if self.vfd.at_speed(rpm_meas):
            self.held_ticks[-1][1] = int(self.loop.tick)
            self.pending = None
            if not self.loop.stop_request:      # a stop asked for meanwhile keeps the hold
                self.loop.follower.scaler.hold = False
            return
        if time.monotonic() - self.t_sent > self.vfd.opt.spinup_timeout_s:
            raise HalError(f"{self.vfd.device}: not at speed {self.vfd.opt.spinup_timeout_s:g} s after "
                           f"S{abs(want):g}: {rpm_meas:g} rpm in {self.vfd.r.name(self.vfd.r.speed_rpm)}")


class SpindleSession:
    """The spindle for one run: (simulated VFD,) connect, start and wait at speed, watch, stop."""

    def __init__(self, opt: VfdOptions, log=print):
        self.opt = replace(opt)            # the simulated port is written back into this copy
        self.log = log
        self.server = self.device = None
        self.sim = None
        self.vfd = None
        self.monitor = None
        self.changer = None
        self._at_start = None
        self.direction = 1.0             # the monitor's samples are signed already

    def connect(self):
        try:
            if self.opt.simulate:
                self.sim, self.device, self.server = start_simulated("vfd", sim_spec(self.opt), "simulated spindle VFD")
                self.opt.port = self.sim.info["vfd_port"]
                if self.opt.transport == "rtu":
                    self.opt.serial_port = self.sim.info["vfd_serial"]
            self.vfd = SpindleVFD(self.opt).connect()
        except BaseException:
            self.close()
            raise
        return self

    def start(self, rpm: float):
        self.vfd.start(rpm)
        t0 = time.monotonic()
        got = self.vfd.wait_at_speed()
        self._at_start = -got if rpm < 0 else got     # the speed the loop starts with (tick 0)
        self.log(f"spindle {'M3' if rpm > 0 else 'M4'} S{abs(rpm):g}: at speed ({got:g} rpm) after "
                 f"{time.monotonic() - t0:.2f} s")

    def follow(self, loop, targets, spindle_rpm):
        """Speed changes inside the job: the loop waits at each for the new speed (call before
        ``watch``)."""
        changes = speed_changes(spindle_rpm, targets.q, targets.job_start)
        if not changes:
            return None
        self.changer = SpeedChanger(self.vfd, loop, changes)
        prev = loop.hook

        def hook(lp, k, st):
            st = self.changer.hook(lp, k, st)
            return prev(lp, k, st) if prev is not None else st
        loop.hook = hook
        return self.changer

    def watch(self, tick, on_fault):
        self.monitor = SpindleMonitor(self.vfd, tick, on_fault)
        self.monitor.changer = self.changer
        if self._at_start is not None:        # measured by the wait at speed, just before the loop
            self.monitor.samples.append((0, self._at_start))
        self.monitor.start()

    def per_tick(self, n):
        if self.monitor is None:
            return np.full(n, np.nan)
        return self.monitor.per_tick(n)

    def close(self):
        """M5 (when the link still answers), then the monitor and the simulated device go."""
        if self.monitor is not None:
            self.monitor.stop()
        if self.vfd is not None:
            try:
                self.vfd.stop()
            except HalError as e:
                self.log(f"warning: {e} (M5 not acknowledged)")
            self.vfd.close()
        stop_simulated(self.sim, self.server)
        self.sim = self.server = None
