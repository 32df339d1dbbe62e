"""The strain DAQ over Modbus TCP (pymodbus client), polled by the supervisor at its own rate,
never in the tick.

Input registers (function 04) from ``base``: strain gauges 1-3 as signed 16-bit counts of
``ue_per_count`` microstrain, then the DAQ's sample counter. Each poll is time-stamped on arrival;
a sample whose counter has not advanced for ``max_age_ms`` is stale (the DAQ froze while its link
answers), a request without answer within ``timeout_ms`` is a timeout: both are faults naming the
device and the register, and the run stops in a controlled way.

Modbus cannot carry a 1 kHz feedback path: the DAQ feeds recordings, monitoring and slow
compensation (``SlowDeflection``: the chains' static elongation, low-passed; with ``compensate``
the session hands its negative to the NC as chain-length offsets, ``DaqSession.on_offset``).
``check_k_theta_source`` refuses it as the K_theta source when it samples slower than
twice the chain mode it would damp (Nyquist; the mode of the machine config).
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, replace

import numpy as np

from pmctl.core.errors import ConfigError
from pmctl.core.strict_toml import Table
from pmctl.hal.base import HalError, HalTimeout
from pmctl.hal.devsim import start_simulated, stop_simulated

K_THETA_SOURCES = ("backend", "daq")
COMP_MAX_MM_LIMIT = 5.0          # comp_max_mm above this is no slow correction of a chain's elongation
COMP_RATE_MM_S_LIMIT = 10.0


@dataclass
class DaqOptions:
    enabled: bool = True
    host: str = "127.0.0.1"
    port: int = 502
    device_id: int = 1
    base: int = 0x0000               # first input register (gauge 1); gauge 2, 3, then the sample counter
    ue_per_count: float = 0.01
    timeout_ms: float = 200.0
    poll_ms: float = 20.0
    max_age_ms: float = 100.0
    max_missed_polls: int = 3        # consecutive unanswered polls before it is a timeout fault
    k_theta_source: str = "backend"  # which strain feeds K_theta: the backend's cyclic data, or this DAQ
    simulate: bool = False           # serve the sim plant's strain from a simulated DAQ on host:port
    sim_sample_hz: float = 100.0
    comp_tau_s: float = 2.0          # low-pass of the static chain deflection estimate (slow compensation)
    compensate: bool = False         # apply the estimate: chain-length offset = -deflection (NC input)
    comp_max_mm: float = 0.2         # bound of the offset per chain; a larger estimate is refused (held)
    comp_rate_mm_s: float = 0.05     # slew rate of the offset in the NC (a step of the estimate is a ramp)

    @classmethod
    def from_dict(cls, d: dict, where="daq") -> "DaqOptions":
        """The ``[daq]`` table read strictly (pmctl.core.strict_toml.Table: every key known, every
        value of its exact type and range); ConfigError(where, key, reason)."""
        t = Table(where, d, "")
        b = cls()
        pos = dict(positive=True, hi=1e15)
        o = cls(
            enabled=t.boolean("enabled", default=b.enabled),
            host=t.string("host", default=b.host),
            port=t.integer("port", default=b.port, lo=0, hi=65535),
            device_id=t.integer("device_id", default=b.device_id, lo=0, hi=247),
            base=t.integer("base", default=b.base, lo=0, hi=0xFFFC),
            ue_per_count=t.number("ue_per_count", default=b.ue_per_count, **pos),
            timeout_ms=t.number("timeout_ms", default=b.timeout_ms, **pos),
            poll_ms=t.number("poll_ms", default=b.poll_ms, **pos),
            max_age_ms=t.number("max_age_ms", default=b.max_age_ms, **pos),
            max_missed_polls=t.integer("max_missed_polls", default=b.max_missed_polls, lo=1, hi=100),
            k_theta_source=t.string("k_theta_source", default=b.k_theta_source, choices=K_THETA_SOURCES),
            simulate=t.boolean("simulate", default=b.simulate),
            sim_sample_hz=t.number("sim_sample_hz", default=b.sim_sample_hz, **pos),
            comp_tau_s=t.number("comp_tau_s", default=b.comp_tau_s, **pos),
            compensate=t.boolean("compensate", default=b.compensate),
            comp_max_mm=t.number("comp_max_mm", default=b.comp_max_mm, positive=True, hi=COMP_MAX_MM_LIMIT),
            comp_rate_mm_s=t.number("comp_rate_mm_s", default=b.comp_rate_mm_s, positive=True,
                                    hi=COMP_RATE_MM_S_LIMIT),
        )
        t.finish()
        if not o.host:
            raise ConfigError(where, "host", "must be a host name or address, got an empty string")
        if o.port == 0 and not o.simulate:
            raise ConfigError(where, "port", "0 (any free port) only with simulate = true")
        if o.simulate and not (o.host.startswith("127.") or o.host == "localhost"):
            raise ConfigError(where, "host", f"a simulated DAQ listens on a loopback address, not {o.host}")
        if o.max_age_ms <= o.poll_ms:
            raise ConfigError(where, "max_age_ms", f"{o.max_age_ms:g} ms must exceed poll_ms = {o.poll_ms:g}")
        return o

    @property
    def sample_hz(self):
        return 1e3 / self.poll_ms


def chain_mode_hz(machine) -> float:
    """The chain's axial mode the K_theta feedback damps: sqrt(k / (m / 3)) / 2 pi."""
    k = machine.stiffness.chain_axial * 1e3          # N/m
    m = machine.mass.platform_kg / 3
    return math.sqrt(k / m) / (2 * math.pi)


