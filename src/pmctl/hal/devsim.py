"""The device simulator: a process of its own hosting the simulated devices of the service config,
so that they do not share the control loop's process (and its interpreter lock):

- CiA 402 drives (pmctl.hal.cia402_sim) on a CAN "wire" made of slcan links
  (pmctl.hal.slcan_link), loopback TCP connections and/or ptys: the process is the hub; a frame
  written on one link goes to every other link and to the simulated drives, a frame a drive sends
  goes to every link. The master is one link; listeners (tests, benchmarks) are others, opened
  with python-can's own ``slcan`` interface like a USB-CAN adapter;
- the spindle VFD and the strain DAQ (pmctl.hal.modbus_sim), pymodbus servers on 127.0.0.1; the
  VFD speaks RTU instead on one end of a null modem made of two ptys, the client opens the other.

Start: ``python -m pmctl.hal.devsim '<spec as JSON>'``; it prints one JSON line when every device
answers (``{"ready": true, "can_tcp_port": .., "links": [pty, ...], "vfd_port": .., "daq_port": ..}``), then obeys
JSON lines on its standard input (fault injection, queries; each answered by one line) and ends
at the end of its input: the process that started it going away takes the devices with it.

``DeviceSimulator`` is the starting side: start, wait for ready, ``call``/``proxy``, stop.
"""

from __future__ import annotations

import json
import os
import queue
import select
import socket
import subprocess
import sys
import threading
import time

from pmctl.hal.base import HalError
from pmctl.hal.vfd_registers import VfdRegisters

READY_TIMEOUT_S = 60.0      # imports and server start on a loaded 2-core machine


# ------------------------------------------------------------------ the simulator process

def _close_ptys(ptys):
    for m, s, _p in ptys:
        for fd in (m, s):
            try:
                os.close(fd)
            except OSError:
                pass


PENDING_MAX = 1 << 20    # bytes a link's reader may fall behind (about 7 s of a 2 ms cycle) before it is given up


