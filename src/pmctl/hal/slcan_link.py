"""CAN frames between processes as slcan (Lawicel) ASCII lines, the link of a USB-CAN adapter,
over a pty or a loopback TCP connection: ``t`` + 3 hex digits of identifier + the length + the data in hex + CR (``T`` + 8 digits
for an extended identifier, ``r``/``R`` for a remote frame); ``S8`` sets 1 Mbit/s, ``O`` opens the
channel, ``C`` closes it; the adapter answers a command with CR and an error with BEL.

``SlcanLinkBus`` is a python-can bus on such a link. python-can's own ``slcan`` interface speaks
the same lines (the tests listen with it), but reads a byte per system call: on the control
loop's process that costs a third of a core at 1 Mbit/s; this one reads whatever is there at once.

Pure encode/decode plus one small bus class; the hub that joins several links is
pmctl.hal.devsim.
"""

from __future__ import annotations

import binascii
import errno
import os
import queue
import select
import socket
import termios
import time
import tty

import can

CR, BEL = b"\r", b"\x07"
BITRATE_CODES = {10_000: "S0", 20_000: "S1", 50_000: "S2", 100_000: "S3", 125_000: "S4", 250_000: "S5",
                 500_000: "S6", 800_000: "S7", 1_000_000: "S8"}


def encode(msg: can.Message) -> bytes:
    """One frame as an slcan line (with its CR)."""
    n, cid = msg.dlc, msg.arbitration_id
    if msg.is_remote_frame:
        return (b"R%08X%d\r" if msg.is_extended_id else b"r%03X%d\r") % (cid, n)
    return (b"T%08X%d%s\r" if msg.is_extended_id else b"t%03X%d%s\r") % (cid, n, binascii.hexlify(msg.data).upper())


def encode_batch(msgs) -> bytes:
    """Several frames as their slcan lines, in order."""
    return b"".join([encode(m) for m in msgs])


def decode(line: bytes) -> can.Message | None:
    """A frame from one slcan line (without its CR); None for anything that is not a frame
    (a command's answer, a transmit acknowledge ``z``). A malformed frame raises ValueError."""
    if not line:
        return None
    k = line[:1]
    if k in (b"t", b"r"):
        ext, idl = False, 3
    elif k in (b"T", b"R"):
        ext, idl = True, 8
    else:
        return None
    if len(line) < 1 + idl + 1:
        raise ValueError(f"slcan frame too short: {line!r}")
    cid = int(line[1:1 + idl], 16)
    n = int(line[1 + idl:2 + idl])
    if n > 8 or (not ext and cid > 0x7FF):
        raise ValueError(f"slcan frame out of range: {line!r}")
    if k in (b"r", b"R"):
        return can.Message(arbitration_id=cid, is_extended_id=ext, is_remote_frame=True, dlc=n)
    hexdata = line[2 + idl:2 + idl + 2 * n]
    if len(hexdata) != 2 * n:
        raise ValueError(f"slcan frame shorter than its length {n}: {line!r}")
    return can.Message(arbitration_id=cid, is_extended_id=ext, data=bytes.fromhex(hexdata.decode()), dlc=n)


def raw(fd: int) -> None:
    """No line discipline on a pty: CR stays CR, nothing echoes."""
    tty.setraw(fd, termios.TCSANOW)


class LineReader:
    """Splits what a file descriptor delivers into CR-terminated lines."""

    def __init__(self, fd: int):
        self.fd = fd
        self.buf = bytearray()

    def read(self) -> list[bytes]:
        """The complete lines now readable (blocks only if nothing is; [] at end of file)."""
        chunk = os.read(self.fd, 65536)
        if not chunk:
            raise EOFError("slcan link closed")
        self.buf += chunk
        *lines, rest = bytes(self.buf).split(CR)
        self.buf = bytearray(rest)
        return [ln.lstrip(BEL) for ln in lines]


class SlcanLinkBus(can.BusABC):
    """A python-can bus on an slcan link: a serial device (a pty's slave side) opened by path, or
    a loopback TCP connection ``socket://127.0.0.1:port`` (pyserial's URL form, which python-can's
    ``slcan`` interface opens too)."""

    def __init__(self, channel: str, bitrate: int = 1_000_000, **kwargs):
        if bitrate not in BITRATE_CODES:
            raise can.CanInitializationError(f"slcan: no bit rate code for {bitrate}")
        self._sock = None
        self.closed_by_peer = False
        try:
            if channel.startswith("socket://"):
                host, _, port = channel[len("socket://"):].rpartition(":")
                self._sock = socket.create_connection((host, int(port)), timeout=5.0)
                self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self.fd = self._sock.fileno()
            else:
                self.fd = os.open(channel, os.O_RDWR | os.O_NOCTTY)
                raw(self.fd)
        except (OSError, ValueError) as e:
            raise can.CanInitializationError(f"slcan: cannot open {channel}: {e}") from None
        os.set_blocking(self.fd, False)     # a device side that stops reading must not block a send
        self._lines = LineReader(self.fd)
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self.channel_info = f"slcan link {channel}"
        os.write(self.fd, (BITRATE_CODES[bitrate] + "\rO\r").encode())
        super().__init__(channel, **kwargs)

    def _recv_internal(self, timeout):
        if not self._queue.empty():
            return self._queue.get_nowait(), False
        if self.closed_by_peer:
            # nothing will come: quiet (the protocol above notices: no heartbeat, no answers)
            time.sleep(0.1 if timeout is None else min(timeout, 0.1))
            return None, False
        r, _, _ = select.select([self.fd], [], [], timeout)
        if not r:
            return None, False
        try:
            lines = self._lines.read()
        except BlockingIOError:
            return None, False
        except (OSError, EOFError) as e:
            if isinstance(e, EOFError) or e.errno in (errno.EIO, errno.ECONNRESET):   # the device side is gone
                self.closed_by_peer = True
                return None, False
            raise can.CanOperationError(f"slcan link: {e}") from None
        for ln in lines:
            try:
                m = decode(ln)
            except ValueError:
                continue                   # a damaged line is a lost frame (the protocol layers notice)
            if m is not None:
                self._queue.put(m)
        if self._queue.empty():
            return None, False
        return self._queue.get_nowait(), False

    def send(self, msg: can.Message, timeout=None) -> None:
        self._write(encode(msg), timeout)

    def send_batch(self, msgs, timeout=None) -> None:
        """Several frames in one write (one system call instead of one per frame): the same lines
        on the link, in the same order, as ``send`` of each in turn."""
        self.send_lines(encode_batch(msgs), timeout)

    def send_lines(self, data: bytes, timeout=None) -> None:
        """Frames already encoded (``encode``, ``encode_batch``), written whole."""
        self._write(data, timeout)

    def _write(self, data: bytes, timeout) -> None:
        t_end = None
        while data:
            try:
                data = data[os.write(self.fd, data):]
            except BlockingIOError:
                # the link's buffer is full: the device side stalls; a frame is never cut in two
                t_end = t_end or time.monotonic() + (0.01 if timeout is None else timeout)
                if time.monotonic() > t_end:
                    raise can.CanOperationError("slcan link: the device side does not read (link full)") from None
                select.select([], [self.fd], [], 0.001)
            except OSError as e:
                raise can.CanOperationError(f"slcan link: {e}") from None

    def fileno(self) -> int:
        return self.fd

    def shutdown(self) -> None:
        if self.fd >= 0:
            try:
                os.write(self.fd, b"C\r")
            except OSError:
                pass
            super().shutdown()
            if self._sock is not None:
                self._sock.close()
            else:
                os.close(self.fd)
            self.fd = -1
