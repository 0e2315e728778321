"""What a Foxglove client asks and is answered: services, parameters, assets, and mrosd's extensions for its
page (topic statistics, node details). The session (``mrosd.web.foxglove_server``) adds subscriptions,
client publishing and the sender on top.

Each request is bounded per client: service calls and node details by ``SessionLimits.max_calls`` in flight,
parameter watches by ``max_subscriptions``, assets by ``MAX_PENDING_ASSETS`` waiting and one read at a time.
"""

from __future__ import annotations

import asyncio
import base64
import collections
import time
import urllib.parse
from typing import TYPE_CHECKING, Any, cast

from mrosd.errors import MrosError
from mrosd.master.cleanup import Probe, probe_get_pid
from mrosd.web import foxglove as fg
from mrosd.web.assets import AssetRefused
from mrosd.web.compressed import ImageSettings
from mrosd.web.hub import HoldingSink, ServiceInfo
from mrosd.web.rates import RateWindow
from mrosd.web.session import ClientSession

if TYPE_CHECKING:
    from aiohttp import web

    from mrosd.web.hub import WebHub
    from mrosd.web.limits import SessionLimits

__all__ = ["MAX_PENDING_ASSETS", "NODE_TIMEOUT", "STATS_PERIOD", "STATS_WINDOW", "FoxgloveRequests", "service_json"]

#: Seconds between two ``x-mrosd.topicStats`` reports, and the window their rates are measured over.
STATS_PERIOD = 1.0
STATS_WINDOW = 5.0
#: Seconds a node's ``getPid`` may take for ``x-mrosd.nodeDetails``.
NODE_TIMEOUT = 2.0
#: fetchAsset requests one client may have waiting behind the one being read and sent (Foxglove asks for a
#: robot's meshes all at once); each beyond is answered at once with an error
MAX_PENDING_ASSETS = 256