class Hub:
    """slcan links joined into one wire, plus a python-can bus for the local nodes. Links: ptys
    (``n_pty``, made now) and loopback TCP connections (accepted on ``tcp_port`` as they come).
    A pty hands its data over through a kernel worker of ordinary priority, which on a loaded
    machine delays a frame by milliseconds (tens at worst); loopback TCP delivers in the sender's
    own time slice."""

    def __init__(self, n_pty: int = 0, tcp: bool = True):

        from pmctl.hal.slcan_link import LineReader, raw  # lazy: python-can loads only when CAN drives are simulated
        self.ptys = []                      # (master fd, slave fd, slave path)
        self.fds = {}                       # link fd -> its LineReader
        for _ in range(n_pty):
            m, s = os.openpty()
            raw(s)                          # the slave's line discipline off before anyone opens it
            os.set_blocking(m, False)
            self.ptys.append((m, s, os.ttyname(s)))
            self.fds[m] = LineReader(m)
        self.listener = None
        if tcp:
            self.listener = socket.create_server(("127.0.0.1", 0))
        self.socks = {}                     # fd -> socket of the TCP links
        self.local: queue.SimpleQueue = queue.SimpleQueue()
        self.frames = 0
        self.dropped_links = set()
        self._pending = {}                  # link fd -> bytes its reader has not taken yet, in order
        self._wlock = threading.Lock()
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True, name="pmctl-devsim-hub")

    @property
    def paths(self):
        return [p for _m, _s, p in self.ptys]

    @property
    def tcp_port(self):
        return self.listener.getsockname()[1] if self.listener is not None else None

    def start(self):
        self._t.start()
        return self

    def broadcast(self, line: bytes, exclude: int | None = None):
        with self._wlock:
            for fd in list(self.fds):
                if fd == exclude or fd in self.dropped_links:
                    continue
                self._write(fd, line)

    def _write(self, fd: int, data: bytes) -> None:
        """``data`` to link ``fd`` without waiting (under _wlock): what its reader has not room for
        yet is kept in order and written as the link drains (the hub thread), so a reader that
        stalls a moment (a listener thread on a loaded host; a pty holds 4 kB, a few cycles) delays
        only its own link and loses nothing. Past PENDING_MAX the link is given up: a listener that
        went away must not hold the wire's memory."""
        buf = self._pending.get(fd)
        if buf is not None:
            buf += data
            if len(buf) > PENDING_MAX:
                self._pending.pop(fd, None)
                self.dropped_links.add(fd)
            return
        try:
            n = os.write(fd, data)
        except BlockingIOError:
            n = 0
        except OSError:
            self.dropped_links.add(fd)
            return
        if n < len(data):
            self._pending[fd] = bytearray(data[n:])

    def _flush(self, fds) -> None:
        with self._wlock:
            for fd in fds:
                buf = self._pending.get(fd)
                if buf is None:
                    continue
                try:
                    n = os.write(fd, buf)
                except BlockingIOError:
                    continue
                except OSError:
                    self._pending.pop(fd, None)
                    self.dropped_links.add(fd)
                    continue
                del buf[:n]
                if not buf:
                    self._pending.pop(fd, None)

    def _accept(self):

        from pmctl.hal.slcan_link import LineReader  # lazy: python-can loads only when CAN drives are simulated
        conn, _ = self.listener.accept()
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn.setblocking(False)
        with self._wlock:
            self.socks[conn.fileno()] = conn
            self.fds[conn.fileno()] = LineReader(conn.fileno())

    def _drop(self, fd):
        with self._wlock:
            self.fds.pop(fd, None)
            self.dropped_links.discard(fd)
            self._pending.pop(fd, None)
            sock = self.socks.pop(fd, None)
        if sock is not None:
            sock.close()

    def _run(self):
        from pmctl.hal.slcan_link import CR, decode  # lazy: python-can loads only when CAN drives are simulated
        while not self._stop.is_set():
            watch = list(self.fds) + ([self.listener.fileno()] if self.listener is not None else [])
            with self._wlock:
                backlog = [fd for fd in self._pending if fd in self.fds]
            r, w, _ = select.select(watch, backlog, [], 0.1 if not backlog else 0.005)
            if w:
                self._flush(w)
            for fd in r:
                if self.listener is not None and fd == self.listener.fileno():
                    self._accept()
                    continue
                rd = self.fds.get(fd)
                if rd is None:
                    continue
                try:
                    lines = rd.read()
                except BlockingIOError:
                    continue
                except (EOFError, OSError):
                    if fd in self.socks:    # a TCP link closed by its peer
                        self._drop(fd)
                    else:                   # EIO: no process has the pty's slave open right now
                        time.sleep(0.01)
                    continue
                for ln in lines:
                    try:
                        msg = decode(ln)
                    except ValueError:
                        msg = None
                    if msg is None:
                        if ln[:1] in (b"S", b"O", b"C", b"L", b"V", b"N", b"s"):
                            with self._wlock:      # an adapter's answer to a command
                                self._write(fd, b"V1013\r" if ln[:1] == b"V" else CR)
                        continue
                    self.frames += 1
                    self.broadcast(ln + CR, exclude=fd)
                    self.local.put(msg)

    def stop(self):
        self._stop.set()
        self._t.join(1.0)
        for fd in list(self.socks):
            self._drop(fd)
        if self.listener is not None:
            self.listener.close()
        _close_ptys(self.ptys)


class NullModem:
    """Two ptys joined like two serial ports by a null-modem cable: what one side's user writes,
    the other side's user reads (e.g. an RTU server on one, the client on the other)."""

    def __init__(self):
        from pmctl.hal.slcan_link import raw  # lazy: python-can loads only when CAN drives are simulated
        self.ends = []
        for _ in range(2):
            m, s = os.openpty()
            raw(s)
            self.ends.append((m, s, os.ttyname(s)))
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True, name="pmctl-devsim-null-modem")
        self._t.start()

    @property
    def paths(self):
        return [p for _m, _s, p in self.ends]

    def _run(self):
        (ma, _sa, _pa), (mb, _sb, _pb) = self.ends
        other = {ma: mb, mb: ma}
        while not self._stop.is_set():
            r, _, _ = select.select([ma, mb], [], [], 0.1)
            for fd in r:
                try:
                    data = os.read(fd, 4096)
                    os.write(other[fd], data)
                except OSError:             # EIO: that end is not open right now: the bytes are lost
                    time.sleep(0.01)

    def stop(self):
        self._stop.set()
        self._t.join(1.0)
        _close_ptys(self.ends)


