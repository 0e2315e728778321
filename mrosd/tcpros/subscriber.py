"""Subscriber: follows the master's publisher list, one connection task per publisher, typed or raw.

Each publisher URI gets one ``PublisherLink`` task that asks the publisher's slave API for a TCPROS
endpoint (requestTopic), connects, handshakes and then receives frames through ``SubscriberProtocol``.
A lost connection is retried with capped exponential backoff (0.1 s doubling to 10 s). The backoff starts
over only after a healthy connection (one that lasted ``HEALTHY_AFTER`` seconds, or delivered a frame and
ended without a protocol error), so a publisher that handshakes and then sends garbage is re-dialled at
the growing interval, not every 0.1 s; failures are logged rate-limited per publisher. A publisher that
refuses us (md5/type mismatch) is reported with its own error text in the log and in ``Subscriber.errors``.
A publisher missing from the master's list (``publisherUpdate``, or the reply to registering again after a
master restart) is dropped only if we are not connected to it: a live connection is kept until it ends, as
rospy keeps it, so a restarted master never cuts data that is flowing. Messages go to a callback, or into
a bounded drop-oldest queue read with ``async for``. With ``AnyMsg`` the subscriber yields ``RawMessage(data, header)``.
"""

from __future__ import annotations

import asyncio
import collections
import inspect
import itertools
import logging
from typing import TYPE_CHECKING, Any, ClassVar

import msgspec

from mrosd import backports
from mrosd.errors import HandshakeError, LocalProtocolError, MrosError, XmlRpcError
from mrosd.lograte import RateLimitedLog
from mrosd.shm.views import decode_view as _decode_view
from mrosd.tcpros.protocol import TcprosProtocol
from mrosd.tcpros.sockopts import enable_keepalive
from mrosd.wire.handshake import check_publisher_reply
from mrosd.wire.header import ConnectionHeader, encode_header

if TYPE_CHECKING:
    from collections.abc import Callable

    from mrosd.shm.subscriber import ShmSubscriberConnection
    from mrosd.tcpros.owner import EndpointOwner

log = logging.getLogger(__name__)
#: Failures a publisher can cause at will (garbage after the handshake, refused dials) are logged rate-limited.
_ratelog = RateLimitedLog(log, period=60.0, burst=3)
_connection_ids = itertools.count(1)

#: Reconnection backoff bounds (seconds), as DESIGN.md fixes them.
BACKOFF_MIN = 0.1
BACKOFF_MAX = 10.0
#: Time allowed for requestTopic, TCP connect and the publisher's header.
CONNECT_TIMEOUT = 10.0
#: A connection that stayed up this long (seconds) counts as healthy and starts the backoff over.
HEALTHY_AFTER = 5.0
DEFAULT_QUEUE_SIZE = 100


class AnyMsg:
    """Subscribe with this type to receive every message as ``RawMessage`` (md5/type wildcard ``*``)."""

    _type: ClassVar[str] = "*"
    _md5sum: ClassVar[str] = "*"
    _full_text: ClassVar[str] = ""


class RawMessage(msgspec.Struct, gc=False):
    """A message body as received (no length prefix) and the publisher's connection header.

    Decode it with ``mrosd.msg.load_type(header.type, header.message_definition).deserialize(data)`` (on an event
    loop, the class from ``await mrosd.msg.load_type_async(...)``: a peer's definition is compiled off the loop).
    """

    data: bytes | bytearray
    header: ConnectionHeader


