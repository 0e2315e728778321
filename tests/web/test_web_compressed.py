"""``T/compressed`` for browser clients (mrosd.web.compressed): real clients, real publishers.

A @foxglove/ws-protocol client (node) and roslibpy (rosbridge, ``cbor`` and JSON) get ``T/compressed`` for an
mrosd camera and a rospy one, decoded here as a JPEG (PNG for 16-bit depth) of the right size; nothing is
encoded while no one subscribes (the hub's own counters, as ``x-mrosd.topicStats`` reports them); two clients
share one encoder; a real ``T/compressed`` in the graph is passed through, not encoded again.
"""

from __future__ import annotations

import asyncio
import base64
import io
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import aiohttp
import cbor2
import pytest

from mrosd.master import Master
from mrosd.msg import get_message_class
from mrosd.web.server import WebServer
from tests.rosenv import ROS_PYTHON, ros_available, ros_env
from tests.web.inloop import Collect, node, until
from tests.web.test_web_real_clients import HERE, NodeClient, client_of, needs_node

PIL = pytest.importorskip("PIL.Image")

__all__ = ["client_of"]  # fixtures

Image = get_message_class("sensor_msgs/Image")
CompressedImage = get_message_class("sensor_msgs/CompressedImage")

W, H = 64, 48


def gradient(seq: int, width: int = W, height: int = H) -> bytes:
    """An rgb8 gradient that moves with ``seq`` (JPEG compresses it as it would a camera's)."""
    return bytes((x * 4 + seq) & 255 for y in range(height) for x in range(width) for _ in range(3))


def rgb_image(seq: int) -> Any:
    return Image(height=H, width=W, encoding="rgb8", step=W * 3, data=gradient(seq))


def depth_image() -> Any:
    data = b"".join((1000 + x * 10).to_bytes(2, "little") for _ in range(H) for x in range(W))
    return Image(height=H, width=W, encoding="16UC1", step=W * 2, data=data)


def decoded(hex_body: str) -> tuple[str, Any]:
    msg = CompressedImage.deserialize(bytes.fromhex(hex_body))
    return msg.format, PIL.open(io.BytesIO(bytes(msg.data)))


@needs_node
async def test_foxglove_clients_share_one_encoder_that_runs_only_while_subscribed(
    master: Master, client_of: Any
) -> None:
    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1") as server,
        node("camera", master.uri) as robot,
    ):
        cam = await robot.advertise("/cam/image", Image)
        depth = await robot.advertise("/cam/depth", Image)
        first = await client_of(server)
        ch = await first.until("channel", topic="/cam/image/compressed")
        assert ch["schemaName"] == "sensor_msgs/CompressedImage"
        await first.until("channel", topic="/cam/depth/compressed")
        status = server.hub.compressed.status()
        # nobody subscribes: the raw camera is not even subscribed, nothing is encoded
        for _ in range(3):
            await cam.publish(rgb_image(0))
        assert server.hub.sink_count("/cam/image") == 0
        assert status["/cam/image/compressed"]["encoded"] == 0

        second = await client_of(server)
        await second.until("channel", topic="/cam/image/compressed")
        for client in (first, second):
            await client.send(cmd="subscribe", topic="/cam/image/compressed", full=True)
            await client.until("subscribed")
        await cam.wait_for_subscribers(1, timeout=10)
        # both clients' subscriptions have reached the server (a client's "subscribed" is only what it sent)
        await until(lambda: server.hub.sink_count("/cam/image/compressed") == 2)
        frames = 5
        for seq in range(frames):
            await cam.publish(rgb_image(seq))
            for client in (first, second):
                got = await client.until("message", topic="/cam/image/compressed")
                fmt, pic = decoded(got["hex"])
                assert fmt == "rgb8; jpeg compressed bgr8"
                assert (pic.format, pic.size) == ("JPEG", (W, H))
        # one encoder for both clients: one encode per frame
        stats = server.hub.compressed.status()["/cam/image/compressed"]
        assert stats["encoded"] == frames and stats["active"]
        assert len(server.hub.compressed.sources) == 1

        # 16-bit depth: a lossless 16-bit PNG
        await first.send(cmd="subscribe", topic="/cam/depth/compressed", full=True)
        await depth.wait_for_subscribers(1, timeout=10)
        await depth.publish(depth_image())
        fmt, pic = decoded((await first.until("message", topic="/cam/depth/compressed"))["hex"])
        assert fmt == "16UC1; png compressed "
        assert (pic.format, pic.size, pic.mode) == ("PNG", (W, H), "I;16")
        assert pic.getpixel((5, 0)) == 1050

        # the last client leaves: the encoder stops and the raw subscription closes
        await first.close()
        await second.close()
        await until(lambda: server.hub.sink_count("/cam/image") == 0 and not server.hub.compressed.sources)
        await cam.publish(rgb_image(9))
        assert server.hub.compressed.status()["/cam/image/compressed"]["encoded"] == frames


