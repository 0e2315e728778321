"""What ``mrosd.tcpros`` calls to use shared memory for a topic: the whole wiring behind a few calls.

A ``Publisher`` keeps one ``ShmTopicPublisher`` (made when it is created; the ring and socket only when a
same-host subscriber first asks) and calls it from requestTopic (``answer``), on every publish
(``publish`` / ``publish_parts``), and for getBusStats/getBusInfo (``stats_rows``/``bus_info_rows``, same
shapes as its TCPROS rows, transport ``SHMROS``). A ``PublisherLink`` offers ``request_protocols()`` in
requestTopic and, when the answer is ``MROSSHM``, calls ``attach_subscriber``; any failure there is logged
once by the caller and the link asks again with TCPROS only. These functions read only public attributes of
the publisher and subscriber (typed by the protocols below), so the TCPROS classes need no other change.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from typing import Any, Protocol

from mrosd.errors import MrosError, RemoteProtocolError
from mrosd.shm.negotiate import (
    PROTOCOL,
    TRANSPORT,
    HostIdentity,
    choose_protocol,
    enabled,
    local_identity,
    parse_answer,
    subscriber_offer,
    trusted_uids,
)
from mrosd.shm.publisher import ShmPublisherEndpoint
from mrosd.shm.subscriber import ShmRefused, ShmSubscriberConnection
from mrosd.wire.handshake import check_publisher_reply, publisher_reply
from mrosd.wire.header import ConnectionHeader

__all__ = ["ShmTopicPublisher", "attach_subscriber", "request_protocols"]

log = logging.getLogger(__name__)

_identity: HostIdentity | None = None
_identity_read = False


def identity() -> HostIdentity | None:
    """This process's host identity, read once; None when shared memory is off (``MROSD_SHM=0``) or unknown."""
    global _identity, _identity_read
    if not enabled():
        return None
    if not _identity_read:
        _identity, _identity_read = local_identity(), True
    return _identity


class _Named(Protocol):
    name: str


class PublisherLike(Protocol):
    topic: str
    type: str
    md5sum: str
    message_definition: str
    latch: bool
    queue_size: int
    #: declared largest message: the ring is made, faulted in, at advertise time (None: on demand)
    max_message_size: int | None
    #: the latched frame, length prefix included
    latched: bytes | None

    @property
    def node(self) -> Any: ...


class SubscriberLike(Protocol):
    topic: str
    type: str
    md5sum: str
    message_definition: str

    @property
    def node(self) -> Any: ...


