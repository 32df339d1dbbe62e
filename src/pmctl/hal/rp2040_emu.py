"""The step/dir bridge's RP2040 image running in an emulated RP2040: hardware-in-the-loop on the
exact binary, in simulated time.

``make -C firmware_bridge rp2040`` builds ``firmware_bridge/build/rp2040/bridge.elf`` (the image a
Pico is flashed with, as ``bridge.uf2``) and installs the pinned emulator, npm's ``rp2040js``, into
``firmware_bridge/emu/node_modules``. :class:`Emulator` runs that ELF there with
``firmware_bridge/emu/run.mjs`` under node and connects the chip's UART0 to a pseudo-terminal, which
the ``stepdir`` backend opens as its serial port (``[hal.stepdir] port = "rp2040-emu"``, or
``pmctl run --bridge rp2040-emu``).

- **Simulated time.** The chip runs as fast as node can emulate it (a fraction of real time while it
  steps, and never more than a few ms ahead of real time). :meth:`Emulator.sim_time` reads the
  chip's clock; the backend times its timeouts and retransmits in it, so a slow emulator is never a
  late chip: the host waits for the emulated chip (run the NC loop with ``--no-realtime``).
- **Pins.** Every STEP/DIR edge and every tick start (the TICK strobe pin) is recorded with its
  simulated time in ``edge_log`` (the host build's format: :func:`pmctl.hal.bridge_protocol.read_edge_log`).
  The pulse counters the backend receives are counted from those pin edges by the harness, which
  rewrites the chip's STATUS frames with them: what the host checks is what came out of the pins.
- **Offline runs.** The backend starts it with ``host_paced_ms`` = 5: while the chip steps, its
  time stops when 5 ms of it passed since the host's last byte, until the host sends again (10 s of
  real-time silence releases it, so a dead host still trips the watchdog). A host that was not
  scheduled for a while on a loaded computer is then not late for the chip; the tests of the
  watchdog run without it.
- **Inputs.** ``control`` is a FIFO taking the host build's lines (``estop 0|1``, ``alarm AXIS 0|1``,
  ``home AXIS 0|1``, ``adc CH COUNTS``, ``quit``), which set the chip's input pins; ``home_at``
  simulates home switches at pulse positions, as the host build's ``--home-at`` does.

Layer: hal (a driver's peer process). It needs node and the built image; :func:`ensure_built`
makes both and names the Debian package of a missing tool.
"""

from __future__ import annotations

import json
import os
import pty
import select
import shutil
import struct
import subprocess
import tempfile
import time
import tty
from pathlib import Path

from pmctl.hal.base import HalError, HalTimeout

FIRMWARE_DIR = Path(__file__).resolve().parents[3] / "firmware_bridge"
EMU_PORT = "rp2040-emu"
STALL_S = 60.0           # the emulated clock standing still this long (wall time): the emulator is stuck


def image_paths(firmware_dir: Path = FIRMWARE_DIR) -> dict:
    d = Path(firmware_dir)
    b = d / "build" / "rp2040"
    return {"elf": b / "bridge.elf", "bin": b / "bridge.bin", "uf2": b / "bridge.uf2",
            "runner": d / "emu" / "run.mjs", "stamp": d / "emu" / "node_modules" / ".installed"}


def _stale(target: Path, sources) -> bool:
    return not target.is_file() or any(p.stat().st_mtime > target.stat().st_mtime for p in sources)


def ensure_built(firmware_dir: Path = FIRMWARE_DIR) -> dict:
    """The RP2040 image and the pinned emulator, made with ``make -C firmware_bridge rp2040`` when
    missing or older than their sources; a missing tool is named with its Debian package."""
    d = Path(firmware_dir)
    paths = image_paths(d)
    if not (d / "Makefile").is_file():
        raise HalError(f"rp2040 emulator: {d}/Makefile not found; it needs the firmware_bridge folder of a "
                       f"source checkout")
    sources = [p for p in d.iterdir() if p.suffix in (".c", ".h") or p.name == "Makefile"]
    sources += [p for p in (d / "rp2040").iterdir() if p.is_file()]
    npm = [d / "emu" / "package.json", d / "emu" / "package-lock.json"]
    if not (_stale(paths["elf"], sources) or _stale(paths["uf2"], sources) or _stale(paths["stamp"], npm)):
        if shutil.which("node") is None:
            raise HalError("rp2040 emulator: node not found (it runs the emulator): apt-get install nodejs")
        return paths
    make = shutil.which("make")
    if make is None:
        raise HalError("rp2040 emulator: 'make' not found; building the image needs make "
                       "(Debian/Ubuntu: apt-get install build-essential)")
    r = subprocess.run([make, "-C", str(d), "rp2040"], capture_output=True, text=True)
    if r.returncode != 0 or not paths["elf"].is_file():
        tail = "\n".join((r.stderr or r.stdout).strip().splitlines()[-8:])
        raise HalError(f"rp2040 emulator: 'make -C {d} rp2040' failed (exit {r.returncode}):\n{tail}")
    return paths


CPU_LOG_DTYPE = [("t", "<u8"), ("cycles", "<u8"), ("spin", "<u8")]


def read_cpu_log(path):
    """The emulator's --cpu-log: per tick start, the simulated time (ns), the cycles the CPU executed
    so far (not asleep), and the cycles of those the firmware spent spinning on a time."""
    import numpy as np
    return np.fromfile(path, dtype=np.dtype(CPU_LOG_DTYPE))


