"""The one ROS side of every browser client: the graph it may show, its types, and what it subscribes.

Every WebSocket protocol (Foxglove, rosbridge, the page) is a thin client of one ``WebHub``:

- the graph is followed name by name (``mrosd.web.graphwatch``: the daemon's own master tells the hub what
  each registration changed; another master is long-polled or polled and diffed), so a registration costs
  the hub O(1);
- each topic becomes a ``TopicInfo`` with the type's full message_definition, looked up where
  ``mrosd.msg.TypeStore`` looks (mrosd's definitions, ``ROS_PACKAGE_PATH``, ``/usr/share/<pkg>``); a type found
  nowhere there is learnt from a publisher's connection header, and a service's type from a ``probe=1``
  connection to its server, but only while a browser client is connected (nobody else asked: a node sees
  no subscriber that no client wanted). Probes are bounded per peer and in all (``mrosd.web.probes``); a
  publisher that failed one is not probed again until the topic's publishers change;
- a topic that any client wants is subscribed once, raw, and shared by the clients' sinks
  (``mrosd.web.shared``);
- a topic a client publishes is advertised once per topic (shared by the clients that advertise it).
"""

from __future__ import annotations

import asyncio
import itertools
import logging
from collections.abc import Callable
from typing import Any

from mrosd import backports
from mrosd.errors import MrosError, MsgError, RemoteProtocolError
from mrosd.lograte import RateLimitedLog
from mrosd.master.client import MasterClient
from mrosd.msg import get_service_class, load_type_async
from mrosd.msg.loader import default_store
from mrosd.tcpros import Node
from mrosd.web.access import AccessPolicy
from mrosd.web.assets import AssetReader
from mrosd.web.clientwrites import ClientWrites
from mrosd.web.compressed import COMPRESSED_TYPE, CompressedTopics, VirtualSubscriptions
from mrosd.web.foxglove import SystemState
from mrosd.web.graphwatch import (
    ClientSet,
    GraphListener,
    GraphSource,
    LiveGraph,
    ServiceInfo,
    TopicInfo,
    graph_deltas,
)
from mrosd.web.probes import Attempt, ProbePool, definition_from_publisher, service_type, split_rosrpc
from mrosd.web.queue import Ledger
from mrosd.web.shared import MAX_QUEUED_BYTES, PAUSE_BYTES, HoldingSink, Shared, TopicSink

log = logging.getLogger(__name__)
#: a rogue node can make every one of its hundreds of services fail a probe: a few lines, then a count
_ratelog = RateLimitedLog(log)

__all__ = [
    "PAUSE_BYTES",
    "GraphListener",
    "HoldingSink",
    "ServiceInfo",
    "TopicInfo",
    "TopicSink",
    "WebHub",
    "split_rosrpc",
]

#: Where simulated time comes from, as in rospy and roscpp, and the parameter that turns it on.
CLOCK_TOPIC = "/clock"
SIM_TIME_PARAM = "/use_sim_time"


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