class SubscriberProtocol(TcprosProtocol):
    """Our end of one publisher connection."""

    def __init__(self, link: PublisherLink) -> None:
        super().__init__()
        self.link = link
        self.handshake: asyncio.Future[ConnectionHeader] = asyncio.get_running_loop().create_future()
        #: Why we closed the connection on a protocol error ('' when the peer closed it or all was well).
        self.error = ""

    def abort(self, reason: str) -> None:
        # A publisher controls how often this happens: rate-limited, and remembered for the backoff.
        self.error = reason
        _ratelog.warning(
            f"abort {self.link.uri}",
            "%s: closing the connection to publisher %s: %s",
            self.link.subscriber.topic,
            self.link.uri,
            reason,
        )
        if self.transport is not None:
            self.transport.abort()

    def header_received(self, header: ConnectionHeader) -> None:
        # Checked here, synchronously: a latched frame may follow in the same read.
        sub = self.link.subscriber
        try:
            self.link.header = check_publisher_reply(
                header, topic=sub.topic, msg_type=sub.type, md5sum=sub.md5sum, peer=self.link.uri
            )
        except HandshakeError as exc:
            if not self.handshake.done():
                self.handshake.set_exception(exc)
            self.close()
            return
        if not self.handshake.done():
            self.handshake.set_result(header)

    def frame_received(self, body: bytes | bytearray) -> None:
        self.link.bytes_received += len(body) + 4
        self.link.messages_received += 1
        self.link.subscriber._deliver(body, self.link)

    def connection_closed(self, exc: BaseException | None) -> None:
        if not self.handshake.done():
            self.handshake.set_exception(ConnectionResetError("publisher closed the connection during the handshake"))


