"""The fleet bridge: one Zenoh session and one local node that carry chosen topics and services across.

Sending side: a local topic in ``send_topics`` is subscribed raw; once its type and md5 are known, a Zenoh
publisher on the bridge's data key is declared and the topic is announced (``pub``) every second. Bodies go to
Zenoh only while a remote subscriber matches (Zenoh's matching status): a topic nobody remote asked for costs
no bandwidth. A latched topic's last body also answers queries on its data key, so a late joiner gets it.

Receiving side: a remote ``pub`` announcement whose renamed local name is in ``receive_topics`` makes a local
publisher of that name; its Zenoh subscription exists only while a local subscriber is connected, and starts
with a query for the latched body. Three seconds without an announcement and the item is gone.

Services: a local service in ``send_services`` is a Zenoh queryable on its data key (``srv``); a remote one in
``receive_services`` becomes a local service that queries it.
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib
import json
import logging
import threading
import time
from collections.abc import Callable, Coroutine
from dataclasses import dataclass, field
from typing import Any, ClassVar

from mrosd.errors import ConfigError, MrosError, ServiceError
from mrosd.fleet.frames import prefix_tf_frames, wants_tf_prefix
from mrosd.fleet.handoff import Inbox, Outbox
from mrosd.fleet.keys import (
    ANNOUNCE_PERIOD,
    LATCHED_ATTACHMENT,
    FleetKeyError,
    Item,
    ItemKind,
    data_key,
    discovery_key,
    discovery_subscription,
    parse_discovery_key,
)
from mrosd.fleet.limits import RateLimit, RateMeter
from mrosd.fleet.options import FleetOptions, zenoh_settings
from mrosd.fleet.presence import Presence
from mrosd.lograte import RateLimitedLog
from mrosd.tcpros.node import Node
from mrosd.tcpros.service import probe_service
from mrosd.tcpros.subscriber import AnyMsg, RawMessage

log = logging.getLogger(__name__)
_ratelog = RateLimitedLog(log, period=60.0, burst=3)

#: Seconds between two looks at the local graph, and between two checks of what must be subscribed.
GRAPH_PERIOD = 0.5
TICK_PERIOD = 0.25
#: Seconds a query across the fleet may take (a service call, a latched body).
QUERY_TIMEOUT = 10.0
#: Service calls from the fleet in flight at once; more are refused at once.
MAX_INFLIGHT_CALLS = 64
#: The inbox's name for announcements, and how many may wait for the loop (each item repeats every second, so
#: one lost in a burst comes again; a flood of names costs this many strings at most).
DISCOVERY = "@discovery"
DISCOVERY_QUEUE = 4096
#: The fleet node's service that answers its status as JSON.
STATUS_SERVICE = "~status"
#: Seconds allowed to probe a local service for its type.
PROBE_TIMEOUT = 3.0


def require_zenoh() -> Any:
    """The ``zenoh`` module.

    Raises:
        ConfigError: eclipse-zenoh is not installed.
    """
    try:
        return importlib.import_module("zenoh")
    except ImportError:
        raise ConfigError(
            "the fleet part needs Eclipse Zenoh for Python: pip install 'mrosd[fleet]' (eclipse-zenoh>=1.10)"
        ) from None


# --- raw bodies as message and service classes ------------------------------------------------------


class RawBody:
    """A serialized body carried as is: what the bridge forwards needs no decoding."""

    __slots__ = ("data",)
    _type: ClassVar[str] = "*"
    _md5sum: ClassVar[str] = "*"
    _full_text: ClassVar[str] = ""

    def __init__(self, data: bytes = b"") -> None:
        self.data = data

    def serialize(self) -> bytes:
        return self.data

    @classmethod
    def deserialize(cls, body: bytes | bytearray | memoryview) -> RawBody:
        return cls(bytes(body))


def _definition(msg_type: str) -> str:
    # Tools that decode from the header (rosbag, mrosd itself) want the text; it is there when the type is known.
    from mrosd.msg import get_message_class

    try:
        return str(get_message_class(msg_type)._full_text)
    except MrosError:
        return ""


#: How a received body came: a plain sample, a sample of a latched topic, or the answer to the latched query.
_LIVE, _LIVE_LATCHED, _CACHED = 0, 1, 2


def _how(sample: Any) -> int:
    """``_LIVE_LATCHED`` when the sender marked the sample as a latched topic's (runs on Zenoh's thread)."""
    attachment = sample.attachment
    if attachment is not None and attachment.to_bytes() == LATCHED_ATTACHMENT:
        return _LIVE_LATCHED
    return _LIVE


def _known_md5(msg_type: str) -> str:
    """The md5 of a type on the search path, or "" (then the first message's header tells it)."""
    from mrosd.msg import get_message_class

    if not msg_type or msg_type == "*":
        return ""
    try:
        return str(get_message_class(msg_type)._md5sum)
    except MrosError:
        return ""


def raw_message_class(msg_type: str, md5sum: str) -> type[RawBody]:
    """A message class whose instances are bodies of ``msg_type`` (for ``Node.advertise``)."""
    attrs = {"__slots__": (), "_type": msg_type, "_md5sum": md5sum, "_full_text": _definition(msg_type)}
    return type("Raw_" + msg_type.replace("/", "_"), (RawBody,), attrs)


def raw_service_class(srv_type: str, md5sum: str) -> type[Any]:
    """A service class whose requests and responses are bodies (for ``advertise_service``/``service_proxy``)."""
    req = type("RawRequest", (RawBody,), {"__slots__": (), "_type": srv_type + "Request", "_md5sum": md5sum})
    resp = type("RawResponse", (RawBody,), {"__slots__": (), "_type": srv_type + "Response", "_md5sum": md5sum})
    return type(
        "RawService",
        (),
        {"_type": srv_type, "_md5sum": md5sum, "_request_class": req, "_response_class": resp},
    )


# --- what crosses ---------------------------------------------------------------------------------


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


@dataclass
class ReceivedService:
    """A remote service provided here under its local name."""

    local: str
    item: Item
    service: Any = None
    calls: int = 0
    errors: int = 0


@dataclass
class _Counters:
    bad_keys: int = 0
    refused_items: int = 0
    refused_calls: int = 0
    inflight: int = 0
    started: float = field(default_factory=time.monotonic)


class FleetBridge:
    """``async with FleetBridge(options, master_uri):`` links this master to the fleet until closed.

    Raises (from ``start``):
        ConfigError: eclipse-zenoh is missing or the options are refused by Zenoh.
        MasterUnreachableError: the local master does not answer.
    """

    def __init__(
        self, options: FleetOptions, master_uri: str, *, node_name: str = "mrosd_fleet", host: str | None = None
    ) -> None:
        self.options = options
        self.master_uri = master_uri
        self.node = Node(node_name, master_uri, argv=[], host=host, rosout=False, logger_services=False)
        self.session: Any = None
        #: the zenoh module (imported at start: mrosd runs without it while the fleet part is off)
        self._zenoh: Any = None
        self.sent: dict[str, SentTopic] = {}
        self.received: dict[str, ReceivedTopic] = {}
        self.sent_services: dict[str, SentService] = {}
        self.received_services: dict[str, ReceivedService] = {}
        self.presence = Presence()
        self.counters = _Counters()
        self._tasks: list[asyncio.Task[None]] = []
        self._inbox: Inbox | None = None
        self._outbox: Outbox | None = None
        self._discovery_sub: Any = None
        self._closed = False
        self._background: set[asyncio.Task[None]] = set()
        self._changed = asyncio.Event()
        #: calls from the fleet in flight are counted by Zenoh's threads and the loop alike
        self._inflight_lock = threading.Lock()

    # --- lifecycle ---------------------------------------------------------------------------------

    async def start(self) -> None:
        zenoh = self._zenoh = require_zenoh()
        config = zenoh.Config()
        try:
            for path, value in zenoh_settings(self.options):
                config.insert_json5(path, value)
        except Exception as exc:
            raise ConfigError(f"fleet: Zenoh refused the configuration: {exc}") from exc
        loop = asyncio.get_running_loop()
        await self.node.start()
        try:
            try:
                # zenoh.open waits for the first connection attempts: off the loop.
                self.session = await asyncio.to_thread(zenoh.open, config)
            except Exception as exc:
                raise ConfigError(f"fleet: cannot open the Zenoh session: {exc}") from exc
            self._inbox = Inbox(loop, self._deliver, self.options.queue_size, {DISCOVERY: DISCOVERY_QUEUE})
            announce = {
                "congestion_control": zenoh.CongestionControl.DROP,
                "priority": zenoh.Priority.BACKGROUND,
                "allowed_destination": zenoh.Locality.REMOTE,
            }
            self._outbox = Outbox(self.session, self.options.queue_size, announce)
            self._outbox.start()
            self._discovery_sub = self.session.declare_subscriber(
                discovery_subscription(),
                lambda sample: self._inbox_put(DISCOVERY, str(sample.key_expr)),
                allowed_origin=zenoh.Locality.REMOTE,
            )
            await self._advertise_status()
        except BaseException:
            await self.aclose()
            raise
        self._tasks = [
            asyncio.create_task(self._graph_loop(), name="fleet-graph"),
            asyncio.create_task(self._tick_loop(), name="fleet-tick"),
        ]
        log.info("fleet: robot %s on Zenoh %s (%s)", self.options.robot, self.session.zid(), self.options.mode)

    async def aclose(self) -> None:
        if self._closed:
            return
        self._closed = True
        tasks = [*self._tasks, *self._background]
        for task in tasks:
            task.cancel()
        for task in tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        if self._inbox is not None:
            self._inbox.closed = True
        if self._outbox is not None:
            await asyncio.to_thread(self._outbox.close)
        for st in list(self.sent.values()):
            await self._drop_sent(st)
        for rt in list(self.received.values()):
            await self._drop_received(rt)
        for ss in list(self.sent_services.values()):
            self._undeclare(ss.queryable)
        for rs in list(self.received_services.values()):
            if rs.service is not None:
                with contextlib.suppress(MrosError, OSError):
                    await rs.service.aclose()
        self._undeclare(self._discovery_sub)
        if self.session is not None:
            await asyncio.to_thread(self.session.close)
        await self.node.aclose()

    async def __aenter__(self) -> FleetBridge:
        await self.start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()

    def _spawn(self, coro: Coroutine[Any, Any, None]) -> None:
        task = asyncio.create_task(coro)
        self._background.add(task)
        task.add_done_callback(self._background.discard)

    def _touch(self) -> None:
        """Something crossed or the set of bridged items changed: wake ``wait_until``."""
        self._changed.set()

    async def wait_until(self, predicate: Callable[[], bool], timeout: float) -> None:
        """Return once ``predicate()`` holds, checked after every change of the bridge.

        Raises:
            TimeoutError: it did not hold within ``timeout`` seconds.
        """
        async with asyncio.timeout(timeout):
            while not predicate():
                self._changed.clear()
                await self._changed.wait()

    @staticmethod
    def _undeclare(entity: Any) -> None:
        if entity is not None:
            with contextlib.suppress(Exception):
                entity.undeclare()

    def _inbox_put(self, name: str, item: Any) -> None:
        inbox = self._inbox
        if inbox is not None:
            inbox.put(name, item)

    def _announce(self) -> None:
        if self._outbox is None:
            return
        keys = {st.announced for st in self.sent.values() if st.announced}
        keys |= {ss.announced for ss in self.sent_services.values() if ss.announced}
        for rt in self.received.values():
            if rt.subscriber is not None:
                it = rt.item
                keys.add(discovery_key(ItemKind.SUBSCRIBER, it.type, it.md5sum, it.namespace, it.topic))
        self._outbox.announcements = frozenset(keys)
        self._touch()

    # --- the local graph -------------------------------------------------------------------------

    async def _graph_loop(self) -> None:
        while True:
            try:
                state = await self.node.master.call("getSystemState")
                types = dict(await self.node.master.call("getTopicTypes"))
                await self._reconcile(state, types)
            except asyncio.CancelledError:
                raise
            except (MrosError, OSError, ValueError, TypeError) as exc:
                _ratelog.warning("graph", "fleet: cannot read the local graph: %s", exc)
            await asyncio.sleep(GRAPH_PERIOD)

    async def _reconcile(self, state: Any, types: dict[str, str]) -> None:
        pubs, _subs, srvs = state
        own = self.node.name
        received = set(self.received)
        want = {
            str(topic)
            for topic, nodes in pubs
            if topic in self.options.send_topics and topic not in received and any(n != own for n in nodes)
        }
        for topic in want - set(self.sent):
            await self._add_sent(topic, types.get(topic, ""))
        for topic in set(self.sent) - want:
            await self._drop_sent(self.sent.pop(topic))
        services = {
            str(name)
            for name, nodes in srvs
            if name in self.options.send_services
            and name not in self.received_services
            and any(n != own for n in nodes)
        }
        for name in services - set(self.sent_services):
            await self._add_sent_service(name)
        for name in set(self.sent_services) - services:
            ss = self.sent_services.pop(name)
            self._undeclare(ss.queryable)
        self._announce()

    # --- sending topics --------------------------------------------------------------------------

    async def _add_sent(self, topic: str, msg_type: str) -> None:
        st = SentTopic(topic, self.options.limit_for(topic))
        self.sent[topic] = st
        try:
            st.subscriber = await self.node.subscribe(
                topic, AnyMsg, callback=lambda msg: self._local_message(st, msg), queue_size=self.options.queue_size
            )
        except MrosError as exc:
            _ratelog.warning(f"sub {topic}", "fleet: cannot subscribe to %s: %s", topic, exc)
            self.sent.pop(topic, None)
            return
        # A known type is announced at once (a topic that publishes rarely is seen before its first message);
        # an unknown one when its first message tells the md5.
        md5sum = _known_md5(msg_type)
        if md5sum:
            self._declare_sent(st, msg_type, md5sum)

    def _local_message(self, st: SentTopic, msg: RawMessage) -> None:
        msg_type, md5sum = msg.header.type or "", msg.header.md5sum or ""
        told = bool(msg_type) and md5sum not in ("", "*")
        if st.publisher is not None and told and (msg_type, md5sum) != (st.msg_type, st.md5sum):
            self._undeclare_sent(st)  # the publisher's definition differs from ours: its own md5 is the key
        if st.publisher is None:
            if not told:
                return  # a publisher that does not say its type and md5 cannot be announced
            self._declare_sent(st, msg_type, md5sum)
            if st.publisher is None:
                return
        body = bytes(msg.data)
        if msg.header.latching == "1":
            st.latched = body
            if st.latch_queryable is None:
                self._declare_latch_queryable(st)
        if not st.matched or self._outbox is None:
            return
        now = time.monotonic()
        if st.limit is not None and not st.limit.admit(now, len(body)):
            return
        st.meter.tick(now)
        st.sent += 1
        st.bytes_sent += len(body)
        self._outbox.put(st.key, st.publisher, body, LATCHED_ATTACHMENT if st.latched is not None else None)

    def _declare_sent(self, st: SentTopic, msg_type: str, md5sum: str) -> None:
        zenoh = self._zenoh
        st.msg_type, st.md5sum = msg_type, md5sum
        try:
            st.key = data_key(msg_type, md5sum, self.options.robot, st.topic)
        except ValueError as exc:
            _ratelog.warning(f"key {st.topic}", "fleet: cannot send %s: %s", st.topic, exc)
            return
        st.publisher = self.session.declare_publisher(
            st.key,
            congestion_control=zenoh.CongestionControl.BLOCK,
            reliability=zenoh.Reliability.RELIABLE,
            allowed_destination=zenoh.Locality.REMOTE,
        )

        def matching(status: Any) -> None:
            st.matched = bool(status.matching)  # a plain store: read by the loop, written by Zenoh's thread

        st.matching = st.publisher.declare_matching_listener(matching)
        st.matched = bool(st.publisher.matching_status.matching)
        st.announced = discovery_key(ItemKind.PUBLISHER, msg_type, md5sum, self.options.robot, st.topic)
        self._announce()

    def _declare_latch_queryable(self, st: SentTopic) -> None:
        zenoh = self._zenoh
        key = st.key

        def answer(query: Any) -> None:
            # On Zenoh's thread: reads one reference, the loop replaces it whole.
            with query:
                body = st.latched
                if body is not None:
                    query.reply(key, body)

        st.latch_queryable = self.session.declare_queryable(key, answer, allowed_origin=zenoh.Locality.REMOTE)

    def _undeclare_sent(self, st: SentTopic) -> None:
        for entity in (st.latch_queryable, st.matching, st.publisher):
            self._undeclare(entity)
        st.publisher = st.latch_queryable = st.matching = None
        st.matched = False
        st.announced = ""
        if self._outbox is not None and st.key:
            self._outbox.forget(st.key)

    async def _drop_sent(self, st: SentTopic) -> None:
        self._undeclare_sent(st)
        if st.subscriber is not None:
            with contextlib.suppress(MrosError, OSError):
                await st.subscriber.aclose()

    # --- receiving topics ------------------------------------------------------------------------

    def _deliver(self, name: str, items: list[Any]) -> None:
        if name == DISCOVERY:
            self._heard(items)
            return
        rt = self.received.get(name)
        if rt is None or rt.publisher is None or (rt.publisher.closed and not rt.relatching):
            return
        for raw, how in items:
            body = raw
            if rt.tf_robot:
                try:
                    body = prefix_tf_frames(raw, rt.tf_robot)
                except MrosError as exc:
                    rt.refused += 1
                    _ratelog.warning(f"tf {name}", "fleet: dropping a malformed TFMessage on %s: %s", name, exc)
                    continue
            if how == _CACHED and rt.received:
                continue  # live data already came: the cached body is older
            rt.latched_seen = rt.latched_seen or how != _LIVE
            if rt.latched_seen and not rt.publisher.latch and rt.publisher.shm is None:
                # Latched at the sender: latched here too, so later local subscribers get the last body. TCPROS
                # reads the flag at each new connection (a shared-memory side, made later, takes it then too).
                rt.publisher.latch = True
            if rt.relatching or (rt.latched_seen and not rt.publisher.latch):
                # The publisher's shared-memory side took its latch when made: advertise it again, latched.
                rt.pending = body
                if not rt.relatching:
                    rt.relatching = True
                    self._spawn(self._relatch(rt))
                continue
            rt.received += 1
            rt.bytes_received += len(body)
            rt.meter.tick(time.monotonic())
            rt.publisher.publish_serialized(body)
        self._touch()

    def _heard(self, keys: list[str]) -> None:
        now = time.monotonic()
        for key in dict.fromkeys(keys):
            try:
                item = parse_discovery_key(key)
            except FleetKeyError as exc:
                self.counters.bad_keys += 1
                _ratelog.warning("badkey", "fleet: ignoring an announcement: %s", exc)
                continue
            if item.namespace == self.options.robot:
                continue
            self.presence.heard(item, now)
            if item not in self.presence:
                continue  # the table is full: not bridged, and not remembered either
            # Every announcement is checked, not only the first: an item refused while full gets in later.
            local = self.options.rename.local_name(item.namespace, item.topic)
            if item.kind is ItemKind.PUBLISHER and local in self.options.receive_topics:
                if local not in self.received and local not in self.sent and self._room_for(item):
                    self.received[local] = ReceivedTopic(local, item, tf_robot=self._tf_robot(item))
                    self._spawn(self._add_received(self.received[local]))
            elif (
                item.kind is ItemKind.SERVICE
                and local in self.options.receive_services
                and local not in self.received_services
                and local not in self.sent_services
                and self._room_for(item)
            ):
                self.received_services[local] = ReceivedService(local, item)
                self._spawn(self._add_received_service(self.received_services[local]))

    def _tf_robot(self, item: Item) -> str:
        if not self.options.prefix_tf or not wants_tf_prefix(item.topic, item.type):
            return ""
        return self.options.rename.wildcard_robot if item.namespace == "*" else item.namespace

    def _room_for(self, item: Item) -> bool:
        """True while fewer than ``max_received`` remote topics and services are published here."""
        if len(self.received) + len(self.received_services) < self.options.max_received:
            return True
        self.counters.refused_items += 1
        _ratelog.warning(
            "full",
            "fleet: %s from %s refused: max_received (%d) reached",
            item.topic,
            item.namespace,
            self.options.max_received,
        )
        return False

    async def _add_received(self, rt: ReceivedTopic) -> None:
        cls = raw_message_class(rt.item.type, rt.item.md5sum)
        try:
            rt.publisher = await self.node.advertise(rt.local, cls, queue_size=self.options.queue_size)
            self._touch()
        except MrosError as exc:
            _ratelog.warning(f"adv {rt.local}", "fleet: cannot publish %s here: %s", rt.local, exc)
            self.received.pop(rt.local, None)

    async def _relatch(self, rt: ReceivedTopic) -> None:
        """Replace the local publisher of ``rt`` by a latched one and publish the last body on it.

        Its subscribers see the publisher leave and come back (publisherUpdate) and get the body on
        reconnecting, once; bodies that arrive meanwhile replace the pending one.
        """
        old = rt.publisher
        try:
            if old is not None:
                with contextlib.suppress(MrosError, OSError):
                    await old.aclose()
            cls = raw_message_class(rt.item.type, rt.item.md5sum)
            pub = await self.node.advertise(rt.local, cls, latch=True, queue_size=self.options.queue_size)
        except MrosError as exc:
            _ratelog.warning(f"adv {rt.local}", "fleet: cannot publish %s latched here: %s", rt.local, exc)
            return
        finally:
            rt.relatching = False
        if self.received.get(rt.local) is not rt:  # forgotten meanwhile
            await pub.aclose()
            return
        rt.publisher = pub
        if rt.pending is not None:
            body, rt.pending = rt.pending, None
            rt.received += 1
            rt.bytes_received += len(body)
            rt.meter.tick(time.monotonic())
            pub.publish_serialized(body)
        self._touch()

    async def _drop_received(self, rt: ReceivedTopic) -> None:
        self._undeclare(rt.subscriber)
        rt.subscriber = None
        if self._inbox is not None:
            self._inbox.forget(rt.local)
        if rt.publisher is not None:
            with contextlib.suppress(MrosError, OSError):
                await rt.publisher.aclose()

    def _subscribe_received(self, rt: ReceivedTopic) -> None:
        zenoh = self._zenoh
        local = rt.local
        key = rt.item.data_key
        rt.subscriber = self.session.declare_subscriber(
            key,
            lambda sample: self._inbox_put(local, (sample.payload.to_bytes(), _how(sample))),
            allowed_origin=zenoh.Locality.REMOTE,
        )

        def reply(r: Any) -> None:
            if r.ok is not None:
                self._inbox_put(local, (r.ok.payload.to_bytes(), _CACHED))

        # The latched body, if the sender holds one (a late joiner's first message).
        self.session.get(key, reply, timeout=QUERY_TIMEOUT, allowed_destination=zenoh.Locality.REMOTE)

    # --- the periodic checks ---------------------------------------------------------------------

    async def _tick_loop(self) -> None:
        while True:
            await asyncio.sleep(TICK_PERIOD)
            try:
                await self._tick()
            except asyncio.CancelledError:
                raise
            except Exception:
                log.exception("fleet: periodic check failed")

    async def _tick(self) -> None:
        for item in self.presence.expire(time.monotonic()):
            local = self.options.rename.local_name(item.namespace, item.topic)
            if item.kind is ItemKind.PUBLISHER:
                rt = self.received.get(local)
                if rt is not None and rt.item == item:
                    del self.received[local]
                    await self._drop_received(rt)
                    self._touch()
            elif item.kind is ItemKind.SERVICE:
                rs = self.received_services.get(local)
                if rs is not None and rs.item == item:
                    del self.received_services[local]
                    if rs.service is not None:
                        with contextlib.suppress(MrosError, OSError):
                            await rs.service.aclose()
        changed = False
        for rt in self.received.values():
            wanted = rt.publisher is not None and rt.publisher.get_num_connections() > 0
            if wanted and rt.subscriber is None:
                self._subscribe_received(rt)
                changed = True
            elif not wanted and rt.subscriber is not None:
                self._undeclare(rt.subscriber)
                rt.subscriber = None
                changed = True
        if changed:
            self._announce()

    # --- services --------------------------------------------------------------------------------

    async def _add_sent_service(self, name: str) -> None:
        zenoh = self._zenoh
        ss = SentService(name)
        self.sent_services[name] = ss
        try:
            fields = await probe_service(self.node.master, name, self.node.name, PROBE_TIMEOUT)
            srv_type, md5sum = fields["type"], fields.get("md5sum", "")
            if not md5sum or md5sum == "*":
                raise ServiceError(f"service {name}: the server did not say its md5sum")
            ss.key = data_key(srv_type, md5sum, self.options.robot, name)
        except (MrosError, ValueError) as exc:
            _ratelog.warning(f"probe {name}", "fleet: cannot offer %s: %s", name, exc)
            self.sent_services.pop(name, None)
            return
        proxy = self.node.service_proxy(name, raw_service_class(srv_type, md5sum))
        loop = asyncio.get_running_loop()

        def on_query(query: Any) -> None:
            # Zenoh's thread: refuse at once beyond the cap (or once closing), else hand the call to the loop.
            with self._inflight_lock:
                admitted = not self._closed and self.counters.inflight < MAX_INFLIGHT_CALLS
                if admitted:
                    self.counters.inflight += 1
                else:
                    self.counters.refused_calls += 1
            if not admitted:
                with query:
                    query.reply_err(b"mrosd fleet: too many calls in flight")
                return
            try:
                loop.call_soon_threadsafe(self._spawn, self._serve_call(ss, proxy, query))
            except RuntimeError:  # the loop is gone
                self._call_done()
                query.drop()

        ss.queryable = self.session.declare_queryable(ss.key, on_query, allowed_origin=zenoh.Locality.REMOTE)
        ss.announced = discovery_key(ItemKind.SERVICE, srv_type, md5sum, self.options.robot, name)
        self._announce()

    async def _serve_call(self, ss: SentService, proxy: Any, query: Any) -> None:
        try:
            if self._closed:
                query.reply_err(b"mrosd fleet: closing")
                return
            payload = query.payload
            request = proxy.request_class(payload.to_bytes() if payload is not None else b"")
            ss.calls += 1
            try:
                response = await proxy.call(request, timeout=QUERY_TIMEOUT)
            except (MrosError, TimeoutError, OSError) as exc:
                # The caller learns the error as an error reply (a bridge's ROS client then fails the call).
                ss.errors += 1
                query.reply_err(str(exc).encode())
                return
            query.reply(ss.key, response.data)
        except Exception as exc:
            _ratelog.warning(f"call {ss.name}", "fleet: answering a call of %s failed: %s", ss.name, exc)
        finally:
            self._call_done()
            with contextlib.suppress(Exception):
                query.drop()

    def _call_done(self) -> None:
        with self._inflight_lock:
            self.counters.inflight -= 1

    async def _add_received_service(self, rs: ReceivedService) -> None:
        cls = raw_service_class(rs.item.type, rs.item.md5sum)
        key = rs.item.data_key

        async def handler(request: RawBody) -> RawBody:
            rs.calls += 1
            try:
                body = await self._query(key, request.data)
                response: RawBody = cls._response_class(body)
                return response
            except ServiceError:
                rs.errors += 1
                raise

        try:
            rs.service = await self.node.advertise_service(rs.local, cls, handler)
            self._touch()
        except MrosError as exc:
            _ratelog.warning(f"srv {rs.local}", "fleet: cannot provide %s here: %s", rs.local, exc)
            self.received_services.pop(rs.local, None)

    async def _query(self, key: str, body: bytes) -> bytes:
        """The first reply to a query on ``key`` (a remote service's response body).

        Raises:
            ServiceError: an error reply, no reply within QUERY_TIMEOUT, or nobody answering.
        """
        zenoh = self._zenoh
        loop = asyncio.get_running_loop()
        done: asyncio.Future[bytes] = loop.create_future()

        def settle(value: bytes | None, error: str | None) -> None:
            if done.done():
                return
            if error is not None:
                done.set_exception(ServiceError(error))
            elif value is not None:
                done.set_result(value)

        def on_reply(reply: Any) -> None:
            if reply.ok is not None:
                value = reply.ok.payload.to_bytes()
                loop.call_soon_threadsafe(settle, value, None)
            else:
                text = reply.err.payload.to_bytes().decode("utf-8", "replace")
                loop.call_soon_threadsafe(settle, None, f"the remote service answered an error: {text}")

        def on_done() -> None:
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(settle, None, f"no answer from {key} across the fleet")

        self.session.get(
            key,
            zenoh.handlers.Callback(on_reply, on_done),
            payload=body,
            timeout=QUERY_TIMEOUT,
            allowed_destination=zenoh.Locality.REMOTE,
        )
        async with asyncio.timeout(QUERY_TIMEOUT + 1.0):
            return await done

    # --- status ----------------------------------------------------------------------------------

    async def _advertise_status(self) -> None:
        """``~status`` (std_srvs/Trigger): ``status()`` as JSON in ``message``; what ``mros fleet status`` reads.

        A ROS service, so any tool (``rosservice call /mrosd_fleet/status``) and any host that reaches the
        master can ask, with no extra port or protocol.
        """
        from mrosd.msg import get_service_class

        trigger = get_service_class("std_srvs/Trigger")

        def answer(_request: Any) -> Any:
            return trigger._response_class(success=True, message=json.dumps(self.status()))

        await self.node.advertise_service(STATUS_SERVICE, trigger, answer)

    def status(self) -> dict[str, Any]:
        """Peers, links and per-topic counts, as ``mros fleet status`` prints them (plain data)."""
        now = time.monotonic()
        peers: list[str] = []
        if self.session is not None:
            with contextlib.suppress(Exception):
                peers = [str(z) for z in self.session.info.peers_zid()]
        outbox = self._outbox
        inbox = self._inbox
        return {
            "robot": self.options.robot,
            "mode": self.options.mode,
            "zid": str(self.session.zid()) if self.session is not None else "",
            "peers": peers,
            "remote_items": len(self.presence.items()),
            "bad_announcements": self.counters.bad_keys,
            "refused_items": self.counters.refused_items,
            "refused_calls": self.counters.refused_calls,
            "sent": {
                t: {
                    "key": st.key,
                    "matched": st.matched,
                    "messages": st.sent,
                    "bytes": st.bytes_sent,
                    "rate_hz": st.meter.rate(now),
                    "dropped": outbox.dropped(st.key) if outbox is not None and st.key else 0,
                    "rate_limited": st.limit.limited if st.limit is not None else 0,
                    "latched": st.latched is not None,
                }
                for t, st in self.sent.items()
            },
            "received": {
                t: {
                    "key": rt.item.data_key,
                    "robot": rt.item.namespace,
                    "subscribed": rt.subscriber is not None,
                    "messages": rt.received,
                    "bytes": rt.bytes_received,
                    "rate_hz": rt.meter.rate(now),
                    "dropped": inbox.dropped(t) if inbox is not None else 0,
                    "refused": rt.refused,
                    "latched": rt.latched_seen,
                }
                for t, rt in self.received.items()
            },
            "services_sent": {
                n: {"key": s.key, "calls": s.calls, "errors": s.errors} for n, s in self.sent_services.items()
            },
            "services_received": {
                n: {"key": s.item.data_key, "calls": s.calls, "errors": s.errors}
                for n, s in self.received_services.items()
            },
            "announce_period": ANNOUNCE_PERIOD,
        }
