"""The one ROS side of every browser client: graph watch, shared raw subscriptions, client publishers.

Every WebSocket protocol (Foxglove, rosbridge, the page) is a thin client of one ``WebHub``:

- the graph comes from ``mrosd.master.client.watch_graph`` (pushed by an mrosd master, polled against
  rosmaster); each topic becomes a ``TopicInfo`` with the type's full message_definition, looked up where
  ``mrosd.msg.TypeStore`` looks (mrosd's definitions, ``ROS_PACKAGE_PATH``, ``/usr/share/<pkg>``), else read
  from a publisher's connection header (a short-lived raw subscription, as rosbridge does for unknown types);
- a topic that any client wants is subscribed once, raw (``AnyMsg``): each message body is handed as
  received (no decode, no copy) with its receipt time to every ``TopicSink`` holding the topic; the last
  sink to leave closes the subscription;
- a topic a client publishes is advertised once per topic (shared by the clients that advertise it).

No per-client buffering here: each sink owns its byte-bounded queue (``mrosd.web.queue``), so a slow client
costs only what its own queues hold.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from mrosd.errors import MrosError, MsgError, RemoteProtocolError
from mrosd.master.client import GraphSnapshot, MasterClient, watch_graph
from mrosd.msg import get_service_class, load_type
from mrosd.msg.loader import default_store
from mrosd.tcpros import Node
from mrosd.tcpros.subscriber import AnyMsg, RawMessage, Subscriber
from mrosd.web.access import AccessPolicy
from mrosd.web.assets import AssetReader
from mrosd.web.foxglove import SystemState
from mrosd.web.queue import Ledger
from mrosd.wire.header import MAX_HEADER_SIZE, ConnectionHeader, decode_connection_header, encode_header

log = logging.getLogger(__name__)

__all__ = ["GraphListener", "HoldingSink", "ServiceInfo", "TopicInfo", "TopicSink", "WebHub", "split_rosrpc"]

#: How long a probe waits for a publisher's connection header before the topic stays unadvertised.
PROBE_TIMEOUT = 5.0
#: Bytes queued for all clients together (each client also has its own budget, SessionLimits.client_bytes).
MAX_QUEUED_BYTES = 256 * 1024 * 1024
#: Seconds before a topic whose probe found no publisher's definition is probed again.
PROBE_RETRY = 30.0
#: Probes in flight at once (each is one TCPROS connection to a publisher).
MAX_PROBES = 8
#: When every client of a topic holds at least this many bytes of it not yet sent, the hub stops reading the
#: topic's TCPROS connections until one catches up: the bridge then receives what its fastest client takes,
#: not everything the publisher sends (the publisher's per-subscriber queue drops the rest, as for any slow
#: subscriber). Clients that fall further behind still drop from their own queues.
PAUSE_BYTES = 4 * 1024 * 1024


def split_rosrpc(uri: str) -> tuple[str, int]:
    """``rosrpc://host:port`` -> ``(host, port)`` (IPv6 brackets removed).

    Raises:
        MrosError: not a rosrpc URI with a port.
    """
    if not uri.startswith("rosrpc://"):
        raise MrosError(f"not a rosrpc URI: {uri!r}")
    host, _, port = uri[len("rosrpc://") :].rstrip("/").rpartition(":")
    if not host or not port.isdigit():
        raise MrosError(f"not a rosrpc URI: {uri!r}")
    return host.strip("[]"), int(port)


#: Where simulated time comes from, as in rospy and roscpp, and the parameter that turns it on.
CLOCK_TOPIC = "/clock"
SIM_TIME_PARAM = "/use_sim_time"


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


class _ClockSink(HoldingSink):
    """The hub's own sink on /clock: rosgraph_msgs/Clock is one time (uint32 secs, uint32 nsecs)."""

    def __init__(self, hub: WebHub) -> None:
        self.hub = hub

    def deliver(self, topic: str, body: bytes | bytearray, receipt_ns: int) -> None:
        if len(body) != 8:
            return
        secs = int.from_bytes(body[:4], "little")
        nsecs = int.from_bytes(body[4:], "little")
        now = self.hub.clock_ns = secs * 1_000_000_000 + nsecs
        for listener in list(self.hub.time_listeners):
            try:
                listener(now)
            except Exception:
                log.exception("web: a time listener failed")


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