def check_k_theta_source(opt: DaqOptions | None, k_theta, machine, where="daq"):
    """Refuse the DAQ as the K_theta source when it samples slower than twice the mode it damps."""
    if opt is None or opt.k_theta_source != "daq" or not any(k_theta):
        return
    f = chain_mode_hz(machine)
    if opt.sample_hz < 2 * f:
        raise ConfigError(where, "k_theta_source",
                          f"the DAQ samples at {opt.sample_hz:g} Hz (poll_ms = {opt.poll_ms:g}); K_theta damps the "
                          f"chain mode at {f:.0f} Hz and needs a strain source faster than {2 * f:.0f} Hz "
                          f"(twice the mode): use k_theta_source = \"backend\" or K_theta = 0")


def chain_deflection_mm(strain_ue, machine):
    """Static axial elongation of each chain (mm, tension positive) from its plate-link strain
    (microstrain, tension positive): tension = strain / strain_gain (N), elongation = tension /
    the chain's axial stiffness (N/mm)."""
    return np.asarray(strain_ue, float) / machine.strain_gain / machine.stiffness.chain_axial


class SlowDeflection:
    """The slow-compensation estimate fed by the DAQ: each chain's static deflection
    (``chain_deflection_mm`` of the DAQ strain), low-passed with time constant ``tau_s`` over the
    samples' own time stamps, so that the chain mode and noise do not reach it. It is an estimate
    for monitoring and for a slow correction of the chain lengths; the control loop's K_theta
    damping is a different, per-tick path (``k_theta_source``)."""

    def __init__(self, machine, tau_s: float):
        self.machine, self.tau = machine, float(tau_s)
        self.value = None               # mm per chain
        self._t = None

    def update(self, t: float, strain_ue) -> list[float]:
        d = chain_deflection_mm(strain_ue, self.machine)
        if self.value is None:
            self.value = d.copy()
        else:
            a = 1.0 - math.exp(-max(0.0, t - self._t) / self.tau)
            self.value = self.value + a * (d - self.value)
        self._t = t
        return self.value.tolist()


