"""The ``[images]`` part against mrosd's own master and nodes, in one event loop: ``T/compressed`` is
advertised at once but ``T`` is subscribed only while ``T/compressed`` has a subscriber; a burst is encoded
down to the newest image; a peer's bad image is refused and the topic goes on."""

from __future__ import annotations

import asyncio
import logging
import random
from collections.abc import Callable

import pytest

import mrosd
from mrosd import backports
from mrosd.images.part import NODE_NAME, CompressedImages
from mrosd.master import Master
from mrosd.msg import get_message_class

pytest.importorskip("numpy")
pytest.importorskip("simplejpeg")

Image = get_message_class("sensor_msgs/Image")
CompressedImage = get_message_class("sensor_msgs/CompressedImage")


def node(name: str, master: str) -> mrosd.Node:
    return mrosd.Node(name, master_uri=master, argv=[], host="127.0.0.1")


def picture(i: int, w: int = 320, h: int = 240) -> object:
    msg = Image(height=h, width=w, encoding="rgb8", is_bigendian=0, step=w * 3, data=bytes([i % 256]) * (w * h * 3))
    msg.header.frame_id = f"f{i}"
    return msg


async def until(what: str, check: Callable[[], bool], timeout: float = 10.0) -> None:
    async with backports.timeout(timeout):
        while not check():  # noqa: ASYNC110 - the state lives in the part's and the publisher's callbacks
            await asyncio.sleep(0.02)


async def raw_subscribers(n: mrosd.Node, topic: str) -> list[str]:
    state = await n.master_call("getSystemState")
    return next((list(nodes) for t, nodes in state[1] if t == topic), [])


async def test_raw_topic_is_subscribed_only_while_compressed_has_subscribers() -> None:
    async with Master(host="127.0.0.1", port=0) as master, node("camera", master.uri) as cam:
        pub = await cam.advertise("/camera/image", Image)
        part = CompressedImages(master.uri, ["/camera/*"], host="127.0.0.1")
        await part.start()
        try:
            await until("advertised", lambda: "/camera/image" in part.topics)
            await asyncio.sleep(0.5)
            assert NODE_NAME not in await raw_subscribers(cam, "/camera/image")
            async with node("viewer", master.uri) as viewer:
                sub = await viewer.subscribe("/camera/image/compressed", CompressedImage, queue_size=100)
                await pub.wait_for_subscribers(1, timeout=10)
                assert NODE_NAME in await raw_subscribers(cam, "/camera/image")
                await pub.publish(picture(1))
                got = await sub.next(timeout=10)
                assert got.format == "rgb8; jpeg compressed bgr8" and got.header.frame_id == "f1"
                assert got.data[:2] == b"\xff\xd8"
            await until("unsubscribed", lambda: pub.get_num_connections() == 0)
            for _ in range(50):
                if NODE_NAME not in await raw_subscribers(cam, "/camera/image"):
                    break
                await asyncio.sleep(0.1)
            assert NODE_NAME not in await raw_subscribers(cam, "/camera/image")
            assert not part.topics["/camera/image"].stats.subscribed
        finally:
            await part.aclose()


async def test_a_burst_is_encoded_down_to_the_newest_image() -> None:
    async with Master(host="127.0.0.1", port=0) as master, node("camera", master.uri) as cam:
        pub = await cam.advertise("/camera/image", Image, queue_size=200)
        part = CompressedImages(master.uri, ["/camera/*"], host="127.0.0.1")
        await part.start()
        try:
            async with node("viewer", master.uri) as viewer:
                await until("advertised", lambda: "/camera/image" in part.topics)
                sub = await viewer.subscribe("/camera/image/compressed", CompressedImage, queue_size=200)
                await pub.wait_for_subscribers(1, timeout=10)
                burst = 60
                noise = random.Random(32).randbytes(1280 * 720 * 3)  # JPEG's slowest case: encoding falls behind
                for i in range(burst):
                    msg = Image(height=720, width=1280, encoding="rgb8", step=1280 * 3, data=noise)
                    msg.header.frame_id = f"f{i}"
                    await pub.publish(msg)
                frames = []
                while not frames or frames[-1] != f"f{burst - 1}":
                    frames.append((await sub.next(timeout=10)).header.frame_id)
                stats = part.topics["/camera/image"].stats
                assert stats.encoded == len(frames) < burst  # fell behind: dropped to the newest
                assert stats.received == stats.encoded + stats.dropped
                assert frames == sorted(frames, key=lambda f: int(f[1:]))  # in order, never an old one late
        finally:
            await part.aclose()


async def test_a_bad_image_from_a_peer_is_one_log_line_and_the_topic_goes_on(
    caplog: pytest.LogCaptureFixture,
) -> None:
    async with Master(host="127.0.0.1", port=0) as master, node("camera", master.uri) as cam:
        pub = await cam.advertise("/camera/image", Image)
        part = CompressedImages(master.uri, ["/camera/*"], host="127.0.0.1")
        await part.start()
        try:
            async with node("viewer", master.uri) as viewer:
                await until("advertised", lambda: "/camera/image" in part.topics)
                sub = await viewer.subscribe("/camera/image/compressed", CompressedImage)
                await pub.wait_for_subscribers(1, timeout=10)
                liar = Image(height=60000, width=60000, encoding="rgb8", step=180000, data=b"\0" * 64)
                with caplog.at_level(logging.WARNING, logger="mrosd.images.part"):
                    await pub.publish(liar)
                    await until("refused", lambda: part.topics["/camera/image"].stats.refused == 1)
                lines = [r.getMessage() for r in caplog.records if r.name == "mrosd.images.part"]
                assert len(lines) == 1 and "outside" in lines[0] and not caplog.records[-1].exc_info
                await pub.publish(picture(7))
                assert (await sub.next(timeout=10)).header.frame_id == "f7"
        finally:
            await part.aclose()
