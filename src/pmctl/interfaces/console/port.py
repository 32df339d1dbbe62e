"""Where the console talks: a pty created for it (``pty:LINK``, LINK a symlink to the slave side)
or a serial device (a path: raw mode, 115200 baud, as grbl's USB serial).

On a pty the console sees a sender arrive and leave: pmctl keeps only the master side open, so the
master reads as hung up (POLLHUP) while no program has the slave open, and the hang-up goes away
when a sender opens it (:meth:`ConsolePort.client_present`). The console greets a sender that
arrives (grbl's banner), as a grbl board does when its USB port is opened, and drops what it would
write while nobody listens (it would otherwise wait in the pty for the next sender). The raw mode set
on the slave stays with the pty between senders."""

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
        self.pty = spec.startswith("pty:")
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
            os.close(slave)                         # the senders open it; meanwhile the master reads HUP
            self.fd, self.link, self.device = master, link, name
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

    def client_present(self) -> bool:
        """Whether a sender has the port open: on a pty, the master is not hung up; a serial device
        cannot tell (always True)."""
        if not self.pty:
            return True
        return client_present(self.fd)

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


def client_present(fd: int) -> bool:
    """A pty master ``fd``: whether some program has its slave side open (no POLLHUP)."""
    import select
    p = select.poll()
    p.register(fd, select.POLLIN | select.POLLHUP)
    try:
        return not any(ev & (select.POLLHUP | select.POLLERR | select.POLLNVAL) for _, ev in p.poll(0))
    except OSError:
        return False
