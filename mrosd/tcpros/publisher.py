"""Publisher: one serialization per message, fanned out to per-subscriber bounded queues.

Each subscriber connection is a ``SubscriberLink``. While its socket keeps up, a frame is written at once
(one ``transport.write``). When the transport pushes back (pause_writing), frames wait in that link's
queue of at most ``queue_size`` frames (and, with ``max_queued_bytes``, at most that many bytes: a bridge
republishing what a stranger sends bounds its memory, not only its count), dropping the OLDEST when full and
counting the drop (reported in getBusStats); once the socket drains, everything waiting goes out as ONE
coalesced write. A large message is never joined: its length prefix and its pieces (``serialize_parts``: the
payload is the very object the message holds, e.g. a view into the frame it was received in) go to the socket
in one ``writev`` (``TcprosProtocol.write_parts``). A slow subscriber therefore never delays the others and
costs at most WRITE_HIGH_WATER plus its queue. Latching keeps the serialized bytes, never the live message
object. Messages with ``Header header`` get the publisher's sequence number in ``header.seq``, as rospy and
roscpp do.
"""

from __future__ import annotations

import asyncio
import collections
import itertools
import logging
from typing import TYPE_CHECKING, Any

from mrosd import backports
from mrosd.errors import HandshakeError, LocalProtocolError
from mrosd.lograte import RateLimitedLog
from mrosd.msg.runtime import is_immutable
from mrosd.spin import loop_spinner
from mrosd.tcpros.protocol import TcprosProtocol
from mrosd.wire.framing import LARGE_FRAME, frame_prefix
from mrosd.wire.handshake import error_header, publisher_reply
from mrosd.wire.header import ConnectionHeader, encode_header

if TYPE_CHECKING:
    from mrosd.shm.topic import ShmTopicPublisher
    from mrosd.tcpros.owner import EndpointOwner

log = logging.getLogger(__name__)
#: what peers get wrong (a refused handshake): a few lines per topic and minute, never one per peer attempt
_ratelog = RateLimitedLog(log, period=60.0, burst=3)

#: A queued frame: the whole frame, or its pieces (length prefix, then the body's) for a large body that is
#: never concatenated.
Frame = bytes | tuple[bytes | bytearray | memoryview, ...]
_connection_ids = itertools.count(1)

#: Default per-subscriber queue length (frames), as rospy's and roscpp's usual queue_size choices.
DEFAULT_QUEUE_SIZE = 100


