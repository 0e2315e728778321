"""Hostile and slow WebSocket clients of mrosd.web: what they can make the daemon hold, and that it answers.

Real sockets and a real master; the server runs in the test's loop so that its state can be inspected.
"""

from __future__ import annotations

import asyncio
import json

import aiohttp
import pytest

from mrosd import backports
from mrosd.master import Master
from mrosd.msg import get_message_class
from mrosd.web.foxglove_server import SessionLimits
from mrosd.web.server import WebServer
from tests.web.inloop import node, until

Image = get_message_class("sensor_msgs/Image")
MiB = 1024 * 1024


async def channels_of(ws: aiohttp.ClientWebSocketResponse, topics: set[str]) -> dict[str, int]:
    found: dict[str, int] = {}
    async with backports.timeout(10):
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
        async with backports.timeout(10):
            while (await bad.receive()).type not in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED):
                pass
        await good.send_str(json.dumps({"op": "getParameters", "parameterNames": ["/nope"], "id": "x"}))
        async with backports.timeout(10):
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
        # under BIG_MESSAGE_BYTES: a big topic keeps only its newest message and never pauses the hub
        img = Image(height=200, width=1000, encoding="mono8", step=1000, data=bytes(200 * 1000))
        entry = server.hub._shared["/image"]
        async with backports.timeout(30):
            steady = 0
            while steady < 50:  # paused, and staying paused: the stalled client's socket is full
                await pub.publish(img)
                await asyncio.sleep(0.01)
                steady = steady + 1 if entry.paused else 0
        live = await http.ws_connect(server.url, protocols=["foxglove.websocket.v1"])
        await channels_of(live, {"/image"})
        await live.send_str(subscribe)
        await until(lambda: server.hub.sink_count("/image") == 2)
        async with backports.timeout(20):
            while True:
                await pub.publish(img)
                try:
                    msg = await backports.wait_for(live.receive(), 0.2)
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


# --- the page (mrosd/web/page.py, static/) and its x-mrosd ops ---------------------------------------------


@pytest.mark.parametrize(
    "path",
    [
        "/static/../server.py",
        "/static/..%2fserver.py",
        "/static/%2e%2e/server.py",
        "/static/..%5cserver.py",
        "/static//etc/passwd",
        "/static/%2fetc%2fpasswd",
        "/static/app.js%00.css",
        "/static/__init__.py",
        "/static/.hidden.js",
        "/static/APP.JS",
        "/static/" + "a" * 5000 + ".js",
        "/../../etc/passwd",
    ],
)
async def test_a_hostile_asset_path_is_404_and_serves_nothing_outside_the_folder(master: Master, path: str) -> None:
    async with WebServer(master.uri, port=0, node_host="127.0.0.1") as server, aiohttp.ClientSession() as http:
        # raw path: the client must not normalise the dots away before they reach the server
        url = aiohttp.client.URL(f"http://127.0.0.1:{server.port}{path}", encoded=True)
        async with http.get(url) as resp:
            body = await resp.read()
        assert resp.status in (400, 404, 414, 431), (path, resp.status)
        assert b"import" not in body and b"root:" not in body


async def test_the_page_and_its_assets_are_served_with_their_content_types(master: Master) -> None:
    async with WebServer(master.uri, port=0, node_host="127.0.0.1") as server, aiohttp.ClientSession() as http:
        base = f"http://127.0.0.1:{server.port}"
        for path, ctype in [
            ("/", "text/html"),
            ("/static/app.js", "text/javascript"),
            ("/static/ros1.js", "text/javascript"),
            ("/static/style.css", "text/css"),
            ("/static/favicon.svg", "image/svg+xml"),
        ]:
            async with http.get(base + path) as resp:
                assert resp.status == 200, path
                assert resp.content_type == ctype, (path, resp.content_type)
                assert resp.headers["X-Content-Type-Options"] == "nosniff"
        # the same path still upgrades to the Foxglove protocol
        async with http.ws_connect(base + "/", protocols=["foxglove.websocket.v1"]) as ws:
            assert json.loads((await ws.receive(timeout=10)).data)["op"] == "serverInfo"