class FoxgloveRequests(ClientSession):
    """The request/answer half of a Foxglove session."""

    def __init__(self, hub: WebHub, ws: web.WebSocketResponse, limits: SessionLimits, peer: str) -> None:
        super().__init__(hub, ws, limits, peer)
        self._params: set[str] = set()
        #: x-mrosd.subscribeStats: the sink holding each measured topic open, and each topic's window
        self._stats_sink = HoldingSink()
        self._stats: dict[str, RateWindow] | None = None
        self._stats_task: asyncio.Task[None] | None = None
        #: fetchAsset requests not yet served, and the task serving them one at a time (one asset of this
        #: client in memory at once: a client that asks for 1000 meshes and reads none holds one)
        self._asset_requests: collections.deque[fg.FetchAsset] = collections.deque()
        self._asset_task: asyncio.Task[None] | None = None

    def _send_json(self, data: bytes) -> None:
        self._queue_control(True, data)

    def status(self, level: int, message: str, status_id: str | None = None) -> None:
        self._send_json(fg.status(level, message, status_id))

    # --- assets ----------------------------------------------------------------------------------

    def _request_asset(self, op: fg.FetchAsset) -> None:
        if self.hub.assets is None:
            self.status(fg.STATUS_ERROR, "fetchAsset is not offered (no assets capability: [web] assets is empty)")
            return
        if len(self._asset_requests) >= MAX_PENDING_ASSETS:
            why = f"{op.uri[:200]}: more than {MAX_PENDING_ASSETS} asset requests pending for this client"
            self._queue_control(False, fg.fetch_asset_error(op.requestId, why))
            return
        self._asset_requests.append(op)
        if self._asset_task is None:
            self._asset_task = asyncio.get_running_loop().create_task(
                self._serve_assets(), name=f"foxglove assets {self.peer}"
            )

    async def _serve_assets(self) -> None:
        """Read and send this client's requested assets in order, one at a time."""
        assets = self.hub.assets
        assert assets is not None
        try:
            while self._asset_requests and not self._closed:
                op = self._asset_requests.popleft()
                try:
                    held = await assets.read(op.uri, fg.fetch_asset_head(op.requestId))
                except AssetRefused as exc:
                    self._queue_control(False, fg.fetch_asset_error(op.requestId, f"{op.uri[:200]}: {exc}"))
                    continue
                try:
                    # not through the control queue: an asset may be far bigger than its bound. Written as one
                    # frame, like messageData; aiohttp's drain (and its heartbeat, for a client that stops
                    # reading) is the flow control, and this client's next asset waits for it
                    await self.ws.send_bytes(cast(bytes, held.frame))  # aiohttp takes any bytes-like, no copy
                finally:
                    held.release()
        except ConnectionError:
            pass  # the client left; run() releases the rest
        finally:
            self._asset_task = None

    # --- mrosd's extensions for its page ----------------------------------------------------------

    async def _report_stats(self) -> None:
        """Hold every advertised topic open with a counting sink; report Hz and bytes/s once a second."""
        hub = self.hub
        while self._stats is not None:
            stats = self._stats
            wanted = set(hub.topics) - hub.compressed.virtual.keys()  # held open, they would encode
            for topic in [t for t in stats if t not in wanted]:
                del stats[topic]
                await hub.remove_sink(topic, self._stats_sink)
            for topic in wanted - stats.keys():
                # listed before subscribing: whoever stops the stats (even mid-subscribe) releases it
                stats[topic] = RateWindow(STATS_WINDOW)
                try:
                    await hub.add_sink(topic, self._stats_sink)
                except MrosError:
                    del stats[topic]
            now = time.monotonic()
            report = []
            for topic, window in stats.items():
                counts = hub.topic_stats(topic)
                if counts is None:
                    continue
                window.add(now, *counts)
                rate = window.rate()
                report.append(
                    {
                        "topic": topic,
                        "messages": counts[0],
                        "bytes": counts[1],
                        "hz": None if rate is None else round(rate[0], 3),
                        "bps": None if rate is None else round(rate[1], 1),
                    }
                )
            self._send_json(fg.encode_json("x-mrosd.topicStats", topics=report, compressed=hub.compressed.status()))
            await asyncio.sleep(STATS_PERIOD)

    def _image_settings(self, op: fg.ImageSettings) -> None:
        """x-mrosd.imageSettings: change a ``T/compressed`` topic's shared settings, answer with them."""
        compressed = self.hub.compressed
        now = compressed.settings_for(op.topic)
        try:
            if op.quality is not None or op.maxWidth is not None or op.maxRate is not None:
                compressed.set_settings(
                    op.topic,
                    ImageSettings(
                        quality=now.quality if op.quality is None else op.quality,
                        max_width=now.max_width if op.maxWidth is None else op.maxWidth,
                        max_rate=now.max_rate if op.maxRate is None else op.maxRate,
                    ),
                )
        except (MrosError, ValueError) as exc:
            self.status(fg.STATUS_ERROR, f"x-mrosd.imageSettings: {exc}")
            return
        settings = compressed.settings_for(op.topic).as_dict()
        self._send_json(fg.encode_json("x-mrosd.imageSettings", topic=op.topic, **settings))

    async def _stop_stats(self) -> None:
        stats, self._stats = self._stats, None
        task, self._stats_task = self._stats_task, None
        if task is not None:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
        for topic in stats or ():
            await self.hub.remove_sink(topic, self._stats_sink)

    async def _reply_node_details(self, op: fg.NodeDetails) -> None:
        self._send_json(await self._node_details(op))

    async def _node_details(self, op: fg.NodeDetails) -> bytes:
        """What the master knows of a node, its pid from ``getPid``, and ``alive`` (False: refused)."""
        reply: dict[str, Any] = {"id": op.id, "node": op.node, "uri": None}
        try:
            pubs, subs, srvs = await self.hub.node.master.get_system_state()
        except MrosError as exc:
            reply["error"] = str(exc)
            return fg.encode_json("x-mrosd.nodeDetails", **reply)
        reply.update(
            publishing=sorted(t for t, ns in pubs if op.node in ns),
            subscribing=sorted(t for t, ns in subs if op.node in ns),
            services=sorted(s for s, ns in srvs if op.node in ns),
        )
        try:
            uri = await self.hub.node.master.lookup_node(op.node)
        except MrosError as exc:
            reply["error"] = str(exc)
            return fg.encode_json("x-mrosd.nodeDetails", **reply)
        reply["uri"] = uri
        reply["host"] = urllib.parse.urlsplit(uri).hostname
        probe, pid = await probe_get_pid(uri, NODE_TIMEOUT)
        reply["pid"] = pid
        reply["alive"] = None if probe is Probe.NO_ANSWER else probe is Probe.ANSWERED
        return fg.encode_json("x-mrosd.nodeDetails", **reply)

    # --- services --------------------------------------------------------------------------------

    def _start_call(self, msg: fg.ServiceCallRequest) -> None:
        """Run a call in a task of its own (a slow service must not stop this client's other requests)."""
        if len(self._calls) >= self.limits.max_calls:
            self._call_failed(msg, f"at most {self.limits.max_calls} service calls in flight per client")
            return
        if msg.encoding != "ros1":
            self._call_failed(msg, f"encoding {msg.encoding!r} (only ros1)")
            return
        info = next((s for s in self.hub.services.values() if s.id == msg.service_id), None)
        if info is None:
            self._call_failed(msg, f"no service {msg.service_id}")
            return
        task = asyncio.get_running_loop().create_task(self._call(msg, info.name, bytes(msg.data)))
        self._calls.add(task)
        task.add_done_callback(self._calls.discard)

    async def _call(self, msg: fg.ServiceCallRequest, name: str, request: bytes) -> None:
        try:
            response = await self.hub.call_service(name, request, timeout=self.limits.call_timeout)
        except (MrosError, OSError, TimeoutError) as exc:
            self._call_failed(msg, f"{name}: {exc or type(exc).__name__}")
            return
        self._queue_control(False, fg.service_call_response(msg.service_id, msg.call_id, "ros1", response))

    def _call_failed(self, msg: fg.ServiceCallRequest, why: str) -> None:
        self._send_json(fg.encode_json("serviceCallFailure", serviceId=msg.service_id, callId=msg.call_id, message=why))

    # --- parameters ------------------------------------------------------------------------------

    async def _param_names(self, names: list[str]) -> list[str]:
        if names:
            return names
        return [n for n in await self.hub.node.master.get_param_names() if self.hub.policy.allows_param(n)]

    async def _get_parameters(self, names: list[str], request_id: str | None) -> None:
        values = []
        for name in await self._param_names(names):
            if not self.hub.policy.allows_param(name):
                self.status(fg.STATUS_WARNING, f"getParameters: {name} is not allowed by the [web] params allow-list")
                continue
            try:
                value = await self.hub.node.master.get_param(name)
            except MrosError:
                continue  # unset: left out, as ROS 2 bridges do
            values.append(_parameter(name, value))
        self._send_json(fg.encode_json("parameterValues", parameters=values, id=request_id))

    async def _set_parameters(self, op: fg.SetParameters) -> None:
        master = self.hub.node.master
        done = []
        for param in op.parameters:
            if not self.hub.policy.allows_param(param.name):
                self.status(
                    fg.STATUS_ERROR, f"setParameters: {param.name} is not allowed by the [web] params allow-list"
                )
                continue
            try:
                if param.value is None:
                    await master.delete_param(param.name)
                else:
                    await master.set_param(param.name, _from_parameter(param))
            except MrosError as exc:
                self.status(fg.STATUS_ERROR, f"setParameters {param.name}: {exc}")
                continue
            done.append(param.name)
        if op.id is None:
            return
        if done:
            await self._get_parameters(done, op.id)
        else:
            self._send_json(fg.encode_json("parameterValues", parameters=[], id=op.id))

    async def _subscribe_params(self, names: list[str]) -> None:
        for name in names:
            if name in self._params:
                continue
            if len(self._params) >= self.limits.max_subscriptions:
                self.status(fg.STATUS_ERROR, f"subscribeParameterUpdates: at most {self.limits.max_subscriptions}")
                return
            try:
                await self.hub.watch_param(name, self._param_update)
            except MrosError as exc:
                self.status(fg.STATUS_ERROR, f"subscribeParameterUpdates {name}: {exc}")
                continue
            self._params.add(name)

    def _param_update(self, key: str, value: Any) -> None:
        self._send_json(fg.encode_json("parameterValues", parameters=[_parameter(key, value)]))


def _parameter(name: str, value: Any) -> dict[str, Any]:
    """A ROS parameter value as a Foxglove parameter (binary values as base64 byte_array)."""
    if isinstance(value, bytes | bytearray):
        return {"name": name, "value": base64.b64encode(value).decode(), "type": "byte_array"}
    if isinstance(value, dict) and value == {}:
        return {"name": name, "value": {}}
    return {"name": name, "value": value}


def _from_parameter(param: fg.Parameter) -> Any:
    if param.type == "byte_array" and isinstance(param.value, str):
        try:
            return base64.b64decode(param.value, validate=True)
        except ValueError as exc:
            raise MrosError(f"{param.name}: byte_array value is not base64: {exc}") from None
    return param.value


def service_json(info: ServiceInfo) -> dict[str, Any]:
    def half(suffix: str, schema: str) -> dict[str, str]:
        return {"encoding": "ros1", "schemaName": info.type + suffix, "schemaEncoding": "ros1msg", "schema": schema}

    return {
        "id": info.id,
        "name": info.name,
        "type": info.type,
        "request": half("Request", info.request_definition),
        "response": half("Response", info.response_definition),
        "requestSchema": info.request_definition,
        "responseSchema": info.response_definition,
    }
