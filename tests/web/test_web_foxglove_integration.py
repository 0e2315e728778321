"""The Foxglove WebSocket server against mrosd's master, with real sockets and an aiohttp WebSocket client."""

from __future__ import annotations

import asyncio
import json
import struct
from collections.abc import AsyncIterator
from typing import Any

import aiohttp
import pytest

from mrosd import backports
from mrosd.master import Master
from mrosd.msg import get_message_class
from mrosd.web.foxglove_server import SessionLimits
from mrosd.web.server import WebServer
from tests.web.inloop import node, until

String = get_message_class("std_msgs/String")
Image = get_message_class("sensor_msgs/Image")


class Client:
    """A minimal Foxglove client: JSON ops out, JSON and binary messages in, each awaited with a timeout."""

    def __init__(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        self.ws = ws
        self.channels: dict[str, dict[str, Any]] = {}
        self.json: list[dict[str, Any]] = []
        self.binary: list[bytes] = []

    async def send(self, **op: Any) -> None:
        await self.ws.send_str(json.dumps(op))

    async def receive(self, timeout: float = 10.0) -> dict[str, Any] | bytes:
        msg = await self.ws.receive(timeout=timeout)
        if msg.type == aiohttp.WSMsgType.TEXT:
            data = json.loads(msg.data)
            if data["op"] == "advertise":
                for ch in data["channels"]:
                    self.channels[ch["topic"]] = ch
            self.json.append(data)
            return data
        assert msg.type == aiohttp.WSMsgType.BINARY, msg
        return bytes(msg.data)

    async def until_json(self, op: str, timeout: float = 10.0, **match: Any) -> dict[str, Any]:
        async with backports.timeout(timeout):
            while True:
                got = await self.receive(timeout)
                if isinstance(got, dict) and got["op"] == op and all(got.get(k) == v for k, v in match.items()):
                    return got

    async def until_channel(self, topic: str, timeout: float = 10.0) -> dict[str, Any]:
        async with backports.timeout(timeout):
            while topic not in self.channels:
                await self.receive(timeout)
            return self.channels[topic]

    async def until_binary(self, timeout: float = 10.0) -> bytes:
        async with backports.timeout(timeout):
            while True:
                got = await self.receive(timeout)
                if isinstance(got, bytes):
                    return got


@pytest.fixture
async def server(master: Master) -> AsyncIterator[WebServer]:
    async with WebServer(master.uri, port=0, node_host="127.0.0.1") as s:
        yield s


async def connect(session: aiohttp.ClientSession, server: WebServer, protocol: str = "foxglove.websocket.v1") -> Client:
    return await connect_url(session, server.url, protocol)


async def connect_url(session: aiohttp.ClientSession, url: str, protocol: str = "foxglove.websocket.v1") -> Client:
    ws = await session.ws_connect(url, protocols=[protocol], max_msg_size=0)
    assert ws.protocol == protocol
    return Client(ws)


async def test_server_info_advertise_subscribe_forwards_the_raw_body(server: WebServer, master: Master) -> None:
    async with node("talker", master.uri) as talker, aiohttp.ClientSession() as http:
        pub = await talker.advertise("/chatter", String)
        client = await connect(http, server)
        info = await client.until_json("serverInfo")
        assert "clientPublish" in info["capabilities"]
        channel = await client.until_channel("/chatter")
        assert channel["encoding"] == "ros1"
        assert channel["schemaName"] == "std_msgs/String"
        assert channel["schema"] == String._full_text
        await client.send(op="subscribe", subscriptions=[{"id": 7, "channelId": channel["id"]}])
        await pub.wait_for_subscribers(1, timeout=10)
        msg = String(data="hello browser")
        await pub.publish(msg)
        frame = await client.until_binary()
        op, sub_id, stamp = struct.unpack_from("<BIQ", frame)
        assert (op, sub_id) == (1, 7)
        assert stamp > 0
        assert frame[13:] == msg.serialize()


async def test_the_sdk_subprotocol_is_answered_with_its_own_name(server: WebServer) -> None:
    async with aiohttp.ClientSession() as http:
        client = await connect(http, server, "foxglove.sdk.v1")
        assert (await client.until_json("serverInfo"))["op"] == "serverInfo"


async def test_two_clients_share_one_subscription_and_disconnect_releases_it(server: WebServer, master: Master) -> None:
    async with node("talker", master.uri) as talker, aiohttp.ClientSession() as http:
        pub = await talker.advertise("/shared", String)
        a, b = await connect(http, server), await connect(http, server)
        for c, sub_id in ((a, 1), (b, 2)):
            ch = await c.until_channel("/shared")
            await c.send(op="subscribe", subscriptions=[{"id": sub_id, "channelId": ch["id"]}])
        await until(lambda: server.hub.sink_count("/shared") == 2)
        await pub.wait_for_subscribers(1, timeout=10)
        assert pub.get_num_connections() == 1  # one TCPROS subscription for both clients
        await pub.publish(String(data="x"))
        assert (await a.until_binary())[13:] == (await b.until_binary())[13:]
        await a.ws.close()
        await b.ws.close()
        await until(lambda: server.hub.topic_stats("/shared") is None and not server.sessions)


async def test_refusals_are_status_messages_and_the_connection_stays(server: WebServer) -> None:
    async with aiohttp.ClientSession() as http:
        client = await connect(http, server)
        await client.until_json("serverInfo")
        await client.ws.send_str("{not json")
        assert (await client.until_json("status"))["level"] == 2
        await client.send(op="frobnicate")
        assert "unknown op" in (await client.until_json("status"))["message"]
        await client.send(op="subscribe", subscriptions=[{"id": 1, "channelId": 999999}])
        assert "no channel" in (await client.until_json("status"))["message"]
        await client.ws.send_bytes(b"\x09")
        assert "opcode" in (await client.until_json("status"))["message"]
        await client.send(op="subscribe", subscriptions=[{"id": -1, "channelId": 1}])
        assert (await client.until_json("status"))["level"] == 2


async def test_client_publish_reaches_a_ros_subscriber(server: WebServer, master: Master) -> None:
    async with node("listener", master.uri) as listener, aiohttp.ClientSession() as http:
        sub = await listener.subscribe("/from_browser", String)
        client = await connect(http, server)
        await client.until_json("serverInfo")
        await client.send(
            op="advertise",
            channels=[{"id": 3, "topic": "/from_browser", "encoding": "ros1", "schemaName": "std_msgs/String"}],
        )
        await sub.wait_for_publishers(1, timeout=10)
        await client.ws.send_bytes(struct.pack("<BI", 1, 3) + String(data="hi ros").serialize())
        assert (await sub.next(timeout=10)).data == "hi ros"
        await client.ws.send_bytes(struct.pack("<BI", 1, 3) + b"\xff\xff\xff\xff")
        assert "not a std_msgs/String" in (await client.until_json("status"))["message"]


async def test_parameters_get_set_and_subscribe(server: WebServer, master: Master) -> None:
    async with node("setter", master.uri) as setter, aiohttp.ClientSession() as http:
        await setter.set_param("/robot/speed", 1.5)
        client = await connect(http, server)
        await client.send(op="getParameters", parameterNames=["/robot/speed"], id="a")
        got = await client.until_json("parameterValues", id="a")
        assert got["parameters"] == [{"name": "/robot/speed", "value": 1.5}]
        await client.send(op="subscribeParameterUpdates", parameterNames=["/robot/speed"])
        await client.send(op="setParameters", parameters=[{"name": "/robot/speed", "value": 2.5}], id="b")
        assert (await client.until_json("parameterValues", id="b"))["parameters"][0]["value"] == 2.5
        await setter.set_param("/robot/speed", 3.5)
        async with backports.timeout(10):
            while True:
                update = await client.until_json("parameterValues")
                if update.get("id") is None and update["parameters"][0]["value"] == 3.5:
                    break


async def test_connection_graph_lists_publishers(server: WebServer, master: Master) -> None:
    async with node("talker", master.uri) as talker, aiohttp.ClientSession() as http:
        await talker.advertise("/graph_topic", String)
        client = await connect(http, server)
        await client.send(op="subscribeConnectionGraph")
        async with backports.timeout(10):
            while True:
                update = await client.until_json("connectionGraphUpdate")
                names = {t["name"]: t["publisherIds"] for t in update["publishedTopics"]}
                if "/talker" in names.get("/graph_topic", []):
                    break


async def test_a_stalled_client_costs_a_bounded_queue_and_gets_a_drop_report(master: Master) -> None:
    limits = SessionLimits(queue_bytes=256 * 1024)
    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1", limits=limits) as server,
        node("camera", master.uri) as camera,
        aiohttp.ClientSession() as http,
    ):
        pub = await camera.advertise("/image", Image)
        client = await connect(http, server)
        ch = await client.until_channel("/image")
        await client.send(op="subscribe", subscriptions=[{"id": 1, "channelId": ch["id"]}])
        await pub.wait_for_subscribers(1, timeout=10)
        # The client reads nothing while 40 MB are published: the session holds at most its queue bound.
        img = Image(height=100, width=1000, encoding="mono8", step=1000, data=bytes(100_000) * 10)
        for _ in range(40):
            await pub.publish(img)
            await asyncio.sleep(0.005)
        (session,) = server.sessions
        await until(lambda: sum(s.queue.dropped for s in session.subs.values()) > 0)
        assert all(s.queue.size <= limits.queue_bytes + 1_000_100 for s in session.subs.values())
        async with backports.timeout(10):
            while True:
                status = await client.until_json("status")
                if "dropped" in status["message"]:
                    break


