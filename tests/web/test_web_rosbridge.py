"""rosbridge v2 served by mrosd: the pure core, then ops over a real socket with an aiohttp client."""

from __future__ import annotations

import asyncio
import base64
import io
import json
import math
import random
from collections.abc import AsyncIterator
from typing import Any

import aiohttp
import pytest
from hypothesis import given
from hypothesis import strategies as st

import mrosd
from mrosd.master import Master
from mrosd.msg import get_message_class, get_service_class
from mrosd.web import rosbridge as rb
from mrosd.web.server import WebServer

String = get_message_class("std_msgs/String")
Image = get_message_class("sensor_msgs/Image")
Point = get_message_class("geometry_msgs/Point")
SetBool = get_service_class("std_srvs/SetBool")


def test_messages_encode_as_rosbridge_does() -> None:
    img = Image(height=1, width=2, encoding="mono8", step=2, data=b"\x00\xff")
    img.header.stamp.secs = 5
    data = json.loads(rb.encode_message(img))
    assert base64.b64decode(data["data"]) == b"\x00\xff"
    assert data["header"]["stamp"] == {"secs": 5, "nsecs": 0}
    assert json.loads(rb.encode_message(Point(x=math.nan, y=math.inf)))["x"] is None


def test_client_messages_take_defaults_and_refuse_wrong_types() -> None:
    img = rb.message_from_json(Image, {"width": 3, "data": base64.b64encode(b"abc").decode()})
    assert (img.width, bytes(img.data), img.height) == (3, b"abc", 0)
    with pytest.raises(rb.RosbridgeRefusal, match="width"):
        rb.message_from_json(Image, {"width": "wide"})


@pytest.mark.parametrize(
    ("text", "why"),
    [("[]", "not a JSON object"), ('{"op":"nuke"}', "unknown op"), ('{"op":"fragment"}', "not served")],
)
def test_bad_ops_are_refused_with_a_reason(text: str, why: str) -> None:
    with pytest.raises(rb.RosbridgeRefusal, match=why):
        rb.decode_op(text)


def png_text(png: bytes) -> tuple[tuple[int, int], bytes]:
    """A PNG read back by a real decoder (Pillow): its size and its RGB bytes."""
    pil = pytest.importorskip("PIL.Image", reason="Pillow (a matplotlib dependency of the dev extra) is missing")
    image = pil.open(io.BytesIO(png), formats=["PNG"])
    assert image.mode == "RGB"
    return image.size, image.tobytes()


@given(st.binary(max_size=5000))
def test_png_holds_the_text_in_rosbridges_layout(text: bytes) -> None:
    (width, height), pixels = png_text(rb.png_image(text))
    if len(text) >= 3:  # rosbridge's own formula (it fails on shorter texts; a publish op never is)
        assert (width, height) == (math.floor(math.sqrt(len(text) / 3.0)), math.ceil(len(text) / 3.0 / width))
    assert pixels[: len(text)] == text
    assert set(pixels[len(text) :]) <= {ord("\n")}  # padding JSON.parse ignores
    assert len(pixels) - len(text) < 3 * width or not text  # only the last row is padded


def test_png_op_is_the_publish_op_as_an_image() -> None:
    img = Image(height=480, width=640, encoding="rgb8", step=1920, data=bytes(range(256)) * 3600)
    text = rb.publish_json("/camera", img)
    op = json.loads(rb.png_op(text))
    assert list(op) == ["op", "data"]
    assert op["op"] == "png"
    _, pixels = png_text(base64.b64decode(op["data"]))
    assert json.loads(pixels) == json.loads(text)


@given(st.text(max_size=200))
def test_any_text_decodes_or_is_refused(text: str) -> None:
    try:
        rb.decode_op(text)
    except rb.RosbridgeRefusal:
        pass


def node(name: str, master: str) -> mrosd.Node:
    return mrosd.Node(name, master_uri=master, argv=[], host="127.0.0.1")


@pytest.fixture
async def master() -> AsyncIterator[Master]:
    async with Master(host="127.0.0.1", port=0) as m:
        yield m