class StrainDAQ:
    """Client + poller. ``latest()`` gives (t_monotonic, counter, strain[3]) of the newest sample."""

    def __init__(self, opt: DaqOptions, before_poll=None):
        self.opt = opt
        self.before_poll = before_poll     # e.g. hands a simulated DAQ the strain to serve
        self.slow = None                   # a SlowDeflection fed by the watched samples
        self.on_estimate = None            # called with each new slow estimate (mm per chain), in the poll thread
        self.deflection: list[tuple[int, list[float]]] = []   # (tick, low-passed mm per chain)
        self.client = None
        self.samples: list[tuple[int, float, list[float]]] = []     # (tick, t, strain)
        self.fault = ""
        self._last = None             # (t, counter, strain)
        self._t_counter = None        # when the counter last advanced
        self._stop = threading.Event()
        self._thread = None

    @property
    def device(self):
        return f"strain DAQ {self.opt.host}:{self.opt.port} (unit {self.opt.device_id})"

    def reg_name(self, i):
        a = self.opt.base + i
        return f"input register 0x{a:04X} ({'sample counter' if i == 3 else f'strain gauge {i + 1}'})"

    def connect(self):
        from pymodbus.client import ModbusTcpClient  # lazy: pymodbus loads only when a Modbus device is used
        self.client = ModbusTcpClient(self.opt.host, port=self.opt.port, timeout=self.opt.timeout_ms / 1e3,
                                      retries=0, reconnect_delay=0)
        if not self.client.connect():
            raise HalError(f"{self.device}: cannot connect")
        self.poll()
        return self

    def poll(self):
        """One read of the four registers; checks the age. Returns (t, counter, strain)."""
        from pymodbus.exceptions import ModbusException  # lazy: pymodbus loads only when a Modbus device is used
        if self.before_poll is not None:
            self.before_poll()
        t_req = time.monotonic()
        try:
            rr = self.client.read_input_registers(self.opt.base, count=4, device_id=self.opt.device_id)
        except (ModbusException, OSError) as e:
            what = "no answer within" if "timeout" in str(e).lower() or "no response" in str(e).lower() \
                else "link lost"
            raise HalTimeout(f"{self.device}: {self.reg_name(0)} .. {self.reg_name(3)}: {what} "
                           f"({self.opt.timeout_ms:g} ms timeout): {e}") from None
        if rr.isError():
            raise HalError(f"{self.device}: {self.reg_name(0)}: exception response {rr}")
        t = time.monotonic()
        if t - t_req > self.opt.timeout_ms / 1e3:
            raise HalTimeout(f"{self.device}: {self.reg_name(0)}: answered after {(t - t_req) * 1e3:.0f} ms, "
                           f"over the {self.opt.timeout_ms:g} ms timeout")
        regs = rr.registers
        strain = [((v - 65536) if v >= 32768 else v) * self.opt.ue_per_count for v in regs[:3]]
        n = regs[3]
        # the DAQ read its counter somewhere between the request and the answer: an unchanged
        # counter is known stuck only from the arrival of the answer that first showed it to this
        # request (a late answer, within the timeout, says nothing about the time after the request)
        if self._last is None or n != self._last[1]:
            self._t_counter = t
        elif (t_req - self._t_counter) * 1e3 > self.opt.max_age_ms:
            raise HalError(f"{self.device}: stale data: {self.reg_name(3)} stuck at {n} for "
                           f"{(t_req - self._t_counter) * 1e3:.0f} ms (max age {self.opt.max_age_ms:g} ms)")
        self._last = (t, n, strain)
        return self._last

    def watch(self, tick, on_fault):
        def run():
            missed = 0
            while not self._stop.is_set():
                try:
                    t, n, s = self.poll()
                    self.samples.append((int(tick()), t, s))
                    if self.slow is not None:
                        est = self.slow.update(t, s)
                        self.deflection.append((int(tick()), est))
                        if self.on_estimate is not None:
                            self.on_estimate(est)
                    missed = 0
                except HalTimeout as e:      # one unanswered poll is no timeout fault yet
                    missed += 1
                    if missed < self.opt.max_missed_polls:
                        self._stop.wait(self.opt.poll_ms / 1e3)
                        continue
                    self.fault = f"{e} ({missed} polls in a row)"
                    on_fault(self.fault)
                    return
                except HalError as e:
                    self.fault = str(e)
                    on_fault(self.fault)
                    return
                self._stop.wait(self.opt.poll_ms / 1e3)
        self._thread = threading.Thread(target=run, daemon=True, name="pmctl-daq")
        self._thread.start()

    def per_tick(self, n):
        """Strain (n, 3) per tick, each sample held until the next (NaN before the first)."""
        out = np.full((n, 3), np.nan)
        for tk, _t, s in self.samples:
            out[max(0, tk):] = s
        return out

    def close(self):
        self._stop.set()
        if self._thread is not None and self._thread.is_alive():
            self._thread.join(5.0)
        if self.client is not None:
            self.client.close()
            self.client = None


