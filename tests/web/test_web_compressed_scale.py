"""How ``T/compressed`` is encoded when it matters (mrosd.web.compressed), in-process on the hub: ``maxRate``
on the one timer every topic shares, the newest frame always the last encoded, and a big frame that stops the
hub reading ``T`` only while it is encoded and only when no client reads ``T`` itself.
"""

from __future__ import annotations

import asyncio
from typing import Any

import pytest

from mrosd.master import Master
from mrosd.msg import get_message_class
from mrosd.web.compressed import ImageSettings
from mrosd.web.server import WebServer
from mrosd.web.shared import PAUSE_BYTES
from tests.web.inloop import Collect, node, until

Image = get_message_class("sensor_msgs/Image")
CompressedImage = get_message_class("sensor_msgs/CompressedImage")
RAW, MADE = "/cam/image", "/cam/image/compressed"


def frame(seq: int, side: int) -> Any:
    image = Image(height=side, width=side, encoding="mono8", step=side, data=bytes([seq & 255]) * (side * side))
    image.header.frame_id = str(seq)
    return image


async def frames_until(out: Collect, last: str, timeout: float = 20.0) -> list[str]:
    """The frame ids ``out`` is given, up to ``last``."""
    ids: list[str] = []
    async with asyncio.timeout(timeout):
        while not ids or ids[-1] != last:
            ids.append(CompressedImage.deserialize(await out.bodies.get()).header.frame_id)
    return ids


async def test_max_rate_encodes_on_one_timer_and_the_newest_frame_goes_last(master: Master) -> None:
    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1") as server,
        node("camera", master.uri) as robot,
    ):
        hub = server.hub
        pub = await robot.advertise(RAW, Image)
        await until(lambda: MADE in hub.compressed.virtual)
        hub.compressed.set_settings(MADE, ImageSettings(max_rate=5))
        out = Collect()
        await hub.add_sink(MADE, out)
        await until(lambda: pub.get_num_connections() == 1)
        for seq in range(30):  # 0.3 s of a 100 Hz camera
            await pub.publish(frame(seq, 32))
            await asyncio.sleep(0.01)
        ids = await frames_until(out, "29")
        stats = hub.compressed.status()[MADE]
        assert 2 <= len(ids) <= 4, ids  # the first at once, then one per 200 ms: the newest waits for its turn
        assert stats["received"] == 30 == stats["encoded"] + stats["dropped"] + stats["refused"], stats
        await hub.remove_sink(MADE, out)


async def test_a_big_frame_stops_reading_the_camera_only_while_it_is_encoded_and_only_for_the_encoder(
    master: Master, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("MROSD_SHM", "0")  # TCPROS, whose reading the hub pauses
    side = 2100  # 4.2 MiB: past PAUSE_BYTES
    assert side * side >= PAUSE_BYTES
    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1") as server,
        node("camera", master.uri) as robot,
    ):
        hub = server.hub
        pub = await robot.advertise(RAW, Image, queue_size=2)
        await until(lambda: MADE in hub.compressed.virtual)
        out = Collect()
        await hub.add_sink(MADE, out)
        await until(lambda: pub.get_num_connections() == 1)
        paused: list[bool] = []

        async def watch() -> None:
            while True:
                entry = hub.subs.entries.get(RAW)
                paused.append(entry is not None and entry.paused)
                await asyncio.sleep(0.002)

        watcher = asyncio.create_task(watch())
        for seq in range(6):
            await pub.publish(frame(seq, side))
            await asyncio.sleep(0.05)
        ids = await frames_until(out, "5")  # the hold always ends: the newest frame is encoded
        watcher.cancel()
        assert any(paused), "the camera was never paused while a big frame was encoded"
        await until(lambda: not hub.subs.entries[RAW].paused)
        # a client of the raw topic as well: the encoder no longer stops it; every frame reaches the client
        raw = Collect()
        await hub.add_sink(RAW, raw)
        for seq in range(6, 12):
            await pub.publish(frame(seq, side))
            assert not hub.subs.entries[RAW].paused
            await asyncio.sleep(0.05)
        async with asyncio.timeout(20):
            got = [Image.deserialize(await raw.bodies.get()).header.frame_id for _ in range(6)]
        assert got == [str(seq) for seq in range(6, 12)]
        assert (await frames_until(out, "11"))[-1] == "11"
        assert ids[-1] == "5"
        await hub.remove_sink(RAW, raw)
        await hub.remove_sink(MADE, out)