async def receive(ws: aiohttp.ClientWebSocketResponse, op: str, timeout: float = 10.0, **match: Any) -> dict[str, Any]:
    async with asyncio.timeout(timeout):
        while True:
            msg = json.loads((await ws.receive()).data)
            if msg["op"] == op and all(msg.get(k) == v for k, v in match.items()):
                return msg


async def test_rosbridge_subscribe_publish_services_and_rosapi(master: Master) -> None:
    async with (
        WebServer(master.uri, port=0, rosbridge_port=0, node_host="127.0.0.1") as server,
        node("robot", master.uri) as robot,
        aiohttp.ClientSession() as http,
    ):
        cam = await robot.advertise("/image", Image)
        listener = await robot.subscribe("/cmd", String)
        await robot.advertise_service("/enable", SetBool, lambda r: SetBool._response_class(success=r.data))
        await robot.set_param("/robot/name", "bot")
        ws = await http.ws_connect(server.rosbridge_url)
        await ws.send_str(json.dumps({"op": "subscribe", "topic": "/image", "type": "sensor_msgs/Image"}))
        await cam.wait_for_subscribers(1, timeout=10)
        pixels = bytes(range(256)) * 3600
        await cam.publish(Image(height=480, width=640, encoding="rgb8", step=1920, data=pixels))
        got = await receive(ws, "publish", topic="/image")
        assert base64.b64decode(got["msg"]["data"]) == pixels

        await ws.send_str(json.dumps({"op": "advertise", "topic": "/cmd", "type": "std_msgs/String"}))
        await listener.wait_for_publishers(1, timeout=10)
        await ws.send_str(json.dumps({"op": "publish", "topic": "/cmd", "msg": {"data": "go"}}))
        assert (await listener.next(timeout=10)).data == "go"

        async with asyncio.timeout(10):
            while "/enable" not in server.hub.services:  # noqa: ASYNC110 - the hub probes the service's type
                await asyncio.sleep(0.01)
        await ws.send_str(json.dumps({"op": "call_service", "service": "/enable", "args": {"data": True}, "id": "c1"}))
        reply = await receive(ws, "service_response", id="c1")
        assert reply["result"] is True
        assert reply["values"]["success"] is True

        for name, args, key, want in [
            ("rosapi/get_param", {"name": "/robot/name"}, "value", '"bot"'),
            ("/rosapi/has_param", {"name": "/robot/name"}, "exists", True),
        ]:
            await ws.send_str(json.dumps({"op": "call_service", "service": name, "args": args, "id": name}))
            assert (await receive(ws, "service_response", id=name))["values"][key] == want
        await ws.send_str(json.dumps({"op": "call_service", "service": "/rosapi/topics", "args": {}, "id": "topics"}))
        topics = (await receive(ws, "service_response", id="topics"))["values"]
        assert "/image" in topics["topics"]

        await ws.send_str(json.dumps({"op": "publish", "topic": "/cmd", "msg": {"data": 5}, "id": "bad"}))
        status = await receive(ws, "status", id="bad")
        assert status["level"] == "error"
        await ws.close()


async def test_rosbridge_cbor_and_cbor_raw(master: Master) -> None:
    import cbor2

    async with (
        WebServer(master.uri, port=0, rosbridge_port=0, node_host="127.0.0.1") as server,
        node("robot", master.uri) as robot,
        aiohttp.ClientSession() as http,
    ):
        cam = await robot.advertise("/image", Image)
        a = await http.ws_connect(server.rosbridge_url)
        b = await http.ws_connect(server.rosbridge_url)
        await a.send_str(
            json.dumps({"op": "subscribe", "topic": "/image", "type": "sensor_msgs/Image", "compression": "cbor"})
        )
        await b.send_str(json.dumps({"op": "subscribe", "topic": "/image", "compression": "cbor-raw"}))
        async with asyncio.timeout(10):
            while server.hub.sink_count("/image") < 2:  # noqa: ASYNC110 - the sessions subscribe in the server
                await asyncio.sleep(0.01)
        await cam.wait_for_subscribers(1, timeout=10)
        img = Image(height=2, width=2, encoding="mono8", step=2, data=b"\x01\x02\x03\x04")
        await cam.publish(img)
        got_a = cbor2.loads((await a.receive(timeout=10)).data)
        assert (got_a["op"], got_a["topic"], got_a["msg"]["data"]) == ("publish", "/image", b"\x01\x02\x03\x04")
        got_b = cbor2.loads((await b.receive(timeout=10)).data)
        assert got_b["msg"]["bytes"] == img.serialize()
        assert got_b["msg"]["secs"] > 0
        await a.close()
        await b.close()
        async with asyncio.timeout(10):
            while server.rosbridge_sessions:  # noqa: ASYNC110 - the server ends the sessions
                await asyncio.sleep(0.01)
        assert server.hub.ledger.size == 0