class DaqSession:
    """The DAQ for one run: (a simulated DAQ serving ``source()``,) connect, watch, record, close.

    Given the machine, the slow chain-deflection estimate is kept (``daq.deflection``); with
    ``compensate = true`` each estimate also goes to ``on_offset(offsets_mm)`` as the chain-length
    offsets that cancel it: offset = -deflection per chain (a chain stretched by d under tension is
    commanded d shorter; the NC adds the offset to the commanded chain length, slew-limited and
    bounded: pmctl.motion.nc). When the DAQ faults (stale data, timeout) the estimates stop: the
    last offset is held while the run stops."""

    def __init__(self, opt: DaqOptions, source=None, log=print, machine=None, on_offset=None):
        self.opt = replace(opt)
        self.machine = machine             # given: the slow chain-deflection estimate is kept too
        self.source = source or (lambda: (0.0, 0.0, 0.0))
        self.log = log
        self.on_offset = on_offset         # callable(offsets_mm: tuple of 3), with compensate = true
        self.offsets: tuple | None = None  # the last offsets handed to on_offset
        self.server = self.device = None
        self.sim = None
        self.daq = None
        if self.opt.compensate and machine is None:
            raise ValueError("DaqSession: compensate = true needs the machine (chain stiffness, strain gain)")

    def connect(self):
        try:
            if self.opt.simulate:
                # the simulated DAQ in a device-simulator process; the strain it serves is pushed
                # to it before each poll
                o = self.opt
                spec = {"base": o.base, "ue_per_count": o.ue_per_count, "sample_hz": o.sim_sample_hz,
                        "host": o.host, "port": o.port, "device_id": o.device_id}
                self.sim, self.device, self.server = start_simulated("daq", spec, "simulated strain DAQ")
                self.opt.port = self.sim.info["daq_port"]
                self.sim.push_strain(self.source())
            self.daq = StrainDAQ(self.opt, self._feed if self.sim is not None else None).connect()
            if self.machine is not None:
                self.daq.slow = SlowDeflection(self.machine, self.opt.comp_tau_s)
                if self.opt.compensate and self.on_offset is not None:
                    self.daq.on_estimate = self._estimate
        except BaseException:
            self.close()
            raise
        return self

    def _estimate(self, deflection_mm):
        """Each slow estimate -> the offsets that cancel it (in the poll thread)."""
        off = tuple(-float(x) for x in deflection_mm)
        self.offsets = off
        try:
            self.on_offset(off)
        except Exception as e:       # noqa: BLE001 -- a compensation problem must not end the monitoring
            self.log(f"{self.daq.device}: slow compensation not applied: {type(e).__name__}: {e}")

    def watch(self, tick, on_fault):
        self.daq.watch(tick, on_fault)

    def per_tick(self, n):
        return self.daq.per_tick(n)

    def _feed(self):
        self.sim.push_strain(self.source())

    def close(self):
        if self.daq is not None:
            self.daq.close()
        stop_simulated(self.sim, self.server)
        self.sim = self.server = None
