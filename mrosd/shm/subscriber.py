"""A subscriber's end of the shared-memory transport: its connection to one publisher's ring.

``ShmSubscriberConnection`` attaches (token and connection header out; header, read-only ring, its
acknowledgement page and its end of a wake-up socket pair in, over the socket of ``mrosd.shm.channel``), then is
woken by the loop (``add_reader`` on its end of the pair, spin-then-block through ``mrosd.spin``) and reads the ring:
copies by default, or zero-copy ``ShmView``s on request (``mrosd.shm.lease``: the view and its lease). After
each message it writes the number of the next one it wants into its acknowledgement page (for a view: once the
view is released), and wakes the publisher when the ring says the publisher waits for a slot. A subscriber
that falls too far behind loses the oldest messages and counts them; it reports the count to the publisher for
its statistics. The publisher's end (exit, crash) is its socket closing; ``closed`` is then done and ``error``
says why. A publisher breaking the protocol closes this connection, with one log line.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import logging
import socket
import time
from collections.abc import Callable
from typing import Any

from mrosd import backports
from mrosd.errors import HandshakeError, LocalProtocolError, RemoteProtocolError
from mrosd.ixm.channel import drain_socket, is_wake_socket, small_send_buffer, wake_socket
from mrosd.msg.runtime import FrameBuffer
from mrosd.shm import control
from mrosd.shm.channel import (
    ATTACH_TIMEOUT,
    ControlChannel,
    abstract_name,
    close_fds,
    connect_unix,
    peer_credentials,
)
from mrosd.shm.lease import ShmView
from mrosd.shm.negotiate import ShmAnswer, trusted_uids
from mrosd.shm.ring import RingCursor
from mrosd.shm.segment import MAX_LEASES, MappedAck, MappedRing
from mrosd.spin import Anticipation, loop_spinner
from mrosd.wire.header import ConnectionHeader, decode_connection_header, encode_header
from mrosd.wire.spares import spare_pool

__all__ = [
    "DEFAULT_MAX_MAP_BYTES",
    "DRAIN_BATCH",
    "MAX_NEXT_RINGS",
    "Frame",
    "ShmRefused",
    "ShmSubscriberConnection",
    "ShmView",
]

log = logging.getLogger(__name__)

#: A subscriber maps a ring of at most this many bytes.
DEFAULT_MAX_MAP_BYTES = 2 << 30
#: Replacement rings announced and not yet reached; more is a publisher misbehaving.
MAX_NEXT_RINGS = 8
#: Messages delivered per wake-up before the loop gets a turn (the rest follow at once).
DRAIN_BATCH = 64


class ShmRefused(HandshakeError):
    """The publisher refused this subscriber (``reason``: its words, as a TCPROS error header carries them)."""

    def __init__(self, reason: str) -> None:
        self.reason = reason
        super().__init__(f"publisher refused the shared-memory connection: {reason}")


Frame = bytes | bytearray | ShmView


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
        #: the publisher closed its sockets: the ring is read to its end, then the connection ends
        self._leaving = False
        #: why the connection ended ("" when we closed it or the publisher went away cleanly)
        self.error = ""
        self.publisher_pid = 0
        self._channel: ControlChannel | None = None
        #: our end of the wake-up pair: the publisher wakes us through it, we wake it through it
        self._wake: socket.socket | None = None
        self.publisher_uid = -1
        self._ring: MappedRing | None = None
        self._cursor: RingCursor | None = None
        self._ack: MappedAck | None = None
        #: copies are made into the process's spare buffers, reused once the messages decoded from them are gone
        self._pool = spare_pool()
        self._dropped_before = 0
        self._reported = 0
        self._on_frame: Callable[[Any], None] | None = None
        self._zero_copy = False
        self._event = asyncio.Event()
        #: leases: words of our acknowledgement page we may use (granted by the publisher), free ones, the
        #: views dropped while still exported (their lease ends when the export does), and the messages
        #: dropped because every lease was held
        self.max_leased = 0
        self._free_leases: list[int] = []
        self._deferred: collections.deque[ShmView] = collections.deque()
        self.lease_drops = 0
        #: rings the publisher moved on to, not yet switched to (the current one still has messages)
        self._next_rings: collections.deque[MappedRing] = collections.deque()
        self._scheduled = False
        self._max_map = DEFAULT_MAX_MAP_BYTES
        spinner = loop_spinner(self._loop)
        self._poke = spinner.poke
        self._anticipate = spinner.anticipate
        #: the publisher's rhythm, and the timer of the spin window around its next message (``mrosd.spin``)
        self._rhythm = Anticipation()
        self._window: asyncio.TimerHandle | None = None

    @classmethod
    async def attach(
        cls,
        answer: ShmAnswer,
        header: ConnectionHeader,
        *,
        on_frame: Callable[[Any], None] | None = None,
        zero_copy: bool = False,
        max_leased: int = 2,
        timeout: float = ATTACH_TIMEOUT,
        trusted: frozenset[int] | None = None,
        max_map_bytes: int = DEFAULT_MAX_MAP_BYTES,
    ) -> ShmSubscriberConnection:
        """Connect to ``answer.address``, show the token and ``header``, map the ring.

        ``zero_copy``: deliver ``ShmView``s under leases, at most ``max_leased`` held at once (the publisher
        may grant fewer: ``max_leased`` then says how many; with none granted, messages are copied out).
        With every lease held, further messages are dropped (``lease_drops``, counted in ``dropped``): the
        publisher never waits for a lease.

        Raises:
            HandshakeError: the publisher refused us (its reason).
            RemoteProtocolError: the publisher is not of a trusted uid or broke the protocol.
            OSError, TimeoutError: it could not be reached in ``timeout`` seconds.
        """
        self = cls()
        self._on_frame = on_frame
        self._zero_copy = zero_copy
        self._max_map = max_map_bytes
        self.max_leased = max(0, max_leased) if zero_copy else 0
        try:
            async with backports.timeout(timeout):
                await self._handshake(answer, header, trusted_uids() if trusted is None else trusted)
        except BaseException:
            self._release()
            raise
        return self

    async def _handshake(self, answer: ShmAnswer, header: ConnectionHeader, trusted: frozenset[int]) -> None:
        loop = self._loop
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC | socket.SOCK_NONBLOCK)
        self._channel = channel = ControlChannel(sock)
        await connect_unix(sock, abstract_name(answer.address))
        pid, uid = peer_credentials(sock)
        if uid not in trusted:
            raise RemoteProtocolError(f"the shared-memory publisher (pid {pid}) runs as untrusted uid {uid}")
        self.publisher_pid, self.publisher_uid = pid, uid
        channel.send(control.Attach(token=answer.token, header=encode_header(header)[4:], leases=self.max_leased))
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
        close_fds(f for _, more in rest for f in more)
        if isinstance(msg, control.Refused):
            raise ShmRefused(msg.reason)
        if not isinstance(msg, control.Attached):
            close_fds(fds)
            raise RemoteProtocolError(f"expected Attached from the shared-memory publisher, got {type(msg).__name__}")
        if rest:
            raise RemoteProtocolError("the shared-memory publisher sent messages before we were attached")
        ring_fd, ack_fd, wake_fd = fds
        try:
            self._wake = socket.socket(fileno=wake_fd)
        except OSError:
            close_fds([ring_fd, ack_fd, wake_fd])
            raise RemoteProtocolError("the shared-memory publisher's wake-up descriptor is not a socket") from None
        # sends ignore the flags (MSG_DONTWAIT); a pair the publisher made cannot carry our bytes to a third party
        if not is_wake_socket(self._wake, uid):
            close_fds([ring_fd, ack_fd])
            raise RemoteProtocolError("the shared-memory publisher's wake-up descriptor is not its own socket pair")
        small_send_buffer(self._wake)
        try:
            self._ack = MappedAck(ack_fd)
        except BaseException:
            close_fds([ring_fd])
            raise
        self.reply_header = decode_connection_header(msg.header)
        self.max_leased = max(0, min(msg.leases, self.max_leased, MAX_LEASES))
        self._free_leases = list(range(self.max_leased, 0, -1))
        if self._zero_copy and not self.max_leased:
            log.info("shared-memory publisher pid %d grants no leases: copying its messages out", pid)
            self._zero_copy = False
        self._ring = MappedRing(ring_fd, self._max_map)
        self._cursor = RingCursor(self._ring.layout, max(1, msg.first))
        loop.add_reader(self._wake.fileno(), self._on_wake)
        loop.add_reader(sock.fileno(), self._on_control)
        if self._on_frame is not None:
            self._schedule()
        elif self._cursor.available():
            self._event.set()

    # stats -------------------------------------------------------------------------------------------------

    @property
    def dropped(self) -> int:
        """Messages lost: overwritten in the ring before this subscriber read them."""
        return self._dropped_before + self.lease_drops + (self._cursor.dropped if self._cursor is not None else 0)

    @property
    def connected(self) -> bool:
        return not self._ended

    # wake-ups ----------------------------------------------------------------------------------------------

    def _on_wake(self) -> None:
        self._poke()
        if self._on_frame is None:
            if self._wake is not None and not drain_socket(self._wake):
                self._publisher_left()  # its control socket says so too, maybe later
                return
            self._event.set()
            return
        # The messages first, then the wake-up byte: its recv is not on their path. After an idle period every
        # code path runs cold, and that recv measured 55-65 us of an 8 MB loan's 310-330 us (300 messages).
        received = self.messages_received
        self._drain()
        if self._wake is not None and not drain_socket(self._wake):
            self._publisher_left()
            return
        # A message committed between that read of the ring and the recv woke us with a byte just taken.
        cursor = self._cursor
        if cursor is not None and (cursor.available() or self._next_rings):
            self._schedule()
        if self._zero_copy and self.messages_received != received:  # not the wake-up of what a probe read
            self._expect_next()

    def _expect_next(self) -> None:
        """Learn the publisher's rhythm; once steady, spin through the window of its next message.

        Zero-copy subscribers only: they asked for the lowest latency, and pay for it with at most
        ``mrosd.spin.DUTY`` of a CPU per periodic publisher (measured 4-5 % of one at 50 Hz); after an idle
        period the halted CPU's wake-up was 110-130 us of a loaned message's 250-310 (docs/shm.md)."""
        if self._window is not None:
            self._window.cancel()
            self._window = None
        if self._ended:  # the message just read was the last (its callback may have closed us)
            return
        window = self._rhythm.arrived(time.monotonic_ns())
        if window is not None:
            self._window = self._anticipate(window, self._probe)

    def _probe(self) -> bool:
        """Inside a spin window: is the next message in the ring already? Then read it now (its wake-up byte,
        when it comes, finds nothing more to read)."""
        cursor = self._cursor
        if self._ended or cursor is None or not cursor.available():
            return False
        self._drain()
        self._expect_next()
        return True

    def _schedule(self) -> None:
        if not self._scheduled:
            self._scheduled = True
            self._loop.call_soon(self._drain_soon)

    def _drain_soon(self) -> None:
        self._scheduled = False
        if not self._ended:
            self._drain()

    def _publisher_left(self) -> None:
        """The publisher closed its sockets (exit, crash, unadvertise). What it published before is in the ring
        and is still delivered, as TCPROS delivers the bytes already in a closed socket; then the connection
        ends. The sockets are no longer watched (their end-of-file would wake us on every loop turn)."""
        if self._ended or self._leaving:
            return
        self._leaving = True
        # Rings announced just before the publisher left are read first (its wake-up socket's end may be seen
        # before its control socket's): each read takes one recv, and the stream ends within MAX_NEXT_RINGS.
        for _ in range(MAX_NEXT_RINGS + 2):
            if not self._read_control() or self._ended:
                break
        if self._ended:
            return
        cursor = self._cursor
        if cursor is None or (not cursor.available() and not self._next_rings):
            self._end("")  # nothing left to read: the connection ends now, as before
            return
        loop = self._loop
        for sock in (self._wake, self._channel.sock if self._channel is not None else None):
            if sock is not None:
                with contextlib.suppress(Exception):
                    loop.remove_reader(sock.fileno())
        if self._on_frame is not None:
            self._schedule()  # ``_drain`` ends the connection once the ring is read
        else:
            self._event.set()  # ``__anext__`` ends it once the ring is read

    def _drain(self) -> None:
        cursor = self._cursor
        callback = self._on_frame
        if cursor is None or callback is None:
            return
        try:
            for _ in range(DRAIN_BATCH):
                frame = self._read_one()
                if frame is None:
                    if self._leaving:
                        self._end("")
                        return
                    break
                try:
                    callback(frame)
                except Exception:
                    log.exception("shared-memory subscriber callback failed")
                del frame  # not held while the next one is copied: its buffer can be refilled
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
                leased = self._lease_next(cursor)
                if leased is not None:
                    frame: Frame = leased
                    n = len(leased.data)
                    break
            else:
                data = cursor.read(self._pool)
                if type(data) is FrameBuffer:
                    self._pool.watch(self._loop)  # kept for reuse: given back once idle
                if data is not None:
                    frame, n = data, len(data)
                    self._acknowledge(cursor.next)
                    break
            if not self._next_rings:
                return None
            cursor = self._switch()
        self.messages_received += 1
        self.bytes_received += n
        return frame

    def _lease_next(self, cursor: RingCursor) -> ShmView | None:
        """The next message under a lease, or None when none is ready. Every lease held: the message is
        dropped (counted), not waited for. The lease is written before the slot is checked again, and
        before the acknowledgement moves past the message (the order the publisher relies on)."""
        ack = self._ack
        if ack is None:
            return None
        self._retry_deferred()
        while True:
            got = cursor.begin()
            if got is None:
                return None
            m, n = got
            slot = cursor.slot
            if not self._free_leases:
                self.lease_drops += 1
                cursor.next = m + 1
                self._acknowledge(m + 1)
                continue
            index = self._free_leases.pop()
            ack.lease(index, m)
            if not cursor.intact(m, slot):  # overwritten before the lease was seen: lost, as a copy would be
                ack.lease(index, 0)
                self._free_leases.append(index)
                cursor.finish(m)
                continue
            cursor.next = m + 1
            self._acknowledge(m + 1)
            start = cursor.start
            data = cursor.ring.data[slot][start : start + n].toreadonly()
            layout = self._ring.layout if self._ring is not None else None
            return ShmView(self, layout, data, number=m, slot=slot, index=index)

    def end_lease(self, index: int) -> None:
        """A lease ended: its word goes back to 0 (the publisher may reuse the slot) and is free again. May run
        on another thread (a frame handed to a worker): one word written, one list append, one ``send``."""
        ack = self._ack
        if ack is None or self._ended:
            return
        ack.lease(index, 0)
        self._free_leases.append(index)
        ring = self._ring
        if ring is not None and ring.layout.waiting and self._wake is not None:
            wake_socket(self._wake)

    def keep_lease(self, view: ShmView) -> None:
        """A lease dropped while one of its views is still referenced (kept, or a numpy array over it): it
        lasts until that is gone, looked at again before each message is leased."""
        self._deferred.append(view)

    def _retry_deferred(self) -> None:
        deferred = self._deferred  # a deque: another thread may drop a view (append) meanwhile
        for _ in range(len(deferred)):
            view = deferred.popleft()
            if view.in_use():
                deferred.append(view)
            else:
                view.release_views()
                self.end_lease(view.index)

    def _acknowledge(self, next_message: int) -> None:
        """Tell the publisher we are done with the messages before ``next_message``; wake it if it waits."""
        ack = self._ack
        if ack is None:
            return
        ack.write(next_message)
        ring = self._ring
        if ring is not None and ring.layout.waiting and self._wake is not None:
            wake_socket(self._wake)  # never blocks: a full buffer is a wake-up the publisher has pending

    def _report(self) -> None:
        dropped = self.dropped
        if dropped != self._reported and self._channel is not None:
            self._reported = dropped
            with contextlib.suppress(OSError):
                self._channel.send(control.Progress(dropped=dropped, received=self.messages_received))

    def _on_control(self) -> None:
        if self._read_control() and not self._ended:
            if self._on_frame is not None:
                self._schedule()
            else:
                self._event.set()

    def _read_control(self) -> bool:
        """Apply what waits on the control socket (announced rings); False at its end or on a protocol error
        (which ends the connection)."""
        channel = self._channel
        if channel is None:
            return False
        try:
            got = channel.receive()
            if got is None:
                self._publisher_left()
                return False
            for msg, fds in got:
                if isinstance(msg, control.Ring):
                    self._next_rings.append(MappedRing(fds[0], self._max_map))
                    if len(self._next_rings) > MAX_NEXT_RINGS:
                        raise RemoteProtocolError("the shared-memory publisher replaced its ring too often")
                else:
                    close_fds(fds)
                    raise RemoteProtocolError(f"unexpected {type(msg).__name__} from the shared-memory publisher")
        except RemoteProtocolError as exc:
            self._end(str(exc))
            return False
        return True

    def _switch(self) -> RingCursor:
        """Our ring is exhausted and retired (the publisher retires a ring before announcing the next one):
        continue in the next, where the message numbers go on."""
        old, cursor = self._ring, self._cursor
        assert old is not None and cursor is not None
        new = self._next_rings.popleft()
        self._dropped_before += cursor.dropped
        self._ring = new
        self._cursor = RingCursor(new.layout, cursor.next)
        old.close()  # views still leased keep their mapping (and the publisher never writes a retired ring)
        return self._cursor

    # iteration --------------------------------------------------------------------------------------------

    def __aiter__(self) -> ShmSubscriberConnection:
        return self

    async def __anext__(self) -> Frame:
        """The next message (bytes, or a leased ``ShmView``); stops when the connection ends."""
        if self._on_frame is not None:
            raise LocalProtocolError("this connection delivers to a callback; it cannot be iterated")
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
                return frame
            if self._leaving:
                self._end("")
                raise StopAsyncIteration
            await self._event.wait()  # set by a wake-up, a new ring, or the end of the connection

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
        if self._window is not None:
            self._window.cancel()
            self._window = None
        if self._wake is not None:
            with contextlib.suppress(Exception):
                loop.remove_reader(self._wake.fileno())
            self._wake.close()
            self._wake = None
        if self._channel is not None:
            with contextlib.suppress(Exception):
                loop.remove_reader(self._channel.sock.fileno())
            self._channel.close()
            self._channel = None
        self._deferred.clear()
        if self._cursor is not None:
            self._dropped_before += self._cursor.dropped
            self._cursor = None
        if self._ring is not None:
            self._ring.close()
            self._ring = None
        if self._ack is not None:
            self._ack.close()
            self._ack = None
        while self._next_rings:
            self._next_rings.popleft().close()

    async def aclose(self) -> None:
        """Detach: the publisher sees our socket close; the mapping is released."""
        self._end("")