async def test_a_rosbridge_client_provides_a_service_to_ros(master: Master) -> None:
    async with (
        WebServer(master.uri, port=0, rosbridge_port=0, node_host="127.0.0.1") as server,
        node("caller", master.uri) as caller,
        aiohttp.ClientSession() as http,
    ):
        ws = await http.ws_connect(server.rosbridge_url)
        await ws.send_str(json.dumps({"op": "advertise_service", "service": "/toggle", "type": "std_srvs/SetBool"}))
        proxy = caller.service_proxy("/toggle", SetBool)
        await proxy.wait_for_service(timeout=10)
        call = asyncio.ensure_future(proxy.call(SetBool._request_class(data=True), timeout=10))
        request = await receive(ws, "call_service", service="/toggle")
        assert request["args"] == {"data": True}
        reply = {"op": "service_response", "id": request["id"], "service": "/toggle", "result": True}
        await ws.send_str(json.dumps({**reply, "values": {"success": True, "message": "toggled"}}))
        response = await call
        assert (response.success, response.message) == (True, "toggled")
        # A refusal from the client reaches the ROS caller as a service error.
        call = asyncio.ensure_future(proxy.call(SetBool._request_class(data=False), timeout=10))
        request = await receive(ws, "call_service", service="/toggle")
        await ws.send_str(json.dumps({**reply, "id": request["id"], "result": False, "values": "no way"}))
        with pytest.raises(mrosd.errors.ServiceError, match="no way"):
            await call
        await ws.close()
        async with asyncio.timeout(10):
            while True:  # the client's service is withdrawn when it disconnects
                try:
                    await caller.master.lookup_service("/toggle")
                except mrosd.errors.MasterError:
                    break
                await asyncio.sleep(0.02)


async def test_rosapi_details_and_unknown_types(master: Master) -> None:
    async with (
        WebServer(master.uri, port=0, rosbridge_port=0, node_host="127.0.0.1") as server,
        node("talker", master.uri) as talker,
        aiohttp.ClientSession() as http,
    ):
        await talker.advertise("/chatter", String)
        ws = await http.ws_connect(server.rosbridge_url)
        calls = [
            ("rosapi/message_details", {"type": "sensor_msgs/Image"}),
            ("/rosapi/publishers", {"topic": "/chatter"}),
            ("/rosapi/get_ros_version", {}),
        ]
        for i, (service, args) in enumerate(calls):
            await ws.send_str(json.dumps({"op": "call_service", "service": service, "args": args, "id": str(i)}))
        answers = {}
        while len(answers) < len(calls):  # calls run concurrently: answers come in any order
            reply = await receive(ws, "service_response")
            answers[reply["id"]] = reply["values"]
        assert [d["type"] for d in answers["0"]["typedefs"]] == ["sensor_msgs/Image", "std_msgs/Header"]
        assert answers["1"]["publishers"] == ["/talker"]
        assert answers["2"]["version"] == 1
        sub = {"op": "subscribe", "topic": "/x", "type": "nope_msgs/Nope", "id": "u"}
        await ws.send_str(json.dumps(sub))
        status = await receive(ws, "status", id="u")
        assert "nope_msgs/Nope" in status["msg"]
        assert "searched" in status["msg"]
        await ws.close()


