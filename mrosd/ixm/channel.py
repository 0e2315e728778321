"""Bytes plus file descriptors over a Unix stream socket: the one place that calls sendmsg/recvmsg.

Both the daemon and the clients pass file descriptors (segments, eventfds) with SCM_RIGHTS beside the
protocol frames. ``FdReader`` keeps the received fds in arrival order next to the frame decoder: Linux
delivers a sendmsg's fds with the first byte of its data, so by the time a frame that announces N fds is
complete, those N fds have arrived. A frame that claims fds which never came, a truncated control message
or too many unclaimed fds is a protocol error, and every fd still held is closed with the connection.
"""

from __future__ import annotations

import array
import os
import socket
from collections import deque
from collections.abc import Sequence

from mrosd.errors import RemoteProtocolError
from mrosd.wire.framing import FrameDecoder

__all__ = ["MAX_FDS_PER_MESSAGE", "MAX_PENDING_FDS", "FdReader", "is_eventfd", "recv_with_fds", "send_frame"]

#: The kernel's SCM_MAX_FD: at most 253 fds in one sendmsg.
MAX_FDS_PER_MESSAGE = 253
#: fds received but not yet claimed by a frame; more than this means the peer is misbehaving.
MAX_PENDING_FDS = 512
_RECV_SIZE = 65536
_CMSG_SPACE = socket.CMSG_SPACE(MAX_FDS_PER_MESSAGE * 4)


def recv_with_fds(sock: socket.socket, flags: int = 0) -> tuple[bytes, list[int]]:
    """One recvmsg: the bytes (empty at end of stream) and the descriptors that came with them.

    Raises:
        RemoteProtocolError: the control data was truncated (the descriptors that did arrive are closed).
        BlockingIOError: nothing to read on a non-blocking socket.
    """
    data, ancdata, msg_flags, _ = sock.recvmsg(_RECV_SIZE, _CMSG_SPACE, flags)
    fds = array.array("i")
    for level, kind, payload in ancdata:
        if level == socket.SOL_SOCKET and kind == socket.SCM_RIGHTS:
            fds.frombytes(payload[: len(payload) - (len(payload) % fds.itemsize)])
    if msg_flags & socket.MSG_CTRUNC:
        for fd in fds:
            try:
                os.close(fd)
            except OSError:
                pass
        raise RemoteProtocolError("file descriptors were truncated in transit (too many in one message)")
    return data, list(fds)


class FdReader:
    """Receives from one socket; yields complete frame bodies and hands out fds on request."""

    def __init__(self, sock: socket.socket, max_frame: int) -> None:
        self.sock = sock
        self.decoder = FrameDecoder(max_frame)
        self.fds: deque[int] = deque()

    def recv(self, flags: int = 0) -> bool:
        """One recvmsg; False at end of stream. BlockingIOError propagates for non-blocking sockets.

        Raises:
            RemoteProtocolError: the control data was truncated or too many fds are pending.
        """
        data, fds = recv_with_fds(self.sock, flags)
        self.fds.extend(fds)
        if len(self.fds) > MAX_PENDING_FDS:
            raise RemoteProtocolError(f"peer sent more than {MAX_PENDING_FDS} unclaimed file descriptors")
        if not data:
            return False
        self.decoder.feed(data)
        return True

    def next_frame(self) -> bytes | None:
        """The next complete frame body, or None while incomplete.

        Raises:
            RemoteProtocolError: the frame announces more than the connection's limit.
        """
        return self.decoder.maybe_next_frame()

    def take_fds(self, n: int) -> list[int]:
        """The next ``n`` received fds (the caller owns them now).

        Raises:
            RemoteProtocolError: fewer than ``n`` fds arrived with the frame.
        """
        if n < 0 or n > len(self.fds):
            raise RemoteProtocolError(f"a message announced {n} file descriptors but {len(self.fds)} arrived")
        return [self.fds.popleft() for _ in range(n)]

    def close(self) -> None:
        """Close every fd received and not claimed."""
        while self.fds:
            try:
                os.close(self.fds.popleft())
            except OSError:
                pass


def send_frame(sock: socket.socket, frame: bytes | memoryview, fds: Sequence[int] = ()) -> int:
    """One sendmsg with the fds attached; returns the bytes sent (may be partial on non-blocking sockets)."""
    if fds:
        anc = [(socket.SOL_SOCKET, socket.SCM_RIGHTS, array.array("i", fds).tobytes())]
        return sock.sendmsg([frame], anc)
    return sock.send(frame)


def is_eventfd(fd: int) -> bool:
    """Is ``fd`` an eventfd (what a peer sends as its wake-up descriptor must be: a pipe or a socket could
    block the writes that wake it)?"""
    try:
        return os.readlink(f"/proc/self/fd/{fd}") == "anon_inode:[eventfd]"
    except OSError:
        return False
