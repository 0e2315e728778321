"""Hostile and slow WebSocket clients of mrosd.web: what they can make the daemon hold, and that it answers.

Real sockets and a real master; the server runs in the test's loop so that its state can be inspected.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator, Callable

import aiohttp
import pytest

import mrosd
from mrosd.master import Master
from mrosd.msg import get_message_class
from mrosd.web.foxglove_server import SessionLimits
from mrosd.web.server import WebServer

Image = get_message_class("sensor_msgs/Image")
MiB = 1024 * 1024


async def until(cond: Callable[[], object], timeout: float = 10.0) -> None:
    async with asyncio.timeout(timeout):
        while not cond():  # noqa: ASYNC110 - the state lives in the server's callbacks
            await asyncio.sleep(0.005)


@pytest.fixture
async def master() -> AsyncIterator[Master]:
    async with Master(host="127.0.0.1", port=0) as m:
        yield m


def node(name: str, master: str) -> mrosd.Node:
    return mrosd.Node(name, master_uri=master, argv=[], host="127.0.0.1")


async def channels_of(ws: aiohttp.ClientWebSocketResponse, topics: set[str]) -> dict[str, int]:
    found: dict[str, int] = {}
    async with asyncio.timeout(10):
        while set(found) != topics:
            msg = json.loads((await ws.receive()).data)
            if msg["op"] == "advertise":
                found.update({c["topic"]: c["id"] for c in msg["channels"] if c["topic"] in topics})
    return found


async def test_a_stalled_client_on_many_topics_costs_at_most_its_client_budget(master: Master) -> None:
    """Per-subscription bounds alone let one client hold (topics x queue_bytes): its total is bounded too."""
    limits = SessionLimits(queue_bytes=4 * MiB, client_bytes=8 * MiB)
    topics = {f"/cam{i}" for i in range(6)}
    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1", limits=limits) as server,
        node("cameras", master.uri) as cams,
        aiohttp.ClientSession() as http,
    ):
        pubs = [await cams.advertise(t, Image) for t in sorted(topics)]
        ws = await http.ws_connect(server.url, protocols=["foxglove.websocket.v1"])
        ids = await channels_of(ws, topics)
        subs = [{"id": i, "channelId": ids[t]} for i, t in enumerate(sorted(topics))]
        await ws.send_str(json.dumps({"op": "subscribe", "subscriptions": subs}))
        await until(lambda: all(server.hub.sink_count(t) == 1 for t in topics))
        for pub in pubs:
            await pub.wait_for_subscribers(1, timeout=10)
        (session,) = server.sessions
        img = Image(height=1000, width=1000, encoding="mono8", step=1000, data=bytes(1000 * 1000))
        # The client reads nothing: 6 topics x 12 MB published, far more than the client's budget.
        peak = 0
        for _ in range(12):
            for pub in pubs:
                await pub.publish(img)
            await asyncio.sleep(0.01)
            peak = max(peak, sum(s.queue.size for s in session.subs.values()))
        await until(lambda: sum(s.queue.dropped for s in session.subs.values()) > 0)
        await asyncio.sleep(0.2)
        peak = max(peak, sum(s.queue.size for s in session.subs.values()))
        assert peak <= limits.client_bytes + 1_000_100, peak
        await ws.close()


async def test_an_oversized_client_frame_closes_only_that_client(master: Master) -> None:
    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1", max_frame=64 * 1024) as server,
        aiohttp.ClientSession() as http,
    ):
        bad = await http.ws_connect(server.url, protocols=["foxglove.websocket.v1"])
        good = await http.ws_connect(server.url, protocols=["foxglove.websocket.v1"])
        await bad.send_bytes(b"\x01" + bytes(200 * 1024))
        async with asyncio.timeout(10):
            while (await bad.receive()).type not in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED):
                pass
        await good.send_str(json.dumps({"op": "getParameters", "parameterNames": ["/nope"], "id": "x"}))
        async with asyncio.timeout(10):
            while True:
                msg = json.loads((await good.receive()).data)
                if msg["op"] == "parameterValues":
                    break
        await until(lambda: len(server.sessions) == 1)
        await good.close()


async def test_a_client_without_the_subprotocol_is_refused_before_any_state(master: Master) -> None:
    async with WebServer(master.uri, port=0, node_host="127.0.0.1") as server, aiohttp.ClientSession() as http:
        with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
            await http.ws_connect(server.url)
        assert refused.value.status == 400
        assert not server.sessions


async def test_a_client_joining_a_topic_that_a_stalled_client_paused_gets_messages(
    master: Master, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The hub stops reading a topic while every client of it is behind; a newcomer must wake it up."""
    monkeypatch.setenv("MROSD_SHM", "0")  # TCPROS between the nodes of this process: its reading is what pauses
    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1") as server,
        node("camera", master.uri) as camera,
        aiohttp.ClientSession() as http,
    ):
        pub = await camera.advertise("/image", Image)
        stalled = await http.ws_connect(server.url, protocols=["foxglove.websocket.v1"])
        ids = await channels_of(stalled, {"/image"})
        subscribe = json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": ids["/image"]}]})
        await stalled.send_str(subscribe)
        await pub.wait_for_subscribers(1, timeout=10)
        img = Image(height=1000, width=1000, encoding="mono8", step=1000, data=bytes(1000 * 1000))
        entry = server.hub._shared["/image"]
        async with asyncio.timeout(30):
            steady = 0
            while steady < 50:  # paused, and staying paused: the stalled client's socket is full
                await pub.publish(img)
                await asyncio.sleep(0.01)
                steady = steady + 1 if entry.paused else 0
        live = await http.ws_connect(server.url, protocols=["foxglove.websocket.v1"])
        await channels_of(live, {"/image"})
        await live.send_str(subscribe)
        await until(lambda: server.hub.sink_count("/image") == 2)
        async with asyncio.timeout(20):
            while True:
                await pub.publish(img)
                try:
                    msg = await asyncio.wait_for(live.receive(), 0.2)
                except TimeoutError:
                    continue
                if msg.type == aiohttp.WSMsgType.BINARY:
                    break
        await live.close()
        await stalled.close()


async def test_stalled_clients_together_cost_at_most_the_global_budget(master: Master) -> None:
    """Per-client budgets alone let N clients hold N x client_bytes: the hub bounds the sum too."""
    limits = SessionLimits(queue_bytes=4 * MiB, client_bytes=4 * MiB)
    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1", limits=limits, max_queued_bytes=6 * MiB) as server,
        node("camera", master.uri) as camera,
        aiohttp.ClientSession() as http,
    ):
        pub = await camera.advertise("/image", Image)
        clients = [await http.ws_connect(server.url, protocols=["foxglove.websocket.v1"]) for _ in range(4)]
        for ws in clients:
            ids = await channels_of(ws, {"/image"})
            await ws.send_str(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": ids["/image"]}]}))
        await until(lambda: server.hub.sink_count("/image") == 4)
        await pub.wait_for_subscribers(1, timeout=10)
        img = Image(height=1000, width=1000, encoding="mono8", step=1000, data=bytes(1000 * 1000))
        peak = 0
        for _ in range(40):  # nobody reads
            await pub.publish(img)
            await asyncio.sleep(0.01)
            peak = max(peak, sum(q.queue.size for s in server.sessions for q in s.subs.values()))
        assert peak <= 6 * MiB + 4 * 1_000_100, peak
        for ws in clients:
            await ws.close()
        await until(lambda: not server.sessions)
        assert server.hub.ledger.size == 0  # every byte counted was given back
