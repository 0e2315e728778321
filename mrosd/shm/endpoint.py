"""The asyncio ends of the shared-memory topic transport: a publisher's ring and listener, a subscriber's attachment.

``ShmPublisherEndpoint`` owns one topic's ring (a sealed memfd, ``mrosd.shm.segment``), an abstract Unix
socket (no file to leave behind, scoped to the network namespace) on which same-host subscribers attach, and
one eventfd per subscriber. ``publish`` copies the serialized message once into the ring and writes 8 bytes
to each subscriber's eventfd: its cost does not grow with the message size per subscriber, and it never
waits for anyone. A message bigger than the slots makes the publisher retire the ring and continue in a
bigger one, announced with its descriptor over each subscriber's socket.

``ShmSubscriberConnection`` attaches (token, connection header, eventfd out; header, read-only ring in),
then is woken by the loop (``add_reader`` on the eventfd, spin-then-block through ``mrosd.spin``) and reads
the ring: copies by default, or zero-copy ``ShmView``s on request. A subscriber that falls behind loses
the oldest messages and counts them; it reports the count to the publisher for its statistics. Either side
sees the other's end (exit, crash) as its socket closing; ``closed`` is then done and ``error`` says why.
Every problem with a peer closes only that peer's connection, with one log line.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import errno
import hmac
import itertools
import logging
import os
import secrets
import socket
import struct
import sys
from collections.abc import Callable, Iterable
from typing import Any

from mrosd.errors import HandshakeError, LocalProtocolError, MrosError, RemoteProtocolError
from mrosd.ixm.channel import FdReader, send_frame
from mrosd.shm import control
from mrosd.shm.negotiate import TRANSPORT, ShmAnswer, publisher_answer, trusted_uids
from mrosd.shm.ring import MAX_SLOTS, RingCursor, slot_stride
from mrosd.shm.segment import MappedRing, RingSegment
from mrosd.spin import loop_spinner
from mrosd.tcpros.header import ConnectionHeader, decode_connection_header, encode_header

__all__ = [
    "DEFAULT_MAX_RING_BYTES",
    "ShmPublisherEndpoint",
    "ShmRefused",
    "ShmSubscriberConnection",
    "ShmSubscriberLink",
    "ShmView",
    "slots_for",
]

log = logging.getLogger(__name__)

#: A publisher's ring is at most this big (more slots than fit are not made; at least 2 always are).
DEFAULT_MAX_RING_BYTES = 128 << 20
#: A subscriber maps a ring of at most this many bytes.
DEFAULT_MAX_MAP_BYTES = 2 << 30
#: First slot size; the ring grows (by replacement) when a bigger message comes.
INITIAL_CAPACITY = 64 << 10
#: Subscribers that connected but have not attached yet, and how long they may take.
MAX_PENDING = 64
ATTACH_TIMEOUT = 10.0
#: Replacement rings announced and not yet reached; more is a publisher misbehaving.
MAX_NEXT_RINGS = 8
#: Messages delivered per wake-up before the loop gets a turn (the rest follow at once).
DRAIN_BATCH = 64

_ONE = (1).to_bytes(8, sys.byteorder)
_PEERCRED = struct.Struct("3i")
_ids = itertools.count(1)


def slots_for(queue_size: int, capacity: int, max_ring_bytes: int) -> int:
    """Ring slots for a publisher's ``queue_size``: one more than the queue (the one being written), at least
    3, and no more than ``max_ring_bytes`` holds (but never fewer than 2)."""
    wanted = min(MAX_SLOTS, max(3, queue_size + 1))
    fit = max_ring_bytes // slot_stride(capacity)
    return max(2, min(wanted, fit))


def _grown(capacity: int, needed: int) -> int:
    """The slot size of a replacement ring: room for ``needed`` plus an eighth, page-rounded, at least double
    the old one while that stays under twice ``needed``."""
    size = max(needed + needed // 8, min(capacity * 2, needed * 2))
    return (size + 4095) // 4096 * 4096


def _abstract(address: str) -> str:
    return "\0" + address[1:]


def _peer_uid(sock: socket.socket) -> tuple[int, int]:
    pid, uid, _gid = _PEERCRED.unpack(sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, _PEERCRED.size))
    return pid, uid


def _settle(future: asyncio.Future[None]) -> None:
    if not future.done():
        future.set_result(None)


async def _connect(sock: socket.socket, address: str) -> None:
    """Connect a non-blocking Unix socket (by hand: uvloop's sock_connect does not take abstract names)."""
    try:
        sock.connect(address)
        return
    except (BlockingIOError, InterruptedError):
        pass  # the listener's backlog is full: wait until it takes us
    loop = asyncio.get_running_loop()
    ready: asyncio.Future[None] = loop.create_future()
    loop.add_writer(sock.fileno(), _settle, ready)
    try:
        await ready
    finally:
        loop.remove_writer(sock.fileno())
    err = sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
    if err:
        raise OSError(err, os.strerror(err))


def _is_eventfd(fd: int) -> bool:
    try:
        return os.readlink(f"/proc/self/fd/{fd}") == "anon_inode:[eventfd]"
    except OSError:
        return False


def _close_fds(fds: Iterable[int]) -> None:
    for fd in fds:
        with contextlib.suppress(OSError):
            os.close(fd)


class ShmRefused(HandshakeError):
    """The publisher refused this subscriber (``reason``: its words, as a TCPROS error header carries them)."""

    def __init__(self, reason: str) -> None:
        self.reason = reason
        super().__init__(f"publisher refused the shared-memory connection: {reason}")


class _Channel:
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
            wants = 1 if isinstance(msg, (control.Attach, control.Attached, control.Ring)) else 0
            out.append((msg, self.reader.take_fds(wants)))
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


# publisher ---------------------------------------------------------------------------------------------------


class ShmSubscriberLink:
    """One attached subscriber, seen from the publisher."""

    def __init__(self, endpoint: ShmPublisherEndpoint, channel: _Channel, wake_fd: int, callerid: str, pid: int):
        self.endpoint = endpoint
        self.channel = channel
        self.wake_fd = wake_fd
        self.callerid = callerid
        self.pid = pid
        self.id = next(_ids)
        self.messages_sent = 0
        self.bytes_sent = 0
        #: as last reported by the subscriber
        self.dropped = 0
        self.connected = True

    def close(self) -> None:
        if not self.connected:
            return
        self.connected = False
        loop = self.endpoint._loop
        with contextlib.suppress(Exception):
            loop.remove_reader(self.channel.sock.fileno())
        self.channel.close()
        _close_fds([self.wake_fd])


class ShmPublisherEndpoint:
    """One topic's shared-memory side: ``await start()``, answer requestTopic with ``answer()``, ``publish``.

    Args:
        topic: for names and log lines.
        queue_size: the ring keeps this many messages for a slow subscriber (see ``slots_for``).
        latch: a subscriber that attaches gets the last message first.
        handshake: checks a subscriber's TCPROS connection header and returns the publisher's (as
            ``mrosd.tcpros.handshake.publisher_reply`` does); raise ``HandshakeError`` to refuse.
        on_change: called when a subscriber attaches or goes.
        trusted: uids whose processes may attach (default root, ours, ``$MROSD_SHM_TRUSTED_UIDS``).
    """

    def __init__(
        self,
        topic: str,
        *,
        queue_size: int = 100,
        latch: bool = False,
        handshake: Callable[[ConnectionHeader], ConnectionHeader] | None = None,
        on_change: Callable[[], None] | None = None,
        trusted: frozenset[int] | None = None,
        max_ring_bytes: int = DEFAULT_MAX_RING_BYTES,
        initial_capacity: int = INITIAL_CAPACITY,
    ) -> None:
        self.topic = topic
        self.queue_size = queue_size
        self.latch = latch
        self.handshake = handshake or (lambda header: ConnectionHeader(callerid="", latching="1" if latch else "0"))
        self.on_change = on_change or (lambda: None)
        self.trusted = trusted_uids() if trusted is None else trusted
        self.max_ring_bytes = max_ring_bytes
        self.capacity = max(64, initial_capacity)
        self.token = secrets.token_hex(16)
        self.address = "@mrosd-shm-" + secrets.token_hex(12)
        self.links: list[ShmSubscriberLink] = []
        self.ring: RingSegment | None = None
        #: rings made so far (the first and each replacement)
        self.rings_made = 0
        self.closed = False
        self._loop = asyncio.get_running_loop()
        self._sock: socket.socket | None = None
        self._pending: dict[int, tuple[_Channel, asyncio.TimerHandle]] = {}
        self._poke = loop_spinner(self._loop).poke

    async def start(self) -> None:
        """Listen on the abstract Unix socket ``address``."""
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC | socket.SOCK_NONBLOCK)
        try:
            sock.bind(_abstract(self.address))
            sock.listen(64)
        except BaseException:
            sock.close()
            raise
        self._sock = sock
        self._loop.add_reader(sock.fileno(), self._accept)

    def answer(self) -> list[Any]:
        """requestTopic's protocol parameters that send a subscriber here."""
        return publisher_answer(self.address, self.token)

    # publishing ------------------------------------------------------------------------------------------

    def publish(self, body: bytes | bytearray | memoryview) -> None:
        """Copy one serialized message (no length prefix) into the ring once and wake every subscriber."""
        self.publish_parts((body,), len(body))

    def publish_parts(self, parts: Iterable[bytes | bytearray | memoryview], size: int) -> None:
        """``publish(b"".join(parts))`` without the join (``size`` bytes in all)."""
        if self.closed:
            raise LocalProtocolError(f"shared-memory publisher of {self.topic} is closed")
        if not self.links and not self.latch:
            return  # nobody reads it, and nobody will read this one later
        ring = self._ring_for(size)
        ring.layout.write_parts(parts, size)
        for link in self.links:
            link.messages_sent += 1
            link.bytes_sent += size
            try:
                os.write(link.wake_fd, _ONE)
            except BlockingIOError:
                pass  # the counter is saturated: the subscriber is woken anyway
            except OSError as exc:
                self._drop(link, f"cannot wake it: {exc}")
        self._poke()

    def _ring_for(self, size: int) -> RingSegment:
        ring = self.ring
        if ring is not None and size <= ring.layout.capacity:
            return ring
        if ring is None:
            capacity = max(self.capacity, _grown(0, size) if size > self.capacity else self.capacity)
        else:
            capacity = _grown(ring.layout.capacity, size)
        head = ring.layout.head if ring is not None else 0
        slots = slots_for(self.queue_size, capacity, self.max_ring_bytes)
        new = RingSegment(self.topic.strip("/").replace("/", "-"), slots, capacity, head)
        self.rings_made += 1
        self.capacity = capacity
        self.ring = new
        if ring is not None:
            ring.layout.retire()
            for link in list(self.links):
                self._send_ring(link, control.Ring(slots=new.layout.slots))
            ring.close()
        return new

    def _send_ring(self, link: ShmSubscriberLink, msg: control.Message) -> bool:
        assert self.ring is not None
        fd = self.ring.reader_fd()
        try:
            link.channel.send(msg, (fd,))
        except OSError as exc:
            self._drop(link, f"cannot send it the ring: {exc}")
            return False
        finally:
            os.close(fd)
        return True

    # subscribers ------------------------------------------------------------------------------------------

    def _accept(self) -> None:
        assert self._sock is not None
        while True:
            try:
                conn, _ = self._sock.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                log.warning("%s: shared-memory accept failed: %s", self.topic, exc)
                return
            pid, uid = _peer_uid(conn)
            if uid not in self.trusted or len(self._pending) >= MAX_PENDING:
                why = "uid not trusted" if uid not in self.trusted else "too many pending attachments"
                log.warning("%s: refusing shared-memory subscriber pid %d uid %d: %s", self.topic, pid, uid, why)
                conn.close()
                continue
            channel = _Channel(conn)
            fd = conn.fileno()
            timer = self._loop.call_later(ATTACH_TIMEOUT, self._abandon, fd, "did not attach in time")
            self._pending[fd] = (channel, timer)
            self._loop.add_reader(fd, self._on_pending, fd, pid)

    def _abandon(self, fd: int, why: str) -> None:
        entry = self._pending.pop(fd, None)
        if entry is None:
            return
        channel, timer = entry
        timer.cancel()
        with contextlib.suppress(Exception):
            self._loop.remove_reader(fd)
        log.warning("%s: closing a shared-memory subscriber connection: %s", self.topic, why)
        channel.close()

    def _on_pending(self, fd: int, pid: int) -> None:
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
        msg, fds = got[0]
        if not isinstance(msg, control.Attach) or len(got) > 1:
            _close_fds(f for _, more in got for f in more)
            self._abandon(fd, f"expected one attach, got {type(msg).__name__}")
            return
        wake_fd = fds[0]
        entry = self._pending.pop(fd)
        entry[1].cancel()
        self._loop.remove_reader(fd)
        self._attach(channel, msg, wake_fd, pid)

    def _attach(self, channel: _Channel, msg: control.Attach, wake_fd: int, pid: int) -> None:
        def refuse(why: str) -> None:
            log.warning("%s: refusing shared-memory subscriber (pid %d): %s", self.topic, pid, why)
            with contextlib.suppress(OSError):
                channel.send(control.Refused(reason=why))
            channel.close()
            _close_fds([wake_fd])

        if not hmac.compare_digest(msg.token.encode(), self.token.encode()):
            refuse("wrong token")
            return
        if not _is_eventfd(wake_fd):
            refuse("the wake-up descriptor is not an eventfd")
            return
        os.set_blocking(wake_fd, False)
        try:
            header = decode_connection_header(msg.header)
            reply = self.handshake(header)
        except (HandshakeError, RemoteProtocolError) as exc:
            refuse(str(exc))
            return
        if self.closed:
            refuse("the publisher is closing")
            return
        ring = self._ring_for(0)
        head = ring.layout.head
        first = head if self.latch and head > 0 else head + 1
        link = ShmSubscriberLink(self, channel, wake_fd, header.callerid or "?", pid)
        if not self._send_ring(link, control.Attached(header=encode_header(reply)[4:], first=first)):
            return
        if first <= head:  # the latched message
            link.messages_sent += 1
            link.bytes_sent += int(ring.layout.words[(head - 1) % ring.layout.slots][1])
        self.links.append(link)
        self._loop.add_reader(channel.sock.fileno(), self._on_link, link)
        self.on_change()

    def _on_link(self, link: ShmSubscriberLink) -> None:
        try:
            got = link.channel.receive()
        except RemoteProtocolError as exc:
            self._drop(link, str(exc))
            return
        if got is None:
            self._drop(link, "")
            return
        for msg, fds in got:
            _close_fds(fds)
            if isinstance(msg, control.Progress):
                link.dropped = max(0, min(msg.dropped, 1 << 62))
            else:
                self._drop(link, f"unexpected {type(msg).__name__}")
                return

    def _drop(self, link: ShmSubscriberLink, why: str) -> None:
        if why:
            log.warning("%s: closing shared-memory subscriber %s: %s", self.topic, link.callerid, why)
        else:
            log.info("%s: shared-memory subscriber %s went away", self.topic, link.callerid)
        link.close()
        if link in self.links:
            self.links.remove(link)
            self.on_change()

    # introspection ---------------------------------------------------------------------------------------

    def stats(self) -> list[dict[str, Any]]:
        """Per subscriber: id, callerid, messages and bytes written for it, drops it reported, connected."""
        return [
            {
                "id": lk.id,
                "callerid": lk.callerid,
                "messages": lk.messages_sent,
                "bytes": lk.bytes_sent,
                "dropped": lk.dropped,
                "connected": lk.connected,
            }
            for lk in self.links
        ]

    def bus_info(self) -> list[list[Any]]:
        """getBusInfo rows of the shared-memory subscribers (transport ``SHMROS``)."""
        return [[lk.id, lk.callerid, "o", TRANSPORT, self.topic, lk.connected, f"pid {lk.pid}"] for lk in self.links]

    # lifecycle ------------------------------------------------------------------------------------------

    async def aclose(self) -> None:
        """Close every subscriber connection (they see their socket close), the listener and the ring."""
        if self.closed:
            return
        self.closed = True
        if self._sock is not None:
            with contextlib.suppress(Exception):
                self._loop.remove_reader(self._sock.fileno())
            self._sock.close()
            self._sock = None
        for fd in list(self._pending):
            self._abandon(fd, "the publisher is closing")
        for link in list(self.links):
            link.close()
        self.links.clear()
        if self.ring is not None:
            self.ring.close()
            self.ring = None