def symbol_address(elf: Path, name: str) -> int:
    """The address of a symbol in the ELF's symbol table (32-bit little-endian ELF)."""
    b = Path(elf).read_bytes()
    shoff, = struct.unpack_from("<I", b, 32)
    shentsize, shnum = struct.unpack_from("<HH", b, 46)
    sections = [struct.unpack_from("<IIIIIIIIII", b, shoff + i * shentsize) for i in range(shnum)]
    for sh in sections:
        if sh[1] != 2:                     # SHT_SYMTAB
            continue
        strtab = sections[sh[6]]           # sh_link: its string table
        for off in range(sh[4], sh[4] + sh[5], 16):
            st_name, st_value = struct.unpack_from("<II", b, off)
            end = b.index(b"\0", strtab[4] + st_name)
            if b[strtab[4] + st_name:end].decode() == name:
                return st_value
    raise HalError(f"rp2040 emulator: no symbol {name} in {elf}")


class Emulator:
    """``bridge.elf`` in rp2040js, its UART0 on a pty (``port``). Stop it with :meth:`stop`, which
    returns the runner's figures (simulated and wall time, CPU cycles, pin counts, ...).

    ``host_paced_ms`` > 0: the chip's time waits for the host while the chip steps and that many ms
    of its time passed since the host's last byte (offline runs: a host that was not scheduled is
    not late for the chip; 10 s of real-time silence still lets the watchdog trip). 0: the chip's
    time runs on, as a real chip's does (the HIL tests of the watchdog)."""

    def __init__(self, *, edge_log: str | os.PathLike | None = None, control: str | os.PathLike | None = None,
                 home_at=(), cpu_log: str | os.PathLike | None = None, speed: float = 1.0,
                 baud: int = 3_000_000, trace: str | os.PathLike | None = None,
                 profile: str | os.PathLike | None = None, host_paced_ms: float = 0.0,
                 firmware_dir: Path = FIRMWARE_DIR):
        paths = ensure_built(firmware_dir)
        node = shutil.which("node")
        if node is None:
            raise HalError("rp2040 emulator: node not found (it runs the emulator): apt-get install nodejs")
        self._tmp = tempfile.TemporaryDirectory(prefix="pmctl-rp2040-")
        self.clock_file = Path(self._tmp.name) / "clock"
        self.clock_file.write_bytes(bytes(8))
        self.control = Path(control) if control else None
        if self.control is not None and not self.control.exists():
            os.mkfifo(self.control, 0o600)
        master, self._slave = pty.openpty()
        tty.setraw(self._slave)        # the harness keeps the slave open: a host that closes it is a silent line
        os.set_blocking(master, False)
        self.port = os.ttyname(self._slave)
        cmd = [node, str(paths["runner"]), "--elf", str(paths["elf"]), "--link-fd", str(master),
               "--clock-file", str(self.clock_file), "--speed", repr(float(speed)), "--baud", str(int(baud))]
        if cpu_log:
            cmd += ["--spin-addr", f"{symbol_address(paths['elf'], 'g_spin_cycles'):x}"]
        for opt, val in (("--edge-log", edge_log), ("--control", self.control), ("--cpu-log", cpu_log),
                         ("--trace", trace), ("--profile", profile)):
            if val:
                cmd += [opt, str(val)]
        if host_paced_ms > 0:
            cmd += ["--host-paced", repr(float(host_paced_ms))]
        for axis, pulses in home_at:
            cmd += ["--home-at", f"{int(axis)}:{int(pulses)}"]
        self.proc = subprocess.Popen(cmd, pass_fds=[master], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     cwd=str(paths["runner"].parent))
        os.close(master)
        self._clock_fd = os.open(self.clock_file, os.O_RDONLY)
        self._ctl = None
        self._last = (0.0, time.monotonic())
        r, _, _ = select.select([self.proc.stdout], [], [], 30.0)
        line = self.proc.stdout.readline().decode(errors="replace").strip() if r else ""
        if line != "READY":
            self.stop()
            raise HalError(f"rp2040 emulator: {paths['runner']} did not start within 30 s (got {line!r})")

    def sim_time(self) -> float:
        """The emulated chip's clock, s. Raises HalTimeout when it has stood still for STALL_S of wall
        time while the emulator process is gone or stuck."""
        b = os.pread(self._clock_fd, 8, 0)
        t = struct.unpack("<d", b)[0] / 1e9 if len(b) == 8 else self._last[0]
        now = time.monotonic()
        if t != self._last[0]:
            self._last = (t, now)
        elif now - self._last[1] > STALL_S or (self.proc.poll() is not None and now - self._last[1] > 1.0):
            raise HalTimeout(f"rp2040 emulator: the chip's clock stopped at {t:.6f} s "
                             f"({'the emulator exited' if self.proc.poll() is not None else 'the emulator is stuck'})")
        return t

    def ctl(self, line: str):
        """One line to the control FIFO (E-stop, alarm, home switch, ADC)."""
        if self.control is None:
            raise HalError("rp2040 emulator: started without a control FIFO")
        if self._ctl is None:
            self._ctl = os.open(self.control, os.O_WRONLY)
        os.write(self._ctl, (line + "\n").encode())

    def stop(self) -> dict:
        """Stops the emulator (the edge log is flushed and closed) and returns its figures."""
        out = {}
        if self._ctl is not None:
            os.close(self._ctl)
            self._ctl = None
        p = self.proc
        if p is not None and p.poll() is None:
            p.terminate()
            try:
                data, _ = p.communicate(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                data, _ = p.communicate()
            for line in (data or b"").decode(errors="replace").splitlines():
                if line.startswith("{"):
                    out = json.loads(line)
        elif p is not None:
            p.communicate()
        for fd in ("_clock_fd", "_slave"):
            f = getattr(self, fd, None)
            if f is not None:
                try:
                    os.close(f)
                except OSError:
                    pass
                setattr(self, fd, None)
        self._tmp.cleanup()
        self.proc = None
        return out
