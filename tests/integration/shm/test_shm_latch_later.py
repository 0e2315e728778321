"""``Publisher.latch`` set after the shared-memory side exists reaches it, as it reaches TCPROS.

TCPROS reads the flag at each new connection. The shared-memory side once copied it when it was made, so a
publisher latched later (the fleet's does it when the first latched body arrives) gave a shared-memory
subscriber that came after the message nothing, and one unlatched later kept serving its last message.
"""

from __future__ import annotations

import asyncio

from mrosd import backports
from mrosd.master import Master
from mrosd.msg import get_message_class
from mrosd.tcpros import Node, Subscriber

String = get_message_class("std_msgs/String")


async def shared_memory_attached(sub: Subscriber) -> None:
    """Until the subscription's link to the publisher has moved to shared memory (bounded by the caller)."""
    # the link exposes no event for the attach: polled, bounded by the caller's timeout
    while not any(link.transport_name == "SHMROS" for link in sub.links.values()):  # noqa: ASYNC110
        await asyncio.sleep(0.01)


async def test_a_publisher_latched_after_its_shared_memory_side_exists_latches_it_too() -> None:
    async with Master(host="127.0.0.1", port=0) as master, Node("talker", master_uri=master.uri, argv=[]) as talker:
        pub = await talker.advertise("/later", String)
        async with Node("first", master_uri=master.uri, argv=[]) as first:
            sub = await first.subscribe("/later", String)
            async with backports.timeout(10):
                await shared_memory_attached(sub)
            assert pub.shm is not None and pub.shm.endpoint is not None
            pub.latch = True
            await pub.publish(String(data="kept"))
            assert (await sub.next(timeout=5)).data == "kept"
        async with Node("late", master_uri=master.uri, argv=[]) as late:
            sub = await late.subscribe("/later", String)
            async with backports.timeout(10):
                await shared_memory_attached(sub)
            assert (await sub.next(timeout=5)).data == "kept"
        pub.latch = False
        async with Node("unlatched", master_uri=master.uri, argv=[]) as unlatched:
            sub = await unlatched.subscribe("/later", String)
            async with backports.timeout(10):
                await shared_memory_attached(sub)
            await pub.publish(String(data="fresh"))
            assert (await sub.next(timeout=5)).data == "fresh"  # not the message latched before