class WebHub:
    """The ROS node behind the browser protocols (``name`` is its node name in the graph).

    ``use_master(master)`` before ``start()`` follows the graph from a master in this process (the daemon's)
    instead of over XML-RPC.
    """

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
        self.policy = policy or AccessPolicy()
        self.poll_interval = poll_interval
        self.node = Node(name, master_uri=master_uri, argv=[], rosout=False, logger_services=False, host=host)
        #: ``T/compressed`` for every Image topic ``T`` that has no real one (``mrosd.web.compressed``)
        self.compressed = CompressedTopics(
            lambda topic, sink: self.add_sink(topic, sink, check=False),
            self.remove_sink,
            hold_raw=self._hold_raw,
            resume_raw=self.resume,
        )
        self.subs = VirtualSubscriptions(
            self.node, self.compressed, max_queued_bytes=max_queued_bytes, before_subscribe=self._unprobe
        )
        #: subscriptions being moved between a made T/compressed and a real one
        self._reconciles: set[asyncio.Task[None]] = set()
        self.probes = ProbePool()
        self.local_master: GraphSource | None = None
        self.graph = LiveGraph()
        #: advertisable topics by name (allowed by the policy, with a known definition)
        self.topics: dict[str, TopicInfo] = {}
        #: callable services by name (allowed by the policy, type probed, definitions found)
        self.services: dict[str, ServiceInfo] = {}
        self.listeners: set[GraphListener] = ClientSet(self._client_arrived)
        self._ids = itertools.count(1)
        self._unresolved: dict[str, str] = {}
        #: topics whose type only a publisher can tell (name -> type), and the publishers a probe failed for
        self._topic_wanted: dict[str, str] = {}
        self._topic_failed: dict[str, tuple[str, ...]] = {}
        #: services not probed yet (name -> provider), and the provider a probe failed for
        self._service_wanted: dict[str, str] = {}
        self._service_failed: dict[str, str] = {}
        self._watch: asyncio.Task[None] | None = None
        self._first_graph: asyncio.Future[None] | None = None
        #: called with the full system state after every graph change, while any is registered
        self.state_listeners: set[Callable[[SystemState], None]] = set()
        self._state_again = False
        self._state_task: asyncio.Task[None] | None = None
        #: the publishers and parameter watches clients asked for
        self.writes = ClientWrites(self.node, self.policy)
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

    @property
    def ledger(self) -> Ledger:
        """Every client queue of every protocol counts its bytes here (``SharedSubscriptions.ledger``)."""
        return self.subs.ledger

    @property
    def max_queued_bytes(self) -> int:
        return self.subs.max_queued_bytes

    @max_queued_bytes.setter
    def max_queued_bytes(self, value: int) -> None:
        self.subs.max_queued_bytes = value

    @property
    def _shared(self) -> dict[str, Shared]:
        return self.subs.entries

    def use_master(self, master: GraphSource) -> None:
        """Follow the graph from ``master``, running in this process (before ``start``)."""
        self.local_master = master

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
            async with backports.timeout(timeout):
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
        """Stop watching and probing, close every shared subscription and publisher, and the node."""
        tasks = [t for t in (self._watch, self._state_task, self._sim_task, *self._reconciles) if t is not None]
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        await self.probes.aclose()
        await self.compressed.aclose()
        self._watch = None
        self.subs.close()
        self.writes.publishers.clear()
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
            async for delta in graph_deltas(client, local=self.local_master, poll_interval=self.poll_interval):
                self.graph.apply(delta)
                self._topics_changed(delta.topics.keys() | delta.publishers.keys())
                self._services_changed(set(delta.services))
                if self.state_listeners:
                    self.refresh_state()
                if first is not None and not first.done():
                    first.set_result(None)
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            if first is not None and not first.done():
                first.set_exception(exc)
            else:
                log.exception("web: the graph watch ended")

    def _topics_changed(self, names: set[str]) -> None:
        added: list[TopicInfo] = []
        removed: list[TopicInfo] = []
        for name in names | self.compressed.affected(names):
            changed = self.compressed.update(name, self.graph.topics, self.graph.publishers, self.policy.allows_topic)
            if changed is not None and name in self.subs.entries:
                self._reconciles.add(asyncio.get_running_loop().create_task(self.subs.reconcile(name)))
                self._reconciles = {t for t in self._reconciles if not t.done()}
            msg_type = COMPRESSED_TYPE if name in self.compressed.virtual else self.graph.topics.get(name)
            info = self.topics.get(name)
            if info is not None and info.type == msg_type and changed is None:
                continue
            if info is not None:
                removed.append(self.topics.pop(name))
            self._topic_wanted.pop(name, None)
            if msg_type is None:
                self._topic_failed.pop(name, None)
                self.probes.discard(f"topic {name}")
                continue
            if msg_type in ("", "*") or not self.policy.allows_topic(name):
                continue
            definition = self._definition(msg_type)
            if definition is None:
                self._topic_wanted[name] = msg_type
                self._probe_topic(name)
                continue
            info = TopicInfo(next(self._ids), name, msg_type, definition)
            self.topics[name] = info
            added.append(info)
        if added or removed:
            self._notify_topics(added, removed)

    def _services_changed(self, names: set[str]) -> None:
        gone: list[ServiceInfo] = []
        for name in names:
            provider = self.graph.services.get(name)
            if provider is None:
                if name in self.services:
                    gone.append(self.services.pop(name))
                self._service_wanted.pop(name, None)
                self._service_failed.pop(name, None)
                self.probes.discard(f"service {name}")
                continue
            if name in self.services or not self.policy.allows_service(name):
                continue
            if self._service_failed.get(name) == provider:
                continue
            self._service_wanted[name] = provider
            self._probe_service(name)
        if gone:
            self._notify_services([], gone)

    def _client_arrived(self) -> None:
        """The first client connected: learn the types that waited for one."""
        for name in list(self._topic_wanted):
            self._probe_topic(name)
        for name in list(self._service_wanted):
            self._probe_service(name)

    def topic_types(self) -> dict[str, str]:
        """Every topic of the graph with its type, and the ``T/compressed`` topics made here (rosapi lists both)."""
        types = dict(self.graph.topics)
        types.update(dict.fromkeys(self.compressed.virtual, COMPRESSED_TYPE))
        return types

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
        """Fetch the system state (coalesced: a change during a fetch means one more fetch after it, so the
        listeners always end with a state newer than the change) and hand it to every state listener."""
        if self._state_task is not None and not self._state_task.done():
            self._state_again = True
            return
        self._state_task = asyncio.get_running_loop().create_task(self._push_state(), name="web system state")

    async def _push_state(self) -> None:
        while True:
            self._state_again = False
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
            if not self._state_again:
                return

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

    # --- types: services -------------------------------------------------------------------------

    def _probe_service(self, name: str) -> None:
        provider = self._service_wanted.get(name)
        if provider is None or not self.listeners:  # nobody asked yet
            return

        async def probe(attempt: Attempt) -> None:
            srv_type = await service_type(self.node, name, attempt)
            store = default_store()
            spec = store.srv_spec(srv_type)
            request, response = store.full_text(spec.request.full_name), store.full_text(spec.response.full_name)
            if self.graph.services.get(name) != provider or name in self.services:
                return
            self._service_wanted.pop(name, None)
            info = ServiceInfo(next(self._ids), name, srv_type, request, response)
            self.services[name] = info
            self._notify_services([info], [])

        def failed(reason: str) -> None:
            self._service_wanted.pop(name, None)
            self._service_failed[name] = provider
            _ratelog.log(logging.INFO, "service probe", "web: service %s is not offered: %s", name, reason)

        self.probes.submit(provider, f"service {name}", probe, failed)

    async def probe_service_type(self, name: str) -> str:
        """The type of service ``name`` asked now (lookupService, then a probe), for a call that comes before
        the hub knows it: rosbridge looks a service's type up at call time too. It never waits behind other
        probes, and fails within ``ProbePool.lookup_timeout``.

        Raises:
            MrosError: the master does not know it, its server refused the probe or is quarantined, or too
                many lookups are in flight.
            OSError, TimeoutError: its server could not be reached in time.
        """
        peer = self.graph.services.get(name) or name
        return await self.probes.lookup(peer, lambda attempt: service_type(self.node, name, attempt))

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

    # --- types: topics ---------------------------------------------------------------------------

    def _definition(self, msg_type: str) -> str | None:
        if msg_type in self._unresolved:
            return None
        try:
            return default_store().full_text(msg_type)
        except MsgError as exc:
            self._unresolved[msg_type] = str(exc)
            return None

    def _probe_topic(self, name: str) -> None:
        """Learn a topic's definition from a publisher's connection header, once a client is there to ask."""
        msg_type = self._topic_wanted.get(name)
        publishers = self.graph.publishers.get(name, ())
        if msg_type is None or not publishers or not self.listeners or self._topic_failed.get(name) == publishers:
            return

        async def probe(_attempt: Attempt) -> None:
            definition = await definition_from_publisher(self.subs, name, self.probes.timeout + 1.0)
            if not definition:
                raise RemoteProtocolError(f"no publisher of {name} sent its type's definition")
            try:  # refuse a definition that does not parse before advertising it (built off the loop)
                await load_type_async(msg_type, definition)
            except MsgError as exc:
                raise RemoteProtocolError(f"the publisher's definition of {msg_type} does not parse: {exc}") from None
            if self.graph.topics.get(name) != msg_type or name in self.topics:
                return
            self._topic_wanted.pop(name, None)
            info = TopicInfo(next(self._ids), name, msg_type, definition)
            self.topics[name] = info
            self._notify_topics([info], [])

        def failed(reason: str) -> None:
            self._topic_failed[name] = publishers  # not again until the topic's publishers change
            _ratelog.log(logging.INFO, "topic probe", "web: topic %s is not offered to clients: %s", name, reason)

        # the probe takes the first definition any publisher sends: charge it to the newest that may be probed
        peer = next((p for p in reversed(publishers) if not self.probes.quarantine_reason(p)), publishers[-1])
        self.probes.submit(peer, f"topic {name}", probe, failed)

    async def _unprobe(self, topic: str) -> None:
        """Before a topic's shared subscription: wait for a probe that holds the node's subscription to it."""
        probe = self.probes.running(f"topic {topic}")
        if probe is not None:
            await asyncio.gather(probe, return_exceptions=True)

    # --- shared subscriptions --------------------------------------------------------------------

    async def add_sink(self, topic: str, sink: TopicSink, *, check: bool = True) -> None:
        """Give ``sink`` every message of ``topic`` (subscribing on the first sink).

        Raises:
            MrosError: the topic is not allowed, or the master refused the subscription.
        """
        if check and not self.policy.allows_topic(topic):
            raise MrosError(f"topic {topic} is not allowed by the [web] topics allow-list")
        await self.subs.add(topic, sink)

    async def remove_sink(self, topic: str, sink: TopicSink) -> None:
        """Stop giving ``sink`` the topic; the last sink closes the subscription."""
        await self.subs.remove(topic, sink)

    def resume(self, topic: str) -> None:
        """A sink of ``topic`` caught up: read from the publishers again (no-op unless paused)."""
        self.subs.resume(topic)

    def _hold_raw(self, topic: str, sink: TopicSink) -> bool:
        """Stop reading ``topic`` while an encoder works on its frame, when that encoder is its only sink (no
        client reads the raw topic): True when paused (``resume`` ends it)."""
        entry = self.subs.entries.get(topic)
        if entry is None or entry.sinks != [sink]:
            return False
        self.subs.pause(topic)
        return True

    def topic_stats(self, topic: str) -> tuple[int, int] | None:
        """``(messages, bytes)`` received on a shared subscription since it opened (None: not subscribed)."""
        return self.subs.stats(topic)

    def sink_count(self, topic: str) -> int:
        return self.subs.sink_count(topic)

    # --- what clients write: publishers and parameter watches (``mrosd.web.clientwrites``) -----------

    @property
    def _publishers(self) -> dict[str, Any]:
        return self.writes.publishers

    def message_class(self, msg_type: str) -> Any:
        return self.writes.message_class(msg_type)

    async def client_class(self, msg_type: str, definition: str | None = None) -> Any:
        return await self.writes.client_class(msg_type, definition)

    async def acquire_publisher(self, topic: str, msg_class: Any) -> Any:
        return await self.writes.acquire_publisher(topic, msg_class)

    async def release_publisher(self, topic: str) -> None:
        await self.writes.release_publisher(topic)

    async def watch_param(self, name: str, callback: Callable[[str, Any], None], *, check: bool = True) -> Any:
        return await self.writes.watch_param(name, callback, check=check)

    async def unwatch_param(self, name: str, callback: Callable[[str, Any], None]) -> None:
        await self.writes.unwatch_param(name, callback)
