"""Hostile images on a topic whose ``T/compressed`` a browser client watches (mrosd.web.compressed): data
shorter than ``height * step``, absurd sizes, an unknown encoding, bytes that are no Image at all. Each topic's
bad frames are one log line (rate-limited), counted in ``refused``; the encoder keeps going (the next good frame
of the same topic is encoded) and the other topics are not touched.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

import pytest

import mrosd
from mrosd import backports
from mrosd.master import Master
from mrosd.msg import get_message_class
from mrosd.web.server import WebServer
from tests.web.inloop import Collect

Image = get_message_class("sensor_msgs/Image")
CompressedImage = get_message_class("sensor_msgs/CompressedImage")

GOOD = Image(height=8, width=8, encoding="mono8", step=8, data=bytes(range(64)))
HOSTILE: dict[str, Any] = {
    "/short": Image(height=720, width=1280, encoding="rgb8", step=3840, data=b"\0" * 100),
    "/huge": Image(height=1 << 31, width=1 << 31, encoding="rgb8", step=1, data=b"\0" * 16),
    "/unknown": Image(height=8, width=8, encoding="yuv999", step=8, data=b"\0" * 64),
    "/garbage": b"\x05\x00\x00\x00not an image at all",
}


async def test_hostile_images_are_one_line_each_and_the_topics_keep_going(
    master: Master, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, logger="mrosd.web.compressed")
    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1") as server,
        mrosd.Node("hostile", master_uri=master.uri, argv=[], host="127.0.0.1") as robot,
    ):
        hub = server.hub
        pubs = {name: await robot.advertise(name, Image) for name in [*HOSTILE, "/good"]}
        async with backports.timeout(10):
            while len(hub.compressed.virtual) < len(pubs):  # noqa: ASYNC110 - the hub follows the graph
                await asyncio.sleep(0.02)
        sinks = {name: Collect() for name in pubs}
        for name, sink in sinks.items():
            await hub.add_sink(name + "/compressed", sink)
        for pub in pubs.values():
            await pub.wait_for_subscribers(1, timeout=10)
        for _ in range(5):
            for name, bad in HOSTILE.items():
                if isinstance(bad, bytes):
                    pubs[name].publish_serialized(bad)
                else:
                    await pubs[name].publish(bad)
            await pubs["/good"].publish(GOOD)
            got = CompressedImage.deserialize(await asyncio.wait_for(sinks["/good"].bodies.get(), 10))
            assert got.format == "mono8; jpeg compressed "
        async with backports.timeout(10):  # every hostile frame was tried (newest-only may skip some)
            while any(hub.compressed.stats[n + "/compressed"].refused == 0 for n in HOSTILE):  # noqa: ASYNC110
                await asyncio.sleep(0.02)
        # the same topics then carry good frames again
        for name in HOSTILE:
            await pubs[name].publish(GOOD)
            assert CompressedImage.deserialize(await asyncio.wait_for(sinks[name].bodies.get(), 10)).data
        for name in HOSTILE:
            assert sinks[name].bodies.empty()
        lines = [r.getMessage() for r in caplog.records if r.name == "mrosd.web.compressed"]
        for name in HOSTILE:
            assert sum(f"{name}/compressed:" in line for line in lines) == 1, lines
        assert all("\n" not in line and "Traceback" not in line for line in lines)
        assert hub.compressed.status()["/good/compressed"]["refused"] == 0
        for name, sink in sinks.items():
            await hub.remove_sink(name + "/compressed", sink)