async def test_fragment_size_splits_a_message_into_fragment_ops(master: Master) -> None:
    async with (
        WebServer(master.uri, port=0, rosbridge_port=0, node_host="127.0.0.1") as server,
        node("talker", master.uri) as talker,
        aiohttp.ClientSession() as http,
    ):
        pub = await talker.advertise("/long", String)
        ws = await http.ws_connect(server.rosbridge_url)
        await ws.send_str(json.dumps({"op": "subscribe", "topic": "/long", "fragment_size": 100}))
        await pub.wait_for_subscribers(1, timeout=10)
        await pub.publish(String(data="x" * 1000))
        first = await receive(ws, "fragment")
        parts = [first]
        while len(parts) < first["total"]:
            parts.append(await receive(ws, "fragment"))
        assert [p["num"] for p in parts] == list(range(first["total"]))
        whole = json.loads("".join(p["data"] for p in parts))
        assert whole == {"op": "publish", "topic": "/long", "msg": {"data": "x" * 1000}}
        await ws.close()


async def test_png_compression_sends_the_publish_op_as_a_png_whole_or_in_fragments(master: Master) -> None:
    async with (
        WebServer(master.uri, port=0, rosbridge_port=0, node_host="127.0.0.1") as server,
        node("camera", master.uri) as camera,
        aiohttp.ClientSession() as http,
    ):
        cam = await camera.advertise("/image", Image)
        whole = await http.ws_connect(server.rosbridge_url)
        cut = await http.ws_connect(server.rosbridge_url)
        await whole.send_str(json.dumps({"op": "subscribe", "topic": "/image", "compression": "png"}))
        sub = {"op": "subscribe", "topic": "/image", "compression": "png", "fragment_size": 50_000}
        await cut.send_str(json.dumps(sub))
        async with asyncio.timeout(10):
            while server.hub.sink_count("/image") < 2:  # noqa: ASYNC110 - the sessions subscribe in the server
                await asyncio.sleep(0.01)
        await cam.wait_for_subscribers(1, timeout=10)
        # 640x480 rgb8 of noise (a camera's, not a pattern zlib shrinks to nothing): compressed off the loop,
        # then cut into 25 fragments
        pixels = random.Random(22).randbytes(640 * 480 * 3)
        img = Image(height=480, width=640, encoding="rgb8", step=1920, data=pixels)
        await cam.publish(img)
        want = json.loads(rb.publish_json("/image", img))

        png = await receive(whole, "png")
        assert json.loads(png_text(base64.b64decode(png["data"]))[1]) == want
        first = await receive(cut, "fragment")
        parts = [first]
        while len(parts) < first["total"]:
            parts.append(await receive(cut, "fragment"))
        assert first["total"] > 1
        assert [p["num"] for p in parts] == list(range(first["total"]))
        png = json.loads("".join(p["data"] for p in parts))
        assert png["op"] == "png"
        assert json.loads(png_text(base64.b64decode(png["data"]))[1]) == want
        await whole.close()
        await cut.close()


async def test_rosbridge_token_by_auth_op_or_url(master: Master) -> None:
    from mrosd.web.access import AccessPolicy

    async with (
        WebServer(
            master.uri, port=0, rosbridge_port=0, node_host="127.0.0.1", policy=AccessPolicy(token="s3cret")
        ) as server,
        aiohttp.ClientSession() as http,
    ):
        ws = await http.ws_connect(server.rosbridge_url)
        topics = {"op": "call_service", "service": "/rosapi/topics", "id": "t"}
        await ws.send_str(json.dumps(topics))
        assert "authenticate first" in (await receive(ws, "status", id="t"))["msg"]
        await ws.send_str(json.dumps({"op": "auth", "mac": "wrong", "id": "a"}))
        assert "wrong token" in (await receive(ws, "status", id="a"))["msg"]
        await ws.send_str(json.dumps({"op": "auth", "mac": "s3cret"}))
        await ws.send_str(json.dumps(topics))
        assert (await receive(ws, "service_response", id="t"))["result"] is True
        await ws.close()
        ws = await http.ws_connect(server.rosbridge_url + "?token=s3cret")
        await ws.send_str(json.dumps(topics))
        assert (await receive(ws, "service_response", id="t"))["result"] is True
        await ws.close()