@needs_node
async def test_a_real_compressed_topic_is_passed_through_not_encoded(master: Master, client_of: Any) -> None:
    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1") as server,
        node("camera", master.uri) as robot,
    ):
        cam = await robot.advertise("/cam2/image", Image)
        client = await client_of(server)
        await client.until("channel", topic="/cam2/image/compressed")
        # a client whose subscription outlives the channel (rosbridge's are by name) holds the made one
        held = Collect()
        await server.hub.add_sink("/cam2/image/compressed", held)
        await cam.wait_for_subscribers(1, timeout=10)
        await cam.publish(rgb_image(0))
        assert CompressedImage.deserialize(await asyncio.wait_for(held.bodies.get(), 10)).format.startswith("rgb8")
        real = await robot.advertise("/cam2/image/compressed", CompressedImage)
        await until(lambda: "/cam2/image/compressed" not in server.hub.compressed.virtual)
        await client.until("channel", topic="/cam2/image/compressed")  # advertised again, as the real one
        await client.send(cmd="subscribe", topic="/cam2/image/compressed", full=True)
        await client.until("subscribed")
        await real.wait_for_subscribers(1, timeout=10)
        # the held sink may have opened the hub's subscription before the client's sink joined it (the topic is
        # not latched): publish until the client has one
        for _ in range(40):
            await real.publish(CompressedImage(format="rgb8; jpeg compressed bgr8", data=b"\xff\xd8real"))
            try:
                message = await client.until("message", timeout=0.5)
                break
            except AssertionError:
                continue
        else:
            raise AssertionError("the client never got a message of the real /cam2/image/compressed")
        got = CompressedImage.deserialize(bytes.fromhex(message["hex"]))
        assert bytes(got.data) == b"\xff\xd8real"
        # the held subscription was moved to the real topic: the same message, nothing encoded any more
        assert bytes(CompressedImage.deserialize(await asyncio.wait_for(held.bodies.get(), 10)).data) == b"\xff\xd8real"
        assert not server.hub.compressed.sources
        await until(lambda: server.hub.sink_count("/cam2/image") == 0)
        await server.hub.remove_sink("/cam2/image/compressed", held)


ROSPY_CAMERA = f"""
import rospy
from sensor_msgs.msg import Image
rospy.init_node("rospy_camera")
pub = rospy.Publisher("/rospy_cam/image", Image, queue_size=1)
img = Image(height={H}, width={W}, encoding="bgr8", step={W * 3})
img.data = bytes((x * 4) & 255 for y in range({H}) for x in range({W}) for _ in range(3))
while not rospy.is_shutdown():
    img.header.stamp = rospy.Time.now()
    pub.publish(img)
    rospy.sleep(0.05)
"""