# subscriber --------------------------------------------------------------------------------------------------


class ShmView:
    """A zero-copy, read-only view of one message in the publisher's ring.

    Lifetime: in a callback, the view is released when the callback returns; from ``async for``, when the
    next message is asked for. Independently, the publisher overwrites the slot ``slots - 1`` messages later:
    the bytes read through ``data`` were those of this message if ``intact()`` is still True after reading
    them (copy what you keep, then check).
    """

    __slots__ = ("_cursor", "data", "number")

    def __init__(self, cursor: RingCursor, number: int, data: memoryview) -> None:
        self._cursor = cursor
        self.number = number
        self.data = data

    def intact(self) -> bool:
        return self._cursor.intact(self.number)

    def release(self) -> None:
        self.data.release()


Frame = bytes | ShmView


class ShmSubscriberConnection:
    """A subscriber's shared-memory connection to one publisher: ``await ShmSubscriberConnection.attach(...)``.

    With ``on_frame``, each message is passed to it as it arrives (bytes, or an ``ShmView`` with
    ``zero_copy``); without, iterate the connection with ``async for``. The ring is the queue: a subscriber
    that reads too slowly loses the oldest messages (``dropped``).
    """

    def __init__(self) -> None:
        self._loop = asyncio.get_running_loop()
        self.reply_header: ConnectionHeader | None = None
        self.messages_received = 0
        self.bytes_received = 0
        #: done when the connection ends; await ``wait_closed()`` rather than this future itself
        self.closed: asyncio.Future[None] = self._loop.create_future()
        self._ended = False
        #: why the connection ended ("" when we closed it or the publisher went away cleanly)
        self.error = ""
        self.publisher_pid = 0
        self._channel: _Channel | None = None
        self._wake_fd: int | None = None
        self._ring: MappedRing | None = None
        self._cursor: RingCursor | None = None
        self._dropped_before = 0
        self._reported = 0
        self._on_frame: Callable[[Any], None] | None = None
        self._zero_copy = False
        self._event = asyncio.Event()
        self._last_view: ShmView | None = None
        #: rings the publisher moved on to, not yet switched to (the current one still has messages)
        self._next_rings: collections.deque[MappedRing] = collections.deque()
        self._scheduled = False
        self._max_map = DEFAULT_MAX_MAP_BYTES
        self._poke = loop_spinner(self._loop).poke

    @classmethod
    async def attach(
        cls,
        answer: ShmAnswer,
        header: ConnectionHeader,
        *,
        on_frame: Callable[[Any], None] | None = None,
        zero_copy: bool = False,
        timeout: float = ATTACH_TIMEOUT,
        trusted: frozenset[int] | None = None,
        max_map_bytes: int = DEFAULT_MAX_MAP_BYTES,
    ) -> ShmSubscriberConnection:
        """Connect to ``answer.address``, show the token and ``header``, map the ring.

        Raises:
            HandshakeError: the publisher refused us (its reason).
            RemoteProtocolError: the publisher is not of a trusted uid or broke the protocol.
            OSError, TimeoutError: it could not be reached in ``timeout`` seconds.
        """
        self = cls()
        self._on_frame = on_frame
        self._zero_copy = zero_copy
        self._max_map = max_map_bytes
        try:
            async with asyncio.timeout(timeout):
                await self._handshake(answer, header, trusted_uids() if trusted is None else trusted)
        except BaseException:
            self._release()
            raise
        return self

    async def _handshake(self, answer: ShmAnswer, header: ConnectionHeader, trusted: frozenset[int]) -> None:
        loop = self._loop
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC | socket.SOCK_NONBLOCK)
        self._channel = channel = _Channel(sock)
        await _connect(sock, _abstract(answer.address))
        pid, uid = _peer_uid(sock)
        if uid not in trusted:
            raise RemoteProtocolError(f"the shared-memory publisher (pid {pid}) runs as untrusted uid {uid}")
        self.publisher_pid = pid
        self._wake_fd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
        channel.send(control.Attach(token=answer.token, header=encode_header(header)[4:]), (self._wake_fd,))
        got: list[tuple[control.Message, list[int]]] = []
        while not got:
            ready = loop.create_future()
            loop.add_reader(sock.fileno(), ready.set_result, None)
            try:
                await ready
            finally:
                loop.remove_reader(sock.fileno())
            received = channel.receive()
            if received is None:
                raise RemoteProtocolError("the shared-memory publisher closed the connection while attaching")
            got = received
        (msg, fds), rest = got[0], got[1:]
        _close_fds(f for _, more in rest for f in more)
        if isinstance(msg, control.Refused):
            raise ShmRefused(msg.reason)
        if not isinstance(msg, control.Attached):
            _close_fds(fds)
            raise RemoteProtocolError(f"expected Attached from the shared-memory publisher, got {type(msg).__name__}")
        if rest:
            raise RemoteProtocolError("the shared-memory publisher sent messages before we were attached")
        self.reply_header = decode_connection_header(msg.header)
        self._ring = MappedRing(fds[0], self._max_map)
        self._cursor = RingCursor(self._ring.layout, max(1, msg.first))
        loop.add_reader(self._wake_fd, self._on_wake)
        loop.add_reader(sock.fileno(), self._on_control)
        if self._on_frame is not None:
            self._schedule()
        elif self._cursor.available():
            self._event.set()

    # stats -------------------------------------------------------------------------------------------------

    @property
    def dropped(self) -> int:
        """Messages lost: overwritten in the ring before this subscriber read them."""
        return self._dropped_before + (self._cursor.dropped if self._cursor is not None else 0)

    @property
    def connected(self) -> bool:
        return not self._ended

    # wake-ups ----------------------------------------------------------------------------------------------

    def _on_wake(self) -> None:
        if self._wake_fd is not None:
            with contextlib.suppress(OSError):
                os.read(self._wake_fd, 8)
        self._poke()
        if self._on_frame is not None:
            self._drain()
        else:
            self._event.set()

    def _schedule(self) -> None:
        if not self._scheduled:
            self._scheduled = True
            self._loop.call_soon(self._drain_soon)

    def _drain_soon(self) -> None:
        self._scheduled = False
        if not self._ended:
            self._drain()

    def _drain(self) -> None:
        cursor = self._cursor
        callback = self._on_frame
        if cursor is None or callback is None:
            return
        try:
            for _ in range(DRAIN_BATCH):
                frame = self._read_one()
                if frame is None:
                    break
                try:
                    callback(frame)
                except Exception:
                    log.exception("shared-memory subscriber callback failed")
                finally:
                    if isinstance(frame, ShmView):
                        frame.release()
            else:
                self._schedule()
        except RemoteProtocolError as exc:
            self._end(str(exc))
            return
        self._report()

    def _read_one(self) -> Frame | None:
        """The next message, moving on to the next ring when ours is exhausted and replaced."""
        cursor = self._cursor
        if cursor is None:
            return None
        while True:
            if self._zero_copy:
                got = cursor.view()
                if got is not None:
                    m, view = got
                    frame: Frame = ShmView(cursor, m, view)
                    n = len(view)
                    break
            else:
                data = cursor.read()
                if data is not None:
                    frame, n = data, len(data)
                    break
            if not self._next_rings:
                return None
            cursor = self._switch()
        self.messages_received += 1
        self.bytes_received += n
        return frame

    def _report(self) -> None:
        dropped = self.dropped
        if dropped != self._reported and self._channel is not None:
            self._reported = dropped
            with contextlib.suppress(OSError):
                self._channel.send(control.Progress(dropped=dropped, received=self.messages_received))

    def _on_control(self) -> None:
        channel = self._channel
        if channel is None:
            return
        try:
            got = channel.receive()
            if got is None:
                self._end("")
                return
            for msg, fds in got:
                if isinstance(msg, control.Ring):
                    self._next_rings.append(MappedRing(fds[0], self._max_map))
                    if len(self._next_rings) > MAX_NEXT_RINGS:
                        raise RemoteProtocolError("the shared-memory publisher replaced its ring too often")
                else:
                    _close_fds(fds)
                    raise RemoteProtocolError(f"unexpected {type(msg).__name__} from the shared-memory publisher")
        except RemoteProtocolError as exc:
            self._end(str(exc))
            return
        if self._on_frame is not None:
            self._schedule()
        else:
            self._event.set()

    def _switch(self) -> RingCursor:
        """Our ring is exhausted and retired (the publisher retires a ring before announcing the next one):
        continue in the next, where the message numbers go on."""
        old, cursor = self._ring, self._cursor
        assert old is not None and cursor is not None
        new = self._next_rings.popleft()
        self._dropped_before += cursor.dropped
        self._ring = new
        self._cursor = RingCursor(new.layout, cursor.next)
        self._release_view()
        old.close()
        return self._cursor

    # iteration --------------------------------------------------------------------------------------------

    def __aiter__(self) -> ShmSubscriberConnection:
        return self

    async def __anext__(self) -> Frame:
        """The next message (bytes, or an ``ShmView`` valid until the next call); stops when the connection ends."""
        if self._on_frame is not None:
            raise LocalProtocolError("this connection delivers to a callback; it cannot be iterated")
        self._release_view()
        while True:
            if self._ended or self._cursor is None:
                raise StopAsyncIteration
            self._event.clear()
            try:
                frame = self._read_one()
            except RemoteProtocolError as exc:
                self._end(str(exc))
                raise StopAsyncIteration from None
            if frame is not None:
                self._report()
                if isinstance(frame, ShmView):
                    self._last_view = frame
                return frame
            await self._event.wait()  # set by a wake-up, a new ring, or the end of the connection

    def _release_view(self) -> None:
        if self._last_view is not None:
            self._last_view.release()
            self._last_view = None

    # lifecycle --------------------------------------------------------------------------------------------

    def _end(self, error: str) -> None:
        if self._ended:
            return
        self._ended = True
        if error:
            self.error = error
            log.warning("closing the shared-memory connection to publisher pid %d: %s", self.publisher_pid, error)
        self._release()
        if not self.closed.done():  # a caller that awaited ``closed`` itself and was cancelled cancels it
            self.closed.set_result(None)
        self._event.set()

    async def wait_closed(self) -> None:
        """Until the connection ends (cancelling the caller leaves ``closed`` alone)."""
        await asyncio.shield(self.closed)

    def _release(self) -> None:
        loop = self._loop
        if self._wake_fd is not None:
            with contextlib.suppress(Exception):
                loop.remove_reader(self._wake_fd)
            _close_fds([self._wake_fd])
            self._wake_fd = None
        if self._channel is not None:
            with contextlib.suppress(Exception):
                loop.remove_reader(self._channel.sock.fileno())
            self._channel.close()
            self._channel = None
        self._release_view()
        if self._cursor is not None:
            self._dropped_before += self._cursor.dropped
            self._cursor = None
        if self._ring is not None:
            self._ring.close()
            self._ring = None
        while self._next_rings:
            self._next_rings.popleft().close()

    async def aclose(self) -> None:
        """Detach: the publisher sees our socket close; the mapping is released."""
        self._end("")


def is_shm_error(exc: BaseException) -> bool:
    """Errors after which a subscriber should fall back to TCPROS rather than retry shared memory."""
    return isinstance(exc, (MrosError, OSError, TimeoutError))
