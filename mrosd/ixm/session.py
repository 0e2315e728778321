"""One process connected to the IXM daemon, as the daemon holds it: who it is, and what waits to be sent to it.

Owns a connection's socket and decoder, the peer's identity as the kernel reports it (SO_PEERCRED, then
/proc for its groups and names), and its outbox: replies with the descriptors they pass (SCM_RIGHTS), sent
without blocking, bounded by ``MAX_OUTBOX`` (a client that does not read its socket is broken off, never
allowed to grow the daemon's memory), descriptors closed once sent or dropped. Must not know the registry,
the segments or the requests: ``mrosd.ixm.server`` decides what to send and what a client's end means.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import os
import socket
import struct
from collections import deque
from collections.abc import Callable
from pathlib import Path

from mrosd.ixm.channel import FdReader, send_frame
from mrosd.ixm.protocol import MAX_REQUEST_SIZE, Reply, encode
from mrosd.ixm.resources import NoticePage
from mrosd.ixm.rules import Peer, names_of

__all__ = ["MAX_OUTBOX", "ClientSession", "close_fd", "peer_of"]

#: Bytes queued for one client before it is considered stuck and disconnected.
MAX_OUTBOX = 32 << 20

_PEERCRED = struct.Struct("3i")


def close_fd(fd: int | None) -> None:
    """Close a descriptor we hold, if any; a failure is no one's business."""
    if fd is not None:
        with contextlib.suppress(OSError):
            os.close(fd)


def peer_of(sock: socket.socket) -> Peer:
    """Who is at the other end of ``sock``: pid, uid and gid from the kernel, groups and names from /proc.

    Raises:
        OSError: the kernel does not say (the peer is gone).
    """
    pid, uid, gid = _PEERCRED.unpack(sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, _PEERCRED.size))
    groups: set[int] = set()
    comm = ""
    argv: list[str] = []
    with contextlib.suppress(OSError):
        comm = Path(f"/proc/{pid}/comm").read_text().strip()
    with contextlib.suppress(OSError):
        argv = [a.decode("utf-8", "replace") for a in Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0") if a]
    with contextlib.suppress(OSError, ValueError):
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("Groups:"):
                groups = {int(g) for g in line.split()[1:]}
    return Peer(pid=pid, uid=uid, gid=gid, groups=frozenset(groups), names=names_of(comm, argv))


class ClientSession:
    """One connected process: its socket, its decoder and fds, and what is queued to send to it.

    ``on_broken(session, reason, level)`` is called soon (never re-entrantly) once a send failed or the
    outbox overflowed; the server then drops the client.
    """

    def __init__(
        self,
        conn_id: int,
        sock: socket.socket,
        peer: Peer,
        loop: asyncio.AbstractEventLoop,
        on_broken: Callable[[ClientSession, str, int], None],
    ) -> None:
        self.id = conn_id
        self.sock = sock
        self.peer = peer
        self.reader = FdReader(sock, MAX_REQUEST_SIZE)
        #: (frame remainder, fds to attach, fds to close once sent)
        self.outbox: deque[tuple[memoryview, list[int], list[int]]] = deque()
        self.queued = 0
        self.writing = False
        self.closed = False
        #: a send failed or the outbox overflowed: dropped on the next loop iteration (never re-entrantly)
        self.broken = False
        #: created at this connection's first open for writing
        self.notice: NoticePage | None = None
        self.pushes = 0
        self._loop = loop
        self._on_broken = on_broken

    def send(self, message: Reply, fds: list[int] | None = None, close_after: list[int] | None = None) -> None:
        """Queue one reply with ``fds`` passed beside it; ``close_after`` are closed once it is sent (or dropped)."""
        if self.closed or self.broken:
            for fd in close_after or ():
                close_fd(fd)
            return
        frame = memoryview(encode(message))
        self.outbox.append((frame, fds or [], close_after or []))
        self.queued += len(frame)
        if self.queued > MAX_OUTBOX:
            self._break(f"does not read its socket ({self.queued} bytes queued)", logging.WARNING)
            return
        if not self.writing:
            self._flush()

    def close(self) -> None:
        """Stop watching the socket, drop what is queued (closing its descriptors) and close everything."""
        self.closed = True
        self._loop.remove_reader(self.sock.fileno())
        if self.writing:
            self._loop.remove_writer(self.sock.fileno())
        self._discard_outbox()
        self.reader.close()
        self.sock.close()
        if self.notice is not None:
            self.notice.close()
            self.notice = None

    def _discard_outbox(self) -> None:
        for _frame, _fds, to_close in self.outbox:
            for fd in to_close:
                close_fd(fd)
        self.outbox.clear()

    def _flush(self) -> None:
        while self.outbox and not self.closed:
            frame, fds, to_close = self.outbox[0]
            try:
                sent = send_frame(self.sock, frame, fds)
            except (BlockingIOError, InterruptedError):
                sent = 0
            except OSError as exc:
                quiet = exc.errno in (errno.EPIPE, errno.ECONNRESET)
                self._break(f"send failed: {exc}", logging.DEBUG if quiet else logging.WARNING)
                return
            if sent == 0 and len(frame):
                if not self.writing:
                    self.writing = True
                    self._loop.add_writer(self.sock.fileno(), self._flush)
                return
            self.queued -= sent
            if sent < len(frame):
                self.outbox[0] = (frame[sent:], [], to_close)  # fds went with the first byte
                continue
            self.outbox.popleft()
            for fd in to_close:
                close_fd(fd)
        if self.writing and not self.closed:
            self.writing = False
            self._loop.remove_writer(self.sock.fileno())

    def _break(self, reason: str, level: int) -> None:
        self.broken = True
        self._discard_outbox()
        with contextlib.suppress(RuntimeError):  # the loop closed meanwhile: the server dropped every client
            self._loop.call_soon(self._on_broken, self, reason, level)
