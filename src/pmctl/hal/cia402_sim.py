"""Simulated CiA 402 servo drives: ``canopen`` LocalNodes built from the shipped EDS
(data/cia402_drive.eds, device type 0x20192), answering on a python-can bus.

What the library's LocalNode gives: the SDO server on the object dictionary, NMT commands, boot-up,
the heartbeat producer (0x1017) and the EMCY producer. What this module adds, as callbacks:
- the CiA 402 state machine on 0x6040 / 0x6041 (controlword by RPDO or SDO), modes 0x6060/0x6061;
- synchronous PDOs: the RPDO (target 0x607A + controlword) is stored when it arrives and applied on
  the next SYNC; on every SYNC the drive samples and sends its TPDO (position actual 0x6064 +
  statusword), as the PDO maps written by SDO say (only while NMT operational);
- a home switch per drive (optional): 0x60FD bit 2 is set while the position is at or past it,
  sampled with the position each SYNC (so the TPDO's position and input belong to one instant);
- motion: in Operation enabled, cyclic synchronous position, the motor follows the latched target
  with a first-order lag per SYNC cycle (lag 0 = reaches each target by the next SYNC);
- its own safety: a target jump beyond the following-error window 0x6065 or a lost host heartbeat
  (consumer 0x1016) ends in Fault with an EMCY; targets are ignored unless enabled.

Fault injection for tests: ``fault(code, emcy=True)`` (statusword fault bit, 0x603F, EMCY),
``emcy(code)`` (an EMCY alone), ``following_error()`` (statusword bit 13 + EMCY 0x8611),
``silence_heartbeat()``, ``go_silent()`` (answers nothing at all), ``drop_tpdos(n)``; each can be
scheduled n SYNCs ahead with ``at_sync(n, fn)``.

Buses: python-can ``virtual`` (one process; every can.Bus on the same channel name sees the
others' frames), or the device simulator's slcan links over ptys (pmctl.hal.devsim: the drives in
a process of their own).
"""

from __future__ import annotations

import math
import struct
import threading
import time
from importlib import resources

import can
import canopen

from pmctl.hal import cia402 as C

EDS_PATH = str(resources.files("pmctl.hal").joinpath("data/cia402_drive.eds"))