class PublisherLink:
    """Our connection to one publisher (by slave URI), kept up by one task."""

    def __init__(self, subscriber: Subscriber, uri: str) -> None:
        self.subscriber = subscriber
        self.uri = uri
        #: False once the master's list no longer has this publisher: the link ends with its connection.
        self.listed = True
        #: TCP dials made (tests and getBusStats-style introspection).
        self.dials = 0
        self.id = next(_connection_ids)
        self.header: ConnectionHeader | None = None
        self.proto: SubscriberProtocol | None = None
        self.bytes_received = 0
        self.messages_received = 0
        #: the shared-memory connection when the publisher is a mrosd node on this host (else None)
        self.shm: ShmSubscriberConnection | None = None
        #: shared memory failed once with this publisher: TCPROS only from now on
        self.shm_failed = False
        self.task = asyncio.get_running_loop().create_task(self._run(), name=f"sub {subscriber.topic} <- {uri}")

    @property
    def shm_dropped(self) -> int:
        return self.shm.dropped if self.shm is not None else 0

    @property
    def transport_name(self) -> str:
        return "SHMROS" if self.shm is not None else "TCPROS"

    def _shm_frame(self, body: Any) -> None:
        """A message from shared memory: bytes, or a leased ``ShmView`` (``zero_copy`` subscribers)."""
        self.messages_received += 1
        if isinstance(body, (bytes, bytearray)):
            self.bytes_received += len(body) + 4
            self.subscriber._deliver(body, self)
        else:
            self.bytes_received += len(body.data) + 4
            self.subscriber._deliver_view(body, self)

    @property
    def connected(self) -> bool:
        if self.shm is not None:
            return self.shm.connected and self.header is not None
        return self.proto is not None and self.proto.transport is not None and self.header is not None

    async def _run(self) -> None:
        sub = self.subscriber
        loop = asyncio.get_running_loop()
        delay = BACKOFF_MIN
        last_reason = ""
        while not sub.closed and self.listed:
            try:
                await self._connect_once()
                last_reason = ""
                since, received = loop.time(), self.messages_received
                if self.shm is not None:
                    await self.shm.wait_closed()
                    error = self.shm.error
                else:
                    proto = self.proto
                    assert proto is not None
                    await proto.closed
                    error = proto.error
                healthy = loop.time() - since >= HEALTHY_AFTER or (not error and self.messages_received > received)
                if healthy:
                    delay = BACKOFF_MIN
                    log.info("%s: publisher %s closed the connection", sub.topic, self.uri)
            except HandshakeError as exc:
                sub.errors.append(str(exc))
                if str(exc) != last_reason:
                    log.error("%s: %s", sub.topic, exc)
                last_reason = str(exc)
                delay = BACKOFF_MAX
            except (OSError, TimeoutError, XmlRpcError, MrosError) as exc:
                reason = f"{type(exc).__name__}: {exc}"
                if reason != last_reason:
                    _ratelog.warning(
                        f"connect {self.uri}",
                        "%s: cannot connect to publisher %s (%s); retrying with backoff",
                        sub.topic,
                        self.uri,
                        reason,
                    )
                else:
                    log.debug("%s: retry to %s failed again: %s", sub.topic, self.uri, reason)
                last_reason = reason
            finally:
                if self.shm is not None:
                    await self.shm.aclose()
                    self.shm = None
                if self.proto is not None:
                    self.proto.close()
                self.proto = None
                self.header = None
                sub._changed.set()
            if sub.closed or not self.listed:
                break
            await asyncio.sleep(delay)
            delay = min(delay * 2, BACKOFF_MAX)
        if not self.listed and sub.links.get(self.uri) is self:
            # The master stopped listing this publisher while we were connected: now that the connection
            # has ended, forget it (a later publisherUpdate that lists it again starts a new link).
            del sub.links[self.uri]
            sub._changed.set()

    async def _connect_once(self) -> None:
        sub = self.subscriber
        node = sub.node
        from mrosd.shm import topic as shm_topic  # lazy: only subscribers load the shared-memory transport

        async with backports.timeout(CONNECT_TIMEOUT):
            protocols = shm_topic.request_protocols(allow_shm=not self.shm_failed)
            reply = await node.xmlrpc.call(self.uri, "requestTopic", node.name, sub.topic, protocols)
            if not isinstance(reply, list) or len(reply) != 3 or reply[0] != 1:
                raise MrosError(f"requestTopic refused by {self.uri}: {reply!r}")
            params = reply[2]
            if isinstance(params, list) and params[:1] == ["MROSSHM"]:
                try:
                    attached = await shm_topic.attach_subscriber(
                        sub, self.uri, params, self._shm_frame, timeout=CONNECT_TIMEOUT, max_leased=sub.max_leased
                    )
                except HandshakeError:
                    raise
                except (MrosError, OSError, TimeoutError) as exc:
                    self.shm_failed = True
                    log.warning("%s: shared memory with %s failed (%s); using TCPROS", sub.topic, self.uri, exc)
                    reply = await node.xmlrpc.call(self.uri, "requestTopic", node.name, sub.topic, [["TCPROS"]])
                    if not isinstance(reply, list) or len(reply) != 3 or reply[0] != 1:
                        raise MrosError(f"requestTopic refused by {self.uri}: {reply!r}") from None
                    params = reply[2]
                else:
                    if attached is not None:
                        self.shm, self.header = attached
                        self.dials += 1
                        sub._changed.set()
                        return
            if not isinstance(params, list) or len(params) < 3 or params[0] != "TCPROS":
                raise MrosError(f"{self.uri} offers no TCPROS endpoint: {params!r}")
            host, port = str(params[1]), int(params[2])
            loop = asyncio.get_running_loop()
            self.dials += 1
            transport, proto = await loop.create_connection(lambda: SubscriberProtocol(self), host, port)
            self.proto = proto
            sock = transport.get_extra_info("socket")
            if sock is not None:
                enable_keepalive(sock)
            proto.set_nodelay(True)
            proto.write(
                encode_header(
                    ConnectionHeader(
                        callerid=node.name,
                        topic=sub.topic,
                        md5sum=sub.md5sum,
                        type=sub.type,
                        message_definition=sub.message_definition,
                        tcp_nodelay="1" if sub.tcp_nodelay else "0",
                    )
                )
            )
            await proto.handshake
        sub._changed.set()

    async def aclose(self) -> None:
        self.task.cancel()
        if self.shm is not None:
            await self.shm.aclose()
        if self.proto is not None:
            self.proto.close()
        try:
            await self.task
        except asyncio.CancelledError:
            pass


