"""CANopen backend: CiA 402 servo drives in cyclic synchronous position (CSP) mode, with the
``canopen`` library as master.

Start-up (``open``), all or nothing:
1. every node is probed by SDO (device type 0x1000 = 0x20192, CSP supported in 0x6502) before
   anything is written: a missing or wrong node is reported and no drive is touched;
2. SDO configuration of each drive in pre-operational: heartbeat producer 0x1017, heartbeat consumer
   0x1016 (the host's heartbeat: a drive faults by itself when the host's ticks stop),
   communication cycle 0x1006, interpolation period 0x60C2, mode 0x6060 = 8 (read back in 0x6061),
   RPDO1 = target 0x607A + controlword 0x6040 and TPDO1 = position actual 0x6064 + statusword
   0x6041, both synchronous (transmission type 1); a failure leaves every drive pre-operational
   and disabled and names the node and the object;
3. NMT start, then the CiA 402 state machine to Operation enabled through the RPDO on SYNC (fault
   reset first when a drive is in Fault: re-enabling always goes through it), with the target set
   to the position actual (no jump). The drive positions must agree with the controller's pulse
   counters, else the start is refused (re-home).

Per CAN cycle (``cycle_ms``, a whole number of NC ticks): the host sends each drive's RPDO (the
commanded joint position of the tick, converted to drive increments) and then the SYNC; the drives
apply the targets and answer with their TPDOs (the frames packed once per cycle into prebuilt
can.Messages; on an slcan link written in one write by the cycle writer thread, out of the tick).
Between SYNCs the drive interpolates (0x60C2). At
the tick where the next SYNC is due, ``read`` requires every drive's answer to the previous SYNC
(waiting at most ``read_timeout_ms``). The bus load of this map is computed at config load and a
config above 70 % is refused with the numbers.

Faults, each a HalError naming the node, its axis and the code, after a quick stop of all drives:
a lost heartbeat, an EMCY, a statusword fault or following-error bit, a drive that left Operation
enabled, a TPDO older than its cycle.

A late answer is survivable: the drives interpolate toward the last target they got and hold it,
so the feedback may be a few cycles old without harm. ``late_cycles`` says how many: at the due
tick every drive must have answered all SYNCs but the last ``late_cycles``; the feedback uses each
drive's latest answer with the target it was following then. A lost frame is told apart from a
late one by the other drives: they answer each SYNC in one burst, so a drive still short of SYNC
n-1 when another answers SYNC n lost its answer.

``simulate = true`` runs simulated drives (pmctl.hal.cia402_sim): with ``interface = "virtual"`` on
the same python-can bus in this process (tests), with ``interface = "slcan"`` and ``channel =
"devsim"`` in a device-simulator process of their own (pmctl.hal.devsim) on an slcan link over a
pty, which the backend starts, waits for and stops. A simulator that dies is a lost heartbeat.
"""

from __future__ import annotations

import math
import queue
import struct
import threading
import time
from dataclasses import dataclass, fields

import can
import canopen
import numpy as np

from pmctl.core.errors import ConfigError
from pmctl.hal import cia402 as C
from pmctl.hal.base import AXES, Backend, Feedback, HalError, HalTimeout, Inputs, Status, switch_positions
from pmctl.hal.cia402_sim import EDS_PATH, SimDriveSet
from pmctl.hal.devsim import DeviceSimulator, DeviceSimulatorError
from pmctl.hal.slcan_link import SlcanLinkBus, encode_batch

RPDO_BYTES = 6          # target position (INTEGER32) + controlword (UNSIGNED16)
TPDO_BYTES = 7          # position actual (INTEGER32) + statusword (UNSIGNED16) + digital inputs 0x60FD bits 0-7
DI_BITS = 8             # 0x60FD mapped with its low byte: limits, home switch (bit 2), interlock
MAX_LATE_CYCLES = 32
HISTORY = 64            # targets kept per SYNC (> MAX_LATE_CYCLES + 2)
_RPDO = struct.Struct("<iH")   # RPDO1: target position, controlword
INTERFACES = ("virtual", "slcan", "socketcan", "pcan", "kvaser", "ixxat", "vector", "serial")