class SubscriberLink:
    """One subscriber's connection to a publisher: bounded drop-oldest queue, coalesced writes."""

    def __init__(
        self, publisher: Publisher, proto: TcprosProtocol, callerid: str, queue_size: int, max_bytes: int = 0
    ) -> None:
        self.publisher = publisher
        self.proto = proto
        self.callerid = callerid
        self.queue_size = max(1, queue_size)
        #: bound on the bytes queued (0: none); the newest frame is kept whatever its size
        self.max_bytes = max_bytes
        self.queue: collections.deque[tuple[Frame, int]] = collections.deque()
        self.queued_bytes = 0
        self.id = next(_connection_ids)
        self.bytes_sent = 0
        self.messages_sent = 0
        self.dropped = 0
        self._flusher: asyncio.Task[None] | None = None

    @property
    def connected(self) -> bool:
        return self.proto.transport is not None

    def send(self, frame: bytes) -> None:
        """Write ``frame`` now, or queue it (drop-oldest) while the socket is backed up."""
        proto = self.proto
        if proto.transport is None:
            return
        if not self.queue and not proto.paused:
            proto.transport.write(frame)
            self.bytes_sent += len(frame)
            self.messages_sent += 1
            return
        self._enqueue(frame, len(frame))

    def _enqueue(self, frame: Frame, size: int) -> None:
        queue = self.queue
        self.queued_bytes += size
        while queue and (len(queue) >= self.queue_size or (self.max_bytes and self.queued_bytes > self.max_bytes)):
            self.queued_bytes -= queue.popleft()[1]
            self.dropped += 1
            if self.dropped == 1 or self.dropped % 1000 == 0:
                log.warning(
                    "%s: subscriber %s is slow; dropped %d oldest message(s) so far (queue_size=%d)",
                    self.publisher.topic,
                    self.callerid,
                    self.dropped,
                    self.queue_size,
                )
        queue.append((frame, size))
        if self._flusher is None:
            self._flusher = asyncio.get_running_loop().create_task(self._flush())

    def send_parts(self, parts: tuple[bytes | bytearray | memoryview, ...], size: int) -> None:
        """``send(b"".join(parts))`` (``size`` bytes in all) without building the concatenation."""
        proto = self.proto
        if proto.transport is None:
            return
        if not self.queue and not proto.paused:
            proto.write_parts(parts)
            self.bytes_sent += size
            self.messages_sent += 1
            return
        self._enqueue(parts, size)

    async def _flush(self) -> None:
        try:
            while self.queue:
                await self.proto.drain()
                if self.proto.transport is None:
                    break
                parts: list[bytes | bytearray | memoryview] = []
                for frame, _size in self.queue:
                    if isinstance(frame, tuple):
                        parts.extend(frame)
                    else:
                        parts.append(frame)
                self.messages_sent += len(self.queue)
                self.bytes_sent += self.queued_bytes
                self.queue.clear()
                self.queued_bytes = 0
                # One transport call for everything queued (uvloop writes it with one writev, no join).
                self.proto.transport.writelines(parts)
        except ConnectionResetError:
            self.queue.clear()
            self.queued_bytes = 0
        finally:
            self._flusher = None

    def close(self) -> None:
        """Close now; bytes a stalled subscriber never read are discarded, not waited for."""
        self.queue.clear()
        self.queued_bytes = 0
        if self._flusher is not None:
            self._flusher.cancel()
        transport = self.proto.transport
        if transport is not None:
            if transport.get_write_buffer_size():
                transport.abort()
            else:
                transport.close()


class PublisherProtocol(TcprosProtocol):
    """Inbound connection after its header said it subscribes to one of our topics."""

    link: SubscriberLink | None = None

    def connection_closed(self, exc: BaseException | None) -> None:
        if self.link is not None:
            self.link.publisher._drop(self.link)

    def frame_received(self, body: bytes | bytearray) -> None:
        """Subscribers send nothing after their header; ignore stray bytes."""


