"""ROS 2 -> ROS 1: topics that rmw_zenoh publishers announce, republished on the ROS 1 graph.

The bridge's liveliness subscriber hands every token to ``Inbound.token`` on the loop (through the fleet part's
``Inbox``). A publisher token (``MP``) of another session whose topic matches ``from_ros2`` and whose type has a
ROS 1 form (a standard type, a ``.msg`` on ROS_PACKAGE_PATH, a ROS 2 ``share/`` tree, through the mapping rules)
with the same RIHS01 hash gets a Zenoh subscriber on its data key (in mode "demand" only while a ROS 1 node
subscribes) and a ROS 1 publisher of the ROS 1 type; samples come through the ``Inbox`` (per-topic drop-oldest)
and are converted from CDR on the loop, or, from a body of ``OFFLOAD_SIZE`` on, on a worker thread in order.

A publisher whose token's QoS is TRANSIENT_LOCAL makes the topic latched on ROS 1, and its Zenoh subscriber an
advanced one as rmw_zenoh's TRANSIENT_LOCAL subscription is (``rmw_subscription_data.cpp``): detectable through
liveliness, detecting late publishers and querying their publication caches, so the bridge gets the last
message even if it subscribed after the ROS 2 publisher published. ROS 1 latching keeps one message: one
sample is asked of each cache.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from mrosd.errors import MrosError, RemoteProtocolError
from mrosd.fleet.keys import NameFilter
from mrosd.lograte import RateLimitedLog
from mrosd.names import canonicalize, is_valid_name
from mrosd.ros2.keys import (
    DURABILITY_TRANSIENT_LOCAL,
    RELIABILITY_RELIABLE,
    EntityKind,
    LivelinessToken,
    Qos,
    data_key,
    parse_token,
    ros2_type_of_dds,
)
from mrosd.ros2.srvtypes import HUMBLE_TYPE_HASH

if TYPE_CHECKING:
    from mrosd.fleet.handoff import Inbox
    from mrosd.ros2.types import TypeMapper
    from mrosd.tcpros.node import Node

__all__ = ["Inbound", "ros1_type_name"]

log = logging.getLogger(__name__)
#: what a peer's announcements can make us say: a few lines per kind a minute, under one key per kind (a key per
#: name would be one line per name of a flood), the rest counted in the next line that passes
_ratelog = RateLimitedLog(log, period=60.0, burst=3)

#: ROS 2 topics republished on ROS 1 at most (each holds a ROS 1 publisher and a Zenoh subscription); a peer
#: announcing more gets one log line, as the fleet part's ``max_received`` bounds what it takes
MAX_RECEIVED_TOPICS = 256
#: ROS 2 topics whose subscribers are followed for mode "demand" at most
MAX_DEMANDED_TOPICS = 4096
#: liveliness keys remembered per topic: its ROS 2 publishers (the topic stays on ROS 1 while one is left), or,
#: for mode "demand", its ROS 2 subscribers; a peer announcing more of one topic is not remembered beyond this
#: (rmw_zenoh graphs have a handful per topic), so memory follows the cap, not the announcements
MAX_SOURCES = 256
#: liveliness keys of ROS 2 subscribers followed for mode "demand", over all topics
MAX_FOLLOWED_SUBSCRIBERS = 16_384

#: a CDR body this big or bigger is converted on a worker thread (1080p rgb8 takes about 1 ms, 64 kB some µs),
#: and so is every body of that topic behind it, in order; at most ``OFFLOAD_BACKLOG`` wait (drop-oldest)
OFFLOAD_SIZE = 256 * 1024
OFFLOAD_BACKLOG = 8
#: bytes of samples waiting in the inbox for the loop, over all imported topics and per topic (drop-oldest, the
#: oldest of the topic holding most first: ``Inbox``), and the biggest sample taken at all (4K rgb8 is 25 MB)
INBOX_BYTES = 32 * 1024 * 1024
INBOX_BYTES_EACH = 32 * 1024 * 1024
MAX_SAMPLE_BYTES = INBOX_BYTES_EACH
#: bytes the queue of a slow ROS 1 subscriber of an imported topic may hold (besides its 100 messages)
LINK_BYTES = 16 * 1024 * 1024
#: bytes of bodies waiting for a worker thread or being converted there, per topic and over all topics: a
#: peer's big samples make memory follow this budget, not its sends (the oldest waiting body goes first; a body
#: that finds the budget held by bodies in conversion is refused); both are counted as drops
BACKLOG_BYTES = 32 * 1024 * 1024
BACKLOG_BYTES_ALL = 32 * 1024 * 1024
#: samples asked of each TRANSIENT_LOCAL publisher's cache: a latched ROS 1 topic keeps the last one only
LATCH_HISTORY = 1

#: ROS 2 names whose ROS 1 name is not ``pkg/Type``
_RENAMED_BACK = {"tf2_msgs/msg/TFMessage": "tf2_msgs/TFMessage"}


def ros1_type_name(ros2_type: str) -> str:
    """``pkg/msg/Type`` -> ``pkg/Type``.

    Raises:
        ValueError: not a ``pkg/msg/Type`` name.
    """
    if ros2_type in _RENAMED_BACK:
        return _RENAMED_BACK[ros2_type]
    parts = ros2_type.split("/")
    if len(parts) != 3 or parts[1] != "msg" or not parts[0] or not parts[2]:
        raise ValueError(f"not a ROS 2 message type: {ros2_type!r}")
    return f"{parts[0]}/{parts[2]}"


@dataclass
class ReceivedTopic:
    """One ROS 2 topic republished on ROS 1."""

    topic: str
    ros1_type: str
    ros2_type: str
    key: str
    publisher: Any = None
    subscriber: Any = None
    token: Any = None
    received: int = 0
    bad: int = 0
    mapping: Any = None
    #: the liveliness keys of the ROS 2 publishers seen: the topic stays on ROS 1 while one is left
    sources: set[str] = field(default_factory=set)
    #: bodies waiting for the worker thread (big ones are converted off the loop), drop-oldest
    backlog: deque[bytes] = field(default_factory=deque)
    #: bytes in ``backlog`` and in the batch being converted
    held: int = 0
    worker: asyncio.Task[None] | None = None
    dropped: int = 0
    #: a ROS 2 publisher of it is TRANSIENT_LOCAL: latched on ROS 1, its caches queried on Zenoh
    latched: bool = False
    #: the first publisher's QoS is RELIABLE (rmw_zenoh's subscriber then recovers missed samples on heartbeats)
    reliable: bool = True


def _transient_local(tok: LivelinessToken) -> bool:
    return tok.qos is not None and tok.qos.durability == DURABILITY_TRANSIENT_LOCAL


class Inbound:
    """The ROS 2 -> ROS 1 half of ``Ros2Bridge``; runs on the loop, but for what Zenoh hands to the ``Inbox``."""

    def __init__(
        self,
        include: tuple[str, ...],
        domain_id: int,
        node: Node,
        mapper: TypeMapper,
        own_zid: str,
        *,
        humble: bool = False,
        demand: bool = False,
    ) -> None:
        self.filter = NameFilter(include=include)
        self.humble = humble
        #: mode "demand": a topic's Zenoh subscription exists only while a ROS 1 node subscribes
        self.demand = demand
        #: topic -> liveliness keys of the ROS 2 subscribers of other sessions (what "demand" sends to)
        self.remote_subscribers: dict[str, set[str]] = {}
        self.domain_id = domain_id
        self.node = node
        self.mapper = mapper
        self.own_zid = own_zid
        self.topics: dict[str, ReceivedTopic] = {}
        #: bytes held for worker threads over all topics (``ReceivedTopic.held``)
        self.held = 0
        #: liveliness keys in ``remote_subscribers``
        self._followed = 0
        self._full_logged = False

    async def token(
        self, key: str, alive: bool, *, session: Any, inbox: Inbox, make_token: Any, outbound: set[str]
    ) -> ReceivedTopic | None:
        """A liveliness token appeared (``alive``) or went; returns the topic it started receiving, if any."""
        try:
            tok = parse_token(key)
        except RemoteProtocolError as exc:
            _ratelog.warning("token", "ros2: ignoring a liveliness token: %s", exc)
            return None
        if tok.zid == self.own_zid or tok.domain_id != self.domain_id:
            return None
        if tok.kind is EntityKind.SUBSCRIPTION:
            if self.demand:  # only "demand" sends by them: other modes keep nothing of a subscriber's token
                self._remote_subscriber(tok.topic, key, alive)
            return None
        if tok.kind is not EntityKind.PUBLISHER:
            return None
        known = self.topics.get(tok.topic)
        if not alive:
            if known is not None and key in known.sources:
                known.sources.discard(key)
                if not known.sources:  # the last ROS 2 publisher went: so does the ROS 1 one
                    del self.topics[tok.topic]
                    self._full_logged = False
                    await self._close(known)
            return None
        if known is not None:
            if known.key.rsplit("/", 1)[-1] == tok.type_hash and len(known.sources) < MAX_SOURCES:
                known.sources.add(key)
                if _transient_local(tok) and not known.latched:
                    self._latch(known, session, inbox, make_token)
            return None
        if tok.domain_id != self.domain_id or tok.topic not in self.filter or tok.topic in self.topics:
            return None
        if tok.topic in outbound:
            return None  # we publish it to ROS 2 ourselves: never bridge a topic both ways
        if not self._carriable(tok.topic):
            return None
        if len(self.topics) >= MAX_RECEIVED_TOPICS:
            if not self._full_logged:
                self._full_logged = True
                log.warning(
                    "ros2: ROS 2 announces more than %d topics for ROS 1; the rest are not bridged", MAX_RECEIVED_TOPICS
                )
            return None
        rt = await self._start(tok, session, inbox, make_token)
        if rt is not None:
            rt.sources.add(key)
        return rt

    def _remote_subscriber(self, topic: str, key: str, alive: bool) -> None:
        keys = self.remote_subscribers.get(topic)
        if alive:
            if self._followed >= MAX_FOLLOWED_SUBSCRIBERS or (keys is not None and len(keys) >= MAX_SOURCES):
                return
            if keys is None:
                if len(self.remote_subscribers) >= MAX_DEMANDED_TOPICS:
                    return
                keys = self.remote_subscribers[topic] = set()
            if key not in keys:
                keys.add(key)
                self._followed += 1
        elif keys is not None and key in keys:
            keys.discard(key)
            self._followed -= 1
            if not keys:
                del self.remote_subscribers[topic]

    def _carriable(self, topic: str) -> bool:
        """A canonical global ROS name; anything else a peer announces is refused, one line per name."""
        if topic.startswith("/") and is_valid_name(topic) and canonicalize(topic) == topic:
            return True
        _ratelog.warning("name", "ros2: %r announced by ROS 2 is not a ROS name; not bridged", topic[:200])
        return False

    async def _start(self, tok: LivelinessToken, session: Any, inbox: Inbox, make_token: Any) -> ReceivedTopic | None:
        from mrosd.fleet.raw import raw_message_class

        try:
            ros2_type = ros2_type_of_dds(tok.type_name)
            # ROS_PACKAGE_PATH, then the ROS 2 definitions (Jazzy's, ros2_share); may read files: off the loop
            back = await asyncio.to_thread(self.mapper.ros1_for, ros2_type)
            ros1_type, mapping = back.ros1_type, back.mapping
        except (MrosError, ValueError) as exc:
            _ratelog.warning("type", "ros2: %s from ROS 2 is not bridged: %s", tok.topic[:200], exc)
            return None
        ours = HUMBLE_TYPE_HASH if self.humble else mapping.type_hash
        if ours != tok.type_hash:
            _ratelog.warning(
                "hash",
                "ros2: %s: the ROS 2 publisher's %s hash %s is not ours (%s); not bridged",
                tok.topic,
                ros2_type,
                tok.type_hash,
                ours,
            )
            return None
        rt = ReceivedTopic(
            tok.topic, ros1_type, ros2_type, data_key(self.domain_id, tok.topic, ros2_type, tok.type_hash)
        )
        rt.latched = _transient_local(tok)
        rt.reliable = tok.qos is None or tok.qos.reliability == RELIABILITY_RELIABLE
        self.topics[tok.topic] = rt
        try:
            rt.publisher = await self.node.advertise(
                tok.topic,
                raw_message_class(ros1_type, back.md5sum, back.definition),
                latch=rt.latched,
                max_queued_bytes=LINK_BYTES,
            )
        except MrosError as exc:
            _ratelog.warning(f"adv {tok.topic}", "ros2: cannot publish %s on ROS 1: %s", tok.topic, exc)
            self.topics.pop(tok.topic, None)
            return None
        rt.mapping = mapping
        if not self.demand:
            self._attach(rt, session, inbox, make_token)
        log.info("ros2: %s <- %s (%s%s)", tok.topic, rt.key, ros1_type, ", latched" if rt.latched else "")
        return rt

    def _latch(self, rt: ReceivedTopic, session: Any, inbox: Inbox, make_token: Any) -> None:
        """A TRANSIENT_LOCAL publisher joined a topic received so far from VOLATILE ones: latch it on ROS 1, and
        subscribe again as a TRANSIENT_LOCAL subscriber (which queries the caches)."""
        rt.latched = True
        if rt.publisher is not None:
            rt.publisher.latch = True
        if rt.subscriber is not None:
            self._detach(rt)
            self._attach(rt, session, inbox, make_token)
        log.info("ros2: %s has a TRANSIENT_LOCAL publisher: latched on ROS 1", rt.topic)

    @staticmethod
    def _attach(rt: ReceivedTopic, session: Any, inbox: Inbox, make_token: Any) -> None:
        """Subscribe on Zenoh (with an ``MS`` token) to ``rt``'s samples; a latched topic's subscriber is
        rmw_zenoh's TRANSIENT_LOCAL one, which gets the last sample of each cache of a publisher it finds."""
        name = "in:" + rt.topic

        def heard(sample: Any) -> None:  # on Zenoh's thread
            size = len(sample.payload)
            if size > MAX_SAMPLE_BYTES:  # refused before it is copied out of Zenoh
                rt.dropped += 1
                _ratelog.warning(
                    "bytes", "ros2: %s: a sample of %d bytes refused (at most %d)", name[3:], size, MAX_SAMPLE_BYTES
                )
            elif inbox.put(name, sample.payload.to_bytes()):
                _ratelog.warning(
                    "bytes", "ros2: %s: samples dropped: they come faster than they are converted", name[3:]
                )

        import zenoh

        # run on Zenoh's own thread (``indirect=False``): zenoh-python's default hands each sample to a Python
        # thread through a queue with no bound, where a peer's samples piled up while the GIL was busy
        direct = zenoh.handlers.Callback(heard, indirect=False)
        if rt.latched:
            import zenoh.ext as zenoh_ext

            rt.subscriber = zenoh_ext.declare_advanced_subscriber(
                session,
                rt.key,
                direct,
                history=zenoh_ext.HistoryConfig(detect_late_publishers=True, max_samples=LATCH_HISTORY),
                recovery=zenoh_ext.RecoveryConfig(periodic_queries=None, heartbeat=True) if rt.reliable else None,
                subscriber_detection=True,
            )
            qos = Qos(durability=DURABILITY_TRANSIENT_LOCAL, depth=LATCH_HISTORY)
        else:
            rt.subscriber = session.declare_subscriber(rt.key, direct)
            qos = None
        rt.token = session.liveliness().declare_token(
            make_token(EntityKind.SUBSCRIPTION, rt.topic, rt.mapping, qos=qos).key()
        )

    @staticmethod
    def _detach(rt: ReceivedTopic) -> None:
        for entity in (rt.token, rt.subscriber):
            if entity is not None:
                with contextlib.suppress(Exception):
                    entity.undeclare()
        rt.token = rt.subscriber = None

    def follow_demand(self, session: Any, inbox: Inbox, make_token: Any) -> None:
        """Mode "demand": subscribe on Zenoh to the topics a ROS 1 node subscribes to, and only those."""
        for rt in self.topics.values():
            wanted = rt.publisher is not None and rt.publisher.get_num_connections() > 0
            if wanted and rt.subscriber is None:
                self._attach(rt, session, inbox, make_token)
                log.info("ros2: %s has a ROS 1 subscriber: subscribing on Zenoh", rt.topic)
            elif not wanted and rt.subscriber is not None:
                self._detach(rt)

    async def _close(self, rt: ReceivedTopic) -> None:
        if rt.worker is not None:
            rt.worker.cancel()  # it releases what it holds
        else:
            self._release(rt, rt.held)
            rt.backlog.clear()
        self._detach(rt)
        if rt.publisher is not None:
            with contextlib.suppress(MrosError, OSError):
                await rt.publisher.aclose()

    def deliver(self, topic: str, bodies: list[bytes]) -> None:
        """CDR bodies of ``topic`` (on the loop): converted and published on ROS 1."""
        rt = self.topics.get(topic)
        if rt is None or rt.publisher is None:
            return
        if rt.worker is not None or any(len(cdr) >= OFFLOAD_SIZE for cdr in bodies):
            for body in bodies:
                self._queue(rt, body)
            if rt.worker is None and rt.backlog:
                rt.worker = asyncio.create_task(self._drain(rt))
            return
        for body in self._convert(rt, bodies):
            rt.publisher.publish_serialized(body)

    def _convert(self, rt: ReceivedTopic, bodies: list[bytes]) -> list[bytes]:
        out = []
        for cdr in bodies:
            try:
                out.append(bytes(self.mapper.to_ros1(rt.ros2_type, cdr)))
            except MrosError as exc:
                rt.bad += 1
                _ratelog.warning(f"cdr in {rt.topic}", "%s", exc)
                continue
            rt.received += 1
        return out

    def _queue(self, rt: ReceivedTopic, body: bytes) -> None:
        """Into ``rt``'s backlog within ``OFFLOAD_BACKLOG`` bodies and the byte budgets, dropping its oldest."""
        size = len(body)
        while rt.backlog and (
            len(rt.backlog) >= OFFLOAD_BACKLOG or rt.held + size > BACKLOG_BYTES or self.held + size > BACKLOG_BYTES_ALL
        ):
            self._release(rt, len(rt.backlog.popleft()))
            rt.dropped += 1
        if rt.held + size > BACKLOG_BYTES or self.held + size > BACKLOG_BYTES_ALL:
            rt.dropped += 1
            _ratelog.warning(
                "bytes",
                "ros2: %s: a sample of %d bytes dropped: %d MiB of samples wait for conversion",
                rt.topic,
                size,
                self.held >> 20,
            )
            return
        rt.backlog.append(body)
        rt.held += size
        self.held += size

    def _release(self, rt: ReceivedTopic, size: int) -> None:
        rt.held -= size
        self.held -= size

    async def _drain(self, rt: ReceivedTopic) -> None:
        """Convert the topic's backlog on a worker thread and publish it, in order, until it is empty."""
        size = 0
        try:
            while rt.backlog and rt.publisher is not None:
                batch = list(rt.backlog)
                rt.backlog.clear()
                size = sum(map(len, batch))
                for body in await asyncio.to_thread(self._convert, rt, batch):
                    rt.publisher.publish_serialized(body)
                del batch
                self._release(rt, size)
                size = 0
        finally:
            rt.worker = None
            self._release(rt, size + sum(map(len, rt.backlog)))
            rt.backlog.clear()

    async def aclose(self) -> None:
        for rt in self.topics.values():
            await self._close(rt)
        self.topics.clear()
