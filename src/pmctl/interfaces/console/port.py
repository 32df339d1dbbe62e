"""Where the console talks: a pty created for it (``pty:LINK``, LINK a symlink to the slave side)
or a serial device (a path: raw mode, 115200 baud, as grbl's USB serial)."""

from __future__ import annotations

import os
import termios
import tty

from pmctl.core.errors import PmctlError


def check_console_spec(spec: str) -> None:
    """Refuse a --console that cannot be opened, before anything starts: ``pty:LINK`` needs a LINK
    whose folder exists (and LINK not a file of its own), a device path must exist."""
    if spec.startswith("pty:"):
        link = spec[4:]
        if not link:
            raise PmctlError("--console pty:LINK needs a LINK path")
        parent = os.path.dirname(os.path.abspath(link))
        if not os.path.isdir(parent):
            raise PmctlError(f"--console {spec}: the folder {parent} does not exist")
        if os.path.lexists(link) and not os.path.islink(link):
            raise PmctlError(f"--console {spec}: {link} exists and is not a link; choose another name")
        return
    if not os.path.exists(spec):
        raise PmctlError(f"--console {spec}: no such device (a serial device path, or pty:LINK for a pty)")


class ConsolePort:
    def __init__(self, spec: str):
        self.spec = spec
        self.link = None
        self._keep = None
        if spec.startswith("pty:"):
            link = spec[4:]
            if not link:
                raise PmctlError("--console pty:LINK needs a LINK path")
            master, slave = os.openpty()
            tty.setraw(slave)                       # no echo, no line editing: bytes as sent
            os.set_blocking(master, False)
            name = os.ttyname(slave)
            try:
                if os.path.islink(link):
                    os.unlink(link)
                os.symlink(name, link)
            except OSError as e:
                os.close(master)
                os.close(slave)
                raise PmctlError(f"--console {spec}: cannot create the link: {e.strerror or e}") from None
            self.fd, self._keep, self.link, self.device = master, slave, link, name
        else:
            try:
                fd = os.open(spec, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
            except OSError as e:
                raise PmctlError(f"--console {spec}: cannot open: {e.strerror or e}") from None
            try:
                tty.setraw(fd)
                attr = termios.tcgetattr(fd)
                attr[4] = attr[5] = termios.B115200
                termios.tcsetattr(fd, termios.TCSANOW, attr)
            except termios.error:
                pass                                  # not a tty (a FIFO in a test): bytes as they are
            self.fd, self.device = fd, spec

    def close(self):
        for fd in (self.fd, self._keep):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        if self.link and os.path.islink(self.link):
            try:
                os.unlink(self.link)
            except OSError:
                pass
