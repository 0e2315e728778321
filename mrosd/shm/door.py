"""The door of a shared-memory publisher: the abstract Unix socket its subscribers attach through.

Owns the listening socket (its unguessable address and the token a subscriber must show), who may knock
(uids the kernel reports, checked against the trusted ones), the connections that have not attached yet
(at most ``MAX_PENDING``, each for ``ATTACH_TIMEOUT`` seconds), and reading their one ``Attach``. A
subscriber that shows the token is handed to ``on_attach``; every refusal is one rate-limited line. Must not
know the ring, the handshake or the links: that is ``mrosd.shm.publisher``'s.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import logging
import secrets
import socket
from collections.abc import Callable

from mrosd.errors import RemoteProtocolError
from mrosd.lograte import RateLimitedLog
from mrosd.shm import control
from mrosd.shm.channel import ATTACH_TIMEOUT, ControlChannel, abstract_name, peer_credentials

__all__ = ["MAX_PENDING", "AttachDoor", "refuse"]

log = logging.getLogger(__name__)
#: every line a peer can trigger (connect, refuse, in a loop) goes through this: 5 per kind per 10 s, the
#: rest counted (issue 24: 170k lines in 10 s from one peer connecting and closing)
_ratelog = RateLimitedLog(log)

#: Subscribers that connected but have not attached yet (each has ``ATTACH_TIMEOUT`` seconds).
MAX_PENDING = 64


def refuse(channel: ControlChannel, topic: str, pid: int, why: str) -> None:
    """Tell a subscriber why it may not attach (best effort), in one rate-limited line, and close it."""
    _ratelog.warning("refuse", "%s: refusing shared-memory subscriber (pid %d): %s", topic, pid, why)
    with contextlib.suppress(OSError):
        channel.send(control.Refused(reason=why))
    channel.close()


class AttachDoor:
    """Listens on ``address``; calls ``on_attach(channel, attach, pid, uid)`` for each subscriber with the token."""

    def __init__(
        self,
        topic: str,
        trusted: frozenset[int],
        on_attach: Callable[[ControlChannel, control.Attach, int, int], None],
        loop: asyncio.AbstractEventLoop,
    ) -> None:
        self.topic = topic
        self.trusted = trusted
        self.on_attach = on_attach
        self.token = secrets.token_hex(16)
        self.address = "@mrosd-shm-" + secrets.token_hex(12)
        self._loop = loop
        self._sock: socket.socket | None = None
        self._pending: dict[int, tuple[ControlChannel, asyncio.TimerHandle]] = {}

    def start(self) -> None:
        """Listen on the abstract Unix socket ``address``."""
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC | socket.SOCK_NONBLOCK)
        try:
            sock.bind(abstract_name(self.address))
            sock.listen(64)
        except BaseException:
            sock.close()
            raise
        self._sock = sock
        self._loop.add_reader(sock.fileno(), self._accept)

    def close(self) -> None:
        """Stop listening and close every connection that has not attached yet."""
        if self._sock is not None:
            with contextlib.suppress(Exception):
                self._loop.remove_reader(self._sock.fileno())
            self._sock.close()
            self._sock = None
        for fd in list(self._pending):
            self._abandon(fd, "the publisher is closing")

    def _accept(self) -> None:
        assert self._sock is not None
        for _ in range(64):  # then the loop's other work gets a turn, however fast peers connect
            try:
                conn, _ = self._sock.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                _ratelog.warning("accept", "%s: shared-memory accept failed: %s", self.topic, exc)
                return
            pid, uid = peer_credentials(conn)
            if uid not in self.trusted or len(self._pending) >= MAX_PENDING:
                why = "uid not trusted" if uid not in self.trusted else "too many pending attachments"
                _ratelog.warning(
                    "refuse", "%s: refusing shared-memory subscriber pid %d uid %d: %s", self.topic, pid, uid, why
                )
                conn.close()
                continue
            channel = ControlChannel(conn)
            fd = conn.fileno()
            timer = self._loop.call_later(ATTACH_TIMEOUT, self._abandon, fd, "did not attach in time")
            self._pending[fd] = (channel, timer)
            self._loop.add_reader(fd, self._on_pending, fd, pid, uid)

    def _abandon(self, fd: int, why: str) -> None:
        entry = self._pending.pop(fd, None)
        if entry is None:
            return
        channel, timer = entry
        timer.cancel()
        with contextlib.suppress(Exception):
            self._loop.remove_reader(fd)
        _ratelog.warning("abandon", "%s: closing a shared-memory subscriber connection: %s", self.topic, why)
        channel.close()

    def _on_pending(self, fd: int, pid: int, uid: int) -> None:
        channel = self._pending[fd][0]
        try:
            got = channel.receive()
        except RemoteProtocolError as exc:
            self._abandon(fd, str(exc))
            return
        if got is None:
            self._abandon(fd, "it closed before attaching")
            return
        if not got:
            return
        msg = got[0][0]
        channel.reader.close()  # an Attach carries no descriptor: whatever came is closed, not held
        if not isinstance(msg, control.Attach) or len(got) > 1:
            self._abandon(fd, f"expected one attach, got {type(msg).__name__}")
            return
        entry = self._pending.pop(fd)
        entry[1].cancel()
        self._loop.remove_reader(fd)
        if not hmac.compare_digest(msg.token.encode(), self.token.encode()):
            refuse(channel, self.topic, pid, "wrong token")
            return
        self.on_attach(channel, msg, pid, uid)