async def test_a_throttled_subscription_of_a_client_that_never_reads_holds_one_message(master: Master) -> None:
    """x-mrosd.throttle keeps the latest message only: a stalled tab on a 1 MB topic costs one message."""
    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1") as server,
        node("camera", master.uri) as camera,
        aiohttp.ClientSession() as http,
    ):
        pub = await camera.advertise("/image", Image)
        await until(lambda: "/image" in server.hub.topics)
        ws = await http.ws_connect(server.url, protocols=["foxglove.websocket.v1"], max_msg_size=0)
        channel = server.hub.topics["/image"].id
        await ws.send_str(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": channel}]}))
        await ws.send_str(json.dumps({"op": "x-mrosd.throttle", "subscriptionId": 7, "maxRate": 0.5}))
        await until(lambda: bool(server.sessions) and 7 in next(iter(server.sessions)).subs)
        session = next(iter(server.sessions))
        await until(lambda: session.subs[7].period_ns > 0)
        await pub.wait_for_subscribers(1, timeout=10)
        img = Image(height=512, width=512, encoding="rgba8", step=2048, data=bytes(MiB))
        for _ in range(40):
            await pub.publish(img)
            await asyncio.sleep(0.005)
            assert len(session.subs[7].queue) <= 1
            assert server.hub.ledger.size <= MiB + 4096
        await ws.close()


async def test_stats_hold_topics_open_only_while_asked_and_never_pause_them(master: Master) -> None:
    String = get_message_class("std_msgs/String")
    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1") as server,
        node("talker", master.uri) as talker,
        aiohttp.ClientSession() as http,
    ):
        pub = await talker.advertise("/chatter", String)
        await until(lambda: "/chatter" in server.hub.topics)
        ws = await http.ws_connect(server.url, protocols=["foxglove.websocket.v1"])
        await ws.send_str(json.dumps({"op": "x-mrosd.subscribeStats"}))
        await until(lambda: server.hub.sink_count("/chatter") == 1)
        await pub.wait_for_subscribers(1, timeout=10)
        for _ in range(20):
            await pub.publish(String(data="x" * 1000))
        await until(lambda: (server.hub.topic_stats("/chatter") or (0, 0))[0] == 20)
        async with backports.timeout(10):
            while True:
                msg = json.loads((await ws.receive()).data)
                if msg["op"] == "x-mrosd.topicStats":
                    row = next((t for t in msg["topics"] if t["topic"] == "/chatter"), None)
                    if row is not None and row["messages"] == 20:
                        assert row["bytes"] == 20 * 1004
                        break
        await ws.send_str(json.dumps({"op": "x-mrosd.unsubscribeStats"}))
        await until(lambda: server.hub.sink_count("/chatter") == 0)
        await ws.send_str(json.dumps({"op": "x-mrosd.subscribeStats"}))
        await until(lambda: server.hub.sink_count("/chatter") == 1)
        await ws.close()  # leaving releases them too
        await until(lambda: server.hub.sink_count("/chatter") == 0 and not server.sessions)


async def test_node_details_of_a_dead_node_is_bounded_and_says_so(master: Master) -> None:
    async with WebServer(master.uri, port=0, node_host="127.0.0.1") as server, aiohttp.ClientSession() as http:
        import socket

        with socket.socket() as gone:  # a port nobody listens on: the node "died" without unregistering
            gone.bind(("127.0.0.1", 0))
            dead_uri = f"http://127.0.0.1:{gone.getsockname()[1]}/"
        from mrosd.master.client import MasterClient

        async with MasterClient(master.uri, "/ghost") as ghost:  # registers, then "dies" without unregistering
            await ghost.register_publisher("/ghost_topic", "std_msgs/String", dead_uri)
        ws = await http.ws_connect(server.url, protocols=["foxglove.websocket.v1"])
        await ws.send_str(json.dumps({"op": "x-mrosd.nodeDetails", "node": "/ghost", "id": "g"}))
        async with backports.timeout(10):
            while True:
                msg = json.loads((await ws.receive()).data)
                if msg["op"] == "x-mrosd.nodeDetails":
                    break
        assert msg["alive"] is False and msg["uri"] == dead_uri and msg["publishing"] == ["/ghost_topic"]
        await ws.send_str(json.dumps({"op": "x-mrosd.nodeDetails", "node": "/nobody", "id": "n"}))
        async with backports.timeout(10):
            while True:
                msg = json.loads((await ws.receive()).data)
                if msg["op"] == "x-mrosd.nodeDetails":
                    break
        assert "error" in msg and msg["node"] == "/nobody"
        await ws.close()