def _fields(msg: Any) -> dict[str, Any]:
    return {name: getattr(msg, name) for name in msg.__struct_fields__}


class Subscriber:
    """A topic subscription. Create it with ``await node.subscribe(topic, Type)``; iterate it or give a callback."""

    def __init__(
        self,
        node: EndpointOwner,
        topic: str,
        msg_class: Any,
        *,
        callback: Callable[[Any], Any] | None = None,
        queue_size: int = DEFAULT_QUEUE_SIZE,
        tcp_nodelay: bool = True,
        zero_copy: bool = False,
        max_leased: int = 2,
    ) -> None:
        for attr in ("_type", "_md5sum", "_full_text"):
            if not hasattr(msg_class, attr):
                raise LocalProtocolError(f"{msg_class!r} is not a message class (no {attr}); use mrosd.msg or AnyMsg")
        #: same-host messages as typed views into the publisher's pool, each leased until released or
        #: dropped, at most ``max_leased`` at once (docs/shm.md); 0 when not zero-copy
        self.max_leased = max(1, max_leased) if zero_copy and msg_class is not AnyMsg else 0
        if self.max_leased:
            from mrosd.shm.views import prepare

            prepare(msg_class)  # not on the first message's path
        self.node = node
        self.topic = topic
        self.msg_class = msg_class
        self.raw = msg_class is AnyMsg
        self.type: str = msg_class._type
        self.md5sum: str = msg_class._md5sum
        self.message_definition: str = msg_class._full_text
        self.callback = callback
        self.queue_size = max(1, queue_size)
        self.tcp_nodelay = tcp_nodelay
        self.links: dict[str, PublisherLink] = {}
        self.errors: collections.deque[str] = collections.deque(maxlen=20)
        self.dropped = 0
        self.closed = False
        self._queue: collections.deque[Any] = collections.deque()
        self._waiter: asyncio.Future[None] | None = None
        self._changed = asyncio.Event()
        self._async_callback = callback is not None and inspect.iscoroutinefunction(callback)
        self._consumer: asyncio.Task[None] | None = None
        if self._async_callback:
            self._consumer = asyncio.get_running_loop().create_task(self._consume())

    # --- publishers ------------------------------------------------------------------------------

    def update_publishers(self, uris: list[str]) -> None:
        """Follow the master's current publisher list (registerSubscriber reply or publisherUpdate).

        A publisher that is not listed any more is dropped at once unless we are connected to it; a live
        connection is kept until it ends (rospy keeps it too: a restarted master, which knows none of the
        rospy publishers, must not cut data that is flowing).
        """
        if self.closed:
            return
        wanted = {u for u in uris if isinstance(u, str) and u}
        for uri, link in list(self.links.items()):
            if uri in wanted:
                link.listed = True
            elif link.connected:
                link.listed = False
            else:
                del self.links[uri]
                asyncio.get_running_loop().create_task(link.aclose())
        for uri in wanted:
            if uri not in self.links:
                self.links[uri] = PublisherLink(self, uri)
        self._changed.set()

    def get_num_connections(self) -> int:
        """Publishers we are connected to now."""
        return sum(1 for lk in self.links.values() if lk.connected)

    async def wait_for_publishers(self, count: int = 1, timeout: float = 10.0) -> None:
        """Wait until connected to at least ``count`` publishers.

        Raises:
            TimeoutError: not connected within ``timeout`` seconds.
        """
        async with backports.timeout(timeout):
            while self.get_num_connections() < count:
                self._changed.clear()
                await self._changed.wait()

    # --- delivery --------------------------------------------------------------------------------

    def _deliver_view(self, view: Any, link: PublisherLink) -> None:
        """A leased message in shared memory: decoded with its large arrays as views of the slot (the
        message holds the lease: ``mrosd.shm.views``); one without such arrays refers to nothing in the slot,
        and its lease ends at once."""
        try:
            msg, views = _decode_view(self.msg_class, view.data, view)
        except MrosError as exc:
            view.release()
            self._undecodable(link, exc)
            return
        if views:
            view.views.extend(views)
        else:
            view.release()
        self._hand_over(msg)

    def _undecodable(self, link: PublisherLink, exc: MrosError) -> None:
        """A publisher's message that does not decode: dropped, a few lines per topic and minute."""
        _ratelog.warning(
            self.topic + ":undecodable",
            "%s: dropping a message from %s that does not decode: %s",
            self.topic,
            link.uri,
            exc,
        )

    def _deliver(self, body: bytes | bytearray, link: PublisherLink) -> None:
        if self.raw:
            assert link.header is not None
            msg: Any = RawMessage(body, link.header)
        else:
            try:
                # A large frame arrives as its own FrameBuffer, which the message then owns: its large uint8[]
                # fields are read-only views into it, not copies (mrosd.msg.runtime.FrameBuffer).
                msg = self.msg_class.deserialize(body)
            except MrosError as exc:
                self._undecodable(link, exc)
                return
            if self.max_leased:  # one API whatever the transport: release() and ``with`` (no lease here)
                from mrosd.shm.views import leased_class

                msg = leased_class(self.msg_class)(**_fields(msg))
        self._hand_over(msg)

    def _hand_over(self, msg: Any) -> None:
        if self.callback is not None and not self._async_callback:
            try:
                self.callback(msg)
            except Exception:
                log.exception("%s: subscriber callback failed", self.topic)
            return
        if len(self._queue) >= self.queue_size:
            self._queue.popleft()
            self.dropped += 1
        self._queue.append(msg)
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    async def _next(self) -> Any:
        while not self._queue:
            if self.closed:
                raise StopAsyncIteration
            self._waiter = asyncio.get_running_loop().create_future()
            await self._waiter
        return self._queue.popleft()

    async def _consume(self) -> None:
        assert self.callback is not None
        while True:
            try:
                msg = await self._next()
            except StopAsyncIteration:
                return
            try:
                await self.callback(msg)
            except Exception:
                log.exception("%s: subscriber callback failed", self.topic)

    def __aiter__(self) -> Subscriber:
        return self

    async def __anext__(self) -> Any:
        """The next message (drop-oldest queue of ``queue_size``); stops when the subscriber closes."""
        return await self._next()

    async def next(self, timeout: float | None = None) -> Any:
        """The next message, waiting at most ``timeout`` seconds.

        Raises:
            TimeoutError: nothing arrived in time.
        """
        async with backports.timeout(timeout):
            return await self._next()

    # --- introspection ---------------------------------------------------------------------------

    def stats(self) -> list[Any]:
        """getBusStats subscribeStats entry: [topic, [[id, bytes, msgs, drops, connected], ...]]."""
        return [
            self.topic,
            [
                [lk.id, lk.bytes_received, lk.messages_received, self.dropped + lk.shm_dropped, lk.connected]
                for lk in self.links.values()
            ],
        ]

    def bus_info(self) -> list[list[Any]]:
        return [
            [lk.id, lk.uri, "i", lk.transport_name, self.topic, lk.connected, lk.proto.peer if lk.proto else ""]
            for lk in self.links.values()
        ]

    # --- lifecycle -------------------------------------------------------------------------------

    async def _close_links(self) -> None:
        links = list(self.links.values())
        self.links.clear()
        await asyncio.gather(*(lk.aclose() for lk in links), return_exceptions=True)

    async def aclose(self) -> None:
        """Unregister from the master and close every publisher connection; iteration stops."""
        if self.closed:
            return
        self.closed = True
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)
        await self._close_links()
        if self._consumer is not None:
            self._consumer.cancel()
        await self.node.endpoint_closed(self)

    async def __aenter__(self) -> Subscriber:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()
