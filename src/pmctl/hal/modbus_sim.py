"""Simulated Modbus devices for tests and the out-of-the-box config: a pymodbus TCP server on a
loopback address, run in its own thread (asyncio loop), serving registers computed live by a
device model.

pymodbus trap: the device context adds 1 to every protocol address before it asks the data block
(``block[1]`` answers address 0). ``RegisterBlock`` undoes it in one place, so a device model
speaks protocol addresses only.

Devices:
- ``SimVFD``: a spindle inverter with the register map of pmctl.hal.modbus_vfd (default: Huanyang
  GT), a spin-up ramp, and fault / link-loss injection.
"""

from __future__ import annotations

import asyncio
import threading
import time

from pymodbus.constants import ExcCodes
from pymodbus.datastore import ModbusDeviceContext, ModbusServerContext
from pymodbus.datastore.store import BaseModbusDataBlock
from pymodbus.server import ModbusTcpServer


class RegisterBlock(BaseModbusDataBlock):
    """Holding or input registers answered by ``read(addr)`` / ``write(addr, value)`` of a device
    model (protocol addresses; an unknown address is ILLEGAL_ADDRESS)."""

    def __init__(self, device):
        self.device = device
        self.values = {}
        self.address = 0
        self.default_value = 0

    def getValues(self, address, count=1):
        out = []
        for a in range(address - 1, address - 1 + count):      # the context's +1, undone
            v = self.device.read(a)
            if v is None:
                return ExcCodes.ILLEGAL_ADDRESS
            out.append(int(v) & 0xFFFF)
        return out

    def setValues(self, address, values):
        for i, v in enumerate(values):
            if not self.device.write(address - 1 + i, int(v)):
                return ExcCodes.ILLEGAL_ADDRESS
        return None


class ModbusSimServer:
    """A pymodbus TCP server for one device (unit id ``device_id``) in a background thread; an RTU
    server on a serial device instead when ``serial`` = {port, baudrate, parity, stopbits}."""

    def __init__(self, device, host="127.0.0.1", port=0, device_id=1, input_registers=False, serial=None):
        if not host.startswith("127.") and host not in ("localhost", "::1"):
            raise ValueError(f"simulated Modbus devices listen on loopback addresses only, not {host}")
        self.device, self.host, self.port = device, host, int(port)
        block = RegisterBlock(device)
        dev = ModbusDeviceContext(hr=block, ir=block) if input_registers else ModbusDeviceContext(hr=block)
        self.context = ModbusServerContext(devices={device_id: dev}, single=False)
        self._loop = None
        self._server = None
        self._thread = None
        self._ready = threading.Event()
        self._error = None
        self._stop_lock = threading.Lock()
        self.serial = serial

    def start(self):
        self._thread = threading.Thread(target=self._run, daemon=True, name="pmctl-modbus-sim")
        self._thread.start()
        if not self._ready.wait(5.0):
            raise RuntimeError("simulated Modbus server did not start")
        if self._error:
            raise RuntimeError(f"simulated Modbus server on {self.host}:{self.port}: {self._error}")
        return self

    def _run(self):
        loop = asyncio.new_event_loop()
        self._loop = loop
        asyncio.set_event_loop(loop)

        async def main():
            try:
                if self.serial is not None:
                    from pymodbus import FramerType  # lazy: pymodbus loads only when a Modbus device is used
                    from pymodbus.server import ModbusSerialServer
                    self._server = ModbusSerialServer(self.context, framer=FramerType.RTU, bytesize=8,
                                                      **self.serial)
                    await self._server.serve_forever(background=True)
                    return
                self._server = ModbusTcpServer(self.context, address=(self.host, self.port))
                await self._server.serve_forever(background=True)
                if self.port == 0:
                    self.port = self._server.transport.sockets[0].getsockname()[1]
            except Exception as e:       # noqa: BLE001 -- reported to start()
                self._error = str(e)
            finally:
                self._ready.set()
        loop.run_until_complete(main())
        if not self._error:
            loop.run_forever()
        loop.close()

    def stop(self):
        """Stop serving and close the connections (a lost link, seen from a client). Idempotent."""
        with self._stop_lock:
            self._stop_locked()

    def _stop_locked(self):
        if self._loop is None or self._thread is None or self._loop.is_closed():
            return

        async def down():
            if self._server is not None:
                await self._server.shutdown()
        try:
            fut = asyncio.run_coroutine_threadsafe(down(), self._loop)
            fut.result(5.0)
        except Exception:            # noqa: BLE001 -- already down
            pass
        try:
            self._loop.call_soon_threadsafe(self._loop.stop)
        except RuntimeError:         # the loop closed meanwhile
            pass
        self._thread.join(5.0)
        self._thread = None


