"""The client's side of the IXM control connection, sans I/O: requests out as bytes, bytes and fds in, replies out.

As h11 is to httpcore, ``ClientConnection`` is to ``IxmClient`` and ``AsyncIxmClient``: it frames requests,
decodes what arrives, keeps the received descriptors in order, and applies every ``WakeList`` push to the
key it names (the one place that does), so the shells only move bytes and descriptors and wait. It also
turns an ``Opened`` reply into a mapped ``KeyState`` and checks that the process answering on the socket is
one this client may trust (``check_daemon``: root, our own uid, or a uid we were told to trust), before
any key is handed to it: whoever runs the daemon can feed us any memory.
"""

from __future__ import annotations

import contextlib
import os
import socket
import struct
from collections import deque
from collections.abc import Iterable

from mrosd.errors import IxmError, IxmPermissionError, RemoteProtocolError
from mrosd.ixm.channel import MAX_PENDING_FDS, wake_pipe
from mrosd.ixm.keys import KeyState, Pushes
from mrosd.ixm.protocol import (
    MAX_REPLY_SIZE,
    Error,
    Open,
    Opened,
    Reply,
    Request,
    WakeList,
    decode_reply,
    encode,
)
from mrosd.wire.framing import FrameDecoder

__all__ = ["TRUSTED_UIDS_ENV", "ClientConnection", "check_daemon", "error_from", "trusted_uids"]

#: Comma-separated uids a client trusts to run the daemon, besides root and its own.
TRUSTED_UIDS_ENV = "MROSD_IXM_TRUSTED_UIDS"
_PEERCRED = struct.Struct("3i")


def error_from(reply: Error) -> IxmError:
    if reply.kind == "permission":
        return IxmPermissionError(reply.message)
    return IxmError(reply.message)


def close_all(fds: Iterable[int | None]) -> None:
    for fd in fds:
        if fd is not None:
            with contextlib.suppress(OSError):
                os.close(fd)


def trusted_uids(given: Iterable[int] | None = None) -> frozenset[int]:
    """Root, our own uid, ``given`` and the uids in ``$MROSD_IXM_TRUSTED_UIDS``.

    Raises:
        IxmError: the environment variable is not a list of integers.
    """
    uids = {0, os.geteuid(), *(given or ())}
    raw = os.environ.get(TRUSTED_UIDS_ENV, "")
    try:
        uids.update(int(u) for u in raw.replace(",", " ").split())
    except ValueError:
        raise IxmError(f"{TRUSTED_UIDS_ENV} must list uids (integers), got {raw!r}") from None
    return frozenset(uids)


def check_daemon(sock: socket.socket, path: str, trusted: frozenset[int]) -> None:
    """Refuse a daemon whose uid (SO_PEERCRED, from the kernel) we do not trust.

    Raises:
        IxmError: the socket is served by another uid; the one-line message says how to trust it.
    """
    pid, uid, _gid = _PEERCRED.unpack(sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, _PEERCRED.size))
    if uid not in trusted:
        raise IxmError(
            f"the IXM socket {path} is served by uid {uid} (pid {pid}), not by root or you: refusing to trust it; "
            f"if that is your daemon, set {TRUSTED_UIDS_ENV}={uid}"
        )


def open_request(
    key: str, type: str | None, count: int | None, max_size: int | None, mode: str
) -> tuple[Open, int | None, list[int]]:
    """The Open request, the read end of the wake-up pipe this process will be woken through when it reads,
    and the descriptors to send with the request (the pipe's write end: close it once sent)."""
    wake = "r" in mode
    ends = wake_pipe() if wake else None
    request = Open(key=key, type=type, count=count, max_size=max_size, mode=mode, wake=wake)  # type: ignore[arg-type]
    return request, ends[0] if ends else None, [ends[1]] if ends else []


class ClientConnection:
    """Frames and descriptors of one client connection; ``receive`` then ``next_reply`` until None."""

    def __init__(self, max_reply: int = MAX_REPLY_SIZE) -> None:
        self._decoder = FrameDecoder(max_reply)
        self._fds: deque[int] = deque()
        #: keys open on this connection, by name: where WakeList pushes go
        self.keys: dict[str, KeyState] = {}
        self.pushes = Pushes()
        #: an Error that arrived with no request outstanding (a refusal at connect time)
        self.refusal: Error | None = None

    @staticmethod
    def send(request: Request) -> bytes:
        return encode(request)

    def receive(self, data: bytes, fds: Iterable[int] = ()) -> None:
        """Bytes and descriptors from the socket (empty ``data`` is fine: descriptors only).

        Raises:
            RemoteProtocolError: more unclaimed descriptors than any reply announces.
        """
        self._fds.extend(fds)
        if len(self._fds) > MAX_PENDING_FDS:
            raise RemoteProtocolError(f"the daemon sent more than {MAX_PENDING_FDS} unclaimed file descriptors")
        if data:
            self._decoder.feed(data)

    def next_reply(self) -> Reply | None:
        """The next reply that is not a push (pushes are applied here), or None while none is complete.

        Raises:
            RemoteProtocolError: a malformed frame, or a reply that announces descriptors that never came.
        """
        while True:
            body = self._decoder.maybe_next_frame()
            if body is None:
                return None
            reply = decode_reply(body)
            if not isinstance(reply, WakeList):
                return reply
            fds = self._take(reply.count)
            self.pushes.applied = reply.generation
            state = self.keys.get(reply.key)
            if state is None or state.closed:
                close_all(fds)
            else:
                state.set_targets(fds)

    def opened(self, reply: Reply, efd: int | None) -> KeyState:
        """The key state for the daemon's answer to Open (its descriptors taken and the segment mapped).

        Raises:
            IxmError: the daemon refused, or the segment cannot be mapped (the wake-up pipe is closed).
            RemoteProtocolError: the daemon answered with something other than Opened.
        """
        if not isinstance(reply, Opened):
            close_all([efd])
            if isinstance(reply, Error):
                raise error_from(reply)
            raise RemoteProtocolError(f"unexpected {type(reply).__name__} in answer to open")
        fd, lock_fd = self._take(1)[0], None
        if "w" in reply.mode:
            lock_fd = self._take(1)[0]
        if reply.notice:
            self.pushes.close()
            self.pushes.attach(self._take(1)[0])
            self.pushes.applied = reply.generation
        targets = self._take(reply.wake)
        try:
            state = KeyState(reply, fd, efd, self.pushes, lock_fd)
        except BaseException:
            close_all([*targets, efd, lock_fd])
            raise
        state.set_targets(targets)
        self.keys[reply.key] = state
        return state

    def forget(self, state: KeyState) -> None:
        if self.keys.get(state.key) is state:
            del self.keys[state.key]

    def _take(self, n: int) -> list[int]:
        if n < 0 or n > len(self._fds):
            raise RemoteProtocolError(f"a reply announced {n} file descriptors but {len(self._fds)} arrived")
        return [self._fds.popleft() for _ in range(n)]

    def close(self) -> None:
        """Close every key, every descriptor still held and the notice page."""
        for state in list(self.keys.values()):
            state.close()
        self.keys.clear()
        close_all(self._fds)
        self._fds.clear()
        self.pushes.close()
