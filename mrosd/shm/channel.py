"""The control socket of a shared-memory connection, as both ends use it.

A publisher listens on an abstract Unix socket (no file to leave behind, scoped to the network namespace);
each subscriber connects to it and the two exchange ``mrosd.shm.control`` messages, descriptors attached
(the publisher's rings, acknowledgement pages and wake-up socket pairs). ``ControlChannel`` frames and
unframes those messages;
the functions here are the socket chores both ends share: the abstract name, connecting without blocking,
the peer's credentials from the kernel, closing descriptors received.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import os
import socket
import struct
from collections.abc import Iterable

from mrosd.ixm.channel import FdReader, send_frame
from mrosd.shm import control

__all__ = [
    "ATTACH_TIMEOUT",
    "ControlChannel",
    "abstract_name",
    "close_fds",
    "connect_unix",
    "peer_credentials",
]

#: Seconds a subscriber has to attach once connected (and, by default, to finish attaching on its side).
ATTACH_TIMEOUT = 10.0

_PEERCRED = struct.Struct("3i")


def abstract_name(address: str) -> str:
    """The socket address of ``@name``: the abstract namespace's leading NUL instead of the ``@``."""
    return "\0" + address[1:]


def peer_credentials(sock: socket.socket) -> tuple[int, int]:
    """The pid and uid of the process at the other end of a Unix socket, as the kernel saw them."""
    pid, uid, _gid = _PEERCRED.unpack(sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, _PEERCRED.size))
    return pid, uid


async def connect_unix(sock: socket.socket, address: str) -> None:
    """Connect a non-blocking Unix socket (by hand: uvloop's sock_connect does not take abstract names).

    A Unix socket's connect never completes later: EAGAIN means the listener's backlog is full and nothing
    was started (waiting for the socket to become writable would return an unconnected socket). So it tries
    again, 1 ms apart doubling to 50 ms, until the caller's timeout: a peer flooding the listener with
    connections delays us, it does not make us attach to nothing.
    """
    delay = 0.001
    while True:
        try:
            sock.connect(address)
            return
        except (BlockingIOError, InterruptedError):
            await asyncio.sleep(delay)
            delay = min(0.05, delay * 2)


def close_fds(fds: Iterable[int]) -> None:
    """Close each descriptor, ignoring any already closed."""
    for fd in fds:
        with contextlib.suppress(OSError):
            os.close(fd)


class ControlChannel:
    """A non-blocking Unix stream socket with the ``FdReader`` of what arrives on it."""

    def __init__(self, sock: socket.socket) -> None:
        sock.setblocking(False)
        self.sock = sock
        self.reader = FdReader(sock, control.MAX_CONTROL_FRAME)

    def receive(self) -> list[tuple[control.Message, list[int]]] | None:
        """Every complete message with the descriptors it announced; None at end of stream.

        Raises:
            RemoteProtocolError: a bad frame, or descriptors missing or in excess.
        """
        try:
            if not self.reader.recv(socket.MSG_CMSG_CLOEXEC):
                return None
        except (BlockingIOError, InterruptedError):
            return []
        except ConnectionError:
            return None
        out: list[tuple[control.Message, list[int]]] = []
        while (body := self.reader.next_frame()) is not None:
            msg = control.decode(body)
            out.append((msg, self.reader.take_fds(control.FDS.get(type(msg), 0))))
        return out

    def send(self, msg: control.Message, fds: tuple[int, ...] = ()) -> None:
        """Send one whole message now.

        Raises:
            OSError: the peer's socket is full (it does not read its control messages) or gone.
        """
        frame = control.encode(msg)
        if send_frame(self.sock, frame, fds) != len(frame):
            raise BlockingIOError(errno.EAGAIN, "control message sent in part")

    def close(self) -> None:
        self.reader.close()
        self.sock.close()