@dataclass
class CanopenOptions:
    interface: str = "virtual"
    channel: str = "pmctl-can0"
    bitrate: int = 1_000_000
    node_ids: tuple = (1, 2, 3, 4, 5)          # drives of L1 L2 L3 X Y
    host_node_id: int = 127                    # the host's own heartbeat (drives consume it)
    cycle_ms: float = 2.0                      # CAN (SYNC) cycle, a whole multiple of the NC tick
    increments_per_mm: tuple | float | None = None   # drive position unit; None = the machine's pulses/mm
    heartbeat_ms: int = 50                     # drive heartbeat producer time
    heartbeat_timeout_ms: int = 150            # a drive heard from less often is lost
    host_heartbeat_ms: int = 50                # host heartbeat producer time
    host_timeout_ms: int = 300                 # a drive that does not hear the host this long faults
    read_timeout_ms: float = 2.0               # wait for the TPDOs of the last SYNC at most this long
    sdo_timeout_ms: float = 200.0
    following_window_mm: float = 1.0           # 0x6065: a target jump beyond this faults the drive
    position_tolerance_mm: float = 0.001       # drive position vs controller counters at start
    eds: str = ""                              # "" = the shipped CiA 402 EDS
    late_cycles: int = 4                       # answers may lag the SYNCs by this many cycles (jitter)
    simulate: bool = False                     # run simulated drives on the bus (cia402_sim)
    sim_lag_ms: float = 1.0                    # simulated drives: first-order lag
    sim_rt_priority: int = 0                   # SCHED_FIFO of the device simulator process when permitted
    sim_link: str = "tcp"                      # device simulator's slcan link: "tcp" (loopback) or "pty"
    sim_listen_links: int = 0                  # device simulator: extra pty links for listeners
    bus_thread_priority: int = 51              # SCHED_FIFO of the CAN receive threads when permitted, 0 = off
    sim_home_switch_mm: tuple = ()             # simulated drives: home switch closed at position >= this (5 joint
                                               # positions, mm of the drives' own position); () = none

    @classmethod
    def from_dict(cls, d: dict, where: str = "hal.canopen") -> "CanopenOptions":
        names = {f.name: f for f in fields(cls)}
        kw = {}
        for k, v in d.items():
            if k not in names:
                raise ConfigError(where, k, f"unknown canopen option; known: {', '.join(names)}")
            kw[k] = v
        o = cls(**kw)

        def num(key, lo=None, integer=False, positive=False):
            v = getattr(o, key)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or abs(v) > 1e15 or not math.isfinite(v):
                raise ConfigError(where, key, f"must be a number, got {v!r}")
            if integer and v != int(v):
                raise ConfigError(where, key, f"must be an integer, got {v!r}")
            if positive and v <= 0:
                raise ConfigError(where, key, f"must be > 0, got {v!r}")
            if lo is not None and v < lo:
                raise ConfigError(where, key, f"must be >= {lo}, got {v!r}")
            return int(v) if integer else float(v)

        if o.interface not in INTERFACES:
            raise ConfigError(where, "interface", f"unknown python-can interface {o.interface!r}; known: "
                                                  f"{', '.join(INTERFACES)}")
        if not isinstance(o.channel, str) or not o.channel:
            raise ConfigError(where, "channel", "must be a non-empty string")
        o.bitrate = num("bitrate", integer=True, positive=True)
        if o.bitrate not in (10_000, 20_000, 50_000, 125_000, 250_000, 500_000, 800_000, 1_000_000):
            raise ConfigError(where, "bitrate", f"{o.bitrate} is not a CANopen bit rate (10k .. 1M)")
        ids = o.node_ids
        if not isinstance(ids, (list, tuple)) or len(ids) != 5 or not all(
                isinstance(i, int) and not isinstance(i, bool) for i in ids):
            raise ConfigError(where, "node_ids", f"must be 5 integer node ids (L1 L2 L3 X Y), got {ids!r}")
        bad = [i for i in ids if not 1 <= i <= 127]
        if bad:
            raise ConfigError(where, "node_ids", f"node id {bad[0]} outside 1 .. 127")
        if len(set(ids)) != 5:
            raise ConfigError(where, "node_ids", f"node ids must differ, got {list(ids)}")
        o.node_ids = tuple(ids)
        o.host_node_id = num("host_node_id", integer=True)
        if not 1 <= o.host_node_id <= 127 or o.host_node_id in ids:
            raise ConfigError(where, "host_node_id", f"must be 1 .. 127 and not a drive's id, got {o.host_node_id}")
        o.cycle_ms = num("cycle_ms", positive=True)
        for k in ("heartbeat_ms", "heartbeat_timeout_ms", "host_heartbeat_ms", "host_timeout_ms"):
            setattr(o, k, num(k, integer=True, positive=True))
            if getattr(o, k) > 65535:
                raise ConfigError(where, k, "must fit in 16 bits (<= 65535 ms)")
        if o.heartbeat_timeout_ms <= o.heartbeat_ms:
            raise ConfigError(where, "heartbeat_timeout_ms",
                              f"{o.heartbeat_timeout_ms} ms must exceed heartbeat_ms = {o.heartbeat_ms}")
        if o.host_timeout_ms <= o.host_heartbeat_ms:
            raise ConfigError(where, "host_timeout_ms",
                              f"{o.host_timeout_ms} ms must exceed host_heartbeat_ms = {o.host_heartbeat_ms}")
        o.read_timeout_ms = num("read_timeout_ms", positive=True)
        o.sdo_timeout_ms = num("sdo_timeout_ms", positive=True)
        o.following_window_mm = num("following_window_mm", positive=True)
        o.position_tolerance_mm = num("position_tolerance_mm", positive=True)
        o.sim_lag_ms = num("sim_lag_ms", lo=0.0)
        o.late_cycles = num("late_cycles", lo=0, integer=True)
        if o.late_cycles > MAX_LATE_CYCLES:
            raise ConfigError(where, "late_cycles", f"must be 0 .. {MAX_LATE_CYCLES}, got {o.late_cycles}")
        for k in ("bus_thread_priority", "sim_rt_priority"):
            setattr(o, k, num(k, lo=0, integer=True))
            if getattr(o, k) > 99:
                raise ConfigError(where, k, "must be 0 .. 99")
        o.sim_home_switch_mm = switch_positions(o.sim_home_switch_mm, where, "sim_home_switch_mm")
        o.sim_listen_links = num("sim_listen_links", lo=0, integer=True)
        if o.sim_listen_links > 8:
            raise ConfigError(where, "sim_listen_links", "must be 0 .. 8")
        if o.increments_per_mm is not None:
            v = o.increments_per_mm
            a = np.broadcast_to(np.asarray(v, float), (5,)).copy() if np.ndim(v) == 0 or len(v) == 5 else None
            if a is None or not np.all(np.isfinite(a)) or np.any(a <= 0):
                raise ConfigError(where, "increments_per_mm", f"must be > 0, one number or 5, got {v!r}")
            o.increments_per_mm = tuple(float(x) for x in a)
        if not isinstance(o.simulate, bool):
            raise ConfigError(where, "simulate", f"must be true or false, got {o.simulate!r}")
        if not isinstance(o.eds, str):
            raise ConfigError(where, "eds", "must be a path (string)")
        if o.simulate and o.interface not in ("virtual", "slcan"):
            raise ConfigError(where, "simulate", f"simulated drives need the 'virtual' or 'slcan' interface, "
                                                 f"not {o.interface!r}")
        if o.sim_link not in ("tcp", "pty"):
            raise ConfigError(where, "sim_link", f"must be \"tcp\" or \"pty\", got {o.sim_link!r}")
        if o.simulate and o.interface == "slcan" and o.channel != "devsim":
            raise ConfigError(where, "channel", f"simulated drives on slcan live in the device simulator: "
                                                f"channel = \"devsim\", not {o.channel!r}")
        load = o.bus_load()
        if load.load > C.MAX_BUS_LOAD:
            # the smallest cycle that fits, for the message
            need_ms = (load.planned_bits_per_cycle / (C.MAX_BUS_LOAD * o.bitrate - load.heartbeat_bits_per_s)) * 1e3 \
                if C.MAX_BUS_LOAD * o.bitrate > load.heartbeat_bits_per_s else float("inf")
            raise ConfigError(where, "cycle_ms",
                              f"bus load {load.text}: over {C.MAX_BUS_LOAD * 100:.0f} %; lengthen cycle_ms to "
                              f">= {need_ms:.2f} ms (a whole multiple of the NC tick), raise the bit rate or "
                              f"split the axes over two buses")
        return o

    def bus_load(self) -> C.BusLoad:
        return C.bus_load(len(self.node_ids), RPDO_BYTES, TPDO_BYTES, self.cycle_ms / 1e3, self.bitrate,
                          heartbeat_s=self.heartbeat_ms / 1e3, host_heartbeat_s=self.host_heartbeat_ms / 1e3)


