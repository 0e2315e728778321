"""``SharedSubscriptions``: one raw TCPROS subscription per topic, shared by every client sink that wants it.

Each message body is handed as received (``AnyMsg``: no decode, no copy) with its receipt time to every
``TopicSink`` holding the topic; the last sink to leave closes the subscription. No per-client buffering
here: each sink owns its byte-bounded queue (``mrosd.web.queue``), so a slow client costs only what its own
queues hold; beyond ``max_queued_bytes`` for all clients together the fullest client sheds its oldest messages.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Protocol

from mrosd.tcpros import Node
from mrosd.tcpros.subscriber import AnyMsg, RawMessage, Subscriber
from mrosd.web.queue import Ledger

log = logging.getLogger(__name__)

__all__ = [
    "MAX_LATCHED_BYTES",
    "MAX_QUEUED_BYTES",
    "PAUSE_BYTES",
    "HoldingSink",
    "LatchedStore",
    "SharedSubscriptions",
    "TopicSink",
]

#: Bytes queued for all clients together (each client also has its own budget, SessionLimits.client_bytes).
MAX_QUEUED_BYTES = 256 * 1024 * 1024
#: When every client of a topic holds at least this many bytes of it not yet sent, the hub stops reading the
#: topic's TCPROS connections until one catches up: the bridge then receives what its fastest client takes,
#: not everything the publisher sends (the publisher's per-subscriber queue drops the rest, as for any slow
#: subscriber). Clients that fall further behind still drop from their own queues.
PAUSE_BYTES = 4 * 1024 * 1024


class TopicSink(Protocol):
    """A client's end of a shared subscription; ``deliver`` must not block (queue and return)."""

    def deliver(self, topic: str, body: bytes | bytearray, receipt_ns: int) -> None: ...

    def backlog(self, topic: str) -> int:
        """Bytes of ``topic`` this sink holds, not yet sent."""
        ...

    def queued(self) -> int:
        """Bytes this sink holds over all its topics."""
        ...

    def shed_oldest(self) -> None:
        """Drop the oldest message of this sink's fullest queue (counted as a drop)."""
        ...


class HoldingSink:
    """A sink that queues nothing: it holds a topic's shared subscription open (the hub still counts its
    messages and bytes, ``topic_stats``) and never makes the hub pause the topic. Subclasses act in ``deliver``.
    """

    def deliver(self, topic: str, body: bytes | bytearray, receipt_ns: int) -> None:
        pass

    def backlog(self, topic: str) -> int:
        return 0

    def queued(self) -> int:
        return 0

    def shed_oldest(self) -> None:
        pass


#: caller id -> latched message body (named here: ``Shared``'s own ``bytes`` field shadows the type inside it)
LatchedBodies = dict[str, bytes | bytearray]


@dataclass(slots=True)
class Shared:
    """One raw subscription and the sinks that share it."""

    subscriber: Subscriber
    sinks: list[TopicSink] = field(default_factory=list)
    messages: int = 0
    bytes: int = 0
    #: reading from the publishers is paused: every sink is behind (see ``resume``)
    paused: bool = False
    #: the last message of each latching publisher (by caller id): a publisher sends it once, as the shared
    #: connection opens, so a sink that joins later gets it from here (rosbridge opens a new subscriber for it)
    latched: LatchedBodies = field(default_factory=dict)


#: latching publishers remembered per topic (a dict keeps insertion order: the oldest goes first)
MAX_LATCHED_PUBLISHERS = 64
#: Bytes of latched messages remembered over all topics. Each is the body as received (held, not copied,
#: unless it is a view of a shared-memory ring), so what a topic costs here is what its publishers latched;
#: without this bound, publishers latching big messages on a topic a client watched made the daemon hold all
#: of them (6 publishers of 40 MB and 4 clients: +720 MiB). Past it, the oldest remembered message of any
#: topic goes first; a client that joins later misses that one (the newest of every topic is kept first).
MAX_LATCHED_BYTES = 64 * 1024 * 1024


class LatchedStore:
    """The latched bodies of every shared subscription, oldest first, bounded by ``MAX_LATCHED_BYTES``."""

    def __init__(self, max_bytes: int = MAX_LATCHED_BYTES) -> None:
        self.max_bytes = max_bytes
        self.size = 0
        #: (entry id, caller id) -> (entry, body size), oldest first
        self._order: dict[tuple[int, str], tuple[Shared, int]] = {}

    def keep(self, entry: Shared, callerid: str, body: bytes | bytearray | memoryview) -> None:
        if not isinstance(body, bytes | bytearray):
            body = bytes(body)  # a view into a ring is ours only during the callback
        self._forget(entry, callerid)
        entry.latched[callerid] = body
        self._order[(id(entry), callerid)] = (entry, len(body))
        self.size += len(body)
        while len(entry.latched) > MAX_LATCHED_PUBLISHERS:
            self._forget(entry, next(iter(entry.latched)))
        while self.size > self.max_bytes and len(self._order) > 1:
            (_, oldest_caller), (oldest_entry, _) = next(iter(self._order.items()))
            self._forget(oldest_entry, oldest_caller)

    def drop(self, entry: Shared) -> None:
        """The subscription closed: forget what it latched."""
        for callerid in list(entry.latched):
            self._forget(entry, callerid)

    def _forget(self, entry: Shared, callerid: str) -> None:
        entry.latched.pop(callerid, None)
        gone = self._order.pop((id(entry), callerid), None)
        if gone is not None:
            self.size -= gone[1]


