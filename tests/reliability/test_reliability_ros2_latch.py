"""A TRANSIENT_LOCAL ROS 2 publisher whose publication cache answers the bridge's late-joiner query with a body
that lies (a CDR string length of 2 GiB): one line, counted bad, and the next good message is latched."""

from __future__ import annotations

import asyncio
import logging
import struct

import pytest

from mrosd import backports
from mrosd.ros2.bridge import Ros2Bridge, Ros2Options
from mrosd.tcpros.node import Node
from mrosd.tcpros.subscriber import AnyMsg, RawMessage
from tests.ros2.conftest import router
from tests.ros2.test_ros2_latch_in import Ros2Side, ros2_side

zenoh = pytest.importorskip("zenoh")
__all__ = ["ros2_side", "router"]  # the in-process Zenoh router and rmw_zenoh-style node of tests/ros2


async def test_a_cached_body_that_lies_is_one_line_and_the_next_message_is_latched(
    rosmaster: str, router: int, ros2_side: Ros2Side, caplog: pytest.LogCaptureFixture
) -> None:
    pub, token = ros2_side.publisher("/lying", transient_local=True, depth=1)
    pub.put(b"\x00\x01\x00\x00" + struct.pack("<I", 0x7FFFFFFF) + b"abc")  # only the cache holds it
    ros2_side.announce(token)
    options = Ros2Options(domain_id=0, connect=(f"tcp/127.0.0.1:{router}",), from_ros2=("/lying",))
    with caplog.at_level(logging.WARNING, logger="mrosd.ros2.inbound"):
        async with Ros2Bridge(options, rosmaster) as bridge:
            inbound = bridge.inbound
            assert inbound is not None
            await bridge.wait_until(lambda: "/lying" in inbound.topics and inbound.topics["/lying"].bad >= 1, 20)
            rt = inbound.topics["/lying"]
            assert rt.latched and rt.received == 0
            ros2_side.put(pub, "a true map", 2)
            await bridge.wait_until(lambda: rt.received >= 1, 10)
            node = Node("/late_reader", rosmaster)
            await node.start()
            try:
                got: asyncio.Queue[RawMessage] = asyncio.Queue()
                await node.subscribe("/lying", AnyMsg, callback=got.put_nowait)
                msg = await backports.wait_for(got.get(), 10)
                assert b"a true map" in bytes(msg.data) and msg.header.latching == "1"
            finally:
                await node.aclose()
    lines = [r for r in caplog.records if r.name == "mrosd.ros2.inbound"]
    assert len(lines) == 1 and not any(r.exc_info for r in lines), [r.getMessage() for r in lines]
