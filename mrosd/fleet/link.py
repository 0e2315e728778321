"""What the fleet's parts share: the Zenoh session, the local node, the tables of what crosses, the counters.

``FleetLink`` is the state; the parts act on it (``sending``, ``receiving``, ``services``, ``discovery``) and
``bridge.FleetBridge`` owns it, starts them and closes them. The parts import this module, never each other's
(the discovery part is handed the two it feeds), so there is no import circle.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections.abc import Coroutine
from dataclasses import dataclass, field
from typing import Any

from mrosd.fleet.handoff import Inbox, Outbox
from mrosd.fleet.keys import Item, ItemKind, discovery_key
from mrosd.fleet.limits import MAX_BODY_BYTES, RateLimit, RateMeter
from mrosd.fleet.options import FleetOptions
from mrosd.fleet.presence import Presence
from mrosd.lograte import RateLimitedLog
from mrosd.tcpros.node import Node

log = logging.getLogger("mrosd.fleet")
#: Every line a peer can trigger goes through here: at most three per kind a minute, the rest counted.
ratelog = RateLimitedLog(log, period=60.0, burst=3)

#: Seconds a query across the fleet may take (a service call, a latched body).
QUERY_TIMEOUT = 10.0


@dataclass
class SentTopic:
    """A local topic offered to the fleet."""

    topic: str
    limit: RateLimit | None
    subscriber: Any = None
    msg_type: str = ""
    md5sum: str = ""
    key: str = ""
    publisher: Any = None
    matching: Any = None
    matched: bool = False
    latched: bytes | None = None
    latch_queryable: Any = None
    sent: int = 0
    bytes_sent: int = 0
    meter: RateMeter = field(default_factory=RateMeter)
    announced: str = ""


@dataclass
class ReceivedTopic:
    """A remote topic published here under its local (renamed) name."""

    local: str
    item: Item
    #: the type's generated class, and the checker every body passes before a local subscriber sees it
    cls: Any = None
    checker: Any = None
    publisher: Any = None
    subscriber: Any = None
    received: int = 0
    bytes_received: int = 0
    meter: RateMeter = field(default_factory=RateMeter)
    latched_seen: bool = False
    #: while the local publisher is made again as a latched one, the newest body waits here
    relatching: bool = False
    pending: bytes | None = None
    #: the robot name put before tf frames ("" = bodies pass unchanged)
    tf_robot: str = ""
    #: bodies refused (malformed for the type, or a malformed TFMessage)
    refused: int = 0


@dataclass
class SentService:
    """A local service offered to the fleet as a queryable."""

    name: str
    key: str = ""
    queryable: Any = None
    announced: str = ""
    calls: int = 0
    errors: int = 0
    refused: int = 0


@dataclass
class ReceivedService:
    """A remote service provided here under its local name."""

    local: str
    item: Item
    service: Any = None
    calls: int = 0
    errors: int = 0
    refused: int = 0


@dataclass
class Counters:
    bad_keys: int = 0
    refused_items: int = 0
    #: items whose type this robot cannot check (unknown here, or another md5)
    unchecked_types: int = 0
    refused_calls: int = 0
    #: bodies, requests and responses from Zenoh that did not decode as their type
    malformed: int = 0
    #: bodies and requests over ``limits.MAX_BODY_BYTES``, refused before they were copied out of Zenoh
    oversized: int = 0
    inflight: int = 0
    #: bytes of the requests of calls in flight (at most ``limits.MAX_CALL_BYTES``)
    inflight_bytes: int = 0
    started: float = field(default_factory=time.monotonic)


class FleetLink:
    """The shared state of one fleet bridge (see the module's doc)."""

    def __init__(self, options: FleetOptions, node: Node) -> None:
        self.options = options
        self.node = node
        self.session: Any = None
        #: the zenoh module (imported at start: mrosd runs without it while the fleet part is off)
        self.zenoh: Any = None
        self.inbox: Inbox | None = None
        self.outbox: Outbox | None = None
        self.sent: dict[str, SentTopic] = {}
        self.received: dict[str, ReceivedTopic] = {}
        self.sent_services: dict[str, SentService] = {}
        self.received_services: dict[str, ReceivedService] = {}
        self.presence = Presence()
        self.counters = Counters()
        self.closed = False
        self.background: set[asyncio.Task[None]] = set()
        self.changed = asyncio.Event()
        #: counters written by Zenoh's threads and the loop alike
        self.lock = threading.Lock()

    def spawn(self, coro: Coroutine[Any, Any, None]) -> None:
        task = asyncio.create_task(coro)
        self.background.add(task)
        task.add_done_callback(self.background.discard)

    def touch(self) -> None:
        """Something crossed or the set of bridged items changed: wake ``FleetBridge.wait_until``."""
        self.changed.set()

    @staticmethod
    def undeclare(entity: Any) -> None:
        if entity is not None:
            with contextlib.suppress(Exception):
                entity.undeclare()

    def inbox_put(self, name: str, item: Any) -> None:
        inbox = self.inbox
        if inbox is not None and inbox.put(name, item):
            ratelog.warning("inbox", "fleet: %s: bodies dropped: they come faster than they are published", name)

    def oversized(self, name: str, size: int) -> None:
        """Count one body or request refused for its size; one rate-limited line for all of them."""
        with self.lock:
            self.counters.oversized += 1
        ratelog.warning("oversized", "fleet: refused %d bytes on %s (at most %d)", size, name, MAX_BODY_BYTES)

    def malformed(self, what: str, name: str, why: str) -> None:
        """Count one body from Zenoh that did not decode as its type; one rate-limited line for all of them."""
        with self.lock:
            self.counters.malformed += 1
            total = self.counters.malformed
        ratelog.warning("malformed", "fleet: dropped a malformed %s on %s (%d so far): %s", what, name, total, why)

    def announce(self) -> None:
        """Hand the sender thread the set of discovery keys to repeat every second."""
        if self.outbox is None:
            return
        keys = {st.announced for st in self.sent.values() if st.announced}
        keys |= {ss.announced for ss in self.sent_services.values() if ss.announced}
        for rt in self.received.values():
            if rt.subscriber is not None:
                it = rt.item
                keys.add(discovery_key(ItemKind.SUBSCRIBER, it.type, it.md5sum, it.namespace, it.topic))
        self.outbox.announcements = frozenset(keys)
        self.touch()