async def test_service_calls_with_the_probed_type(server: WebServer, master: Master) -> None:
    from mrosd.msg import get_service_class

    set_bool = get_service_class("std_srvs/SetBool")
    async with node("provider", master.uri) as provider, aiohttp.ClientSession() as http:
        await provider.advertise_service(
            "/enable", set_bool, lambda r: set_bool._response_class(success=r.data, message="ok")
        )
        client = await connect(http, server)
        async with backports.timeout(10):
            svc: dict[str, Any] = {}
            while not svc:
                adv = await client.until_json("advertiseServices")
                svc = next((s for s in adv["services"] if s["name"] == "/enable"), {})
        assert svc["type"] == "std_srvs/SetBool"
        assert svc["request"]["schema"] == set_bool._request_class._full_text
        request = set_bool._request_class(data=True).serialize()
        await client.ws.send_bytes(struct.pack("<BIII", 2, svc["id"], 42, 4) + b"ros1" + request)
        frame = await client.until_binary()
        op, service_id, call_id, enc_len = struct.unpack_from("<BIII", frame)
        assert (op, service_id, call_id, frame[13 : 13 + enc_len]) == (3, svc["id"], 42, b"ros1")
        response = set_bool._response_class.deserialize(frame[13 + enc_len :])
        assert (response.success, response.message) == (True, "ok")
        await client.ws.send_bytes(struct.pack("<BIII", 2, svc["id"], 43, 4) + b"ros1" + b"\x01\x02")
        failure = await client.until_json("serviceCallFailure")
        assert failure["callId"] == 43