class SimVFD:
    """A spindle inverter. Registers (protocol addresses) from ``regs`` (pmctl.hal.modbus_vfd.VfdRegisters):
    command (run forward / reverse / stop codes), frequency set-point (0 .. 10000 = 0 .. max), output
    frequency (0.01 Hz), speed (rpm), fault. The output frequency ramps toward the set-point at
    ``ramp_hz_per_s``; rpm = frequency x 60 x rpm_per_hz_factor (a 2-pole spindle: 60 rpm per Hz)."""

    def __init__(self, regs, max_hz=400.0, rpm_per_hz=60.0, ramp_hz_per_s=200.0):
        self.r = regs
        self.max_hz, self.rpm_per_hz, self.ramp = float(max_hz), float(rpm_per_hz), float(ramp_hz_per_s)
        self.setpoint = 0            # 0 .. 10000
        self.run = 0                 # 0 stopped, +1 forward, -1 reverse
        self.freq = 0.0              # Hz, magnitude
        self.direction = 0
        self.fault_code = 0
        self.commands = []           # (register, value) written, for tests
        self._t = time.monotonic()
        self._lock = threading.Lock()

    def _advance(self):
        now = time.monotonic()
        dt, self._t = now - self._t, now
        if self.fault_code:
            target = 0.0             # a faulted inverter coasts to rest
        else:
            target = self.setpoint / 10000.0 * self.max_hz if self.run else 0.0
            if self.run and self.direction not in (0, self.run):
                target = 0.0         # reversing: down through zero first
        step = self.ramp * dt
        if abs(target - self.freq) <= step:
            self.freq = target
        else:
            self.freq += step if target > self.freq else -step
        if self.freq == 0.0:
            self.direction = self.run if self.run and not self.fault_code else 0
        elif self.direction == 0:
            self.direction = self.run

    def fault(self, code=0x0005):
        with self._lock:
            self._advance()
            self.fault_code = int(code)

    @property
    def rpm(self):
        with self._lock:
            self._advance()
            return self.freq * self.rpm_per_hz

    def read(self, addr):
        r = self.r
        with self._lock:
            self._advance()
            if addr == r.output_freq:
                return int(round(self.freq * 100))
            if addr == r.speed_rpm:
                return int(round(self.freq * self.rpm_per_hz))
            if addr == r.fault:
                return self.fault_code
            if addr == r.setpoint:
                return self.setpoint
            if addr == r.command:
                return {1: r.run_forward, -1: r.run_reverse, 0: r.stop}[self.run]
        return None

    def write(self, addr, value):
        r = self.r
        with self._lock:
            self._advance()
            if addr == r.setpoint:
                if not 0 <= value <= 10000:
                    return False
                self.setpoint = value
            elif addr == r.command:
                if value == r.run_forward:
                    self.run = 1
                elif value == r.run_reverse:
                    self.run = -1
                elif value == r.stop:
                    self.run = 0
                else:
                    return False
            else:
                return False
            self.commands.append((addr, value))
        return True


class SimDAQ:
    """A strain DAQ: input registers ``base`` .. ``base + 2`` hold strain gauges 1-3 as signed 16-bit
    counts of ``ue_per_count`` microstrain, ``base + 3`` a sample counter (mod 65536) that advances
    at ``sample_hz``. ``source()`` gives the strain to serve (e.g. the sim plant's gauges).
    Faults: ``freeze()`` (the counter and values stop: stale data while the link answers),
    ``delay_s`` (answers later than the client's timeout)."""

    def __init__(self, source, base=0x0000, ue_per_count=0.01, sample_hz=100.0):
        self.source, self.base, self.scale, self.hz = source, int(base), float(ue_per_count), float(sample_hz)
        self.frozen = False
        self.delay_s = 0.0
        self._t0 = time.monotonic()
        self._held = None
        self._held_n = 0

    def freeze(self):
        self._held_n = self._count()
        self._held = self._values()
        self.frozen = True

    def _count(self):
        return int((time.monotonic() - self._t0) * self.hz) & 0xFFFF

    def _values(self):
        s = list(self.source())
        return [max(-32768, min(32767, int(round(v / self.scale)))) for v in s[:3]]

    def read(self, addr):
        if self.delay_s:
            time.sleep(self.delay_s)
        i = addr - self.base
        if not 0 <= i <= 3:
            return None
        if i == 3:
            return self._held_n if self.frozen else self._count()
        v = (self._held if self.frozen else self._values())[i]
        return v & 0xFFFF

    def write(self, addr, value):
        return False
