"""The rosbridge v2 shell: one ``RosbridgeSession`` per aiohttp WebSocket, over the same ``WebHub`` as Foxglove.

Subscriptions take the hub's raw bodies like every other client; a body is decoded only when it is about
to be sent (a message dropped by the client's queue or its ``throttle_rate`` is never decoded). Several
``subscribe`` ops for one topic merge as rosbridge merges them: one stream, the smallest throttle_rate,
the largest queue_length, and it ends with the last ``unsubscribe``. Each subscription's queue is bounded in
messages (``queue_length``, when not 0) and in bytes (the session limits), drop-oldest. Answers go only to
what the client asked: ``service_response`` to a ``call_service``, ``status`` to a refused op. A long ``png``
op is compressed in a small thread pool, off the loop; a client's ``fragment`` ops are joined by the session's
``Defragmenter`` (bounded per client and, with the server's ledger, for all clients) and handled as one op.

The ``/rosapi/*`` services that roslibjs, roslibpy, Lichtblick and ros-mcp call are answered by
``mrosd.web.rosapi`` (``rosapi/get_param`` and other relative names resolve to them, as rosbridge's own rosapi
node is found). Publishers follow rosbridge's ROS 1 manager (``mrosd.web.rosbridge_publishers``): one per
topic, kept 10 s after its last client, its first second re-sent to subscribers that connect within it.
"""

from __future__ import annotations

import asyncio
import collections
import itertools
import logging
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import msgspec
from aiohttp import WSMsgType, web

if TYPE_CHECKING:
    from aiohttp.abc import AbstractStreamWriter

from mrosd import backports
from mrosd.errors import MrosError
from mrosd.master.client import GraphSnapshot
from mrosd.msg import get_service_class, load_type_async
from mrosd.web import rosapi
from mrosd.web import rosbridge as rb
from mrosd.web import rosbridge_publishers as publishers
from mrosd.web.deadman import DeadMan
from mrosd.web.fairsend import FairSender
from mrosd.web.foxglove_server import SessionLimits
from mrosd.web.hub import ServiceInfo, TopicInfo, WebHub
from mrosd.web.queue import ByteQueue, Ledger, trim_to_budget
from mrosd.web.rosbridge_sender import RosbridgeSender, png_op_off_loop

log = logging.getLogger(__name__)

__all__ = ["RosbridgeSession", "png_op_off_loop"]


@dataclass(slots=True)
class _Sub:
    topic: str
    msg_class: Any
    queue: ByteQueue[tuple[bytes | bytearray, int]]
    ids: set[str | None] = field(default_factory=set)
    throttle: dict[str | None, int] = field(default_factory=dict)
    length: dict[str | None, int] = field(default_factory=dict)
    last_sent: float = 0.0
    #: "none" (JSON text), "cbor" (the message as CBOR), "cbor-raw" (the TCPROS body untouched, in CBOR),
    #: "png" (the JSON text as a PNG image in a ``png`` op)
    compression: str = "none"
    #: JSON messages longer than this go as rosbridge ``fragment`` ops (None: whole)
    fragment_size: int | None = None
    receipts: collections.deque[int] = field(default_factory=collections.deque)
    #: messages sent to the client (its drops are counted by its queue)
    sent: int = 0

    @property
    def throttle_s(self) -> float:
        return min(self.throttle.values(), default=0) / 1000.0

    @property
    def queue_length(self) -> int:
        """Messages kept per subscription; 0 (rosbridge's default): no count, only the byte bound (rosbridge
        passes such a subscription's every message on to its socket; its queue exists only from 1 on)."""
        return max(self.length.values(), default=0)