class _Drive:
    """Master-side view of one drive: last TPDO contents and counters (written by the bus thread)."""

    __slots__ = ("id", "axis", "node", "pos", "sw", "answers", "t_tpdo", "t_hb", "hb_state", "emcy",
                 "rpdo", "home", "edges", "edge_closed", "edge_pos")

    def __init__(self, node_id, axis, node):
        self.id, self.axis, self.node = node_id, axis, node
        self.pos = 0
        self.sw = 0
        self.answers = 0
        self.t_tpdo = None
        self.t_hb = None
        self.hb_state = None
        self.emcy = None
        self.rpdo = None
        self.home = None            # 0x60FD home switch bit of the last TPDO (None: none received yet)
        self.edges = 0              # home switch transitions seen between two TPDOs
        self.edge_closed = False    # the state after the last one
        self.edge_pos = 0           # position actual in the TPDO that first showed it (increments)

    @property
    def name(self):
        return f"node {self.id} ({self.axis})"


class _CycleWriter:
    """Writes the loop's cycles (encoded slcan lines) to the link from a thread of its own, so the
    system call (on a loopback TCP link the kernel's whole TCP path runs in it) is not part of the
    tick. One thread and one FIFO: cycles leave in the order the ticks made them. Its SCHED_FIFO
    priority is below the loop's: it writes while the loop sleeps (or on the other core), never
    in the loop's place. A failed write is reported through ``failed`` (the backend's fault, raised
    at the next read)."""

    def __init__(self, write, encode, lock, failed, priority: int):
        self.encode = encode
        self._q = queue.SimpleQueue()
        self._write, self._lock, self._failed = write, lock, failed
        self._t = threading.Thread(target=self._run, name="canopen cycle writer", daemon=True)
        self._t.start()
        C.boost_thread(self._t, priority)

    def put(self, data: bytes) -> None:
        self._q.put(data)

    def _run(self):
        ok = True
        while True:
            data = self._q.get()
            if data is None:
                return
            if not ok:
                continue                         # after a failure: the backend stops; drop the rest
            try:
                with self._lock:
                    self._write(data)
            except Exception as e:              # noqa: BLE001 -- CanError / OSError of the link
                ok = False
                self._failed(e)

    def stop(self, timeout: float = 2.0) -> None:
        self._q.put(None)
        self._t.join(timeout)


