"""What a shared-memory publisher published before it left reaches its subscribers, as over TCPROS.

A TCPROS subscriber reads the bytes already in its socket after the publisher closes; a shared-memory
subscriber must likewise read the ring to its end when the publisher's sockets close (a `mros bag play`
publishes and exits at once). This fails when the subscriber ends the connection on the close first.
"""

from __future__ import annotations

import asyncio

from mrosd import backports
from mrosd.master import Master
from mrosd.msg import get_message_class
from mrosd.tcpros import AnyMsg, Node, Subscriber

String = get_message_class("std_msgs/String")
COUNT = 50


async def shared_memory_attached(sub: Subscriber) -> None:
    """Until the subscription's link to the publisher has moved to shared memory (bounded by the caller)."""
    # the link exposes no event for the attach: polled, bounded by the caller's timeout
    while not any(link.transport_name == "SHMROS" for link in sub.links.values()):  # noqa: ASYNC110
        await asyncio.sleep(0.01)


async def test_a_subscriber_gets_every_message_published_before_the_publisher_closed() -> None:
    async with Master(host="127.0.0.1", port=0) as master, Node("listener", master_uri=master.uri, argv=[]) as node:
        sub = await node.subscribe("/burst", AnyMsg, queue_size=COUNT)
        async with Node("talker", master_uri=master.uri, argv=[]) as talker:
            pub = await talker.advertise("/burst", String)
            async with backports.timeout(10):
                await shared_memory_attached(sub)
            for i in range(COUNT):
                await pub.publish(String(data=f"m{i}"))
        got = [await sub.next(timeout=5) for _ in range(COUNT)]
        assert [bytes(m.data)[4:].decode() for m in got] == [f"m{i}" for i in range(COUNT)]
