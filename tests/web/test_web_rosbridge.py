"""rosbridge v2 served by mrosd: the pure core, then ops over a real socket with an aiohttp client."""

from __future__ import annotations

import asyncio
import base64
import io
import json
import math
import random
from typing import Any

import aiohttp
import pytest
from hypothesis import given
from hypothesis import strategies as st

import mrosd
from mrosd import backports
from mrosd.master import Master
from mrosd.msg import get_message_class, get_service_class
from mrosd.web import rosbridge as rb
from mrosd.web.server import WebServer
from tests.web.inloop import rosbridge_and_node

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
    [
        ("[]", "not a JSON object"),
        ('{"op":"nuke"}', "unknown op"),
        ('{"op":"fragment"}', "malformed fragment"),
        ('{"op":"fragment","id":"a","num":0,"total":1e9,"data":""}', "got `float`"),
        ('{"op":"png","data":"iVBORw0KGgo="}', "rosbridge_server does not accept it either"),
    ],
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
    img = Image(height=480, width=640, encoding="rgb8", step=1920, data=random.Random(3).randbytes(921600))
    text = rb.publish_json("/camera", img)
    op = json.loads(rb.png_op(text))
    assert list(op) == ["op", "data"]
    assert op["op"] == "png"
    _, pixels = png_text(base64.b64decode(op["data"]))
    assert json.loads(pixels) == json.loads(text)
    # made in steps (one IDAT each), whose base64 pieces join into the base64 of the whole file
    assert len(list(rb.png_op_pieces(text))) > 10
    assert op["data"].encode() == base64.b64encode(rb.png_image(text))


@given(st.text(max_size=200))
def test_any_text_decodes_or_is_refused(text: str) -> None:
    try:
        rb.decode_op(text)
    except rb.RosbridgeRefusal:
        pass


def defragmenter(**bounds: Any) -> rb.Defragmenter:
    return rb.Defragmenter(**{"max_bytes": 1 << 30, "max_messages": 16, "timeout": 30.0, **bounds})


def fragment_op(message_id: str | int, num: int, total: int, data: str) -> rb.Fragment:
    return rb.Fragment(id=message_id, num=num, total=total, data=data)


@given(
    st.text(min_size=1, max_size=300),
    st.data(),
)
def test_any_cut_of_an_op_in_any_order_joins_back(text: str, data: st.DataObject) -> None:
    cuts = sorted(data.draw(st.sets(st.integers(1, len(text) - 1), max_size=30)) if len(text) > 1 else [])
    parts = [text[a:b] for a, b in zip([0, *cuts], [*cuts, len(text)], strict=True)]
    pieces = [fragment_op("m", num, len(parts), part) for num, part in enumerate(parts)]
    order = data.draw(st.permutations(pieces))
    joiner = defragmenter()
    results = []
    for i, piece in enumerate(order):
        if i and i < len(order) - 1:  # a part already sent, sent again: refused, the message kept
            twice = data.draw(st.sampled_from(order[:i]))
            with pytest.raises(rb.RosbridgeRefusal, match="twice"):
                joiner.feed(twice, 0.0)
        results.append(joiner.feed(piece, 0.0))
    assert [r for r in results if r is not None] == [text.encode()]
    assert (len(joiner), joiner.size, joiner.shared.size) == (0, 0, 0)


@given(
    st.lists(
        st.tuples(st.sampled_from(["a", "b", "c", 7]), st.integers(0, 40), st.integers(1, 40), st.text(max_size=60)),
        max_size=80,
    ),
    st.integers(200, 3000),
    st.integers(300, 5000),
)
def test_what_a_client_holds_stays_within_every_bound(
    ops: list[tuple[str | int, int, int, str]], max_bytes: int, shared_max: int
) -> None:
    from mrosd.web.queue import Ledger

    shared = Ledger()
    clients = [defragmenter(max_bytes=max_bytes, max_messages=2, shared=shared, shared_max=shared_max) for _ in "xy"]
    for i, (key, num, total, data) in enumerate(ops):
        joiner = clients[i % 2]
        try:
            joiner.feed(fragment_op(key, num, total, data), float(i))
        except rb.RosbridgeRefusal:
            pass
        assert joiner.size <= max_bytes
        assert len(joiner) <= 2
        assert shared.size == sum(c.size for c in clients) <= shared_max
        joiner.expire(float(i) - 10.0 + joiner.timeout)  # what has not moved for 10 turns goes
    for joiner in clients:
        joiner.clear()
    assert shared.size == 0


def test_fragments_refused_with_a_reason() -> None:
    joiner = defragmenter(max_messages=1)
    with pytest.raises(rb.RosbridgeRefusal, match="not below total"):
        joiner.feed(fragment_op("a", 2, 2, "x"), 0.0)
    assert joiner.feed(fragment_op("a", 0, 1, '{"op"'), 0.0) == b'{"op"'  # one part: nothing held
    assert joiner.feed(fragment_op("a", 0, 3, "x"), 0.0) is None
    with pytest.raises(rb.RosbridgeRefusal, match="at most 1 fragmented"):
        joiner.feed(fragment_op("b", 0, 3, "x"), 0.0)
    with pytest.raises(rb.RosbridgeRefusal, match="total 4, was 3"):
        joiner.feed(fragment_op("a", 1, 4, "x"), 0.0)
    assert len(joiner) == 0
    assert joiner.feed(fragment_op("a", 0, 3, "x"), 1.0) is None
    assert joiner.deadline() == 31.0
    assert joiner.expire(30.9) == []
    assert joiner.expire(31.0) == [("a", 1, 3)]
    with pytest.raises(rb.RosbridgeRefusal, match="without an id"):
        joiner.feed(rb.Fragment(num=0, total=2, data="x"), 0.0)


