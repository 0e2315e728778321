"""systemd's sd_notify protocol over ``$NOTIFY_SOCKET``, with no dependency on libsystemd.

The protocol is one AF_UNIX datagram per notification, holding newline-separated ``KEY=value`` lines
(``READY=1``, ``STATUS=...``, ``WATCHDOG=1``, ``STOPPING=1``, ``RELOADING=1``). A socket path that starts
with ``@`` lives in the Linux abstract namespace (the ``@`` becomes a NUL byte). When ``NOTIFY_SOCKET`` is
unset (not started by systemd) every call is a silent no-op, so the daemon code never branches on it.
This module owns only the wire format and the socket; when to notify is the daemon's business.
"""

from __future__ import annotations

import contextlib
import os
import socket
from collections.abc import Mapping

__all__ = ["Notifier", "watchdog_interval"]


def _address(path: str) -> str | bytes:
    if path.startswith("@"):
        return b"\0" + path[1:].encode()
    return path


def watchdog_interval(environ: Mapping[str, str] | None = None) -> float | None:
    """Seconds between ``WATCHDOG=1`` pings (half of ``WATCHDOG_USEC``), or None when no watchdog is armed.

    ``WATCHDOG_PID``, when set, must name this process: systemd sets it so that children started with
    the same environment do not ping on the parent's behalf.
    """
    env = os.environ if environ is None else environ
    usec = env.get("WATCHDOG_USEC", "")
    pid = env.get("WATCHDOG_PID", "")
    if not usec:
        return None
    if pid and pid != str(os.getpid()):
        return None
    try:
        value = int(usec)
    except ValueError:
        return None
    if value <= 0:
        return None
    return value / 2_000_000


class Notifier:
    """Sends sd_notify messages to the socket named by ``NOTIFY_SOCKET`` (or ``path``).

    Failures to send are swallowed: a supervisor that stopped listening must not take the daemon down.
    """

    def __init__(self, path: str | None = None) -> None:
        self.path = os.environ.get("NOTIFY_SOCKET", "") if path is None else path
        self._sock: socket.socket | None = None
        if self.path and (self.path.startswith(("@", "/"))):
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)

    @property
    def enabled(self) -> bool:
        """True when a notification socket is configured."""
        return self._sock is not None

    def notify(self, **fields: str | int) -> bool:
        """Send one datagram with ``KEY=value`` lines; keys are upper-cased. Returns True when it was sent."""
        if self._sock is None:
            return False
        payload = "\n".join(f"{key.upper()}={value}" for key, value in fields.items()).encode()
        try:
            self._sock.sendto(payload, _address(self.path))
        except OSError:
            return False
        return True

    def ready(self, status: str | None = None) -> bool:
        """Tell systemd that start-up finished (``READY=1``), optionally with a status line."""
        if status is None:
            return self.notify(ready=1, mainpid=os.getpid())
        return self.notify(ready=1, mainpid=os.getpid(), status=status)

    def status(self, text: str) -> bool:
        """Set the one-line status shown by ``systemctl status``."""
        return self.notify(status=text)

    def watchdog(self) -> bool:
        """Ping the service watchdog (``WATCHDOG=1``)."""
        return self.notify(watchdog=1)

    def reloading(self) -> bool:
        """Say that a configuration reload started (``RELOADING=1``); follow it with ``ready()``."""
        return self.notify(reloading=1)

    def stopping(self) -> bool:
        """Say that shutdown started (``STOPPING=1``)."""
        return self.notify(stopping=1)

    def close(self) -> None:
        """Close the datagram socket."""
        if self._sock is not None:
            with contextlib.suppress(OSError):
                self._sock.close()
            self._sock = None