class CanopenCSP(Backend):
    name = "canopen"
    accepts = "positions"
    can_rereference = True      # homing keeps a counter offset per axis; the drives are not re-homed
    strain_in_loop = False      # the PDO map carries positions only (feedback strain stays 0)

    @classmethod
    def validate_options(cls, table: dict, where: str) -> CanopenOptions:
        try:
            return CanopenOptions.from_dict(table, where)
        except TypeError as e:
            raise ConfigError(where, "-", str(e)) from None

    def __init__(self, machine, dt: float, options: dict | CanopenOptions | None = None):
        o = options if isinstance(options, CanopenOptions) else CanopenOptions.from_dict(options or {})
        self.opt, self.machine, self.dt = o, machine, float(dt)
        ratio = o.cycle_ms / 1e3 / self.dt
        if abs(ratio - round(ratio)) > 1e-6 or round(ratio) < 1:
            raise ConfigError("hal.canopen", "cycle_ms",
                              f"{o.cycle_ms:g} ms is not a whole multiple of the NC tick {self.dt * 1e3:g} ms")
        self.cycle_ticks = int(round(ratio))
        # a paused host: the drives hold their last target; past host_timeout_ms without the host's
        # heartbeat (sent every host_heartbeat_ms from the ticks) they fault by themselves
        self.stall_tolerance_s = (o.host_timeout_ms - o.host_heartbeat_ms) / 1e3
        self.cycle_s = o.cycle_ms / 1e3
        self.inc_per_mm = np.asarray(o.increments_per_mm if o.increments_per_mm is not None
                                     else machine.resolution.pulses_per_mm, float)
        self.bus_load = o.bus_load()
        self.network = None
        self.sim = None
        self.devsim = None
        self.drives: list[_Drive] = []
        self._fb = Feedback()
        self._cond = threading.Condition()
        self._fault = ""
        self._syncs = 0
        self._writes = 0
        self._need = -1                  # write count at which the answers to the last SYNC are due
        self._enabled = False
        self._hb_task = None
        self._t_host_hb = 0.0
        self._targets = np.zeros(5, np.int64)
        self._last_q = None
        self._sent = np.zeros((HISTORY, 5), np.int64)   # targets sent with SYNC s at row s % HISTORY
        self._cw = C.CW_SHUTDOWN
        self.frames_sent = 0
        # homing: controller counters = drive position (as pulses) + _off; the drives keep their positions
        self._off = np.zeros(5, np.int64)
        self._off_mm = np.zeros(5)
        self._inputs = None         # cached Inputs, rebuilt when a home switch changes (_in_ver)
        self._in_ver = 0
        self._in_built = -1

    # ---------------------------------------------------------------- helpers
    def _eds(self):
        return self.opt.eds or EDS_PATH

    def _sdo_write(self, d: _Drive, index, sub, value, what):
        try:
            obj = d.node.sdo[index] if sub is None else d.node.sdo[index][sub]
            obj.raw = value
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError, KeyError) as e:
            where = f"0x{index:04X}" + ("" if sub is None else f":{sub:02X}")
            raise HalError(f"canopen {d.name}: SDO write {where} ({what}) = {value!r} failed: {e}") from None

    def _sdo_read(self, d: _Drive, index, sub, what):
        try:
            obj = d.node.sdo[index] if sub is None else d.node.sdo[index][sub]
            return obj.raw
        except (canopen.SdoCommunicationError, canopen.SdoAbortedError, KeyError) as e:
            where = f"0x{index:04X}" + ("" if sub is None else f":{sub:02X}")
            raise HalError(f"canopen {d.name}: SDO read {where} ({what}) failed: {e}") from None

    # bus-thread callbacks
    def _on_tpdo(self, d: _Drive, data, ts):
        if len(data) < TPDO_BYTES:
            return
        pos, sw = struct.unpack_from("<iH", data)
        home = bool(data[6] & C.DI_HOME_SWITCH) if len(data) > 6 else False
        with self._cond:
            d.pos, d.sw = pos, sw
            if home != d.home:
                if d.home is not None:      # an edge between the last TPDO and this one: latch this position
                    d.edges += 1
                    d.edge_closed, d.edge_pos = home, pos
                d.home = home
                self._in_ver += 1
            d.answers += 1
            d.t_tpdo = time.monotonic()
            if self._enabled and not self._fault:
                # the drives answer each SYNC in one burst, in order on the wire: when one answers
                # SYNC n, all of SYNC n-1 has arrived; a drive still short of it lost a frame
                for o in self.drives:
                    if o.answers < d.answers - 1:
                        self._fault = (f"canopen {o.name}: TPDO1 0x{C.cob_tpdo1(o.id):03X} older than its "
                                       f"cycle: no answer to SYNC {o.answers + 1} while {d.name} answered "
                                       f"SYNC {d.answers} (frame lost)")
                        break
            self._cond.notify_all()

    def _on_heartbeat(self, d: _Drive, data, ts):
        if not data:
            return
        st = data[0] & 0x7F
        with self._cond:
            d.t_hb = time.monotonic()
            d.hb_state = st
            if self._enabled and not self._fault:
                if st == 0:
                    self._fault = f"canopen {d.name}: rebooted (boot-up message) while enabled"
                elif st != 5:
                    self._fault = f"canopen {d.name}: NMT state {st} (not operational) reported by its heartbeat"
            self._cond.notify_all()

    def _on_emcy(self, d: _Drive, data, ts):
        if len(data) < 3:
            return
        code, reg = struct.unpack_from("<HB", data)
        with self._cond:
            if code & 0xFF00 == 0:
                return                       # error reset
            d.emcy = code
            if not self._fault:
                self._fault = (f"canopen {d.name}: EMCY 0x{code:04X} ({C.emcy_text(code)}), "
                               f"error register 0x{reg:02X}")
            self._cond.notify_all()

    # ---------------------------------------------------------------- open
    def open(self, counts) -> None:
        o = self.opt
        counts = np.asarray(counts, np.int64)
        ppm = self.machine.resolution.pulses_per_mm
        q0 = (counts - self._off) / ppm                 # the drives' frame (a homing offset restored)
        self._targets = np.rint(q0 * self.inc_per_mm).astype(np.int64)
        home_at = ([int(round(mm * self.inc_per_mm[i])) for i, mm in enumerate(o.sim_home_switch_mm)]
                   if o.sim_home_switch_mm else None)
        bus = None
        try:
            if o.simulate and o.interface == "slcan":
                spec = {"can": {"node_ids": list(o.node_ids), "positions": self._targets.tolist(),
                                "lag_s": o.sim_lag_ms / 1e3, "eds": self._eds(), "tcp": True, "home_at": home_at,
                                "ptys": (1 if o.sim_link == "pty" else 0) + o.sim_listen_links},
                        "rt_priority": o.sim_rt_priority}
                try:
                    self.devsim = DeviceSimulator(spec, "CiA 402 drive simulator").start()
                    link = self.devsim.links[0] if o.sim_link == "pty" else \
                        f"socket://127.0.0.1:{self.devsim.info['can_tcp_port']}"
                    bus = SlcanLinkBus(link, o.bitrate)
                except (DeviceSimulatorError, can.CanError) as e:
                    raise HalError(f"canopen: simulated drives: {e}") from None
            elif o.simulate:
                self.sim = SimDriveSet(o.node_ids, self._targets.tolist(), interface=o.interface,
                                       channel=o.channel, bitrate=o.bitrate, lag_s=o.sim_lag_ms / 1e3,
                                       eds=self._eds(), home_at=home_at)
            net = canopen.Network(bus)
            kw = {"interface": o.interface, "channel": o.channel}
            if o.interface != "virtual":
                kw["bitrate"] = o.bitrate
            try:
                net.connect(**kw)
            except (can.CanError, OSError, ValueError) as e:
                raise HalError(f"canopen: cannot open CAN interface {o.interface}:{o.channel}: {e}") from None
            self.network = net
            self.rt_bus = C.boost_bus_threads(net, o.bus_thread_priority)
            if self.sim is not None:
                C.boost_bus_threads(self.sim.network, o.bus_thread_priority)
            self.drives = []
            for nid, axis in zip(o.node_ids, AXES):
                node = canopen.RemoteNode(nid, self._eds())
                net.add_node(node)
                node.sdo.RESPONSE_TIMEOUT = o.sdo_timeout_ms / 1e3
                node.sdo.MAX_RETRIES = 1          # one attempt (0 would retry forever)
                self.drives.append(_Drive(nid, axis, node))
            self._probe()
            try:
                self._configure()
                self._start()
            except BaseException:
                self._disable_all()
                raise
        except BaseException:
            self._teardown()
            raise

    def _probe(self):
        """Every drive present, a CiA 402 servo drive with CSP, before anything is written."""
        for d in self.drives:
            dev = self._sdo_read(d, C.OD_DEVICE_TYPE, None, "device type")
            if dev & 0xFFFF != 402:
                raise HalError(f"canopen {d.name}: device type 0x{dev:08X} is not a CiA 402 servo drive "
                               f"(expected 0x{C.DEVICE_TYPE_402:08X}); nothing was configured")
            modes = self._sdo_read(d, C.OD_SUPPORTED_MODES, None, "supported drive modes")
            if not modes & C.CSP_SUPPORTED_BIT:
                raise HalError(f"canopen {d.name}: 0x6502 = 0x{modes:08X}: cyclic synchronous position not "
                               f"supported; nothing was configured")

    def _configure(self):
        o = self.opt
        net = self.network
        net.nmt.send_command(0x80)            # all pre-operational (PDOs off while mapping)
        for d in self.drives:
            n = d.node
            self._sdo_write(d, C.OD_HB_PRODUCER, None, o.heartbeat_ms, "producer heartbeat time, ms")
            self._sdo_write(d, C.OD_HB_CONSUMER, 1, (o.host_node_id << 16) | o.host_timeout_ms,
                            "consumer heartbeat time of the host")
            self._sdo_write(d, C.OD_COMM_CYCLE, None, int(round(o.cycle_ms * 1000)), "communication cycle, us")
            ms = o.cycle_ms
            if ms == int(ms) and ms <= 255:
                val, idx = int(ms), -3
            else:
                val, idx = int(round(ms * 10)), -4
            if not 1 <= val <= 255:
                raise HalError(f"canopen {d.name}: interpolation period {ms:g} ms cannot be written to 0x60C2")
            self._sdo_write(d, C.OD_INTERP_PERIOD, 1, val, "interpolation time period value")
            self._sdo_write(d, C.OD_INTERP_PERIOD, 2, idx, "interpolation time index")
            win = int(round(o.following_window_mm * float(self.inc_per_mm[AXES.index(d.axis)])))
            self._sdo_write(d, C.OD_FOLLOWING_WINDOW, None, win, "following error window, increments")
            self._sdo_write(d, C.OD_MODE, None, C.MODE_CSP, "modes of operation = CSP")
            shown = self._sdo_read(d, C.OD_MODE_DISPLAY, None, "modes of operation display")
            if shown != C.MODE_CSP:
                raise HalError(f"canopen {d.name}: 0x6061 shows mode {shown}, not CSP (8) after writing 0x6060")
            try:
                rp = n.rpdo[1]
                rp.clear()
                rp.add_variable(C.OD_TARGET)
                rp.add_variable(C.OD_CONTROLWORD)
                rp.cob_id, rp.trans_type, rp.enabled = C.cob_rpdo1(d.id), 1, True
                rp.save()
                tp = n.tpdo[1]
                tp.clear()
                tp.add_variable(C.OD_POSITION_ACTUAL)
                tp.add_variable(C.OD_STATUSWORD)
                tp.add_variable(C.OD_DIGITAL_INPUTS, 0, DI_BITS)
                tp.cob_id, tp.trans_type, tp.enabled = C.cob_tpdo1(d.id), 1, True
                tp.save()
            except (canopen.SdoCommunicationError, canopen.SdoAbortedError) as e:
                raise HalError(f"canopen {d.name}: PDO mapping by SDO failed: {e}") from None
            if rp.length != 8 * RPDO_BYTES or tp.length != 8 * TPDO_BYTES:
                raise HalError(f"canopen {d.name}: PDO map sizes {rp.length // 8}/{tp.length // 8} bytes, "
                               f"expected {RPDO_BYTES}/{TPDO_BYTES}")
            d.rpdo = rp

    def _start(self):
        o = self.opt
        net = self.network
        for d in self.drives:
            net.subscribe(C.cob_tpdo1(d.id), lambda cid, data, ts, _d=d: self._on_tpdo(_d, data, ts))
            net.subscribe(C.cob_heartbeat(d.id), lambda cid, data, ts, _d=d: self._on_heartbeat(_d, data, ts))
            net.subscribe(C.cob_emcy(d.id), lambda cid, data, ts, _d=d: self._on_emcy(_d, data, ts))
        self._host_heartbeat(force=True)
        for d in self.drives:
            d.node.nmt.send_command(0x01)       # NMT start
        t_end = time.monotonic() + max(1.0, 4 * o.heartbeat_ms / 1e3)
        for d in self.drives:
            with self._cond:
                while d.hb_state != 5 and time.monotonic() < t_end:
                    self._cond.wait(0.01)
            if d.hb_state != 5:
                raise HalError(f"canopen {d.name}: no heartbeat in NMT operational after NMT start "
                               f"(last state {d.hb_state})")
        # first answer: where the drives are, and their state
        self._cycle(C.CW_DISABLE_VOLTAGE, settle=False)
        for i, d in enumerate(self.drives):
            tol = o.position_tolerance_mm * self.inc_per_mm[i]
            if abs(d.pos - self._targets[i]) > max(tol, 0.5):
                raise HalError(f"canopen {d.name}: drive at {d.pos / self.inc_per_mm[i]:.4f} mm but the controller's "
                               f"counters say {self._targets[i] / self.inc_per_mm[i]:.4f} mm: re-home; nothing enabled")
        # fault reset first, where a drive is in fault (re-enabling always goes through it)
        if any(C.state_of(d.sw) in (C.FAULT, C.FAULT_REACTION_ACTIVE) for d in self.drives):
            self._cycle(C.CW_DISABLE_VOLTAGE)
            self._cycle(C.CW_FAULT_RESET)
            stuck = [d for d in self.drives if C.state_of(d.sw) == C.FAULT]
            if stuck:
                d = stuck[0]
                code = self._sdo_read(d, C.OD_ERROR_CODE, None, "error code")
                raise HalError(f"canopen {d.name}: fault reset refused, still in Fault (error code 0x{code:04X})")
        with self._cond:
            for d in self.drives:
                d.emcy = None
            self._fault = ""
        for cw, want in ((C.CW_SHUTDOWN, C.READY_TO_SWITCH_ON), (C.CW_SWITCH_ON, C.SWITCHED_ON),
                         (C.CW_ENABLE_OPERATION, C.OPERATION_ENABLED)):
            for _ in range(3):
                self._cycle(cw)
                if all(C.state_of(d.sw) == want for d in self.drives):
                    break
            bad = [d for d in self.drives if C.state_of(d.sw) != want]
            if bad:
                d = bad[0]
                raise HalError(f"canopen {d.name}: did not reach '{want}' (statusword 0x{d.sw:04X}, "
                               f"{C.state_of(d.sw)})")
            if self._fault:
                raise HalError(self._fault)
        self._cw = C.CW_ENABLE_OPERATION
        self._enabled = True
        self._need = -1
        self._writes = 0
        self._fill_feedback()
        # the host heartbeat keeps going from a timer until the first tick takes over
        self._hb_task = self.network.send_periodic(C.cob_heartbeat(o.host_node_id), [5], o.host_heartbeat_ms / 1e3)
        # that timer thread is all the drives hear of the host until the loop runs (the spindle
        # spins up meanwhile): it gets the receive threads' priority
        C.boost_thread(getattr(getattr(self._hb_task, "_task", None), "thread", None), o.bus_thread_priority)

    def _cycle(self, cw: int, settle: bool = True):
        """One CAN cycle outside the loop (start-up): RPDOs with ``cw`` and the held targets, SYNC,
        and wait for every drive's TPDO. Real time does not matter here."""
        self._cw = cw
        self._send_cycle()
        self._wait_answers(max(0.5, 10 * self.cycle_s), "start-up")
        if settle:
            self._send_cycle()                  # a second SYNC: the answer shows the new state
            self._wait_answers(max(0.5, 10 * self.cycle_s), "start-up")

    _frames = None          # the cycle's can.Messages, built at the first cycle (_cycle_frames)
    _batch = None           # the bus's send_batch, if it has one
    _writer = None          # the _CycleWriter while the loop runs on a link that takes encoded lines

    def _send_cycle(self):
        """The cycle's frames: each drive's RPDO1 (target, controlword), the SYNC, and the host's
        heartbeat when due. Packed with struct into can.Message objects built once (not through
        the canopen PDO variables: the same bytes). While the loop runs on an slcan link the
        cycle is encoded here and written by the cycle writer's thread (one write, out of the
        tick); otherwise handed to the bus in one call when it takes a batch, else one send each."""
        net = self.network
        self._sent[(self._syncs + 1) % HISTORY] = self._targets
        fr = self._frames
        if fr is None or len(fr) != len(self.drives) + 2:
            fr = self._frames = self._cycle_frames()
        cw = self._cw
        for m, t in zip(fr, self._targets.tolist()):
            _RPDO.pack_into(m.data, 0, t, cw)
        now = time.monotonic()
        n = len(fr) - 1                                     # RPDOs + SYNC
        if now - self._t_host_hb >= self.opt.host_heartbeat_ms / 1e3:
            self._t_host_hb = now
            n += 1                                          # + the host heartbeat
        w = self._writer
        if w is not None:
            w.put(w.encode(fr[:n]))
        else:
            bus = net.bus
            with net.send_lock:
                if self._batch is not None:
                    self._batch(fr[:n])
                else:
                    for i in range(n):
                        bus.send(fr[i])
        net.check()                                         # the receive thread still alive
        self._syncs += 1
        self.frames_sent += len(self.drives) + 1

    def _cycle_frames(self) -> list:
        """The frames of a cycle, built once: RPDO1 of each drive (6 bytes), SYNC (no data), the
        host heartbeat (operational); and the bus's batch send, if it has one."""
        self._batch = getattr(self.network.bus, "send_batch", None)
        fr = [can.Message(arbitration_id=C.cob_rpdo1(d.id), is_extended_id=False, data=bytearray(RPDO_BYTES))
              for d in self.drives]
        fr.append(can.Message(arbitration_id=C.COB_SYNC, is_extended_id=False, data=b""))
        fr.append(can.Message(arbitration_id=C.cob_heartbeat(self.opt.host_node_id), is_extended_id=False,
                              data=bytes([5])))
        return fr

    def _start_writer(self):
        """The cycle writer, when the bus takes encoded lines (an slcan link)."""
        bus = self.network.bus
        if self._writer is None and hasattr(bus, "send_lines"):
            o = self.opt

            def failed(e):
                with self._cond:
                    if not self._fault:
                        self._fault = f"canopen: sending the cycle failed on {o.interface}:{o.channel}: {e}"
                    self._cond.notify_all()
            self._writer = _CycleWriter(bus.send_lines, encode_batch, self.network.send_lock, failed,
                                        max(0, o.bus_thread_priority - 2))

    def _stop_writer(self):
        """Every queued cycle written, the thread ended: what is sent next goes out after them."""
        w, self._writer = self._writer, None
        if w is not None:
            w.stop()

    def _host_heartbeat(self, force=False):
        now = time.monotonic()
        if force or now - self._t_host_hb >= self.opt.host_heartbeat_ms / 1e3:
            self._t_host_hb = now
            self.network.send_message(C.cob_heartbeat(self.opt.host_node_id), bytes([5]))

    def _wait_answers(self, timeout: float, when: str, late_cycles: int = 0):
        t_end = time.monotonic() + timeout
        need = self._syncs - late_cycles
        with self._cond:
            while True:
                late = [d for d in self.drives if d.answers < need]
                if not late or self._fault:
                    break
                left = t_end - time.monotonic()
                if left <= 0:
                    break
                self._cond.wait(left)
        if late and not (self._fault and self._enabled):   # in the run, a fault that ended the wait is the reason
            d = late[0]
            age = "never" if d.t_tpdo is None else f"{(time.monotonic() - d.t_tpdo) * 1e3:.1f} ms ago"
            allowed = f", {late_cycles} may be late" if late_cycles else ""
            raise HalTimeout(f"canopen {d.name}: TPDO1 0x{C.cob_tpdo1(d.id):03X} older than its cycle "
                             f"({when}): answered {d.answers} of {self._syncs} SYNCs{allowed}, last {age} "
                             f"(frame lost or drive silent)")

    def _fill_feedback(self):
        """Feedback at this tick. The TPDO answering SYNC s holds the drive's position at SYNC s,
        while it followed the target of SYNC s-1; that sample is a cycle or more old by now. The
        drive's own tracking error (target of SYNC s-1 - position at SYNC s) is applied to the last
        commanded position: the transport delay of the cycle is not a following error, the drive's
        lag is. ``positions()`` keeps the raw position actual."""
        fb = self._fb
        q = self._last_q
        with self._cond:
            answers = [(d.answers, d.pos) for d in self.drives]
        for i, (a, pos) in enumerate(answers):
            if q is None or a < 2 or self._syncs - a >= HISTORY - 1:
                fb.enc[i] = pos / self.inc_per_mm[i]
            else:
                # the answer to SYNC a: the drive's position while it followed the target of SYNC a-1
                fb.enc[i] = q[i] - (self._sent[(a - 1) % HISTORY, i] - pos) / self.inc_per_mm[i]
        if self._off.any():
            fb.enc += self._off_mm              # to the controller's frame (homing)
        fb.seq += 1

    # ---------------------------------------------------------------- loop side
    def _with_sim(self, e: HalError) -> HalError:
        """A fault while the drives' simulator process is gone says so."""
        if self.devsim is None or self.devsim.alive() or "device simulator" in str(e):
            return e
        self._fault = f"{e} ({self.devsim.exit_text()})"
        return type(e)(self._fault)

    def read(self) -> Feedback:
        try:
            return self._read()
        except HalError as e:
            raise self._with_sim(e) from None

    def _read(self) -> Feedback:
        if not self._enabled:
            raise HalError(self._fault or "canopen backend: read before open")
        if self._fault:
            self._stop_all()
            raise HalError(self._fault)
        lim = self.opt.heartbeat_timeout_ms / 1e3
        now = time.monotonic()
        for d in self.drives:                       # (a plain loop: this runs every tick)
            t = d.t_hb
            if t is not None and now - t > lim:
                break
        else:
            d = None
        if d is not None:
            # a heartbeat seems overdue: first let the receive thread work off what it has (after a
            # pause of this process the frames are there, unread), at most read_timeout_ms
            t_end = now + self.opt.read_timeout_ms / 1e3
            with self._cond:
                while True:
                    now = time.monotonic()
                    late = [d for d in self.drives if d.t_hb is not None and now - d.t_hb > lim]
                    if not late or now >= t_end:
                        break
                    self._cond.wait(t_end - now)
            if late:
                d = late[0]
                dead = self.devsim.exit_text() if self.devsim is not None else ""
                self._fault = (f"canopen {d.name}: heartbeat lost: none for {(now - d.t_hb) * 1e3:.0f} ms "
                               f"(timeout {self.opt.heartbeat_timeout_ms} ms){'; ' + dead if dead else ''}")
                self._stop_all()
                raise HalError(self._fault)
        if self._writes == self._need:
            try:
                self._wait_answers(self.opt.read_timeout_ms / 1e3, f"SYNC {self._syncs}", self.opt.late_cycles)
            except HalTimeout as e:
                self._fault = str(e)
                self._stop_all()
                raise HalError(self._fault) from None
            if self._fault:
                self._stop_all()
                raise HalError(self._fault)
            for d in self.drives:
                sw = d.sw
                if sw & C.SW_FOLLOWING_ERROR:
                    self._fault = (f"canopen {d.name}: following error reported by the drive (statusword "
                                   f"0x{sw:04X}){self._error_code(d)}")
                elif C.state_of(sw) != C.OPERATION_ENABLED:
                    self._fault = (f"canopen {d.name}: statusword 0x{sw:04X}: {C.state_of(sw)}"
                                   f"{self._error_code(d)}")
                if self._fault:
                    self._stop_all()
                    raise HalError(self._fault)
            self._fill_feedback()
        return self._fb

    def _error_code(self, d: _Drive) -> str:
        """0x603F of a faulted drive (a short SDO read; this is the way out of the run)."""
        if d.emcy is not None:
            return f", EMCY 0x{d.emcy:04X} ({C.emcy_text(d.emcy)})"
        self._stop_writer()                      # the SDO request after the cycles already queued
        old = d.node.sdo.RESPONSE_TIMEOUT
        try:
            d.node.sdo.RESPONSE_TIMEOUT = 0.02
            code = d.node.sdo[C.OD_ERROR_CODE].raw
            return f", error code 0x{code:04X} ({C.emcy_text(code)})"
        except Exception:            # noqa: BLE001 -- the fault is already known; the code is a detail
            return ", error code 0x603F unreadable"
        finally:
            d.node.sdo.RESPONSE_TIMEOUT = old

    def write_positions(self, q_mm) -> None:
        try:
            self._write_positions(q_mm - self._off_mm if self._off.any() else q_mm)
        except HalError as e:
            raise self._with_sim(e) from None

    def _write_positions(self, q_mm) -> None:
        if not self._enabled:
            raise HalError(self._fault or "canopen backend: write before open")
        if self._hb_task is not None:            # the ticks carry the host heartbeat from now on
            self._hb_task.stop()
            self._hb_task = None
            self._start_writer()
        q = np.asarray(q_mm, float)
        self._last_q = q
        if self._writes % self.cycle_ticks == 0:
            self._targets = np.rint(q * self.inc_per_mm).astype(np.int64)
            try:
                self._send_cycle()
            except Exception as e:      # noqa: BLE001 -- python-can raises CanError or OSError subclasses
                self._fault = f"canopen: sending the cycle failed on {self.opt.interface}:{self.opt.channel}: {e}"
                raise HalError(self._fault) from None
            self._need = self._writes + self.cycle_ticks
        self._writes += 1

    # ---------------------------------------------------------------- homing
    def inputs(self) -> Inputs:
        """The home switches (0x60FD bit 2 of each drive's last TPDO) and, per axis, the position the
        drive reported with the first TPDO that showed the switch's last change, as a pulse counter:
        good to the travel of one CAN cycle (the input and the position are sampled at the same SYNC)."""
        if self._in_built != self._in_ver or self._inputs is None:
            with self._cond:
                self._in_built = self._in_ver
                ppm = self.machine.resolution.pulses_per_mm
                home = tuple(bool(d.home) for d in self.drives) if self.drives else (False,) * 5
                latch = tuple((d.edges, d.edge_closed,
                               int(round(d.edge_pos / self.inc_per_mm[i] * ppm[i])) + int(self._off[i]))
                              for i, d in enumerate(self.drives)) if self.drives else None
            self._inputs = Inputs(home, False, latch)
        return self._inputs

    def rereference(self, counts) -> None:
        """Homing, at rest: the controller's counters become ``counts``; the drives keep their positions
        (no drive homing), the difference is kept as a per-axis offset (saved with the counters)."""
        ppm = self.machine.resolution.pulses_per_mm
        q = self._last_q if self._last_q is not None else self._targets / self.inc_per_mm
        self.set_reference_offset(np.asarray(counts, np.int64) - np.rint(q * ppm).astype(np.int64))

    def reference_offset(self) -> np.ndarray:
        return self._off.copy()

    def set_reference_offset(self, off) -> None:
        old = self._off_mm
        self._off = np.asarray(off, np.int64).copy()
        self._off_mm = self._off / self.machine.resolution.pulses_per_mm
        self._fb.enc += self._off_mm - old          # the feedback in hand moves to the new frame at once
        self._in_ver += 1

    def _stop_all(self):
        """Quick stop of every drive (they hold their last target): RPDOs + SYNC, best effort."""
        self._stop_writer()
        if not self._enabled or self.network is None:
            return
        self._enabled = False
        try:
            self._cw = C.CW_QUICK_STOP
            self._send_cycle()
            self._confirm_stop()
        except Exception:               # noqa: BLE001 -- a dead bus: the drives stop on the host heartbeat
            pass

    def _confirm_stop(self, timeout: float = 0.5):
        """After a quick stop: SYNC again (the drives report their statusword only in the TPDO that
        answers a SYNC) until every drive that still answers has left Operation enabled, at most
        ``timeout``; a silent drive stops on its own heartbeat consumer."""
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            with self._cond:
                n0 = [d.answers for d in self.drives]
                self._cond.wait_for(lambda: all(d.answers > a for d, a in zip(self.drives, n0))
                                    or time.monotonic() >= t_end, timeout=max(4 * self.cycle_s, 0.02))
                if all(C.state_of(d.sw) != C.OPERATION_ENABLED for d in self.drives):
                    return
            self._send_cycle()

    def status(self) -> Status:
        return Status(not self._fault, self._fault)

    def positions(self) -> np.ndarray:
        """Last position actual of each drive, increments."""
        return np.array([d.pos for d in self.drives], np.int64)

    def _disable_all(self):
        if self.network is None:
            return
        try:
            if self.drives and all(d.rpdo is not None for d in self.drives):
                self._cw = C.CW_SHUTDOWN if not self._fault else C.CW_DISABLE_VOLTAGE
                self._send_cycle()
        except Exception:              # noqa: BLE001
            pass
        try:
            self.network.nmt.send_command(0x80)      # pre-operational: no PDOs
        except Exception:              # noqa: BLE001
            pass

    def _teardown(self):
        if self._hb_task is not None:
            self._hb_task.stop()
            self._hb_task = None
        if self.network is not None:
            try:
                self.network.disconnect()
            except Exception:          # noqa: BLE001
                pass
            self.network = None
        if self.sim is not None:
            self.sim.stop()
        if self.devsim is not None:
            self.devsim.stop()

    def close(self) -> None:
        self._stop_writer()
        if self.network is not None:
            if self._enabled:
                # the last commanded position to the drives (a tick between SYNCs is not sent yet),
                # until they report it; then powered down and ready (Shutdown), then pre-operational
                self._enabled = False
                try:
                    if self._last_q is not None:
                        self._targets = np.rint(self._last_q * self.inc_per_mm).astype(np.int64)
                    for _ in range(max(10, int(0.2 / self.cycle_s))):
                        self._send_cycle()
                        self._wait_answers(0.2, "close")
                        if self._fault or np.array_equal(self.positions(), self._targets):
                            break
                    self._cw = C.CW_SHUTDOWN
                    self._send_cycle()
                    self._wait_answers(0.2, "close")
                except Exception:      # noqa: BLE001
                    pass
            self._disable_all()
        self._teardown()