@needs_node
@pytest.mark.interop
@pytest.mark.skipif(not ros_available(), reason="Debian ROS 1 (rospy) is not installed: scripts/install-system-deps.sh")
async def test_rospy_camera_compressed_for_foxglove_roslibpy_and_rosbridge_cbor(master: Master, tmp_path: Path) -> None:
    rospy_proc = await asyncio.create_subprocess_exec(
        ROS_PYTHON, "-c", ROSPY_CAMERA, env=ros_env(master.uri, tmp_path), stdout=subprocess.DEVNULL
    )
    fox: NodeClient | None = None
    libs: list[NodeClient] = []
    try:
        async with WebServer(master.uri, port=0, node_host="127.0.0.1", rosbridge_port=0) as server:
            fox = await NodeClient.start(server.url)
            await fox.until("channel", topic="/rospy_cam/image/compressed", timeout=30)
            await fox.send(cmd="subscribe", topic="/rospy_cam/image/compressed", full=True)
            fmt, pic = decoded((await fox.until("message", topic="/rospy_cam/image/compressed", timeout=30))["hex"])
            assert fmt == "bgr8; jpeg compressed bgr8"
            assert (pic.format, pic.size) == ("JPEG", (W, H))
            # roslibpy (JSON; it cannot ask for cbor: its Topic takes "png" or "none")
            proc = await asyncio.create_subprocess_exec(
                sys.executable,
                str(HERE / "roslibpy_compressed.py"),
                "127.0.0.1",
                str(server.rosbridge_port),
                "/rospy_cam/image/compressed",
                "none",
                stdout=subprocess.PIPE,
                limit=1 << 20,
            )
            lib = NodeClient(proc)
            libs.append(lib)
            listed = await lib.until("topics", timeout=30)
            assert listed["type"] == "sensor_msgs/CompressedImage"
            assert "/rospy_cam/image/compressed" in listed["for_type"]
            got = await lib.until("image", timeout=30)
            assert got["format"] == "bgr8; jpeg compressed bgr8"
            pic = PIL.open(io.BytesIO(base64.b64decode(got["data"])))
            assert (pic.format, pic.size) == ("JPEG", (W, H))
            # rosbridge's cbor, from a plain WebSocket client
            async with aiohttp.ClientSession() as http, http.ws_connect(server.rosbridge_url) as ws:
                op = {"op": "subscribe", "topic": "/rospy_cam/image/compressed", "compression": "cbor"}
                await ws.send_str(json.dumps(op))
                msg = cbor2.loads((await ws.receive(timeout=20)).data)["msg"]
                assert msg["format"] == "bgr8; jpeg compressed bgr8"
                pic = PIL.open(io.BytesIO(msg["data"]))
                assert (pic.format, pic.size) == ("JPEG", (W, H))
                # four clients, one encoder
                assert len(server.hub.compressed.sources) == 1
    finally:
        for c in [fox, *libs]:
            if c is not None:
                await c.close()
        rospy_proc.kill()
        await rospy_proc.wait()


async def test_image_settings_from_config_and_from_a_client_shared_and_bounded(master: Master) -> None:
    from mrosd.config import WebImagesConfig
    from mrosd.web.compressed import rules_from_config
    from tests.web.test_web_foxglove_integration import connect

    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1") as server,
        node("camera", master.uri) as robot,
        aiohttp.ClientSession() as http,
    ):
        server.hub.compressed.rules = rules_from_config([WebImagesConfig(topics=["/cam3/*"], quality=50, max_width=32)])
        cam = await robot.advertise("/cam3/image", Image)
        client = await connect(http, server)
        ch = await client.until_channel("/cam3/image/compressed")
        # the counters as clients see them; the stats' own counting sinks do not make it encode
        await client.send(op="x-mrosd.subscribeStats")
        stats = (await client.until_json("x-mrosd.topicStats"))["compressed"]["/cam3/image/compressed"]
        assert (stats["encoded"], stats["active"], stats["quality"]) == (0, False, 50)
        assert server.hub.sink_count("/cam3/image") == 1  # the stats' own, not an encoder's
        await client.send(op="x-mrosd.unsubscribeStats")
        await client.send(op="x-mrosd.imageSettings", topic="/cam3/image/compressed")
        got = await client.until_json("x-mrosd.imageSettings")
        assert (got["quality"], got["maxWidth"], got["maxRate"]) == (50, 32, 0)
        await client.send(op="subscribe", subscriptions=[{"id": 1, "channelId": ch["id"]}])
        await cam.wait_for_subscribers(1, timeout=10)
        await cam.publish(rgb_image(0))
        pic = PIL.open(io.BytesIO(bytes(CompressedImage.deserialize((await client.until_binary())[13:]).data)))
        assert pic.size == (32, 24)  # the rule's max_width: 64 -> 32
        # a client changes it for everyone (the last writer wins): one encoder, one setting per topic
        await client.send(op="x-mrosd.imageSettings", topic="/cam3/image/compressed", maxWidth=0, quality=90)
        got = await client.until_json("x-mrosd.imageSettings")
        assert (got["quality"], got["maxWidth"]) == (90, 0)
        await cam.publish(rgb_image(1))
        pic = PIL.open(io.BytesIO(bytes(CompressedImage.deserialize((await client.until_binary())[13:]).data)))
        assert pic.size == (W, H)
        # bounded: out-of-range values and topics not made here are refused, with a status
        for bad in ({"quality": 0}, {"maxWidth": 8}, {"maxRate": 1e9}):
            await client.send(op="x-mrosd.imageSettings", topic="/cam3/image/compressed", **bad)
            assert (await client.until_json("status"))["level"] == 2
        await client.send(op="x-mrosd.imageSettings", topic="/not/made/compressed", quality=10)
        assert "not a compressed topic" in (await client.until_json("status"))["message"]
        assert list(server.hub.compressed.overrides) == ["/cam3/image/compressed"]