class RosbridgeSession(RosbridgeSender):
    """One connected rosbridge client."""

    KIND = "rosbridge client"

    def __init__(
        self,
        hub: WebHub,
        ws: web.WebSocketResponse,
        limits: SessionLimits,
        *,
        token: str = "",
        peer: str = "?",
        fragments: tuple[Ledger, int] | None = None,
        writer: AbstractStreamWriter | None = None,
    ) -> None:
        super().__init__(hub, ws, limits, peer)
        #: the prepared response's stream: frames not to be deflated are written to its transport directly
        self._writer = writer
        self._fair: FairSender[str, _Sub] = FairSender(self._wake.set)
        self._fair.transport = writer.transport if writer is not None else None
        shared, shared_max = fragments if fragments is not None else (Ledger(), None)
        #: the client's fragment ops not yet joined (``fragments``: the server's ledger of them and its bound)
        self.fragments = rb.Defragmenter(
            max_bytes=limits.fragment_bytes,
            max_messages=limits.max_fragmented,
            timeout=limits.fragment_timeout,
            shared=shared,
            shared_max=shared_max,
        )
        self._fragment_timer: asyncio.TimerHandle | None = None
        self.authed = not token
        self._token = token
        self.subs: dict[str, _Sub] = {}
        self._published: dict[str, Any] = {}  # topic -> publisher
        self._deadman = DeadMan(f"rosbridge client {self.peer}")
        #: services this client provides (advertise_service), and the calls waiting for its service_response
        self._provided: dict[str, Any] = {}
        self._pending: dict[str, asyncio.Future[tuple[bool, Any]]] = {}
        self._request_ids = itertools.count(1)

    # --- hub callbacks ---------------------------------------------------------------------------

    def backlog(self, topic: str) -> int:
        sub = self.subs.get(topic)
        return 0 if sub is None else sub.queue.backlog()

    def deliver(self, topic: str, body: bytes | bytearray, receipt_ns: int) -> None:
        sub = self.subs.get(topic)
        if sub is None:
            return
        sub.queue.put((body, receipt_ns), len(body))
        FairSender.queued(sub.queue, len(body))
        while sub.queue_length and len(sub.queue) > sub.queue_length:
            sub.queue.drop_oldest()
        if self.hub.ledger.size > self.limits.client_bytes:  # all clients' bytes: O(1), the trim O(topics)
            trim_to_budget([s.queue for s in self.subs.values()], self.limits.client_bytes, sub.queue)
        self._wake.set()

    def topics_changed(self, added: list[TopicInfo], removed: list[TopicInfo]) -> None:
        pass

    def graph_changed(self, graph: GraphSnapshot) -> None:
        pass

    def services_changed(self, added: list[ServiceInfo], removed: list[ServiceInfo]) -> None:
        pass

    # --- sending ---------------------------------------------------------------------------------

    def _send(self, data: bytes, binary: bool = False) -> None:
        self._queue_control(binary, data)

    def status(self, level: str, message: str, op_id: str | None = None) -> None:
        self._send(rb.op_json("status", level=level, msg=message, id=op_id))

    # --- the connection --------------------------------------------------------------------------

    async def run(self) -> None:
        self.hub.listeners.add(self)
        sender = asyncio.get_running_loop().create_task(self._sender(), name=f"rosbridge send {self.peer}")
        try:
            async for msg in self.ws:
                if msg.type == WSMsgType.TEXT:
                    await self._on_text(msg.data)
                elif msg.type == WSMsgType.BINARY:
                    self.status("error", "binary (CBOR) ops from clients are not served; send JSON text")
                elif msg.type == WSMsgType.ERROR:
                    break
                if sender.done():
                    break
        finally:
            self._closed = True
            for task in (sender, *self._calls):
                task.cancel()
            await asyncio.gather(sender, *self._calls, return_exceptions=True)
            self._fragment_rest = None
            self._unhold()
            await self._deadman.stop()
            await self._release()

    async def _release(self) -> None:
        self.hub.listeners.discard(self)
        self.fragments.clear()
        if self._fragment_timer is not None:
            self._fragment_timer.cancel()
            self._fragment_timer = None
        for topic, sub in list(self.subs.items()):
            sub.queue.clear()  # gives its bytes back to the hub's ledger
            await self.hub.remove_sink(topic, self)
        self.subs.clear()
        for topic in list(self._published):
            await publishers.linger_release(self.hub, topic)
        self._published.clear()
        for future in self._pending.values():
            if not future.done():
                future.set_exception(MrosError("the rosbridge client that provides the service disconnected"))
        self._pending.clear()
        for service in list(self._provided.values()):
            await service.aclose()
        self._provided.clear()

    async def _on_text(self, text: str | bytes) -> None:
        try:
            op = rb.decode_op(text)
        except rb.RosbridgeRefusal as exc:
            self.status("error", str(exc))
            return
        if not self.authed and not isinstance(op, rb.Auth):
            self.status("error", f"{_op_name(op)}: authenticate first (op auth with the token)", _status_id(op))
            return
        if isinstance(op, rb.Fragment):
            await self._on_fragment(op)
            return
        await self._handle(op)

    async def _handle(self, op: rb.Op) -> None:
        try:
            await self._dispatch(op)
        except (MrosError, rb.RosbridgeRefusal) as exc:
            self.status("error", f"{_op_name(op)}: {exc}", _status_id(op))

    # --- fragment ops ------------------------------------------------------------------------------

    async def _on_fragment(self, piece: rb.Fragment) -> None:
        """Keep a piece; the op it completes is handled as if it came whole, but for another fragment op (a
        message cut twice is refused: what a client holds stays within one budget)."""
        try:
            whole = self.fragments.feed(piece, time.monotonic())
        except rb.RosbridgeRefusal as exc:
            self.status("error", str(exc), _status_id(piece))
            return
        finally:
            if len(self.fragments) and self._fragment_timer is None:
                self._arm_fragment_timer()
        if whole is None:
            return
        try:
            op = rb.decode_op(whole)
        except rb.RosbridgeRefusal as exc:
            self.status("error", f"fragment {piece.id!r}: the joined op: {exc}", _status_id(piece))
            return
        if isinstance(op, rb.Fragment):
            self.status("error", f"fragment {piece.id!r}: the joined op is a fragment again", _status_id(piece))
            return
        await self._handle(op)

    def _arm_fragment_timer(self) -> None:
        deadline = self.fragments.deadline()
        if deadline is None or self._closed:
            return
        delay = max(0.0, deadline - time.monotonic())
        self._fragment_timer = asyncio.get_running_loop().call_later(delay, self._expire_fragments)

    def _expire_fragments(self) -> None:
        """Fragmented messages without a new piece for ``fragment_timeout`` are dropped, each with a status."""
        self._fragment_timer = None
        for key, received, total in self.fragments.expire(time.monotonic()):
            self.status(
                "error",
                f"fragment {key!r}: {received} of {total} parts, then none for {self.limits.fragment_timeout:g} s; "
                f"message dropped",
                str(key),
            )
        self._arm_fragment_timer()

    async def _dispatch(self, op: rb.Op) -> None:
        if isinstance(op, rb.Auth):
            from mrosd.web.access import AccessPolicy

            self.authed = AccessPolicy(token=self._token).token_ok(op.mac)
            if not self.authed:
                self.status("error", "auth: wrong token", op.id)
        elif isinstance(op, rb.Subscribe):
            await self._subscribe(op)
        elif isinstance(op, rb.Unsubscribe):
            await self._unsubscribe(op)
        elif isinstance(op, rb.Advertise):
            await self._advertise(op.topic, op.type)
        elif isinstance(op, rb.Unadvertise):
            if self._published.pop(op.topic, None) is not None:
                await publishers.linger_release(self.hub, op.topic)
        elif isinstance(op, rb.Publish):
            await self._publish(op)
        elif isinstance(op, rb.CallService):
            self._start_call(op)
        elif isinstance(op, rb.AdvertiseService):
            await self._advertise_service(op)
        elif isinstance(op, rb.UnadvertiseService):
            service = self._provided.pop(op.service, None)
            if service is not None:
                await service.aclose()
        elif isinstance(op, rb.ServiceResponse):
            future = self._pending.pop(op.id or "", None)
            if future is None:
                self.status("warning", f"service_response: no call {op.id!r} is waiting", op.id)
            elif not future.done():
                # rosbridge's ROS 1 server reads the values whatever ``result`` says (roslibpy's handlers
                # answer False and mean the values); only a response without values fails the call
                future.set_result((op.result or isinstance(op.values, dict), op.values))
        elif isinstance(op, rb.SetLevel):
            pass  # status levels are not filtered: every refusal is an error the client asked about

    async def _topic_class(self, topic: str, msg_type: str | None) -> Any:
        info = self.hub.topics.get(topic)
        if info is not None and (not msg_type or msg_type == info.type):
            return await load_type_async(info.type, info.definition)
        if not msg_type:
            raise MrosError(f"{topic}: the type is unknown (no publisher yet): give it with 'type'")
        return await load_type_async(msg_type, "")

    async def _subscribe(self, op: rb.Subscribe) -> None:
        compression = op.compression or "none"
        if compression not in ("none", "cbor", "cbor-raw", "png"):
            self.status("warning", f"subscribe {op.topic}: compression {compression!r} not served; sending JSON")
            compression = "none"
        sub = self.subs.get(op.topic)
        if sub is None:
            if len(self.subs) >= self.limits.max_subscriptions:
                raise MrosError(f"at most {self.limits.max_subscriptions} subscriptions")
            sub = _Sub(
                op.topic,
                await self._topic_class(op.topic, op.type),
                ByteQueue(self.limits.queue_bytes, self.hub.ledger),
            )
            self.subs[op.topic] = sub
            try:
                await self.hub.add_sink(op.topic, self)
            except MrosError:
                del self.subs[op.topic]
                raise
        sub.compression = compression
        sub.fragment_size = op.fragment_size or None
        sub.ids.add(op.id)
        sub.throttle[op.id] = op.throttle_rate
        sub.length[op.id] = op.queue_length

    async def _unsubscribe(self, op: rb.Unsubscribe) -> None:
        sub = self.subs.get(op.topic)
        if sub is None:
            return
        for key in [op.id] if op.id is not None and op.id in sub.ids else list(sub.ids):
            sub.ids.discard(key)
            sub.throttle.pop(key, None)
            sub.length.pop(key, None)
        if not sub.ids:
            del self.subs[op.topic]
            sub.queue.clear()
            await self.hub.remove_sink(op.topic, self)

    async def _advertise(self, topic: str, msg_type: str) -> Any:
        pub = self._published.get(topic)
        if pub is not None:
            return pub
        if len(self._published) >= self.limits.max_subscriptions:
            raise MrosError(f"at most {self.limits.max_subscriptions} advertised topics per client")
        cls = await self._topic_class(topic, msg_type or None)
        pub = await self.hub.acquire_publisher(topic, cls)
        publishers.watch_new(pub)
        self._published[topic] = pub
        return pub

    async def _publish(self, op: rb.Publish) -> None:
        pub = self._published.get(op.topic)
        if pub is None:  # rosbridge advertises on the first publish when the topic's type is known
            pub = await self._advertise(op.topic, "")
        msg = rb.message_from_json(pub.msg_class, op.msg)
        pub.publish_nowait(msg)
        publishers.published(pub, msg)
        self._deadman.published_message(pub, msg)

    # --- services this client provides ----------------------------------------------------------

    async def _advertise_service(self, op: rb.AdvertiseService) -> None:
        name = op.service if op.service.startswith("/") else "/" + op.service
        if name in self._provided:
            return
        if not self.hub.policy.allows_service(name):
            raise MrosError(f"service {name} is not allowed by the [web] services allow-list")
        if len(self._provided) >= self.limits.max_subscriptions:
            raise MrosError(f"at most {self.limits.max_subscriptions} services per client")
        srv_class = get_service_class(op.type)

        async def handler(request: Any) -> Any:
            call_id = f"service_request:{name}:{next(self._request_ids)}"
            future: asyncio.Future[tuple[bool, Any]] = asyncio.get_running_loop().create_future()
            self._pending[call_id] = future
            args = msgspec.to_builtins(request)
            self._send(rb.op_json("call_service", id=call_id, service=name, args=args))
            try:
                async with backports.timeout(self.limits.call_timeout):
                    ok, values = await future
            except TimeoutError:
                raise MrosError(f"the rosbridge client did not answer within {self.limits.call_timeout} s") from None
            finally:
                self._pending.pop(call_id, None)
            if not ok:
                raise MrosError(str(values) if values is not None else "the rosbridge client answered result: false")
            return rb.message_from_json(srv_class._response_class, values)

        self._provided[name] = await self.hub.node.advertise_service(name, srv_class, handler)

    # --- services --------------------------------------------------------------------------------

    def _start_call(self, op: rb.CallService) -> None:
        if len(self._calls) >= self.limits.max_calls:
            self._call_done(op, False, f"at most {self.limits.max_calls} service calls in flight")
            return
        task = asyncio.get_running_loop().create_task(self._call(op))
        self._calls.add(task)
        task.add_done_callback(self._calls.discard)

    def _call_done(self, op: rb.CallService, ok: bool, values: Any) -> None:
        self._send(rb.op_json("service_response", service=op.service, values=values, result=ok, id=op.id))

    async def _call(self, op: rb.CallService) -> None:
        name = op.service if op.service.startswith("/") else "/" + op.service
        try:
            if name.startswith("/rosapi/"):
                values = await rosapi.answer(self.hub, name[len("/rosapi/") :], _args(op.args))
            else:
                values = await self._call_ros(name, op)
        except (MrosError, rb.RosbridgeRefusal, OSError, TimeoutError) as exc:
            self._call_done(op, False, str(exc) or type(exc).__name__)
            return
        self._call_done(op, True, values)

    async def _call_ros(self, name: str, op: rb.CallService) -> Any:
        if not self.hub.policy.allows_service(name):
            raise MrosError(f"service {name} is not allowed by the [web] services allow-list")
        # As rosbridge's ROS 1 server: the client's ``type`` is not used; the service's own type is (so a
        # ROS 2-style ``std_srvs/srv/SetBool`` calls a std_srvs/SetBool service)
        info = self.hub.services.get(name)
        srv_type = info.type if info is not None else ""
        if not srv_type:  # registered since the graph watch last looked (or never probed): ask it now
            try:
                srv_type = await self.hub.probe_service_type(name)
            except (MrosError, OSError, TimeoutError) as exc:
                raise MrosError(f"service {name} is not offered: {exc or type(exc).__name__}") from None
        srv_class = get_service_class(srv_type)
        args = op.args
        if isinstance(args, list):
            args = dict(zip(srv_class._request_class.__struct_fields__, args, strict=False))
        request = rb.message_from_json(srv_class._request_class, args)
        proxy = self.hub.node.service_proxy(name, srv_class)
        timeout = op.timeout if op.timeout and op.timeout > 0 else self.limits.call_timeout
        response = await proxy.call(request, timeout=min(timeout, self.limits.call_timeout))
        return msgspec.to_builtins(response)


def _op_name(op: rb.Op) -> str:
    return str(type(op).__struct_config__.tag)


def _status_id(op: rb.Op) -> str | None:
    """The id a status about ``op`` names (a fragment's id may be a number)."""
    return None if op.id is None else str(op.id)


def _args(args: Any) -> dict[str, Any]:
    return args if isinstance(args, dict) else {}