class SimDrive:
    """One simulated drive (a LocalNode and its 402 behaviour)."""

    def __init__(self, node_id: int, position: int = 0, lag_s: float = 0.0, eds: str = EDS_PATH,
                 home_at: int | None = None):
        self.id = node_id
        self.home_at = home_at                  # home switch closed at position >= this (increments); None: none
        self.node = canopen.LocalNode(node_id, eds)
        self.lag_s = float(lag_s)
        self.state = C.SWITCH_ON_DISABLED
        self.pos = float(position)              # motor position, increments
        self.target = int(position)             # latched target
        self._rx_target = int(position)         # last RPDO content, applied on SYNC
        self._rx_cw = 0
        self.cw = 0
        self.error_code = 0
        self.ferr_flag = False
        self.syncs = 0                          # SYNCs seen while operational
        self.tpdos_sent = 0
        self.fault_resets = 0
        self.rpdos = 0
        self._drop = 0
        self.heartbeat_silent = False
        self.silent = False
        self._scheduled: list[tuple[int, object]] = []
        self.last_host_hb = None
        self._lock = threading.RLock()
        self._cache = {}
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)

    # ---------------------------------------------------------------- fault injection
    def at_sync(self, n: int, fn) -> None:
        """Run ``fn()`` when this drive handles the n-th SYNC from now (counted while operational)."""
        with self._lock:
            self._scheduled.append((self.syncs + int(n), fn))

    def fault(self, code: int = 0x2310, emcy: bool = True) -> None:
        with self._lock:
            self.error_code = code
            self.state = C.FAULT
            if emcy and not self.silent:
                self.node.emcy.send(code, 0x01)

    def emcy(self, code: int) -> None:
        self.node.emcy.send(code, 0x01)

    def following_error(self) -> None:
        with self._lock:
            self.ferr_flag = True
        self.fault(C.EMCY_FOLLOWING_ERROR)

    def silence_heartbeat(self) -> None:
        self.heartbeat_silent = True
        self.node.nmt.stop_heartbeat()

    def go_silent(self) -> None:
        """Cut off: sends nothing and hears nothing (it then faults by itself on the host's lost heartbeat)."""
        self.silence_heartbeat()
        self.silent = True

    def drop_tpdos(self, n: int) -> None:
        with self._lock:
            self._drop += int(n)

    # ---------------------------------------------------------------- dictionary callbacks
    @property
    def statusword(self) -> int:
        sw = C.STATUSWORD_OF[self.state]
        if self.state == C.OPERATION_ENABLED and abs(self.pos - self.target) < 0.5:
            sw |= C.SW_TARGET_REACHED
        if self.ferr_flag:
            sw |= C.SW_FOLLOWING_ERROR
        return sw

    @property
    def digital_inputs(self) -> int:
        """0x60FD: the home switch (bit 2), sampled with the position."""
        return C.DI_HOME_SWITCH if self.home_at is not None and self.pos >= self.home_at else 0

    def _on_read(self, index, subindex, od):
        if index == C.OD_DIGITAL_INPUTS:
            return self.digital_inputs
        if index == C.OD_STATUSWORD:
            return self.statusword
        if index == C.OD_POSITION_ACTUAL:
            return int(round(self.pos))
        if index == C.OD_ERROR_CODE:
            return self.error_code
        if index == C.OD_MODE_DISPLAY:
            return self._get(C.OD_MODE, 0)
        if index == C.OD_FOLLOWING_ACTUAL:
            return int(round(self.target - self.pos))
        if index == C.OD_CONTROLWORD:
            return self.cw
        return None

    def _on_write(self, index, subindex, od, data):
        self._cache.clear()                # the SDO server stores the value after this callback
        if index == C.OD_HB_CONSUMER:
            self.last_host_hb = None       # the consumer starts with the next heartbeat it hears
        if index == C.OD_CONTROLWORD:
            cw, = struct.unpack("<H", data)
            self._apply_controlword(cw)
        elif index == C.OD_MODE:
            mode, = struct.unpack("<b", data)
            if mode != C.MODE_CSP:
                raise canopen.SdoAbortedError(0x06090030)  # value range of parameter exceeded
        elif index == C.OD_TARGET and self.state == C.OPERATION_ENABLED:
            raise canopen.SdoAbortedError(0x08000022)      # not while enabled: targets come by PDO

    def _get(self, index, subindex, default=None):
        key = (index, subindex)
        if key in self._cache:
            return self._cache[key]
        v = self._get_od(index, subindex, default)
        if index < 0x6000 or index in (C.OD_MODE, C.OD_FOLLOWING_WINDOW):     # configuration, not live values
            self._cache[key] = v
        return v

    def _get_od(self, index, subindex, default=None):
        try:
            raw = self.node.get_data(index, subindex)
        except canopen.SdoAbortedError:
            return default
        obj = self.node.object_dictionary[index]
        if not isinstance(obj, canopen.objectdictionary.ODVariable):
            obj = obj[subindex]
        return obj.decode_raw(raw)

    def _apply_controlword(self, cw: int) -> None:
        with self._lock:
            new = C.next_state(self.state, cw, self.cw)
            if self.state == C.FAULT and new != C.FAULT:
                self.fault_resets += 1
                self.last_host_hb = None
                self.error_code = 0
                self.ferr_flag = False
                self.node.emcy.reset()
            if new == C.OPERATION_ENABLED and self.state != C.OPERATION_ENABLED:
                self.target = int(round(self.pos))       # no jump on enabling
            self.state = new
            self.cw = cw

    # ---------------------------------------------------------------- PDO
    def _map(self, map_index):
        key = ("map", map_index)
        if key not in self._cache:
            self._cache[key] = self._map_od(map_index)
        return self._cache[key]

    def _map_od(self, map_index):
        n = self._get(map_index, 0, 0)
        out = []
        for s in range(1, n + 1):
            e = self._get(map_index, s, 0)
            out.append((e >> 16, (e >> 8) & 0xFF, e & 0xFF))
        return out

    def on_rpdo(self, data: bytes) -> None:
        if self.silent or self.node.nmt.state != "OPERATIONAL":
            return
        off = 0
        with self._lock:
            self.rpdos += 1
            for index, _sub, bits in self._map(C.OD_RPDO1_MAP):
                n = bits // 8
                chunk = bytes(data[off:off + n])
                off += n
                if len(chunk) < n:
                    return
                if index == C.OD_TARGET:
                    self._rx_target, = struct.unpack("<i", chunk)
                elif index == C.OD_CONTROLWORD:
                    self._rx_cw, = struct.unpack("<H", chunk)

    def on_sync(self, cycle_s: float) -> None:
        with self._lock:
            if self.node.nmt.state != "OPERATIONAL":
                return
            self.syncs += 1
            due = [fn for n, fn in self._scheduled if n == self.syncs]
            self._scheduled = [(n, fn) for n, fn in self._scheduled if n != self.syncs]
        for fn in due:
            fn()
        with self._lock:
            # 1. the motor moved over the past cycle toward the latched target
            if self.state == C.OPERATION_ENABLED:
                if self.lag_s > 0:
                    self.pos += (self.target - self.pos) * (1.0 - math.exp(-cycle_s / self.lag_s))
                    if abs(self.target - self.pos) < 0.5:
                        self.pos = float(self.target)
                else:
                    self.pos = float(self.target)
            # 2. sample and send the TPDO
            payload = bytearray()
            for index, _sub, bits in self._map(C.OD_TPDO1_MAP):
                if index == C.OD_POSITION_ACTUAL:
                    payload += struct.pack("<i", int(round(self.pos)))
                elif index == C.OD_STATUSWORD:
                    payload += struct.pack("<H", self.statusword)
                elif index == C.OD_FOLLOWING_ACTUAL:
                    payload += struct.pack("<i", int(round(self.target - self.pos)))
                elif index == C.OD_DIGITAL_INPUTS:      # mapped whole or as its low bytes
                    payload += struct.pack("<I", self.digital_inputs)[:bits // 8]
                else:
                    payload += bytes(bits // 8)
            drop = self._drop > 0
            if drop:
                self._drop -= 1
            send = not (self.silent or drop)
            cob = self._get(C.OD_TPDO1_COMM, 1, C.cob_tpdo1(self.id))
            # 3. latch what the RPDO brought before this SYNC
            if self._rx_cw != self.cw:
                cw_new = self._rx_cw
            else:
                cw_new = None
            if self.state == C.OPERATION_ENABLED:
                window = self._get(C.OD_FOLLOWING_WINDOW, 0, 0)
                if window and abs(self._rx_target - self.pos) > window:
                    self.error_code = C.EMCY_FOLLOWING_ERROR
                    self.ferr_flag = True
                    self.state = C.FAULT
                    self.node.emcy.send(C.EMCY_FOLLOWING_ERROR, 0x81)
                else:
                    self.target = self._rx_target
            else:
                self.target = int(round(self.pos))
        if send and not cob & 0x80000000:
            self.node.network.send_message(cob & 0x7FF, bytes(payload))
            self.tpdos_sent += 1
        if cw_new is not None:
            self._apply_controlword(cw_new)
            with self._lock:
                if self.state != C.OPERATION_ENABLED:
                    self.target = int(round(self.pos))

    def check_host(self, now: float) -> None:
        """Heartbeat consumer (0x1016:01 = host node << 16 | time ms): a drive that stops hearing
        the host while enabled faults by itself (the host's ticks stopped)."""
        if self.state != C.OPERATION_ENABLED:
            return
        entry = self._get(C.OD_HB_CONSUMER, 1, 0) or 0
        ms = entry & 0xFFFF
        if not ms or self.last_host_hb is None:
            return
        if (now - self.last_host_hb) * 1e3 > ms:
            self.fault(C.EMCY_HEARTBEAT)


class SimDriveSet:
    """Drives on one bus: their own python-can Bus and canopen Network (a second node on the wire)."""

    def __init__(self, node_ids, positions, *, interface="virtual", channel="pmctl-can0", bitrate=1_000_000,
                 lag_s=0.0, eds: str = EDS_PATH, bus: can.BusABC | None = None, home_at=None):
        """``home_at``: per drive the position (increments) at and above which its home switch is
        closed, None for a drive without one; None: no home switches."""
        home_at = list(home_at) if home_at is not None else [None] * len(node_ids)
        self.drives = [SimDrive(n, p, lag_s, eds, h) for n, p, h in zip(node_ids, positions, home_at)]
        self.by_id = {d.id: d for d in self.drives}
        self.network = canopen.Network(bus)          # a given bus: e.g. the device simulator's hub
        kw = {"interface": interface, "channel": channel}
        if interface != "virtual":
            kw["bitrate"] = bitrate
        self.network.connect(**kw)
        self._last_sync = None
        self.cycle_s = 0.0
        for d in self.drives:
            self.network.add_node(d.node)
            sdo = d.node.sdo
            orig = sdo.on_request

            def on_request(can_id, data, ts, _d=d, _orig=orig):
                if not _d.silent:
                    _orig(can_id, data, ts)
            self.network.unsubscribe(sdo.rx_cobid, orig)
            self.network.subscribe(sdo.rx_cobid, on_request)
            self.network.subscribe(C.cob_rpdo1(d.id), lambda cid, data, ts, _d=d: _d.on_rpdo(data))
        self.network.subscribe(C.COB_SYNC, self._on_sync)
        self._host_ids = set()
        for d in self.drives:
            d.node.nmt.send_command(0x81)      # reset: boot-up message
            d.node.nmt.send_command(0x80)      # -> pre-operational
        self._stop = threading.Event()
        self._watch = threading.Thread(target=self._watchdog, daemon=True, name="pmctl-sim402-watchdog")
        self._watch.start()
        self._hb_subscribed: set[int] = set()
        self._refresh_host_subscriptions()

    def _refresh_host_subscriptions(self):
        for d in self.drives:
            entry = d._get(C.OD_HB_CONSUMER, 1, 0) or 0
            host = (entry >> 16) & 0x7F
            if host and host not in self._hb_subscribed:
                self._hb_subscribed.add(host)
                self.network.subscribe(C.cob_heartbeat(host), self._on_host_hb)
        self._host_ids = {((d._get(C.OD_HB_CONSUMER, 1, 0) or 0) >> 16) & 0x7F for d in self.drives}

    def _on_host_hb(self, can_id, data, ts):
        host = can_id - 0x700
        now = time.monotonic()
        for d in self.drives:
            if not d.silent and ((d._get(C.OD_HB_CONSUMER, 1, 0) or 0) >> 16) & 0x7F == host:
                d.last_host_hb = now

    def _on_sync(self, can_id, data, ts):
        if self._hb_subscribed != {h for h in self._host_ids if h}:
            self._refresh_host_subscriptions()
        for d in self.drives:
            period_us = d._get(C.OD_COMM_CYCLE, 0, 0) or 0
            d.on_sync(period_us / 1e6 if period_us else 1e-3)

    def _watchdog(self):
        while not self._stop.wait(0.01):
            self._refresh_host_subscriptions()
            now = time.monotonic()
            for d in self.drives:
                try:
                    d.check_host(now)
                except Exception:        # noqa: BLE001 -- a closing bus must not kill the watchdog noisily
                    pass

    def positions(self) -> list[int]:
        return [int(round(d.pos)) for d in self.drives]

    def stop(self):
        self._stop.set()
        self._watch.join(timeout=1.0)
        for d in self.drives:
            d.node.nmt.stop_heartbeat()
        self.network.disconnect()


def bus(interface="virtual", channel="pmctl-can0", bitrate=1_000_000) -> can.BusABC:
    """A plain python-can bus on the same wire (a listener for tests and benchmarks)."""
    kw = {"interface": interface, "channel": channel}
    if interface != "virtual":
        kw["bitrate"] = bitrate
    return can.Bus(**kw)