async def test_a_token_is_required_when_set_and_allow_lists_hide_topics(master: Master) -> None:
    from mrosd.web.access import AccessPolicy

    policy = AccessPolicy(topics=["/public/*"], token="s3cret")
    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1", policy=policy) as server,
        node("talker", master.uri) as talker,
        aiohttp.ClientSession() as http,
    ):
        await talker.advertise("/public/a", String)
        await talker.advertise("/private/b", String)
        with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
            await http.ws_connect(server.url, protocols=["foxglove.websocket.v1"])
        assert refused.value.status == 401
        ws = await http.ws_connect(server.url + "?token=s3cret", protocols=["foxglove.websocket.v1"])
        client = Client(ws)
        await client.until_channel("/public/a")
        assert "/private/b" not in client.channels
        await client.send(op="getParameters", parameterNames=[], id="all")
        await client.until_json("parameterValues", id="all")


async def test_sim_time_is_offered_and_follows_clock(master: Master) -> None:
    Clock = get_message_class("rosgraph_msgs/Clock")
    async with node("sim", master.uri) as sim:
        await sim.set_param("/use_sim_time", True)
        clock = await sim.advertise("/clock", Clock)
        async with (
            WebServer(master.uri, port=0, node_host="127.0.0.1") as server,
            aiohttp.ClientSession() as http,
        ):
            client = await connect(http, server)
            info = await client.until_json("serverInfo")
            assert "time" in info["capabilities"]
            await clock.wait_for_subscribers(1, timeout=10)
            msg = Clock()
            msg.clock.secs, msg.clock.nsecs = 12, 345
            await clock.publish(msg)
            frame = await client.until_binary()
            assert struct.unpack("<BQ", frame) == (2, 12_000_000_345)


async def test_the_hub_stops_reading_when_every_client_is_behind_and_resumes(
    master: Master, monkeypatch: pytest.MonkeyPatch
) -> None:
    """TCP's own backpressure: the bridge receives what its fastest client takes, not all the publisher sends.

    Messages under ``BIG_MESSAGE_BYTES`` (queued in order; a big topic's queue keeps only its newest message,
    dropped in the bridge rather than left in TCP buffers, where it would be stale when read)."""
    monkeypatch.setenv("MROSD_SHM", "0")  # TCPROS between the nodes of this process: its reading is what pauses
    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1") as server,
        node("camera", master.uri) as camera,
        aiohttp.ClientSession() as http,
    ):
        pub = await camera.advertise("/image", Image)
        client = await connect(http, server)
        ch = await client.until_channel("/image")
        await client.send(op="subscribe", subscriptions=[{"id": 1, "channelId": ch["id"]}])
        await pub.wait_for_subscribers(1, timeout=10)
        entry = server.hub._shared["/image"]
        img = Image(height=200, width=1000, encoding="mono8", step=1000, data=bytes(200 * 1000))
        async with backports.timeout(20):
            while not entry.paused:  # the client reads nothing meanwhile
                await pub.publish(img)
                await asyncio.sleep(0.01)
        async with backports.timeout(20):
            while entry.paused:  # reading again once the client takes its messages
                await client.until_binary()


