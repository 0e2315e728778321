"""The Foxglove WebSocket shell: one ``FoxgloveSession`` per aiohttp WebSocket, over one shared ``WebHub``.

Two tasks per client. The reader decodes each frame with ``mrosd.web.foxglove`` and acts on the hub; a
refused frame is answered with a status message and costs nothing more. The sender (``mrosd.web.
foxglove_sender``) drains control messages, then the subscriptions' byte-bounded queues in a fair order
(deficit round robin by bytes; big topics newest-only, sent when the link is clear). Message bodies are the
hub's raw TCPROS bodies, held by reference until sent.

A stalled client blocks only its own sender (in aiohttp's drain); its queues keep dropping their oldest
messages, counted and reported once per ``REPORT_PERIOD`` as a warning status. Disconnecting releases
every subscription, publisher and parameter watch the client held.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import uuid
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from aiohttp import WSMsgType, web

if TYPE_CHECKING:
    from aiohttp.abc import AbstractStreamWriter

from mrosd.errors import MrosError
from mrosd.master.client import GraphSnapshot
from mrosd.web import foxglove as fg
from mrosd.web.deadman import DeadMan
from mrosd.web.fairsend import FairSender
from mrosd.web.foxglove_requests import FoxgloveRequests, service_json
from mrosd.web.foxglove_sender import FoxgloveSender
from mrosd.web.hub import ServiceInfo, TopicInfo, WebHub
from mrosd.web.limits import SessionLimits
from mrosd.web.queue import ByteQueue, trim_to_budget

log = logging.getLogger(__name__)

__all__ = ["FoxgloveSession", "SessionLimits"]


@dataclass(slots=True)
class _Subscription:
    id: int
    topic: TopicInfo
    queue: Any  # ByteQueue[tuple[int, bytes | bytearray]]
    #: x-mrosd.throttle: at least this long between two messages sent, the latest only (0: every message)
    period_ns: int = 0
    #: monotonic ns before which the next message of a throttled subscription is not sent
    next_ns: int = 0
    #: messages sent to the client (its drops are counted by its queue)
    sent: int = 0


@dataclass(slots=True)
class _ClientChannel:
    topic: str
    msg_class: Any
    publisher: Any


class FoxgloveSession(FoxgloveRequests, FoxgloveSender):
    """One connected Foxglove client."""

    KIND = "Foxglove client"

    CAPABILITIES = ("clientPublish", "parameters", "parametersSubscribe", "services", "connectionGraph")

    def __init__(
        self,
        hub: WebHub,
        ws: web.WebSocketResponse,
        writer: AbstractStreamWriter,
        limits: SessionLimits,
        peer: str = "?",
    ) -> None:
        super().__init__(hub, ws, limits, peer)
        self._init_sender(writer)
        self._queue_type = ByteQueue
        self.subs: dict[int, _Subscription] = {}
        self._by_topic: dict[str, list[_Subscription]] = {}
        self._channels: dict[int, _ClientChannel] = {}
        self._graph_state: fg.SystemState | None = None
        #: serverInfo declared ``time`` (sim time was on as the client connected): it gets /clock's time and
        #: its messages are stamped with it, as the protocol asks, for as long as sim time stays on
        self._offered_time = False
        self._deadman = DeadMan(f"{self.KIND} {peer}")

    # --- hub callbacks (never block) -------------------------------------------------------------

    def backlog(self, topic: str) -> int:
        return sum(s.queue.backlog() for s in self._by_topic.get(topic, ()))

    def deliver(self, topic: str, body: bytes | bytearray, receipt_ns: int) -> None:
        subs = self._by_topic.get(topic, ())
        if self._offered_time and self.hub.sim_time:
            receipt_ns = self.hub.clock_ns  # the time source of its time messages, as roscpp's receipt time
        for sub in subs:
            if sub.period_ns:
                sub.queue.clear()  # throttled: the latest message replaces the one not yet sent
            sub.queue.put((receipt_ns, body), len(body))
            FairSender.queued(sub.queue, len(body))
        if subs:
            if self.hub.ledger.size > self.limits.client_bytes:  # all clients' bytes: O(1), the trim O(topics)
                trim_to_budget([s.queue for s in self.subs.values()], self.limits.client_bytes, subs[-1].queue)
            self._wake.set()

    def topics_changed(self, added: list[TopicInfo], removed: list[TopicInfo]) -> None:
        if removed:
            ids = {t.id for t in removed}
            for sub in [s for s in self.subs.values() if s.topic.id in ids]:
                if self._forget(sub):
                    asyncio.get_running_loop().create_task(self._drop_sink(sub.topic.name))
            self._send_json(fg.encode_json("unadvertise", channelIds=sorted(ids)))
        if added:
            self._send_json(fg.encode_json("advertise", channels=[_channel(t) for t in added]))

    def graph_changed(self, graph: GraphSnapshot) -> None:
        pass

    def services_changed(self, added: list[ServiceInfo], removed: list[ServiceInfo]) -> None:
        if removed:
            self._send_json(fg.encode_json("unadvertiseServices", serviceIds=[s.id for s in removed]))
        if added:
            self._send_json(fg.encode_json("advertiseServices", services=[service_json(s) for s in added]))

    def _time(self, now_ns: int) -> None:
        self._time_ns = now_ns
        self._wake.set()

    def _sim_time_changed(self, on: bool) -> None:
        """/use_sim_time changed. The protocol declares capabilities once, in the serverInfo a client gets as it
        connects (foxglove.websocket.v1 has no update of them, and Foxglove sets up timers per serverInfo): a
        client offered ``time`` gets time messages again while sim time is on; any other is told to reconnect."""
        if self._offered_time:
            if on:
                self.hub.time_listeners.add(self._time)
            else:
                self.hub.time_listeners.discard(self._time)
        if on and not self._offered_time:
            why = "/use_sim_time is now true: reconnect to follow /clock"
        elif not on and self._offered_time:
            why = "/use_sim_time is now false: no more time messages; reconnect to use wall-clock time"
        else:
            return
        self.status(fg.STATUS_INFO, f"{why} (capabilities are declared in serverInfo, once per connection)", "sim_time")

    def _state_changed(self, state: fg.SystemState) -> None:
        if self._graph_state is None:
            return
        update = fg.connection_graph_update(self._graph_state, state)
        self._graph_state = state
        if update is not None:
            self._send_json(update)

    # --- the connection --------------------------------------------------------------------------

    async def run(self) -> None:
        """Serve the client until it disconnects; always releases what it held."""
        hub = self.hub
        self._offered_time = hub.sim_time
        capabilities = [*self.CAPABILITIES, "time"] if self._offered_time else list(self.CAPABILITIES)
        if hub.assets is not None:
            capabilities.append("assets")
        self._send_json(
            fg.server_info(
                "mrosd", capabilities, session_id=uuid.uuid4().hex, metadata={"ros": "1", "node": self.hub.node.name}
            )
        )
        if self._offered_time:
            hub.time_listeners.add(self._time)
        hub.sim_time_listeners.add(self._sim_time_changed)
        self._send_json(fg.encode_json("advertise", channels=[_channel(t) for t in hub.topics.values()]))
        if hub.services:
            self._send_json(
                fg.encode_json("advertiseServices", services=[service_json(s) for s in hub.services.values()])
            )
        hub.listeners.add(self)
        tasks = [
            asyncio.get_running_loop().create_task(self._sender(), name=f"foxglove send {self.peer}"),
            asyncio.get_running_loop().create_task(self._reporter(), name=f"foxglove report {self.peer}"),
        ]
        try:
            async for msg in self.ws:
                if msg.type == WSMsgType.TEXT:
                    await self._on_text(msg.data)
                elif msg.type == WSMsgType.BINARY:
                    await self._on_binary(msg.data)
                elif msg.type == WSMsgType.ERROR:
                    break
                if tasks[0].done():
                    break
        finally:
            self._closed = True
            if self._throttle_timer is not None:
                self._throttle_timer.cancel()
            if self._stats_task is not None:
                tasks.append(self._stats_task)
            if self._asset_task is not None:
                tasks.append(self._asset_task)
            tasks += self._calls
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            await self._deadman.stop()
            await self._release()

    async def _release(self) -> None:
        hub = self.hub
        hub.listeners.discard(self)
        hub.state_listeners.discard(self._state_changed)
        hub.time_listeners.discard(self._time)
        hub.sim_time_listeners.discard(self._sim_time_changed)
        for topic in list(self._by_topic):
            await hub.remove_sink(topic, self)
        for topic in list(self._stats or ()):
            await hub.remove_sink(topic, self._stats_sink)
        self._stats = None
        self._by_topic.clear()
        for sub in self.subs.values():
            sub.queue.clear()  # gives its bytes back to the hub's ledger
        self.subs.clear()
        for channel in list(self._channels.values()):
            await hub.release_publisher(channel.topic)
        self._channels.clear()
        for name in list(self._params):
            await hub.unwatch_param(name, self._param_update)
        self._params.clear()

    # --- client ops ------------------------------------------------------------------------------

    async def _on_text(self, text: str) -> None:
        try:
            op = fg.decode_client_text(text)
        except fg.ProtocolRefusal as exc:
            self.status(fg.STATUS_ERROR, str(exc))
            return
        try:
            await self._dispatch(op)
        except MrosError as exc:
            self.status(fg.STATUS_ERROR, str(exc))

    async def _dispatch(self, op: fg.ClientOp) -> None:
        if isinstance(op, fg.Subscribe):
            await self._subscribe(op)
        elif isinstance(op, fg.Unsubscribe):
            for sub_id in op.subscriptionIds:
                sub = self.subs.get(sub_id)
                if sub is None:
                    self.status(fg.STATUS_WARNING, f"unsubscribe: no subscription {sub_id}")
                    continue
                if self._forget(sub):
                    await self.hub.remove_sink(sub.topic.name, self)
        elif isinstance(op, fg.ClientAdvertise):
            await self._advertise(op)
        elif isinstance(op, fg.ClientUnadvertise):
            for ch_id in op.channelIds:
                channel = self._channels.pop(ch_id, None)
                if channel is not None:
                    await self.hub.release_publisher(channel.topic)
        elif isinstance(op, fg.GetParameters):
            await self._get_parameters(op.parameterNames, op.id)
        elif isinstance(op, fg.SetParameters):
            await self._set_parameters(op)
        elif isinstance(op, fg.SubscribeParameterUpdates):
            await self._subscribe_params(op.parameterNames)
        elif isinstance(op, fg.UnsubscribeParameterUpdates):
            for name in op.parameterNames:
                if name in self._params:
                    self._params.discard(name)
                    await self.hub.unwatch_param(name, self._param_update)
        elif isinstance(op, fg.SubscribeConnectionGraph):
            if self._graph_state is None:
                self._graph_state = fg.EMPTY_STATE
                self.hub.state_listeners.add(self._state_changed)
                self.hub.refresh_state()
        elif isinstance(op, fg.UnsubscribeConnectionGraph):
            self._graph_state = None
            self.hub.state_listeners.discard(self._state_changed)
        elif isinstance(op, fg.Throttle):
            sub = self.subs.get(op.subscriptionId)
            if sub is None:
                self.status(fg.STATUS_WARNING, f"x-mrosd.throttle: no subscription {op.subscriptionId}")
            else:
                sub.period_ns = int(1e9 / op.maxRate) if op.maxRate > 0 else 0
                while sub.period_ns and len(sub.queue) > 1:
                    sub.queue.get()  # from now on only the latest is kept
        elif isinstance(op, fg.ImageSettings):
            self._image_settings(op)
        elif isinstance(op, fg.SubscribeStats):
            if self._stats is None:
                self._stats = {}
                self._stats_task = asyncio.get_running_loop().create_task(self._report_stats())
        elif isinstance(op, fg.UnsubscribeStats):
            await self._stop_stats()
        elif isinstance(op, fg.SubscribeDelivery):
            self.wants_delivery = True
        elif isinstance(op, fg.NodeDetails):
            # in a task of its own, counted with the service calls: a node that does not answer getPid
            # must not hold up this client's other requests
            if len(self._calls) >= self.limits.max_calls:
                self.status(fg.STATUS_ERROR, f"x-mrosd.nodeDetails: at most {self.limits.max_calls} requests in flight")
                return
            task = asyncio.get_running_loop().create_task(self._reply_node_details(op))
            self._calls.add(task)
            task.add_done_callback(self._calls.discard)
        elif isinstance(op, fg.FetchAsset):
            self._request_asset(op)

    async def _subscribe(self, op: fg.Subscribe) -> None:
        by_id = {t.id: t for t in self.hub.topics.values()}
        for entry in op.subscriptions:
            if entry.id in self.subs:
                self.status(fg.STATUS_ERROR, f"subscribe: subscription id {entry.id} is already in use")
                continue
            topic = by_id.get(entry.channelId)
            if topic is None:
                self.status(fg.STATUS_ERROR, f"subscribe: no channel {entry.channelId}")
                continue
            if len(self.subs) >= self.limits.max_subscriptions:
                self.status(fg.STATUS_ERROR, f"subscribe: at most {self.limits.max_subscriptions} subscriptions")
                continue
            first = topic.name not in self._by_topic
            sub = _Subscription(entry.id, topic, self._queue_type(self.limits.queue_bytes, self.hub.ledger))
            self.subs[entry.id] = sub
            self._by_topic.setdefault(topic.name, []).append(sub)
            if first:
                try:
                    await self.hub.add_sink(topic.name, self)
                except MrosError as exc:
                    self._forget(sub)  # the hub holds nothing for us: no sink to release
                    self.status(fg.STATUS_ERROR, f"subscribe {topic.name}: {exc}")

    def _forget(self, sub: _Subscription) -> bool:
        """Drop one subscription; True when it was this client's last one of its topic (release the sink)."""
        self.subs.pop(sub.id, None)
        sub.queue.clear()
        subs = self._by_topic.get(sub.topic.name)
        if subs is None:
            return False
        with contextlib.suppress(ValueError):
            subs.remove(sub)
        if subs:
            self.hub.resume(sub.topic.name)  # what this client holds of the topic just shrank
            return False
        del self._by_topic[sub.topic.name]
        return True

    async def _drop_sink(self, topic: str) -> None:
        if topic not in self._by_topic:
            await self.hub.remove_sink(topic, self)

    async def _advertise(self, op: fg.ClientAdvertise) -> None:
        for ch in op.channels:
            if ch.id in self._channels:
                self.status(fg.STATUS_ERROR, f"advertise: client channel {ch.id} is already advertised")
                continue
            if ch.encoding != "ros1":
                self.status(fg.STATUS_ERROR, f"advertise {ch.topic}: encoding {ch.encoding!r} (only ros1)")
                continue
            if len(self._channels) >= self.limits.max_subscriptions:
                self.status(fg.STATUS_ERROR, f"advertise: at most {self.limits.max_subscriptions} channels")
                continue
            try:
                schema = ch.schema if ch.schemaEncoding in (None, "ros1msg") else None
                msg_class = await self.hub.client_class(ch.schemaName, schema)
                publisher = await self.hub.acquire_publisher(ch.topic, msg_class)
            except MrosError as exc:
                self.status(fg.STATUS_ERROR, f"advertise {ch.topic}: {exc}")
                continue
            self._channels[ch.id] = _ClientChannel(publisher.topic, msg_class, publisher)

    async def _on_binary(self, data: bytes) -> None:
        try:
            msg = fg.decode_client_binary(data)
        except fg.ProtocolRefusal as exc:
            self.status(fg.STATUS_ERROR, str(exc))
            return
        if isinstance(msg, fg.ServiceCallRequest):
            self._start_call(msg)
            return
        channel = self._channels.get(msg.channel_id)
        if channel is None:
            self.status(fg.STATUS_ERROR, f"messageData: client channel {msg.channel_id} is not advertised")
            return
        body = bytes(msg.data)
        try:
            channel.msg_class.deserialize(body)  # never forward bytes that subscribers cannot decode
        except MrosError as exc:
            self.status(fg.STATUS_ERROR, f"messageData on {channel.topic}: not a {channel.msg_class._type}: {exc}")
            return
        try:
            channel.publisher.publish_serialized(body)
            self._deadman.published(channel.publisher, channel.msg_class._type, body)
        except MrosError as exc:
            self.status(fg.STATUS_ERROR, f"messageData on {channel.topic}: {exc}")


def _channel(topic: TopicInfo) -> fg.Channel:
    return fg.Channel(topic.id, topic.name, "ros1", topic.type, topic.definition)