class ShmTopicPublisher:
    """One publisher's shared-memory side; costs nothing until a same-host subscriber asks for it."""

    def __init__(self, publisher: PublisherLike, on_change: Callable[[], None] = lambda: None) -> None:
        self.publisher = publisher
        self.on_change = on_change
        self.endpoint: ShmPublisherEndpoint | None = None
        self._failed = False

    async def answer(self, protocols: list[Any]) -> list[Any] | None:
        """requestTopic's protocol parameters when the subscriber gets shared memory, else None (go on with
        TCPROS as today). Never raises: a failure to set up is logged once and answered None."""
        if self._failed:
            return None
        choice = choose_protocol(protocols, identity(), trusted_uids())
        if choice is None or choice[0] != PROTOCOL:
            return None
        if self.endpoint is None:
            try:
                self.endpoint = await self._start()
            except (OSError, MrosError) as exc:
                self._failed = True
                log.warning("%s: shared memory unavailable, serving TCPROS only: %s", self.publisher.topic, exc)
                return None
        return self.endpoint.answer()

    async def prepare(self) -> None:
        """Make the endpoint and its pool now (advertise time of a publisher that declared its message
        size), when shared memory is on in this process; a failure is logged once (TCPROS only then)."""
        if self.endpoint is None and not self._failed and identity() is not None:
            try:
                self.endpoint = await self._start()
            except (OSError, MrosError) as exc:
                self._failed = True
                log.warning("%s: shared memory unavailable, serving TCPROS only: %s", self.publisher.topic, exc)

    async def _start(self) -> ShmPublisherEndpoint:
        pub = self.publisher

        def handshake(header: ConnectionHeader) -> ConnectionHeader:
            return publisher_reply(
                header,
                topic=pub.topic,
                msg_type=pub.type,
                md5sum=pub.md5sum,
                message_definition=pub.message_definition,
                callerid=pub.node.name,
                latching=pub.latch,
            )

        ep = ShmPublisherEndpoint(
            pub.topic,
            queue_size=pub.queue_size,
            latch=pub.latch,
            handshake=handshake,
            on_change=self.on_change,
            max_message_size=pub.max_message_size,
        )
        await ep.start()
        if pub.latch and pub.latched is not None:
            ep.publish(memoryview(pub.latched)[4:])
        return ep

    def set_latch(self, latch: bool) -> None:
        """The publisher's ``latch`` changed: the endpoint, if made, latches from now on (or stops)."""
        if self.endpoint is not None:
            self.endpoint.set_latch(latch)

    def publish(self, body: bytes | bytearray | memoryview) -> None:
        """Every message the publisher sends (serialized, no length prefix)."""
        if self.endpoint is not None:
            self.endpoint.publish(body)

    def publish_parts(self, parts: Iterable[bytes | bytearray | memoryview], size: int) -> None:
        if self.endpoint is not None:
            self.endpoint.publish_parts(parts, size)

    def count(self) -> int:
        return len(self.endpoint.links) if self.endpoint is not None else 0

    def stats_rows(self) -> list[list[Any]]:
        """getBusStats connection rows, as the TCPROS ones: [id, bytes, messages, connected, dropped]."""
        if self.endpoint is None:
            return []
        return [[lk.id, lk.bytes_sent, lk.messages_sent, lk.connected, lk.dropped] for lk in self.endpoint.links]

    def bus_info_rows(self) -> list[list[Any]]:
        """getBusInfo rows: [id, callerid, "o", "SHMROS", topic, connected, peer]."""
        return self.endpoint.bus_info() if self.endpoint is not None else []

    async def aclose(self) -> None:
        if self.endpoint is not None:
            await self.endpoint.aclose()
            self.endpoint = None


def request_protocols(allow_shm: bool = True) -> list[list[Any]]:
    """The protocol list of a subscriber's requestTopic: shared memory first when possible, then TCPROS."""
    me = identity() if allow_shm else None
    return [subscriber_offer(me), ["TCPROS"]] if me is not None else [["TCPROS"]]


async def attach_subscriber(
    subscriber: SubscriberLike,
    uri: str,
    params: Any,
    on_frame: Callable[[Any], None],
    timeout: float,
    *,
    max_leased: int = 0,
) -> tuple[ShmSubscriberConnection, ConnectionHeader] | None:
    """Attach to the ring a publisher's requestTopic answer points to; None when it answered TCPROS.

    ``max_leased`` > 0: zero-copy, ``on_frame`` gets leased ``ShmView``s (bytes when the publisher grants
    no lease).

    Returns the connection (``await conn.wait_closed()`` returns when it ends) and the publisher's checked header.

    Raises:
        HandshakeError: the publisher refused us, or its header does not match (as over TCPROS).
        RemoteProtocolError, OSError, TimeoutError: shared memory failed: fall back to TCPROS.
    """
    answer = parse_answer(params)
    if answer is None:
        return None
    node = subscriber.node
    header = ConnectionHeader(
        callerid=node.name,
        topic=subscriber.topic,
        md5sum=subscriber.md5sum,
        type=subscriber.type,
        message_definition=subscriber.message_definition,
        tcp_nodelay="1",
    )
    try:
        conn = await ShmSubscriberConnection.attach(
            answer, header, on_frame=on_frame, timeout=timeout, zero_copy=max_leased > 0, max_leased=max_leased
        )
    except ShmRefused as exc:
        # reported in the words of a TCPROS error header, whichever transport carried it
        check_publisher_reply(
            ConnectionHeader(error=exc.reason),
            topic=subscriber.topic,
            msg_type=subscriber.type,
            md5sum=subscriber.md5sum,
            peer=uri,
        )
        raise
    if conn.reply_header is None:
        await conn.aclose()
        raise RemoteProtocolError("the shared-memory publisher sent no connection header")
    try:
        checked = check_publisher_reply(
            conn.reply_header, topic=subscriber.topic, msg_type=subscriber.type, md5sum=subscriber.md5sum, peer=uri
        )
    except BaseException:
        await conn.aclose()
        raise
    return conn, checked


TRANSPORT_NAME = TRANSPORT
