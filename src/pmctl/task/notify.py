"""systemd's notify protocol, without a dependency: one datagram per message to $NOTIFY_SOCKET
(a path, or an abstract socket when it starts with '@')."""

from __future__ import annotations

import os
import socket


def sd_notify(message: str, env=None) -> bool:
    """Send ``message`` (e.g. "READY=1", "WATCHDOG=1", "STATUS=...") if systemd asked for it."""
    env = os.environ if env is None else env
    addr = env.get("NOTIFY_SOCKET")
    if not addr:
        return False
    if addr.startswith("@"):
        addr = "\0" + addr[1:]
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as s:
            s.connect(addr)
            s.sendall(message.encode())
        return True
    except OSError:
        return False


def watchdog_period_s(env=None) -> float | None:
    """Half the watchdog interval systemd set (WATCHDOG_USEC for this process), or None."""
    env = os.environ if env is None else env
    usec = env.get("WATCHDOG_USEC")
    pid = env.get("WATCHDOG_PID")
    if not usec or (pid and pid.isdigit() and int(pid) != os.getpid()):
        return None
    try:
        return int(usec) / 2e6
    except ValueError:
        return None