async def receive(ws: aiohttp.ClientWebSocketResponse, op: str, timeout: float = 10.0, **match: Any) -> dict[str, Any]:
    async with backports.timeout(timeout):
        while True:
            msg = json.loads((await ws.receive()).data)
            if msg["op"] == op and all(msg.get(k) == v for k, v in match.items()):
                return msg


async def test_rosbridge_subscribe_publish_services_and_rosapi(master: Master) -> None:
    async with rosbridge_and_node(master.uri, "robot") as (server, robot, http):
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

        async with backports.timeout(10):
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

    async with rosbridge_and_node(master.uri, "robot") as (server, robot, http):
        cam = await robot.advertise("/image", Image)
        a = await http.ws_connect(server.rosbridge_url)
        b = await http.ws_connect(server.rosbridge_url)
        await a.send_str(
            json.dumps({"op": "subscribe", "topic": "/image", "type": "sensor_msgs/Image", "compression": "cbor"})
        )
        await b.send_str(json.dumps({"op": "subscribe", "topic": "/image", "compression": "cbor-raw"}))
        async with backports.timeout(10):
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
        async with backports.timeout(10):
            while server.rosbridge_sessions:  # noqa: ASYNC110 - the server ends the sessions
                await asyncio.sleep(0.01)
        assert server.hub.ledger.size == 0


async def test_a_rosbridge_client_provides_a_service_to_ros(master: Master) -> None:
    async with rosbridge_and_node(master.uri, "caller") as (server, caller, http):
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
        async with backports.timeout(10):
            while True:  # the client's service is withdrawn when it disconnects
                try:
                    await caller.master.lookup_service("/toggle")
                except mrosd.errors.MasterError:
                    break
                await asyncio.sleep(0.02)


async def test_rosapi_details_and_unknown_types(master: Master) -> None:
    async with rosbridge_and_node(master.uri, "talker") as (server, talker, http):
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
        assert [d["type"] for d in answers["0"]["typedefs"]] == ["sensor_msgs/Image", "std_msgs/Header", "time"]
        assert answers["1"]["publishers"] == ["/talker"]
        assert answers["2"]["version"] == 1
        sub = {"op": "subscribe", "topic": "/x", "type": "nope_msgs/Nope", "id": "u"}
        await ws.send_str(json.dumps(sub))
        status = await receive(ws, "status", id="u")
        assert "nope_msgs/Nope" in status["msg"]
        assert "searched" in status["msg"]
        await ws.close()


async def test_fragment_size_splits_a_message_into_fragment_ops(master: Master) -> None:
    async with rosbridge_and_node(master.uri, "talker") as (server, talker, http):
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
    async with rosbridge_and_node(master.uri, "camera") as (server, camera, http):
        cam = await camera.advertise("/image", Image)
        whole = await http.ws_connect(server.rosbridge_url)
        cut = await http.ws_connect(server.rosbridge_url)
        await whole.send_str(json.dumps({"op": "subscribe", "topic": "/image", "compression": "png"}))
        sub = {"op": "subscribe", "topic": "/image", "compression": "png", "fragment_size": 50_000}
        await cut.send_str(json.dumps(sub))
        async with backports.timeout(10):
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


async def test_a_client_sends_ops_cut_into_fragments(master: Master) -> None:
    """No real client sends fragment ops (roslib and roslibpy only read them): the documented wire ops from a
    raw client, pieces out of order, a 1 MB image published and a service called through them."""
    async with rosbridge_and_node(master.uri, "robot") as (server, robot, http):
        listener = await robot.subscribe("/image", Image)
        await robot.advertise_service("/enable", SetBool, lambda r: SetBool._response_class(success=r.data))
        ws = await http.ws_connect(server.rosbridge_url)

        async def send_cut(op: dict[str, Any], message_id: str | int, size: int) -> None:
            text = json.dumps(op)
            parts = [text[i : i + size] for i in range(0, len(text), size)]
            order = list(range(len(parts)))
            random.Random(5).shuffle(order)
            for num in order:
                piece = {"op": "fragment", "id": message_id, "num": num, "total": len(parts), "data": parts[num]}
                await ws.send_str(json.dumps(piece))

        await send_cut({"op": "advertise", "topic": "/image", "type": "sensor_msgs/Image"}, "adv", 10)
        await listener.wait_for_publishers(1, timeout=10)
        pixels = random.Random(1).randbytes(1024 * 1024)
        msg = {
            "height": 512,
            "width": 512,
            "encoding": "rgba8",
            "step": 2048,
            "data": base64.b64encode(pixels).decode(),
        }
        await send_cut({"op": "publish", "topic": "/image", "msg": msg}, 1, 64 * 1024)
        got = await listener.next(timeout=10)
        assert (got.width, bytes(got.data)) == (512, pixels)

        async with backports.timeout(10):
            while "/enable" not in server.hub.services:  # noqa: ASYNC110 - the hub probes the service's type
                await asyncio.sleep(0.01)
        call = {"op": "call_service", "service": "/enable", "args": {"data": True}, "id": "c1"}
        await send_cut(call, "call", 16)
        reply = await receive(ws, "service_response", id="c1")
        assert reply["values"]["success"] is True
        (session,) = server.rosbridge_sessions
        assert (len(session.fragments), session.fragments.size, server.rosbridge_fragments.size) == (0, 0, 0)
        await ws.close()


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
        await ws.send_str(json.dumps({"op": "fragment", "id": "f", "num": 0, "total": 2, "data": "x" * 1000}))
        assert "authenticate first" in (await receive(ws, "status", id="f"))["msg"]
        assert server.rosbridge_fragments.size == 0  # nothing is held for a client before it authenticates
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
