"""Bytes plus file descriptors over a Unix stream socket, and the wake-up descriptors that cross processes.

This is the one place that calls sendmsg/recvmsg, and the one place that writes and drains a wake-up
descriptor shared with another process (``wake_pipe``, ``wake``, ``drain``, and their socket twins for a
peer of our own: ``wake_socket``, ``drain_socket``).

Both the daemon and the clients pass file descriptors (segments, wake-up pipes) with SCM_RIGHTS beside the
protocol frames. ``FdReader`` keeps the received fds in arrival order next to the frame decoder: Linux
delivers a sendmsg's fds with the first byte of its data, so by the time a frame that announces N fds is
complete, those N fds have arrived. A frame that claims fds which never came, a truncated control message
or too many unclaimed fds is a protocol error, and every fd still held is closed with the connection.
"""

from __future__ import annotations

import array
import errno
import fcntl
import os
import socket
import struct
from collections import deque
from collections.abc import Sequence

from mrosd.errors import RemoteProtocolError
from mrosd.wire.framing import FrameDecoder

__all__ = [
    "MAX_FDS_PER_MESSAGE",
    "MAX_PENDING_FDS",
    "FdReader",
    "drain",
    "drain_socket",
    "is_wake_pipe",
    "is_wake_socket",
    "recv_with_fds",
    "send_frame",
    "small_send_buffer",
    "wake",
    "wake_pipe",
    "wake_socket",
]

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


# wake-ups ------------------------------------------------------------------------------------------------
#
# A descriptor another process holds shares its open file description with us, and with it the file status
# flags: whoever holds it can clear O_NONBLOCK under us. An eventfd cannot be written without blocking
# whatever its flags say (pwritev2's RWF_NOWAIT is refused for eventfds, Linux 6.18 included), and the
# writers and the waiter of one eventfd necessarily share its description: a reader that made it blocking
# and filled its counter froze every writer (issue 24). So wake-ups go through descriptors whose writes
# ignore the file's flags:
#
# - a pipe, for a reader many processes wake (IXM): the reader makes it and keeps the read end; the writers
#   share the write end and write one byte with RWF_NOWAIT, which never blocks, whatever anyone set on the
#   description. A pipe has no shutdown: a hostile writer can fill it (the reader is then woken anyway, a
#   full pipe is a pending wake-up) or shrink it, never cut it for the other writers.
# - a Unix socket pair, between two processes that only wake each other (a shared-memory topic's publisher
#   and one subscriber): MSG_DONTWAIT | MSG_NOSIGNAL, so neither the flags nor a peer gone (EPIPE) can block
#   or kill the writer; each end receives only what the other sent, so neither can steal the other's.

_WAKE = b"\x01"
_WAKE_PARTS = [_WAKE]
_F_SETPIPE_SZ = getattr(fcntl, "F_SETPIPE_SZ", 1031)
#: bytes drained per read: a wake pipe holds one page once shrunk
_DRAIN = 4096
_SEND_FLAGS = socket.MSG_DONTWAIT | socket.MSG_NOSIGNAL
#: False once the kernel refused RWF_NOWAIT on a pipe (before Linux 5.x): plain non-blocking writes then
_nowait = [hasattr(os, "RWF_NOWAIT")]
_UCRED = struct.Struct("3i")


def wake_pipe() -> tuple[int, int]:
    """A new wake-up pipe (read end, write end), non-blocking and close-on-exec, shrunk to one page so that
    pending wake-ups pin at most one page of kernel memory."""
    r, w = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
    try:
        fcntl.fcntl(w, _F_SETPIPE_SZ, os.sysconf("SC_PAGE_SIZE"))
    except OSError:
        pass  # over the user's pipe page budget: the default size works as well
    return r, w


def wake(fd: int) -> bool:
    """One wake-up into the write end of a wake pipe; never blocks. False when no one reads it any more.

    A full pipe (EAGAIN) is a wake-up already pending, not an error.
    """
    try:
        if _nowait[0]:
            os.pwritev(fd, _WAKE_PARTS, -1, os.RWF_NOWAIT)
        else:
            os.write(fd, _WAKE)
    except BlockingIOError:
        return True
    except OSError as exc:
        if exc.errno == errno.EOPNOTSUPP and _nowait[0]:
            _nowait[0] = False
            return wake(fd)
        return False
    return True


def drain(fd: int) -> bool:
    """Empty the read end of a wake pipe (our own, non-blocking description); False at end of file: every
    write end is closed (the daemon, which keeps one while we are a reader, is gone), so no one will wake us
    and the descriptor would stay readable for ever."""
    try:
        while True:
            got = len(os.read(fd, _DRAIN))
            if got == 0:
                return False
            if got < _DRAIN:
                return True
    except OSError:
        return True


def is_wake_pipe(fd: int) -> bool:
    """Is ``fd`` the write end of an anonymous pipe (what a reader must send to be woken through)? Not a named
    FIFO, an eventfd or a socket: writes to those could block, or land with a third party."""
    try:
        return (
            os.readlink(f"/proc/self/fd/{fd}").startswith("pipe:[")
            and fcntl.fcntl(fd, fcntl.F_GETFL) & os.O_ACCMODE == os.O_WRONLY
        )
    except OSError:
        return False


def small_send_buffer(sock: socket.socket) -> None:
    """Keep few wake-ups in flight on our end of a pair: each send queues a buffer in the kernel until the
    peer reads it, so a peer that never reads would otherwise pin the default send buffer (~200 KiB) of
    ours; with a small one, the sends beyond a few find it full, which means a wake-up is already pending."""
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, _DRAIN)
    except OSError:
        pass


def wake_socket(sock: socket.socket) -> bool:
    """One wake-up through our end of a socket pair; never blocks. False when the peer is gone or shut it.

    A full buffer (EAGAIN) is a wake-up already pending, not an error.
    """
    try:
        sock.send(_WAKE, _SEND_FLAGS)
    except BlockingIOError:
        return True
    except OSError:
        return False
    return True


def drain_socket(sock: socket.socket) -> bool:
    """Empty what the peer sent on our end of a socket pair; False at end of stream (the peer closed or
    shut its end: it will not wake us again).

    A short read is taken as the end of what is pending, as ``drain`` does for pipes: it saves the second
    ``recv`` that would only say EAGAIN (on the wake-up path that call measured 20-25 us after an idle
    period). A wake-up sent just after it leaves the socket readable, so the loop calls us again.
    """
    try:
        while True:
            got = len(sock.recv(_DRAIN, socket.MSG_DONTWAIT))
            if got == 0:
                return False
            if got < _DRAIN:
                return True
    except (BlockingIOError, InterruptedError):
        return True
    except OSError:
        return False


def is_wake_socket(sock: socket.socket, uid: int) -> bool:
    """Is ``sock`` one end of a Unix stream socket pair made by a process of ``uid``? Its peer has no
    address (a connection to someone's listening socket has one), so our wake-ups reach only that peer."""
    try:
        if sock.family != socket.AF_UNIX or sock.type != socket.SOCK_STREAM or sock.getpeername():
            return False
        _pid, peer_uid, _gid = _UCRED.unpack(sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, _UCRED.size))
    except OSError:
        return False
    return bool(peer_uid == uid)