async def test_a_type_on_no_search_path_is_read_from_its_publishers_header(server: WebServer, master: Master) -> None:
    from mrosd.msg import load_type

    custom = load_type("my_robot_msgs/Battery", "float32 voltage\nstring cell\n")
    async with node("battery", master.uri) as battery, aiohttp.ClientSession() as http:
        pub = await battery.advertise("/battery", custom)
        client = await connect(http, server)
        channel = await client.until_channel("/battery")
        assert (channel["schemaName"], channel["schema"]) == ("my_robot_msgs/Battery", "float32 voltage\nstring cell\n")
        await client.send(op="subscribe", subscriptions=[{"id": 1, "channelId": channel["id"]}])
        await until(lambda: server.hub.sink_count("/battery") == 1)
        await pub.wait_for_subscribers(1, timeout=10)
        msg = custom(voltage=12.5, cell="A")
        await pub.publish(msg)
        assert (await client.until_binary())[13:] == msg.serialize()


def ipv6_loopback() -> bool:
    import socket

    try:
        with socket.socket(socket.AF_INET6, socket.SOCK_STREAM) as s:
            s.bind(("::1", 0))
        return True
    except OSError:
        return False


@pytest.mark.skipif(not ipv6_loopback(), reason="this machine has no IPv6 loopback (::1 cannot be bound)")
async def test_both_ports_are_served_on_each_of_several_addresses(master: Master) -> None:
    async with (
        WebServer(master.uri, host=["127.0.0.1", "::1"], port=0, rosbridge_port=0, node_host="127.0.0.1") as server,
        aiohttp.ClientSession() as http,
    ):
        assert server.urls == [f"ws://127.0.0.1:{server.port}/", f"ws://[::1]:{server.port}/"]
        for url in server.urls:
            client = await connect_url(http, url)
            assert (await client.until_json("serverInfo"))["name"] == "mrosd"
        for url in server.rosbridge_urls:
            async with http.ws_connect(url) as ws:
                await ws.send_str(json.dumps({"op": "call_service", "service": "/rosapi/get_time", "id": "t"}))
                reply = json.loads((await ws.receive(timeout=10)).data)
                assert (reply["op"], reply["result"]) == ("service_response", True)
        async with http.get(f"http://[::1]:{server.port}/") as page:
            assert page.status == 200


async def test_several_addresses_need_the_token_if_any_is_not_loopback(master: Master) -> None:
    from mrosd.errors import ConfigError
    from mrosd.web.access import AccessPolicy

    with pytest.raises(ConfigError, match=r"binding '0\.0\.0\.0' \(not loopback\) needs a token"):
        WebServer(master.uri, host=["127.0.0.1", "0.0.0.0"], port=0)
    with pytest.raises(ConfigError, match="no address"):
        WebServer(master.uri, host=[], port=0)
    WebServer(master.uri, host=["127.0.0.1", "0.0.0.0"], port=0, policy=AccessPolicy(token="s3cret"))  # not started


async def test_the_hubs_own_sim_time_watch_outlives_clients_and_the_params_allow_list(master: Master) -> None:
    """A client watching /use_sim_time and leaving must not end the hub's watch, and the [web] params
    allow-list (what clients may see) does not hide the parameter from the hub itself."""
    from mrosd.web.access import AccessPolicy

    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1") as server,
        WebServer(
            master.uri, port=0, node_host="127.0.0.1", node_name="narrow", policy=AccessPolicy(params=["/robot/*"])
        ) as narrow,
        node("sim", master.uri) as sim,
        aiohttp.ClientSession() as http,
    ):
        client = await connect(http, server)
        await client.send(op="subscribeParameterUpdates", parameterNames=["/use_sim_time"])
        await until(lambda: server.hub.sink_count("/clock") == 0 and server.sessions)
        await client.send(op="unsubscribeParameterUpdates", parameterNames=["/use_sim_time"])
        await client.ws.close()
        await until(lambda: not server.sessions)
        await sim.set_param("/use_sim_time", True)
        await until(lambda: server.hub.sim_time and narrow.hub.sim_time)
        assert server.hub.sink_count("/clock") == 1 and narrow.hub.sink_count("/clock") == 1
        await sim.master.delete_param("/use_sim_time")  # paramUpdate says {}: unset is false
        await until(lambda: not server.hub.sim_time and not narrow.hub.sim_time)
        assert server.hub.sink_count("/clock") == 0