def hub_bus(hub: Hub):
    """The python-can bus of the simulated nodes on the hub's wire."""
    import can  # lazy: python-can loads only when CAN drives are simulated

    from pmctl.hal.slcan_link import encode  # lazy: python-can loads only when CAN drives are simulated

    class HubBus(can.BusABC):
        def __init__(self):
            self.channel_info = "devsim hub"
            super().__init__("devsim-hub")

        def _recv_internal(self, timeout):
            try:
                return hub.local.get(timeout=timeout), False
            except queue.Empty:
                return None, False

        def send(self, msg, timeout=None):
            hub.broadcast(encode(msg))

    return HubBus()


def _set_rt(priority: int) -> str:
    if priority <= 0:
        return ""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        return ""
    except (OSError, AttributeError) as e:
        return f"no SCHED_FIFO {priority} for the device simulator ({e})"


class _Sim:
    """The devices of one spec, and the commands that reach them."""

    def __init__(self, spec: dict):
        self.spec = spec
        self.notes = []
        note = _set_rt(int(spec.get("rt_priority", 0)))    # threads started from here on inherit it
        if note:
            self.notes.append(note)
        self.hub = self.drives = None
        self.vfd = self.vfd_server = self.modem = None
        self.daq = self.daq_server = None
        self.strain = [0.0, 0.0, 0.0]
        if "can" in spec:
            c = spec["can"]
            # lazy: canopen loads only when CAN drives are simulated
            from pmctl.hal.cia402_sim import EDS_PATH, SimDriveSet
            self.hub = Hub(int(c.get("ptys", 0)), tcp=bool(c.get("tcp", True))).start()
            self.drives = SimDriveSet(c["node_ids"], c["positions"], bus=hub_bus(self.hub),
                                      lag_s=float(c.get("lag_s", 0.0)), eds=c.get("eds") or EDS_PATH,
                                      home_at=c.get("home_at"))
        if "vfd" in spec:
            v = spec["vfd"]
            # lazy: pymodbus loads only when a Modbus device is simulated
            from pmctl.hal.modbus_sim import ModbusSimServer, SimVFD
            self.vfd = SimVFD(VfdRegisters(**v["registers"]), max_hz=v["max_hz"], rpm_per_hz=v["max_rpm"] / v["max_hz"],
                              ramp_hz_per_s=v["ramp_rpm_per_s"] * v["max_hz"] / v["max_rpm"])
            serial = None
            if v.get("rtu"):                # RTU: the server on one end of a null modem, the client's end reported
                self.modem = NullModem()
                serial = {"port": self.modem.paths[0], **v["rtu"]}
            self.vfd_server = ModbusSimServer(self.vfd, v["host"], v["port"], v["device_id"], serial=serial).start()
        if "daq" in spec:
            d = spec["daq"]
            # lazy: pymodbus loads only when a Modbus device is simulated
            from pmctl.hal.modbus_sim import ModbusSimServer, SimDAQ
            self.daq = SimDAQ(lambda: self.strain, d["base"], d["ue_per_count"], d["sample_hz"])
            self.daq_server = ModbusSimServer(self.daq, d["host"], d["port"], d["device_id"],
                                              input_registers=True).start()

    def ready(self) -> dict:
        return {"ready": True, "pid": os.getpid(), "links": self.hub.paths if self.hub else [],
                "can_tcp_port": self.hub.tcp_port if self.hub else None,
                "vfd_port": self.vfd_server.port if self.vfd_server else None,
                "vfd_serial": self.modem.paths[1] if self.modem else None,
                "daq_port": self.daq_server.port if self.daq_server else None, "notes": self.notes}

    def target(self, name: str):
        if name.startswith("drive:"):
            return self.drives.by_id[int(name[6:])]
        return {"drives": self.drives, "hub": self.hub, "vfd": self.vfd, "vfd_server": self.vfd_server,
                "daq": self.daq, "daq_server": self.daq_server}[name]

    def handle(self, req: dict):
        if "strain" in req:                 # pushed by the DAQ's user, no answer
            self.strain = [float(x) for x in req["strain"]]
            return None
        obj = self.target(req["target"])
        if "set" in req:
            setattr(obj, req["set"], req["value"])
            return None
        if "get" in req:
            return getattr(obj, req["get"])
        fn = getattr(obj, req["call"])
        args = req.get("args", [])
        if "at_sync" in req:                # a drive fault scheduled n SYNCs ahead
            obj.at_sync(int(req["at_sync"]), lambda: fn(*args))
            return None
        return fn(*args)

    def stop(self):
        for s in (self.vfd_server, self.daq_server):
            if s is not None:
                s.stop()
        if self.modem is not None:
            self.modem.stop()
        if self.drives is not None:
            self.drives.stop()
        if self.hub is not None:
            self.hub.stop()


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    spec = json.loads(argv[0])
    out = sys.stdout
    try:
        sim = _Sim(spec)
    except Exception as e:                  # noqa: BLE001 -- told to the starting side, which raises it
        out.write(json.dumps({"ready": False, "error": f"{type(e).__name__}: {e}"}) + "\n")
        out.flush()
        return 2
    out.write(json.dumps(sim.ready()) + "\n")
    out.flush()
    try:
        for line in sys.stdin:
            if not line.strip():
                continue
            req = json.loads(line)
            try:
                res = sim.handle(req)
                ans = {"id": req.get("id"), "result": res}
            except Exception as e:          # noqa: BLE001 -- the caller gets the error text
                ans = {"id": req.get("id"), "error": f"{type(e).__name__}: {e}"}
            if "id" in req:
                try:
                    out.write(json.dumps(ans, default=repr) + "\n")
                    out.flush()
                except (BrokenPipeError, OSError):
                    break
    finally:
        sim.stop()
    return 0