class SharedSubscriptions:
    """The shared raw subscriptions of one node; ``before_subscribe(topic)`` runs before a topic's first
    subscription (the hub waits there for a probe that holds the node's subscription to it)."""

    def __init__(
        self,
        node: Node,
        *,
        max_queued_bytes: int = MAX_QUEUED_BYTES,
        before_subscribe: Callable[[str], Awaitable[None]] | None = None,
    ) -> None:
        self.node = node
        #: every client queue of every protocol counts its bytes here (per-client budgets alone let N clients
        #: hold N budgets)
        self.ledger = Ledger()
        self.max_queued_bytes = max_queued_bytes
        self.entries: dict[str, Shared] = {}
        self.latched = LatchedStore()
        self._before = before_subscribe
        self._lock = asyncio.Lock()

    async def subscribe(self, topic: str) -> Subscriber:
        """A raw subscription to ``topic`` whose messages go to the topic's sinks (once it has an entry)."""
        return await self.node.subscribe(topic, AnyMsg, callback=self._raw_callback(topic))

    def _raw_callback(self, topic: str) -> Callable[[RawMessage], None]:
        def deliver(msg: RawMessage) -> None:
            entry = self.entries.get(topic)
            if entry is None:
                return
            now = time.time_ns()
            body = msg.data
            entry.messages += 1
            entry.bytes += len(body)
            header = getattr(msg, "header", None)  # a made topic's bodies (``compressed``) come without one
            if header is not None and header.latching == "1":
                self.latched.keep(entry, header.callerid or "", body)
            behind = True
            for sink in entry.sinks:
                try:
                    sink.deliver(topic, body, now)
                    behind = behind and sink.backlog(topic) >= PAUSE_BYTES
                except Exception:
                    log.exception("web: a sink of %s failed", topic)
            if behind and entry.sinks:
                self._set_reading(entry, False)
            if self.ledger.size > self.max_queued_bytes:
                self._shed()

        return deliver

    def _shed(self) -> None:
        """Bring the server-wide queued bytes under the bound, oldest messages of the fullest client first."""
        sinks = {id(s): s for e in self.entries.values() for s in e.sinks}.values()
        while self.ledger.size > self.max_queued_bytes:
            fullest = max(sinks, key=lambda s: s.queued(), default=None)
            if fullest is None or fullest.queued() == 0:
                return
            fullest.shed_oldest()

    @staticmethod
    def _set_reading(entry: Shared, reading: bool) -> None:
        """Pause or resume reading the topic's TCPROS connections (TCP's own backpressure)."""
        entry.paused = not reading
        for link in entry.subscriber.links.values():
            proto = link.proto
            transport = proto.transport if proto is not None else None
            if transport is not None and not transport.is_closing():
                if reading:
                    transport.resume_reading()
                else:
                    transport.pause_reading()

    def pause(self, topic: str) -> None:
        """Stop reading ``topic``'s publishers until ``resume`` (its one sink takes nothing now)."""
        entry = self.entries.get(topic)
        if entry is not None and not entry.paused:
            self._set_reading(entry, False)

    def resume(self, topic: str) -> None:
        """A sink of ``topic`` caught up: read from the publishers again (no-op unless paused)."""
        entry = self.entries.get(topic)
        if entry is not None and entry.paused:
            self._set_reading(entry, True)

    async def add(self, topic: str, sink: TopicSink) -> None:
        """Give ``sink`` every message of ``topic`` (subscribing on the first sink).

        Raises:
            MrosError: the master refused the subscription.
        """
        async with self._lock:
            entry = self.entries.get(topic)
            if entry is None:
                if self._before is not None:
                    await self._before(topic)
                entry = Shared(await self.subscribe(topic))
                self.entries[topic] = entry
            elif sink not in entry.sinks and entry.latched:
                connected = {link.header.callerid for link in entry.subscriber.links.values() if link.header}
                now = time.time_ns()
                for callerid, body in entry.latched.items():
                    if callerid in connected:
                        sink.deliver(topic, body, now)
            if sink not in entry.sinks:
                entry.sinks.append(sink)
            if entry.paused:
                self._set_reading(entry, True)  # a newcomer is not behind: nothing else would wake the topic

    async def remove(self, topic: str, sink: TopicSink) -> None:
        """Stop giving ``sink`` the topic; the last sink closes the subscription."""
        async with self._lock:
            entry = self.entries.get(topic)
            if entry is None:
                return
            with contextlib.suppress(ValueError):
                entry.sinks.remove(sink)
            if entry.paused:
                self._set_reading(entry, True)  # the sink that left may have been the one holding it
            if not entry.sinks:
                del self.entries[topic]
                self.latched.drop(entry)
                await entry.subscriber.aclose()

    def stats(self, topic: str) -> tuple[int, int] | None:
        """``(messages, bytes)`` received on a shared subscription since it opened (None: not subscribed)."""
        entry = self.entries.get(topic)
        return None if entry is None else (entry.messages, entry.bytes)

    def sink_count(self, topic: str) -> int:
        entry = self.entries.get(topic)
        return 0 if entry is None else len(entry.sinks)

    def close(self) -> None:
        """Forget every subscription (the node's close ends them)."""
        entries, self.entries = self.entries, {}
        for entry in entries.values():
            entry.sinks.clear()
            self.latched.drop(entry)
