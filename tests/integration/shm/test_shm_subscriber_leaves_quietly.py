"""A shared-memory subscriber that leaves normally is a DEBUG line, not INFO.

The web part's hub subscribes through shared memory for the browser tabs and unsubscribes when the last one
closes: before, every tab closed logged ``/rosout_agg: shared-memory subscriber /mrosd_web went away`` at
INFO in the daemon's journal. A subscriber leaving is ordinary; only a dropped one (a reason given) warns.
"""

from __future__ import annotations

import asyncio
import logging

import pytest

from mrosd import backports
from mrosd.master import Master
from mrosd.msg import get_message_class
from mrosd.tcpros import AnyMsg, Node
from tests.integration.shm.test_shm_publisher_leaves import shared_memory_attached

String = get_message_class("std_msgs/String")


async def test_a_subscriber_that_leaves_is_logged_at_debug(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG, logger="mrosd.shm.publisher")
    async with Master(host="127.0.0.1", port=0) as master, Node("talker", master_uri=master.uri, argv=[]) as talker:
        await talker.advertise("/leaving", String)
        async with Node("listener", master_uri=master.uri, argv=[]) as node:
            sub = await node.subscribe("/leaving", AnyMsg)
            async with backports.timeout(10):
                await shared_memory_attached(sub)

        def gone() -> list[logging.LogRecord]:
            return [r for r in caplog.records if "went away" in r.getMessage()]

        async with backports.timeout(10):
            while not gone():  # noqa: ASYNC110  (the publisher notices on its loop; no event to wait on)
                await asyncio.sleep(0.01)
    assert [r.levelno for r in gone()] == [logging.DEBUG]