class Publisher:
    """A topic we publish. Create it with ``await node.advertise(topic, Type)``."""

    def __init__(
        self,
        node: EndpointOwner,
        topic: str,
        msg_class: Any,
        *,
        latch: bool = False,
        queue_size: int = DEFAULT_QUEUE_SIZE,
        max_message_size: int | None = None,
        max_queued_bytes: int = 0,
    ) -> None:
        for attr in ("_type", "_md5sum", "_full_text"):
            if not hasattr(msg_class, attr):
                raise LocalProtocolError(f"{msg_class!r} is not a message class (no {attr}); use mrosd.msg")
        self.node = node
        self.topic = topic
        self.msg_class = msg_class
        self.type: str = msg_class._type
        self.md5sum: str = msg_class._md5sum
        self.message_definition: str = msg_class._full_text
        self._latch = latch
        self.queue_size = queue_size
        #: per subscriber, bytes its queue may hold besides ``queue_size`` frames (0: no bound but the count)
        self.max_queued_bytes = max_queued_bytes
        #: declared largest serialized message: the shared-memory pool is made for it up front
        self.max_message_size = max_message_size
        self.links: list[SubscriberLink] = []
        self.latched: bytes | None = None
        self.messages_published = 0
        #: header.seq of the next message (roscpp's rule: 0 first, one per publish call, subscribers or not).
        self.seq = 0
        self._has_header: bool = bool(getattr(msg_class, "_has_header", False))
        self.closed = False
        self._subscriber_change = asyncio.Event()
        self._poke = loop_spinner().poke
        #: the shared-memory side, made at the first requestTopic that offers it (mrosd.shm.topic)
        self.shm: ShmTopicPublisher | None = None

    @property
    def latch(self) -> bool:
        """Whether a new subscriber gets the last message first; may be set at any time."""
        return self._latch

    @latch.setter
    def latch(self, latch: bool) -> None:
        # Every transport takes the change: TCPROS reads it at each connection, the shared-memory side (made at
        # the first same-host subscriber) is told. Unlatched, the message kept so far is no one's first message.
        self._latch = latch
        if not latch:
            self.latched = None
        if self.shm is not None:
            self.shm.set_latch(latch)

    # --- publishing ------------------------------------------------------------------------------

    async def publish(self, msg: Any) -> None:
        """Serialize once and send to every subscriber; never waits for a slow one.

        Raises:
            LocalProtocolError: the publisher was closed, or ``msg`` is not of the advertised type.
            SerializationError: a field value cannot be serialized.
        """
        self.publish_nowait(msg)

    def publish_nowait(self, msg: Any) -> None:
        """``publish`` for synchronous code on the loop's thread (e.g. a subscriber callback).

        A message whose first field is ``Header header`` gets this publisher's counter in ``header.seq``
        (the object is updated, as rospy does): 0 for the first publish call, then one more per call.

        Raises:
            LocalProtocolError: the publisher was closed, or ``msg`` is not of the advertised type.
            SerializationError: a field value cannot be serialized.
        """
        if type(msg) is not self.msg_class and getattr(msg, "_md5sum", None) != self.md5sum:
            raise LocalProtocolError(f"{self.topic} publishes {self.type}, got {type(msg).__name__}")
        loan = getattr(msg, "_shm_loan", None)
        if loan is not None and (loan.published or self.closed):
            raise LocalProtocolError(
                f"publisher of {self.topic} is closed" if self.closed else "this loan was published already"
            )
        if self._has_header:
            # As rospy and roscpp do for a message whose first field is ``Header header``.
            msg.header.seq = self.seq
            self.seq = (self.seq + 1) & 0xFFFFFFFF
        if loan is not None:
            from mrosd.shm.loan import publish_loan

            publish_loan(self, msg)  # filled in place: published without serializing or copying the array
            self._poke()  # after: the subscribers' wake-up is the first thing that matters
            return
        serialize_parts = getattr(msg, "serialize_parts", None)
        if serialize_parts is None:
            self.publish_serialized(msg.serialize())
            return
        # A type that may carry a large uint8[]: its pieces go to the socket as they are (a payload received
        # into a FrameBuffer, or given as bytes, is never copied), the rest is packed as usual.
        parts = serialize_parts()
        size = sum(map(len, parts))
        if size <= LARGE_FRAME or self._latch:
            self.publish_serialized(b"".join(parts))
            return
        if self.closed:
            raise LocalProtocolError(f"publisher of {self.topic} is closed")
        self.messages_published += 1
        self._poke()
        if self.shm is not None:
            self.shm.publish_parts(parts, size)
        # A piece the caller could still change (a bytearray, a writable view) is copied once, as the join
        # in serialize() would: the transport may hold the pieces after this call returns.
        frame = (frame_prefix(size), *(p if is_immutable(p) else bytes(p) for p in parts))
        for link in self.links:
            link.send_parts(frame, size + 4)

    def loan(self, template: Any = None, **sizes: int) -> Any:
        """A message to fill in place: its ``uint8[]`` field (``loan(data=N)``, or the largest one of
        ``template``, whose other fields are copied) is a writable view into a slot of this topic's
        shared-memory pool (declared with ``max_message_size``), and ``publish(msg)`` sends it without
        serializing or copying that array, to shared-memory and TCPROS subscribers alike. Without a pool it
        is a plain buffer, published as any message. A loan is published once (docs/shm.md).

        Raises:
            LocalProtocolError: not one ``uint8[]`` field, or the publisher is closed.
        """
        if self.closed:
            raise LocalProtocolError(f"publisher of {self.topic} is closed")
        from mrosd.shm.loan import make_loan

        return make_loan(self, template, sizes)

    def publish_serialized(self, body: bytes | bytearray | memoryview) -> None:
        """Send an already serialized message body (no length prefix), e.g. from a bridge.

        Raises:
            LocalProtocolError: the publisher was closed.
        """
        if self.closed:
            raise LocalProtocolError(f"publisher of {self.topic} is closed")
        self.messages_published += 1
        self._poke()
        if self.shm is not None:
            self.shm.publish(body)
        prefix = frame_prefix(len(body))
        if len(body) > LARGE_FRAME and not self._latch:
            # Large bodies are not concatenated with their prefix: both go to the socket in one vectored write.
            for link in self.links:
                link.send_parts((prefix, body), len(body) + 4)
            return
        frame = prefix + body
        if self._latch:
            self.latched = frame
        for link in self.links:
            link.send(frame)

    # --- connections -----------------------------------------------------------------------------

    def accept(self, proto: PublisherProtocol, header: ConnectionHeader) -> None:
        """Handshake with a new subscriber connection (called by the node's TCPROS server)."""
        try:
            reply = publisher_reply(
                header,
                topic=self.topic,
                msg_type=self.type,
                md5sum=self.md5sum,
                message_definition=self.message_definition,
                callerid=self.node.name,
                latching=self.latch,
            )
        except HandshakeError as exc:
            _ratelog.warning(
                self.topic + ":refused", "%s: refusing subscriber %s: %s", self.topic, header.callerid, exc
            )
            proto.write(encode_header(error_header(str(exc))))
            proto.close()
            return
        proto.set_nodelay(header.flag("tcp_nodelay"))
        link = SubscriberLink(self, proto, header.callerid or "?", self.queue_size, self.max_queued_bytes)
        proto.link = link
        data = encode_header(reply)
        if self.latched is not None:
            data += self.latched
            link.messages_sent += 1
        proto.write(data)
        link.bytes_sent += len(data)
        self.links.append(link)
        self._subscriber_change.set()

    def _drop(self, link: SubscriberLink) -> None:
        if link in self.links:
            self.links.remove(link)
            self._subscriber_change.set()

    def get_num_connections(self) -> int:
        """How many subscribers are connected now."""
        return len(self.links) + (self.shm.count() if self.shm is not None else 0)

    async def shm_answer(self, protocols: list[Any]) -> list[Any] | None:
        """requestTopic: the shared-memory answer for a same-host mrosd subscriber, else None (TCPROS)."""
        if not any(isinstance(p, list) and p[:1] == ["MROSSHM"] for p in protocols):
            return None
        return await self._shm_side().answer(protocols)

    async def shm_prepare(self) -> None:
        """Make the shared-memory pool now (a publisher that declared ``max_message_size``), not at the first
        same-host subscriber: its pages are faulted in once, off the data path."""
        await self._shm_side().prepare()
        from mrosd.shm.loan import loaned_class

        loaned_class(self.msg_class)  # not on the first loan's path

    def _shm_side(self) -> ShmTopicPublisher:
        if self.shm is None:
            from mrosd.shm.topic import ShmTopicPublisher  # lazy: loaded only when a mrosd peer offers it

            self.shm = ShmTopicPublisher(self, on_change=self._subscriber_change.set)
        return self.shm

    async def wait_for_subscribers(self, count: int = 1, timeout: float = 10.0) -> None:
        """Wait until at least ``count`` subscribers are connected.

        Raises:
            TimeoutError: they did not connect within ``timeout`` seconds.
        """
        async with backports.timeout(timeout):
            while self.get_num_connections() < count:
                self._subscriber_change.clear()
                await self._subscriber_change.wait()

    def stats(self) -> list[Any]:
        """getBusStats publishStats entry: [topic, bytes, [[id, bytes, msgs, connected, dropped], ...]]."""
        conns = [[lk.id, lk.bytes_sent, lk.messages_sent, lk.connected, lk.dropped] for lk in self.links]
        if self.shm is not None:
            conns += self.shm.stats_rows()
        return [self.topic, sum(c[1] for c in conns), conns]

    def bus_info(self) -> list[list[Any]]:
        rows = [[lk.id, lk.callerid, "o", "TCPROS", self.topic, lk.connected, lk.proto.peer] for lk in self.links]
        return rows + (self.shm.bus_info_rows() if self.shm is not None else [])

    # --- lifecycle -------------------------------------------------------------------------------

    async def aclose(self) -> None:
        """Unregister from the master and close every subscriber connection."""
        if self.closed:
            return
        self.closed = True
        for link in list(self.links):
            link.close()
        self.links.clear()
        if self.shm is not None:
            await self.shm.aclose()
        await self.node.endpoint_closed(self)

    async def __aenter__(self) -> Publisher:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()