class GraphListener(Protocol):
    """Told about topics that became advertisable or went away, and about every graph change."""

    def topics_changed(self, added: list[TopicInfo], removed: list[TopicInfo]) -> None: ...

    def graph_changed(self, graph: GraphSnapshot) -> None: ...

    def services_changed(self, added: list[ServiceInfo], removed: list[ServiceInfo]) -> None: ...


@dataclass(frozen=True, slots=True)
class TopicInfo:
    """A topic a client can subscribe to: ``id`` is stable for as long as its type stays the same."""

    id: int
    name: str
    type: str
    definition: str


@dataclass(frozen=True, slots=True)
class ServiceInfo:
    """A service a client can call: its type as the server told a probe, and both halves' definitions."""

    id: int
    name: str
    type: str
    request_definition: str
    response_definition: str


@dataclass(slots=True)
class _Shared:
    """One raw subscription and the sinks that share it."""

    subscriber: Subscriber
    sinks: list[TopicSink] = field(default_factory=list)
    messages: int = 0
    bytes: int = 0
    #: reading from the publishers is paused: every sink is behind (see WebHub.resume)
    paused: bool = False


@dataclass(slots=True)
class _SharedPublisher:
    publisher: Any
    msg_class: Any
    owners: int = 0


class WebHub:
    """The ROS node behind the browser protocols (``name`` is its node name in the graph)."""

    def __init__(
        self,
        master_uri: str,
        *,
        name: str = "mrosd_web",
        policy: AccessPolicy | None = None,
        poll_interval: float = 0.5,
        host: str | None = None,
        max_queued_bytes: int = MAX_QUEUED_BYTES,
        assets: AssetReader | None = None,
    ) -> None:
        self.master_uri = master_uri
        #: serves fetchAsset for every client (None: the ``assets`` capability is not offered)
        self.assets = assets
        #: every client queue of every protocol counts its bytes here; beyond max_queued_bytes the fullest
        #: client sheds its oldest messages (per-client budgets alone let N clients hold N budgets)
        self.ledger = Ledger()
        self.max_queued_bytes = max_queued_bytes
        self.policy = policy or AccessPolicy()
        self.poll_interval = poll_interval
        self.node = Node(name, master_uri=master_uri, argv=[], rosout=False, logger_services=False, host=host)
        self.graph = GraphSnapshot()
        #: advertisable topics by name (allowed by the policy, with a known definition)
        self.topics: dict[str, TopicInfo] = {}
        self.listeners: set[GraphListener] = set()
        self._ids = itertools.count(1)
        self._shared: dict[str, _Shared] = {}
        self._publishers: dict[str, _SharedPublisher] = {}
        self._probing: dict[str, asyncio.Task[None]] = {}
        self._probe_slots = asyncio.Semaphore(MAX_PROBES)
        self._unresolved: dict[str, str] = {}
        #: topic -> when its last probe found no definition (probed again PROBE_RETRY seconds later at most:
        #: a probe registers a subscriber, which changes the graph, which would start the next probe)
        self._probe_failed: dict[str, float] = {}
        self._watch: asyncio.Task[None] | None = None
        self._first_graph: asyncio.Future[None] | None = None
        self._lock = asyncio.Lock()
        #: called with the full system state after every graph change, while any is registered
        self.state_listeners: set[Callable[[SystemState], None]] = set()
        self._state_task: asyncio.Task[None] | None = None
        self._params: dict[str, set[Callable[[str, Any], None]]] = {}
        #: callable services by name (allowed by the policy, type probed, definitions found)
        self.services: dict[str, ServiceInfo] = {}
        self._service_probes: dict[str, asyncio.Task[None]] = {}
        #: services whose probe failed, with the provider it failed for (probed again when it changes)
        self._service_failed: dict[str, str] = {}
        #: /use_sim_time is true (followed through the master's paramUpdate, as it changes): /clock is
        #: followed and its time handed out
        self.sim_time = False
        #: the latest /clock time (ns since its epoch); 0 before the first, as ROS time under sim time
        self.clock_ns = 0
        #: called with /clock's time (ns) for every message on it, while sim_time
        self.time_listeners: set[Callable[[int], None]] = set()
        #: called with the new sim_time each time it changes
        self.sim_time_listeners: set[Callable[[bool], None]] = set()
        self._clock_sink = _ClockSink(self)
        #: what /use_sim_time last said, and the task bringing sim_time (and the /clock sink) in line with it
        self._want_sim_time = False
        self._sim_task: asyncio.Task[None] | None = None

    # --- lifecycle -------------------------------------------------------------------------------

    async def start(self, timeout: float = 10.0) -> None:
        """Start the node and the graph watch; returns once the first graph is known.

        Raises:
            MasterUnreachableError: no master answers.
            TimeoutError: the first graph did not arrive within ``timeout`` seconds.
        """
        await self.node.start()
        loop = asyncio.get_running_loop()
        self._first_graph = loop.create_future()
        self._watch = loop.create_task(self._watch_graph(), name="web graph watch")
        try:
            async with asyncio.timeout(timeout):
                await asyncio.shield(self._first_graph)
                # its value comes with the subscription: the first clients already see the right capabilities
                try:
                    value = await self.watch_param(SIM_TIME_PARAM, self._sim_time_param, check=False)
                except MrosError as exc:  # every ROS 1 master has subscribeParam; still, never fail the hub for it
                    log.warning("web: cannot follow %s (%s): wall time", SIM_TIME_PARAM, exc)
                    value = False
                self._sim_time_param(SIM_TIME_PARAM, value)
                assert self._sim_task is not None
                await asyncio.shield(self._sim_task)
        except BaseException:
            await self.aclose()
            raise

    async def aclose(self) -> None:
        """Stop watching, close every shared subscription and publisher, and the node."""
        tasks = [
            t
            for t in (
                self._watch,
                self._state_task,
                self._sim_task,
                *self._probing.values(),
                *self._service_probes.values(),
            )
            if t is not None
        ]
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        self._watch = None
        self._probing.clear()
        shared, self._shared = self._shared, {}
        for entry in shared.values():
            entry.sinks.clear()
        self._publishers.clear()
        if self.assets is not None:
            self.assets.close()
        await self.node.aclose()

    # --- simulated time --------------------------------------------------------------------------

    def _sim_time_param(self, _key: str, value: Any) -> None:
        """The master's paramUpdate of /use_sim_time (a callback: the change itself runs in a task, in order)."""
        self._want_sim_time = bool(value)  # as rospy reads it; {} (the master's "unset") is false
        if self._sim_task is None or self._sim_task.done():
            self._sim_task = asyncio.get_running_loop().create_task(self._follow_sim_time(), name="web sim time")

    async def _follow_sim_time(self) -> None:
        """Follow /clock while /use_sim_time is true, not otherwise; tell the listeners of each change."""
        while self.sim_time != self._want_sim_time:
            if self._want_sim_time:
                try:
                    await self.add_sink(CLOCK_TOPIC, self._clock_sink, check=False)
                except MrosError as exc:
                    log.warning("web: /use_sim_time is true but %s cannot be followed: %s", CLOCK_TOPIC, exc)
                    return
                self.sim_time = True
            else:
                self.sim_time = False
                await self.remove_sink(CLOCK_TOPIC, self._clock_sink)
            log.info(
                "web: /use_sim_time is %s: %s", self.sim_time, "following /clock" if self.sim_time else "wall time"
            )
            for listener in list(self.sim_time_listeners):
                try:
                    listener(self.sim_time)
                except Exception:
                    log.exception("web: a sim time listener failed")

    # --- the graph -------------------------------------------------------------------------------

    async def _watch_graph(self) -> None:
        client = MasterClient(self.master_uri, self.node.name, self.node.xmlrpc, timeout=5.0)
        first = self._first_graph
        try:
            async for graph in watch_graph(client, poll_interval=self.poll_interval):
                self._apply_graph(graph)
                if first is not None and not first.done():
                    first.set_result(None)
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            if first is not None and not first.done():
                first.set_exception(exc)
            else:
                log.exception("web: the graph watch ended")

    def _apply_graph(self, graph: GraphSnapshot) -> None:
        self.graph = graph
        added: list[TopicInfo] = []
        removed: list[TopicInfo] = []
        for name, info in list(self.topics.items()):
            if graph.topics.get(name) != info.type:
                removed.append(self.topics.pop(name))
        for name, msg_type in graph.topics.items():
            if name in self.topics or msg_type in ("", "*") or not self.policy.allows_topic(name):
                continue
            definition = self._definition(msg_type)
            if definition is None:
                self._start_probe(name, msg_type)
                continue
            info = TopicInfo(next(self._ids), name, msg_type, definition)
            self.topics[name] = info
            added.append(info)
        if added or removed:
            self._notify_topics(added, removed)
        gone = [self.services.pop(n) for n in list(self.services) if n not in graph.services]
        if gone:
            self._notify_services([], gone)
        for name, provider in graph.services.items():
            if name in self.services or name in self._service_probes or not self.policy.allows_service(name):
                continue
            if self._service_failed.get(name) == provider:
                continue
            self._service_probes[name] = asyncio.get_running_loop().create_task(
                self._probe_service(name, provider), name=f"web probe {name}"
            )
        for listener in list(self.listeners):
            try:
                listener.graph_changed(graph)
            except Exception:
                log.exception("web: a graph listener failed")
        if self.state_listeners:
            self.refresh_state()

    async def system_state(self) -> SystemState:
        """Publishers, subscribers and services with their nodes (one getSystemState), filtered by the policy."""
        pubs, subs, srvs = await self.node.master.get_system_state()
        allow_t, allow_s = self.policy.allows_topic, self.policy.allows_service
        return (
            {n: ids for n, ids in pubs if allow_t(n)},
            {n: ids for n, ids in subs if allow_t(n)},
            {n: ids for n, ids in srvs if allow_s(n)},
        )

    def refresh_state(self) -> None:
        """Fetch the system state once (coalesced) and hand it to every state listener."""
        if self._state_task is not None and not self._state_task.done():
            return
        self._state_task = asyncio.get_running_loop().create_task(self._push_state(), name="web system state")

    async def _push_state(self) -> None:
        try:
            state = await self.system_state()
        except MrosError as exc:
            log.info("web: getSystemState failed: %s", exc)
            return
        for listener in list(self.state_listeners):
            try:
                listener(state)
            except Exception:
                log.exception("web: a state listener failed")

    def _notify_topics(self, added: list[TopicInfo], removed: list[TopicInfo]) -> None:
        for listener in list(self.listeners):
            try:
                listener.topics_changed(added, removed)
            except Exception:
                log.exception("web: a topic listener failed")

    def _notify_services(self, added: list[ServiceInfo], removed: list[ServiceInfo]) -> None:
        for listener in list(self.listeners):
            try:
                listener.services_changed(added, removed)
            except Exception:
                log.exception("web: a service listener failed")

    async def _probe_service(self, name: str, provider: str) -> None:
        """Ask the service its type with a ``probe=1`` connection header, as roscpp's tools do."""
        try:
            async with self._probe_slots:
                srv_type = await self._service_type(name)
                store = default_store()
                spec = store.srv_spec(srv_type)
                info = ServiceInfo(
                    next(self._ids),
                    name,
                    srv_type,
                    store.full_text(spec.request.full_name),
                    store.full_text(spec.response.full_name),
                )
        except (MrosError, OSError, TimeoutError) as exc:
            self._service_failed[name] = provider
            log.info("web: service %s is not offered to clients: %s", name, exc)
            return
        finally:
            self._service_probes.pop(name, None)
        if self.graph.services.get(name) == provider and name not in self.services:
            self.services[name] = info
            self._notify_services([info], [])

    async def probe_service_type(self, name: str) -> str:
        """The type of service ``name`` asked now (lookupService, then a probe), for a call that comes before
        the graph watch has seen the service: rosbridge looks a service's type up at call time too.

        Raises:
            MrosError: the master does not know it, or its server refused the probe.
            OSError, TimeoutError: its server could not be reached in time.
        """
        async with self._probe_slots:
            return await self._service_type(name)

    async def _service_type(self, name: str) -> str:
        uri = await self.node.master.lookup_service(name)
        host, port = split_rosrpc(uri)
        async with asyncio.timeout(PROBE_TIMEOUT):
            reader, writer = await asyncio.open_connection(host, port)
            try:
                writer.write(
                    encode_header(ConnectionHeader(callerid=self.node.name, service=name, md5sum="*", probe="1"))
                )
                size = int.from_bytes(await reader.readexactly(4), "little")
                if size > MAX_HEADER_SIZE:
                    raise RemoteProtocolError(f"service {name}: header of {size} bytes")
                header = decode_connection_header(await reader.readexactly(size))
            finally:
                writer.close()
        if header.error:
            raise RemoteProtocolError(f"service {name} refused the probe: {header.error}")
        if not header.type:
            raise RemoteProtocolError(f"service {name} did not say its type")
        return header.type

    async def call_service(self, name: str, request: bytes | bytearray | memoryview, timeout: float = 10.0) -> bytes:
        """Call a service with a serialized request; returns the serialized response.

        The request is decoded once before it is sent (a malformed one is refused here, not by the server).

        Raises:
            MrosError: not offered, a malformed request, or the call failed (ServiceError says why).
            TimeoutError: no answer within ``timeout`` seconds.
        """
        info = self.services.get(name)
        if info is None:
            raise MrosError(f"service {name} is not offered (unknown, not allowed, or its type is unknown)")
        srv_class = get_service_class(info.type)
        req = srv_class._request_class.deserialize(bytes(request))
        proxy = self.node.service_proxy(name, srv_class)
        response = await proxy.call(req, timeout=timeout)
        return bytes(response.serialize())

    def _definition(self, msg_type: str) -> str | None:
        if msg_type in self._unresolved:
            return None
        try:
            return default_store().full_text(msg_type)
        except MsgError as exc:
            self._unresolved[msg_type] = str(exc)
            return None

    def _start_probe(self, topic: str, msg_type: str) -> None:
        loop = asyncio.get_running_loop()
        if topic in self._probing or loop.time() - self._probe_failed.get(topic, -PROBE_RETRY) < PROBE_RETRY:
            return
        task = loop.create_task(self._probe(topic, msg_type), name=f"web probe {topic}")
        self._probing[topic] = task

    async def _probe(self, topic: str, msg_type: str) -> None:
        """Read the type's message_definition from a publisher's connection header (short-lived raw subscription)."""
        try:
            async with self._probe_slots:
                definition = await self._definition_from_publisher(topic)
            if definition is None:
                self._probe_failed[topic] = asyncio.get_running_loop().time()
                return
            if self.graph.topics.get(topic) != msg_type or topic in self.topics:
                return
            try:
                load_type(msg_type, definition)  # refuse a definition that does not parse before advertising it
            except MsgError as exc:
                log.warning("web: %s: the publisher's definition of %s does not parse: %s", topic, msg_type, exc)
                return
            info = TopicInfo(next(self._ids), topic, msg_type, definition)
            self.topics[topic] = info
            self._notify_topics([info], [])
        finally:
            self._probing.pop(topic, None)

    async def _definition_from_publisher(self, topic: str) -> str | None:
        entry = self._shared.get(topic)
        if entry is not None:
            return await self._header_definition(entry.subscriber)
        sub = await self._subscribe(topic)
        try:
            return await self._header_definition(sub)
        finally:
            if topic not in self._shared:
                await sub.aclose()

    @staticmethod
    async def _header_definition(sub: Subscriber) -> str | None:
        try:
            await sub.wait_for_publishers(1, timeout=PROBE_TIMEOUT)
        except TimeoutError:
            return None
        for link in sub.links.values():
            if link.header is not None and link.header.message_definition:
                return link.header.message_definition
        return None

    async def _subscribe(self, topic: str) -> Subscriber:
        return await self.node.subscribe(topic, AnyMsg, callback=self._raw_callback(topic))

    # --- shared subscriptions --------------------------------------------------------------------

    def _raw_callback(self, topic: str) -> Callable[[RawMessage], None]:
        def deliver(msg: RawMessage) -> None:
            entry = self._shared.get(topic)
            if entry is None:
                return
            now = time.time_ns()
            body = msg.data
            entry.messages += 1
            entry.bytes += len(body)
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
        sinks = {id(s): s for e in self._shared.values() for s in e.sinks}.values()
        while self.ledger.size > self.max_queued_bytes:
            fullest = max(sinks, key=lambda s: s.queued(), default=None)
            if fullest is None or fullest.queued() == 0:
                return
            fullest.shed_oldest()

    @staticmethod
    def _set_reading(entry: _Shared, reading: bool) -> None:
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

    def resume(self, topic: str) -> None:
        """A sink of ``topic`` caught up: read from the publishers again (no-op unless paused)."""
        entry = self._shared.get(topic)
        if entry is not None and entry.paused:
            self._set_reading(entry, True)

    async def add_sink(self, topic: str, sink: TopicSink, *, check: bool = True) -> None:
        """Give ``sink`` every message of ``topic`` (subscribing on the first sink).

        Raises:
            MrosError: the topic is not allowed, or the master refused the subscription.
        """
        if check and not self.policy.allows_topic(topic):
            raise MrosError(f"topic {topic} is not allowed by the [web] topics allow-list")
        async with self._lock:
            entry = self._shared.get(topic)
            if entry is None:
                probe = self._probing.get(topic)
                if probe is not None:  # a probe holds the node's subscription to this topic
                    await asyncio.gather(probe, return_exceptions=True)
                entry = _Shared(await self._subscribe(topic))
                self._shared[topic] = entry
            if sink not in entry.sinks:
                entry.sinks.append(sink)
            if entry.paused:
                self._set_reading(entry, True)  # a newcomer is not behind: nothing else would wake the topic

    async def remove_sink(self, topic: str, sink: TopicSink) -> None:
        """Stop giving ``sink`` the topic; the last sink closes the subscription."""
        async with self._lock:
            entry = self._shared.get(topic)
            if entry is None:
                return
            with contextlib.suppress(ValueError):
                entry.sinks.remove(sink)
            if entry.paused:
                self._set_reading(entry, True)  # the sink that left may have been the one holding it
            if not entry.sinks:
                del self._shared[topic]
                await entry.subscriber.aclose()

    def topic_stats(self, topic: str) -> tuple[int, int] | None:
        """``(messages, bytes)`` received on a shared subscription since it opened (None: not subscribed)."""
        entry = self._shared.get(topic)
        return None if entry is None else (entry.messages, entry.bytes)

    def sink_count(self, topic: str) -> int:
        entry = self._shared.get(topic)
        return 0 if entry is None else len(entry.sinks)

    # --- client publishers -----------------------------------------------------------------------

    def message_class(self, msg_type: str, definition: str | None = None) -> Any:
        """The class of a type a client names (its own definition first, then the type search path).

        Raises:
            MsgError: unknown type (the message names where it was looked for) or a malformed definition.
        """
        return load_type(msg_type, definition or "")

    async def acquire_publisher(self, topic: str, msg_class: Any) -> Any:
        """The shared publisher of ``topic`` (advertised at the first owner).

        Raises:
            MrosError: not allowed, another type already published here, or the master refused.
        """
        if not self.policy.allows_topic(topic):
            raise MrosError(f"topic {topic} is not allowed by the [web] topics allow-list")
        async with self._lock:
            entry = self._publishers.get(topic)
            if entry is None:
                pub = await self.node.advertise(topic, msg_class, queue_size=100)
                entry = _SharedPublisher(pub, msg_class)
                self._publishers[topic] = entry
            elif entry.msg_class._md5sum != msg_class._md5sum:
                raise MrosError(f"{topic} is already published by a web client as {entry.msg_class._type}")
            entry.owners += 1
            return entry.publisher

    async def release_publisher(self, topic: str) -> None:
        async with self._lock:
            entry = self._publishers.get(topic)
            if entry is None:
                return
            entry.owners -= 1
            if entry.owners <= 0:
                del self._publishers[topic]
                await entry.publisher.aclose()

    # --- parameters ------------------------------------------------------------------------------

    async def watch_param(self, name: str, callback: Callable[[str, Any], None], *, check: bool = True) -> Any:
        """Call ``callback(key, value)`` on every update of ``name`` (one master subscription per name).

        ``check=False`` is the hub's own watch (``/use_sim_time``), not a client's: the allow-list does not
        apply. Returns the value the master answered the subscription with (``{}``: unset), or None when the
        name was already watched.

        Raises:
            MrosError: not allowed, or the master refused the subscription.
        """
        if check and not self.policy.allows_param(name):
            raise MrosError(f"parameter {name} is not allowed by the [web] params allow-list")
        callbacks = self._params.get(name)
        value = None
        if callbacks is None:
            callbacks = self._params[name] = set()
            try:
                value = await self.node.subscribe_param(name, lambda key, value: self._param_update(name, key, value))
            except BaseException:
                del self._params[name]
                raise
        callbacks.add(callback)
        return value

    def _param_update(self, name: str, key: str, value: Any) -> None:
        for cb in list(self._params.get(name, ())):
            try:
                cb(key, value)
            except Exception:
                log.exception("web: a parameter listener failed")

    async def unwatch_param(self, name: str, callback: Callable[[str, Any], None]) -> None:
        callbacks = self._params.get(name)
        if callbacks is None:
            return
        callbacks.discard(callback)
        if not callbacks:
            del self._params[name]
            await self.node.unsubscribe_param(name)