# ------------------------------------------------------------------ the starting side

class DeviceSimulatorError(RuntimeError):
    pass


class DeviceSimulator:
    """Starts ``python -m pmctl.hal.devsim`` for ``spec``, waits until its devices answer, talks
    to it, stops it."""

    def __init__(self, spec: dict, what: str = "device simulator"):
        self.spec, self.what = spec, what
        self.proc = None
        self.info = {}
        self._lock = threading.Lock()
        self._ids = 0

    def start(self, timeout: float = READY_TIMEOUT_S):
        env = dict(os.environ)
        src = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        env["PYTHONPATH"] = src + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        self.proc = subprocess.Popen([sys.executable, "-m", "pmctl.hal.devsim", json.dumps(self.spec)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     env=env, text=True, bufsize=1, start_new_session=True)
        line = self._readline(timeout)
        if not line:
            err = self._stderr()
            self.stop()
            raise DeviceSimulatorError(f"{self.what}: no answer within {timeout:g} s{err}")
        info = json.loads(line)
        if not info.get("ready"):
            self.stop()
            raise DeviceSimulatorError(f"{self.what}: {info.get('error', 'did not start')}")
        self.info = info
        return self

    def _readline(self, timeout: float) -> str:
        t_end = time.monotonic() + timeout
        fd = self.proc.stdout
        while True:
            left = t_end - time.monotonic()
            if left <= 0:
                return ""
            r, _, _ = select.select([fd], [], [], min(left, 0.5))
            if r:
                return fd.readline()
            if self.proc.poll() is not None:
                return ""

    def _stderr(self) -> str:
        if self.proc is None or self.proc.poll() is None:
            return ""
        try:
            text = self.proc.stderr.read().strip()
        except (OSError, ValueError):
            text = ""
        return f" (exit code {self.proc.returncode}{': ' + text.splitlines()[-1] if text else ''})"

    @property
    def links(self) -> list[str]:
        return self.info.get("links", [])

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def exit_text(self) -> str:
        if self.proc is None or self.alive():
            return ""
        return f"the device simulator (pid {self.proc.pid}) exited with code {self.proc.returncode}"

    def send(self, req: dict, answer: bool = True, timeout: float = 10.0):
        with self._lock:
            if answer:
                self._ids += 1
                req = {**req, "id": self._ids}
            try:
                self.proc.stdin.write(json.dumps(req) + "\n")
                self.proc.stdin.flush()
            except (OSError, ValueError) as e:
                raise DeviceSimulatorError(f"{self.what}: gone ({e}){self._stderr()}") from None
            if not answer:
                return None
            line = self._readline(timeout)
        if not line:
            raise DeviceSimulatorError(f"{self.what}: no answer to {req}{self._stderr()}")
        ans = json.loads(line)
        if "error" in ans:
            raise DeviceSimulatorError(f"{self.what}: {req.get('target')}.{req.get('call') or req.get('get')}: "
                                       f"{ans['error']}")
        return ans.get("result")

    def call(self, target: str, name: str, *args, at_sync: int | None = None):
        req = {"target": target, "call": name, "args": list(args)}
        if at_sync is not None:
            req["at_sync"] = at_sync
        return self.send(req)

    def get(self, target: str, name: str):
        return self.send({"target": target, "get": name})

    def set(self, target: str, name: str, value):
        return self.send({"target": target, "set": name, "value": value})

    def push_strain(self, strain) -> None:
        try:
            self.send({"strain": [float(x) for x in strain]}, answer=False)
        except DeviceSimulatorError:
            pass                            # a gone simulator shows as the DAQ's timeout

    def proxy(self, target: str) -> "Remote":
        return Remote(self, target)

    def stop(self, timeout: float = 5.0):
        p = self.proc
        if p is None:
            return
        try:
            p.stdin.close()                 # end of input: the simulator stops its devices and exits
        except (OSError, ValueError):
            pass
        try:
            p.wait(timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout)
        for f in (p.stdout, p.stderr):
            try:
                f.close()
            except (OSError, ValueError):
                pass

    def kill(self):
        """The simulator dies (a test of what a dead device means to its master)."""
        if self.alive():
            self.proc.kill()
            self.proc.wait(5.0)


class Remote:
    """A device in the simulator process: attribute reads, writes and method calls go over the pipe."""

    def __init__(self, sim: DeviceSimulator, target: str):
        object.__setattr__(self, "_sim", sim)
        object.__setattr__(self, "_target", target)

    def __getattr__(self, name):
        sim, target = self._sim, self._target
        value = sim.get(target, name) if not name.startswith("_") else None
        if isinstance(value, str) and value.startswith("<bound method"):
            return lambda *args, at_sync=None: sim.call(target, name, *args, at_sync=at_sync)
        return value

    def __setattr__(self, name, value):
        self._sim.set(self._target, name, value)


if __name__ == "__main__":
    sys.exit(main())


def start_simulated(kind: str, spec: dict, what: str):
    """A session's simulated device (``kind`` "vfd" or "daq", ``spec`` its devsim spec) in a device
    simulator process (pmctl.hal.devsim), not in the loop's process. Returns (simulator, device
    proxy, server proxy); a simulator that does not start is a HalError saying why."""
    try:
        sim = DeviceSimulator({kind: spec}, what).start()
    except DeviceSimulatorError as e:
        raise HalError(str(e)) from None
    return sim, sim.proxy(kind), sim.proxy(f"{kind}_server")


def stop_simulated(sim, server) -> None:
    """Shut a session's simulated device down: its device simulator process when it has one, else
    its server in this process (either may be None). The session then drops both."""
    if sim is not None:
        sim.stop()
    elif server is not None:
        server.stop()
