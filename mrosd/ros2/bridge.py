"""``Ros2Bridge``: chosen ROS 1 topics put on Zenoh as an rmw_zenoh ROS 2 node publishes them.

For each ROS 1 topic matching ``to_ros2`` that has a publisher, the bridge subscribes raw over TCPROS. The first
body tells the type and its ``message_definition``; the type is mapped (``mrosd.ros2.types``, off the loop) and a
Zenoh publisher is declared on rmw_zenoh's data key with a ``MP`` liveliness token under the bridge's ``NN``
token. Bodies then go, unconverted, into the fleet part's ``Outbox`` (per-key drop-oldest queues); its one
sender thread converts each to CDR and puts it with a fresh attachment, so neither the conversion nor a slow
link ever holds the loop. A type that cannot be mapped is one log line, and that topic alone is skipped.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from mrosd import backports
from mrosd.errors import ConfigError, MrosError, RemoteProtocolError
from mrosd.fleet.handoff import Inbox, Outbox
from mrosd.fleet.keys import NameFilter
from mrosd.lograte import RateLimitedLog
from mrosd.names import canonicalize, is_valid_name
from mrosd.ros2.attachment import encode_attachment, gid_of
from mrosd.ros2.inbound import INBOX_BYTES, INBOX_BYTES_EACH, Inbound
from mrosd.ros2.keys import (
    DURABILITY_TRANSIENT_LOCAL,
    MAX_TOKEN_LENGTH,
    EntityKind,
    LivelinessToken,
    Qos,
    data_key,
    dds_type_name,
    parse_token,
)
from mrosd.ros2.mapping import load_mapping_rules
from mrosd.ros2.options import Ros2Options, ros2_options, zenoh_config
from mrosd.ros2.services import Ros2Services
from mrosd.ros2.srvtypes import HUMBLE_TYPE_HASH
from mrosd.ros2.status import RateMeter, inbound_rows, outbound_rows, status_document
from mrosd.ros2.tokens import MAX_WAITING, TokenFilter, TokenLanes
from mrosd.ros2.types import TypeMapper, TypeMapping, UnmappableTypeError
from mrosd.tcpros.node import Node
from mrosd.tcpros.subscriber import AnyMsg, RawMessage

__all__ = ["Ros2Bridge", "Ros2Options", "ros2_options"]

log = logging.getLogger(__name__)
_ratelog = RateLimitedLog(log, period=60.0, burst=3)

#: seconds between two reads of the ROS 1 graph
GRAPH_PERIOD = 1.0
#: refused names remembered so each is logged once (a stranger can register any number of them)
MAX_REFUSED_NAMES = 1024
#: liveliness tokens handled per turn of the loop (then other tasks run)
TOKEN_BATCH = 256
#: seconds between sporadic heartbeats of a TRANSIENT_LOCAL publisher (rmw_zenoh's
#: SAMPLE_MISS_DETECTION_HEARTBEAT_PERIOD, 500 ms); sent only when a sample was published since the last one
HEARTBEAT = 0.5


def _none(_name: str) -> int:
    return 0


class RmwPublisher:
    """What the outbox's sender thread puts through: converts a ROS 1 body to CDR and puts it with rmw_zenoh's
    attachment (sequence number counted here, on that one thread)."""

    def __init__(self, publisher: Any, mapper: TypeMapper, mapping: TypeMapping, gid: bytes) -> None:
        self.publisher = publisher
        self.mapper = mapper
        self.ros2_type = mapping.ros2_type
        self.gid = gid
        self.sequence = 0
        self.sent = 0
        self.bad = 0

    def put(self, body: bytes) -> None:
        try:
            cdr = self.mapper.to_cdr(self.ros2_type, body)
        except MrosError as exc:
            self.bad += 1
            _ratelog.warning(f"cdr {self.ros2_type}", "%s", exc)
            return
        self.sequence += 1
        attachment = encode_attachment(self.sequence, time.time_ns(), self.gid)
        # the converter's buffer is a bytearray seen whole through ``cdr``: Zenoh takes it without a copy here
        self.publisher.put(
            cdr.obj if isinstance(cdr.obj, bytearray) and len(cdr.obj) == cdr.nbytes else bytes(cdr),
            attachment=attachment,
        )
        self.sent += 1


@dataclass
class BridgedTopic:
    """One ROS 1 topic on its way to ROS 2."""

    topic: str
    subscriber: Any = None
    mapping: TypeMapping | None = None
    key: str = ""
    rmw: RmwPublisher | None = None
    token: Any = None
    #: a one-line reason this topic does not cross (an unmappable type)
    problem: str = ""
    mapping_task: asyncio.Task[None] | None = None
    #: crossed as TRANSIENT_LOCAL (the ROS 1 publisher latches)
    latched: bool = False
    #: the newest body received while the type was being mapped
    pending: bytes | None = None


class Ros2Bridge:
    """``async with Ros2Bridge(options, master_uri):`` puts the chosen ROS 1 topics on Zenoh until closed.

    Raises (from ``start``):
        ConfigError: eclipse-zenoh is missing or refuses the settings, or the session cannot open.
        MasterUnreachableError: the ROS 1 master does not answer.
    """

    def __init__(self, options: Ros2Options, master_uri: str, *, host: str | None = None) -> None:
        self.options = options
        # The modes widen only what goes to ROS 2: "all" sends everything, "demand" what the globs name (everything
        # if they name nothing). What comes from ROS 2 is always what ``from_ros2`` lists, nothing by default: any
        # peer of the Zenoh network can announce a publisher or a server under any name (``/cmd_vel``), so
        # importing a name into ROS 1 is never implied.
        everything: tuple[str, ...] = ("/**",)
        if options.mode == "all":
            self.to_ros2 = everything
        elif options.mode == "demand":
            self.to_ros2 = options.to_ros2 or everything
        else:
            self.to_ros2 = options.to_ros2
        self.from_ros2 = options.from_ros2
        self.demand = options.mode == "demand"
        self.filter = NameFilter(include=self.to_ros2)
        self.node = Node(options.node_name, master_uri, argv=[], host=host, rosout=False, logger_services=False)
        self.mapper = TypeMapper(load_mapping_rules(options.mapping_rules), options.ros2_share)
        self.topics: dict[str, BridgedTopic] = {}
        self.session: Any = None
        self._zenoh: Any = None
        self._outbox: Outbox | None = None
        self._inbox: Inbox | None = None
        self._token_sub: Any = None
        self.inbound: Inbound | None = None
        self.services: Ros2Services | None = None
        self._background: set[asyncio.Task[None]] = set()
        #: liveliness tokens waiting for the loop, a lane per session (``mrosd.ros2.tokens``)
        self._lanes = TokenLanes()
        self._tokens_waiting = asyncio.Event()
        self._node_token: Any = None
        self._zid = ""
        self._next_id = 0
        self._tasks: list[asyncio.Task[None]] = []
        self._changed = asyncio.Event()
        #: set when the graph should be read before the period is over (a ROS 2 subscriber came or went)
        self._graph_wake = asyncio.Event()
        self._closed = False
        self._lock = threading.Lock()
        #: names refused once (logged once each; cleared when full)
        self._refused: set[str] = set()
        #: completed reads of the ROS 1 graph (tests wait on it)
        self.graph_reads = 0
        self.rates = RateMeter()

    # --- lifecycle ---------------------------------------------------------------------------------

    async def start(self) -> None:
        try:
            import zenoh
        except ImportError:
            raise ConfigError("the ros2 part needs Eclipse Zenoh for Python: pip install 'mrosd[ros2]'") from None
        self._zenoh = zenoh
        config = zenoh_config(zenoh, self.options)
        await self.node.start()
        try:
            try:
                self.session = await asyncio.to_thread(zenoh.open, config)
            except Exception as exc:
                raise ConfigError(f"ros2: cannot open the Zenoh session: {exc}") from exc
            self._zid = str(self.session.zid())
            self._outbox = Outbox(self.session, self.options.queue_size, {})
            self._outbox.start()
            self._node_token = self.session.liveliness().declare_token(self._token(EntityKind.NODE).key())
            self.services = Ros2Services(
                node=self.node,
                mapper=self.mapper,
                session=self.session,
                zenoh=zenoh,
                domain_id=self.options.domain_id,
                humble=self.options.humble,
                to_ros2=self.to_ros2,
                from_ros2=self.from_ros2,
                make_token=self._token,
                changed=self._changed.set,
                call_timeout=self.options.service_timeout,
            )
            if self.from_ros2 or self.demand:  # "demand" follows ROS 2 subscribers' tokens even importing nothing
                self._start_inbound(asyncio.get_running_loop())
            await self._advertise_status()
        except BaseException:
            await self.aclose()
            raise
        self._tasks = [asyncio.create_task(self._graph_loop(), name="ros2-graph")]
        if self.inbound is not None:
            self._tasks.append(asyncio.create_task(self._token_loop(), name="ros2-tokens"))
        log.info("ros2: node %s on Zenoh %s, domain %d", self.options.node_name, self._zid, self.options.domain_id)

    def _start_inbound(self, loop: asyncio.AbstractEventLoop) -> None:
        zenoh = self._zenoh
        self._inbox = Inbox(
            loop, self._deliver, self.options.queue_size, max_bytes=INBOX_BYTES, max_bytes_each=INBOX_BYTES_EACH
        )
        self.inbound = Inbound(
            self.from_ros2,
            self.options.domain_id,
            self.node,
            self.mapper,
            self._zid,
            humble=self.options.humble,
            demand=self.demand,
        )

        wanted = TokenFilter(
            self.options.domain_id, self._zid, NameFilter(include=self.from_ros2), self.filter if self.demand else None
        )
        lanes, waiting = self._lanes, self._tokens_waiting

        def heard(sample: Any) -> None:  # on Zenoh's thread
            key = str(sample.key_expr)
            session = wanted.session_of(key)
            if session is None:
                return  # cannot matter to the bridge: costs the loop nothing
            # no rmw_zenoh token is this long: the lanes hold only what parse_token could take (None: refused)
            token = (key if len(key) <= MAX_TOKEN_LENGTH else None, sample.kind == zenoh.SampleKind.PUT)
            was_empty, dropped = lanes.put(session, token)
            if dropped:
                _ratelog.warning(
                    "tokens", "ros2: over %d liveliness tokens wait; the busiest session's oldest dropped", MAX_WAITING
                )
            if was_empty:
                with contextlib.suppress(RuntimeError):  # the loop is closed
                    loop.call_soon_threadsafe(waiting.set)

        # zenoh-python's default (``indirect``): a Python thread runs ``heard``, through a queue with no bound; run
        # on Zenoh's own thread instead, history's replies stalled the loop's own declarations for seconds. What
        # waits there is what Zenoh itself already holds of each token (its key), and ``heard`` is cheap.
        self._token_sub = self.session.liveliness().declare_subscriber(
            f"@ros2_lv/{self.options.domain_id}/**", heard, history=True
        )

    def _deliver(self, name: str, items: list[Any]) -> None:
        if self.inbound is not None and name.startswith("in:"):
            self.inbound.deliver(name[3:], items)
            self._changed.set()

    async def _token_loop(self) -> None:
        """Handle waiting liveliness tokens, the lanes in turn; one task, so a token's going is never handled
        before its coming (handling one may wait for types loaded off the loop)."""
        while True:
            await self._tokens_waiting.wait()
            self._tokens_waiting.clear()
            while batch := self._lanes.take(TOKEN_BATCH):
                try:
                    await self._tokens(batch)
                except Exception as exc:  # a peer's token never ends the loop that reads them
                    _ratelog.warning("token", "ros2: handling liveliness tokens failed: %s", exc)

    async def _tokens(self, items: list[tuple[str | None, bool]]) -> None:
        inbound, inbox = self.inbound, self._inbox
        if inbound is None or inbox is None or self._closed:
            return
        for key, alive in items:
            if key is None:
                _ratelog.warning("token", "ros2: ignoring a liveliness token over %d characters", MAX_TOKEN_LENGTH)
                continue
            if "/SS/" in key and self.services is not None:  # cheap first look; the kind chunk decides
                try:
                    tok = parse_token(key)
                except RemoteProtocolError as exc:
                    _ratelog.warning("token", "ros2: ignoring a liveliness token: %s", exc)
                    continue
                if tok.kind is EntityKind.SERVICE:
                    if tok.zid != self._zid:
                        await self.services.token(tok, alive, key)
                    continue
            await inbound.token(
                key, alive, session=self.session, inbox=inbox, make_token=self._token, outbound=set(self.topics)
            )
            if self.demand and "/MS/" in key:
                self._graph_wake.set()
        self._changed.set()

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
        self._undeclare(self._token_sub)
        if self.inbound is not None:
            await self.inbound.aclose()
        if self.services is not None:
            await self.services.aclose()
        for bt in list(self.topics.values()):
            await self._drop(bt)
        self.topics.clear()
        if self._outbox is not None:
            await asyncio.to_thread(self._outbox.close)
        self._undeclare(self._node_token)
        if self.session is not None:
            await asyncio.to_thread(self.session.close)
        await self.node.aclose()

    async def __aenter__(self) -> Ros2Bridge:
        await self.start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()

    async def wait_until(self, predicate: Callable[[], bool], timeout: float) -> None:
        """Return once ``predicate()`` holds, checked after every change of the bridge.

        Raises:
            TimeoutError: it did not hold within ``timeout`` seconds.
        """
        async with backports.timeout(timeout):
            while not predicate():
                self._changed.clear()
                await self._changed.wait()

    async def _advertise_status(self) -> None:
        """``~status`` (std_srvs/Trigger): the bridge's status as JSON in ``message``, what ``mros ros2 status``
        reads; a plain ROS service, so any host that reaches the master can ask."""
        from mrosd.msg import get_service_class

        trigger = get_service_class("std_srvs/Trigger")

        def answer(_request: Any) -> Any:
            doc = status_document(
                zid=self._zid,
                domain_id=self.options.domain_id,
                mode=self.options.mode,
                distro=self.options.distro,
                router=self.options.router,
                to_ros2=self.status(),
                from_ros2=self.inbound_status(),
                services=self.services.status() if self.services is not None else [],
            )
            return trigger._response_class(success=True, message=json.dumps(doc))

        await self.node.advertise_service("~status", trigger, answer)

    def inbound_status(self) -> list[dict[str, Any]]:
        """One row per ROS 2 topic republished on ROS 1."""
        inbound, inbox = self.inbound, self._inbox
        if inbound is None:
            return []
        return inbound_rows(inbound.topics.values(), self.rates, inbox.dropped if inbox is not None else _none)

    def summary(self) -> str:
        """A few words for the daemon's status line."""
        services = self.services
        inbound = len(self.inbound.topics) if self.inbound is not None else 0
        count = len(services.offered) + len(services.provided) if services is not None else 0
        where = f"router {' '.join(self.options.listen)}" if self.options.router else f"domain {self.options.domain_id}"
        return f"ros2 {where}: {len(self.topics)} topic(s) to, {inbound} from, {count} service(s)"

    def _sample_rates(self) -> None:
        counts = {"out:" + bt.topic: bt.rmw.sent for bt in self.topics.values() if bt.rmw is not None}
        if self.inbound is not None:
            counts.update({"in:" + rt.topic: rt.received for rt in self.inbound.topics.values()})
        self.rates.sample(time.monotonic(), counts)

    def status(self) -> list[dict[str, Any]]:
        """One row per ROS 1 topic shown to ROS 2: names, key, counts and any problem."""
        outbox = self._outbox
        return outbound_rows(self.topics.values(), self.rates, outbox.dropped if outbox is not None else _none)

    # --- names -------------------------------------------------------------------------------------

    def _token(
        self,
        kind: EntityKind,
        topic: str = "",
        mapping: TypeMapping | Any = None,
        *,
        qos: Qos | None = None,
        type_hash: str = "",
    ) -> LivelinessToken:
        """The liveliness token of the bridge node (``mapping`` None) or of one of its endpoints; ``mapping``
        has ``ros2_type`` and ``type_hash`` (a message's or a service's); Humble's placeholder replaces the hash."""
        with self._lock:
            self._next_id += 1
            entity_id = "0" if kind is EntityKind.NODE else str(self._next_id)
        common: dict[str, Any] = {
            "domain_id": self.options.domain_id,
            "zid": self._zid,
            "nid": "0",
            "id": entity_id,
            "kind": kind,
            "enclave": "/",
            "namespace": "/",
            "node": self.options.node_name,
        }
        if mapping is None:
            return LivelinessToken(**common)
        return LivelinessToken(
            **common,
            topic=topic,
            type_name=dds_type_name(mapping.ros2_type),
            type_hash=type_hash or self._type_hash(mapping),
            qos=qos or Qos(),
        )

    def _type_hash(self, mapping: TypeMapping | Any) -> str:
        return HUMBLE_TYPE_HASH if self.options.humble else str(mapping.type_hash)

    @staticmethod
    def _undeclare(entity: Any) -> None:
        if entity is not None:
            with contextlib.suppress(Exception):
                entity.undeclare()

    # --- the ROS 1 graph ---------------------------------------------------------------------------

    async def _graph_loop(self) -> None:
        while True:
            try:
                pubs, _subs, srvs = await self.node.master.call("getSystemState")
                own = self.node.name
                received = self.inbound.topics if self.inbound is not None else {}
                want = {
                    str(topic)
                    for topic, nodes in pubs
                    if topic in self.filter
                    and topic not in received
                    and any(n != own for n in nodes)
                    and self._carriable(str(topic))
                    and self._demanded(str(topic))
                }
                for topic in sorted(want - set(self.topics)):
                    if len(self.topics) >= self.options.max_topics:
                        _ratelog.warning("max topics", "ros2: over %d topics to bridge", self.options.max_topics)
                        break
                    await self._add(topic)
                for topic in set(self.topics) - want:
                    await self._drop(self.topics.pop(topic))
                if self.services is not None:
                    await self.services.reconcile(srvs)
                if self.demand and self.inbound is not None and self._inbox is not None:
                    self.inbound.follow_demand(self.session, self._inbox, self._token)
                self._sample_rates()
                self.graph_reads += 1
                self._changed.set()
            except asyncio.CancelledError:
                raise
            except (MrosError, OSError, ValueError, TypeError) as exc:
                _ratelog.warning("graph", "ros2: cannot read the ROS 1 graph: %s", exc)
            with contextlib.suppress(TimeoutError):
                await backports.wait_for(self._graph_wake.wait(), GRAPH_PERIOD)
            self._graph_wake.clear()

    def _demanded(self, topic: str) -> bool:
        """Mode "demand": a ROS 1 topic crosses only while a ROS 2 subscriber (another session's) exists."""
        if not self.demand:
            return True
        return self.inbound is not None and topic in self.inbound.remote_subscribers

    def _carriable(self, topic: str) -> bool:
        """A ROS name in canonical form: anything else (a Zenoh wildcard, rmw_zenoh's ``%``, an empty chunk) that a
        stranger registered with the master would be another key on Zenoh, or none; refused, one line per name."""
        if is_valid_name(topic) and topic.startswith("/") and canonicalize(topic) == topic:
            return True
        if topic not in self._refused:
            if len(self._refused) >= MAX_REFUSED_NAMES:
                self._refused.clear()
            self._refused.add(topic)
            log.warning("ros2: %r is not a ROS name; not bridged", topic[:200])
        return False

    async def _add(self, topic: str) -> None:
        bt = BridgedTopic(topic)
        self.topics[topic] = bt
        try:
            bt.subscriber = await self.node.subscribe(
                topic, AnyMsg, callback=lambda msg: self._local_message(bt, msg), queue_size=self.options.queue_size
            )
        except MrosError as exc:
            _ratelog.warning(f"sub {topic}", "ros2: cannot subscribe to %s: %s", topic, exc)
            self.topics.pop(topic, None)
        self._changed.set()

    async def _drop(self, bt: BridgedTopic) -> None:
        if bt.mapping_task is not None:
            bt.mapping_task.cancel()
        self._undeclare(bt.token)
        if bt.rmw is not None:
            self._undeclare(bt.rmw.publisher)
        if self._outbox is not None and bt.key:
            self._outbox.forget(bt.key)
        if bt.subscriber is not None:
            with contextlib.suppress(MrosError, OSError):
                await bt.subscriber.aclose()
        self._changed.set()

    def _local_message(self, bt: BridgedTopic, msg: RawMessage) -> None:
        if bt.problem:
            return
        body = bytes(msg.data)
        if bt.rmw is None:
            bt.pending = body
            if bt.mapping_task is None:
                header = msg.header
                bt.mapping_task = asyncio.create_task(
                    self._map(bt, header.type or "", header.message_definition or "", header.latching == "1")
                )
            return
        if self._outbox is not None:
            self._outbox.put(bt.key, bt.rmw, body)

    async def _map(self, bt: BridgedTopic, ros1_type: str, definition: str, latched: bool) -> None:
        try:
            mapping = await asyncio.to_thread(self.mapper.mapping, ros1_type, definition)
        except UnmappableTypeError as exc:
            bt.problem = str(exc)
            log.warning("%s (topic %s is not bridged)", exc, bt.topic)
            self._changed.set()
            return
        if self.session is None or self._closed or self.topics.get(bt.topic) is not bt:
            return
        zenoh = self._zenoh
        import zenoh.ext as zenoh_ext

        bt.mapping = mapping
        bt.key = data_key(self.options.domain_id, bt.topic, mapping.ros2_type, self._type_hash(mapping))
        try:
            if latched:
                # A latched ROS 1 topic is TRANSIENT_LOCAL: as rmw_zenoh does, an advanced publisher detectable
                # through liveliness whose cache (depth 1: the latched message) answers late joiners' queries;
                # RELIABLE, so sporadic heartbeats let a subscriber that missed the last sample recover it.
                token = self._token(
                    EntityKind.PUBLISHER, bt.topic, mapping, qos=Qos(durability=DURABILITY_TRANSIENT_LOCAL, depth=1)
                )
                publisher = zenoh_ext.declare_advanced_publisher(
                    self.session,
                    bt.key,
                    congestion_control=zenoh.CongestionControl.BLOCK,
                    cache=zenoh_ext.CacheConfig(1),
                    publisher_detection=True,
                    sample_miss_detection=zenoh_ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=HEARTBEAT),
                )
            else:
                token = self._token(EntityKind.PUBLISHER, bt.topic, mapping, qos=Qos(depth=self.options.queue_size))
                publisher = self.session.declare_publisher(bt.key, congestion_control=zenoh.CongestionControl.BLOCK)
        except Exception as exc:  # Zenoh refused the key or the options: this topic alone does not cross
            bt.problem = f"ros2: {bt.topic}: Zenoh refused the publisher on {bt.key}: {exc}"
            log.warning("%s", bt.problem)
            self._changed.set()
            return
        bt.latched = latched
        bt.rmw = RmwPublisher(publisher, self.mapper, mapping, gid_of(token.key()))
        bt.token = self.session.liveliness().declare_token(token.key())
        log.info("ros2: %s (%s) -> %s", bt.topic, ros1_type, bt.key)
        if bt.pending is not None and self._outbox is not None:
            self._outbox.put(bt.key, bt.rmw, bt.pending)
            bt.pending = None
        self._changed.set()
