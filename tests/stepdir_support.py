"""Test support for the step/dir bridge: start the real host bridge (firmware_bridge/build/bridge-host)
on a pty with an edge log and a control FIFO, or the RP2040 image in the emulated chip
(pmctl.hal.rp2040_emu), and read what it did."""

from __future__ import annotations

import os
import select
import subprocess
import time
from pathlib import Path

import numpy as np
import serial

from pmctl.hal import bridge_protocol as bp
from pmctl.hal.stepdir import ensure_built


class Bridge:
    """The host build of the bridge as a child of the test (not of the backend under test)."""

    def __init__(self, tmp: Path):
        self.binary = ensure_built()
        self.edge_log = tmp / "edges.bin"
        self.control = tmp / "control.fifo"
        self.proc = subprocess.Popen([str(self.binary), "--edge-log", str(self.edge_log), "--control",
                                      str(self.control), "--quiet"], stdout=subprocess.PIPE)
        r, _, _ = select.select([self.proc.stdout], [], [], 10.0)
        line = self.proc.stdout.readline().decode().strip() if r else ""
        assert line.startswith("PTY "), line
        self.port = line[4:]
        self._ctl = os.open(self.control, os.O_WRONLY)

    def ctl(self, line: str):
        os.write(self._ctl, (line + "\n").encode())

    def options(self, **kw):
        """Backend options for this bridge. The timeouts are generous: seven test processes share two
        cores here, and these tests check what was executed, not how fast (benchmarks/ does that)."""
        return {"port": self.port, "read_timeout_ms": 200.0, "link_timeout_ms": 500.0, "watchdog_ms": 1000.0,
                **kw}

    def edges(self):
        self.flush()
        return bp.read_edge_log(self.edge_log)

    def flush(self):
        # the bridge flushes its edge log whenever it is not stepping: wait until it says so
        t_end = time.monotonic() + 5
        while self.status().state in (bp.S_RUNNING, bp.S_DRAINING) and time.monotonic() < t_end:
            time.sleep(0.01)
        time.sleep(0.03)

    status_timeout = 1.0

    def _time_us(self):
        """The bridge's clock now (us), to tell a STATUS sent after a request from older ones; None: any."""
        return None

    def status(self) -> bp.BridgeStatus:
        """Opens the pty as a second host would and asks for a status (not sequenced: changes nothing)."""
        with serial.Serial(self.port, timeout=0) as s:
            s.reset_input_buffer()            # the pty may hold old reports: the bridge sends them while idle
            p = bp.Parser()
            t_req = self._time_us()
            t_end = time.monotonic() + self.status_timeout
            s.write(bp.frame(0, bp.T_STATUS_REQ))
            while time.monotonic() < t_end:
                for f in p.feed(s.read(4096)):
                    if f.type == bp.T_STATUS:
                        st = bp.decode_status(f)
                        if t_req is None or st.time_us >= t_req - 2:
                            return st
                time.sleep(0.002)
        raise AssertionError("no status from the bridge")

    def stop(self):
        try:
            os.close(self._ctl)
        except OSError:
            pass
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.proc.stdout.close()


class EmulatedBridge(Bridge):
    """The RP2040 image (build/rp2040/bridge.elf) in the emulated chip, with the host build's test
    interface: the same pty protocol, edge-log format and control lines. Its edge times are the
    chip's simulated time; ``clock`` is that time, for the backend's timeouts."""

    def __init__(self, tmp: Path, **kw):
        from pmctl.hal.rp2040_emu import Emulator
        self.edge_log = tmp / "edges.bin"
        self.control = tmp / "control.fifo"
        self.emu = Emulator(edge_log=self.edge_log, control=self.control, **kw)
        self.port = self.emu.port
        self.clock = self.emu.sim_time
        self.figures = {}

    def ctl(self, line: str):
        self.emu.ctl(line)

    def options(self, **kw):
        """Timeouts in the chip's time (the backend gets ``clock``): the host build's test values."""
        return {"port": self.port, "read_timeout_ms": 200.0, "link_timeout_ms": 500.0, "watchdog_ms": 1000.0,
                **kw}

    def flush(self):
        # the runner writes its edge log when 2 ms of the chip's time pass without an edge
        t_end = time.monotonic() + 20
        while self.status().state in (bp.S_RUNNING, bp.S_DRAINING) and time.monotonic() < t_end:
            time.sleep(0.01)
        t = self.clock()
        while self.clock() < t + 0.003 and time.monotonic() < t_end:
            time.sleep(0.01)
        time.sleep(0.1)

    status_timeout = 20.0

    def _time_us(self):
        """Only a STATUS the chip sent after the request (the pty may hold old ones: the chip reports
        every 10 ms while no host reads); the chip's STATUS time is its TIMER's, the emulator's clock."""
        return self.clock() * 1e6

    def stop(self):
        self.figures = self.emu.stop()


def per_tick_steps(log) -> dict:
    """{tick index: (5,) signed rising edges executed in that tick} from an edge log."""
    out = {}
    sign = np.ones(5, np.int64)
    for r in log:
        a, kind = int(r["axis"]), int(r["kind"])
        if kind == bp.EDGE_DIR_NEG:
            sign[a] = -1
        elif kind == bp.EDGE_DIR_POS:
            sign[a] = 1
        elif kind == bp.EDGE_HIGH:
            out.setdefault(int(r["tick"]), np.zeros(5, np.int64))[a] += sign[a]
    return out
