"""Publish ``std_msgs/String`` on ``/chatter`` at 1 Hz until Ctrl-C (the mrosd twin of rospy's talker).

    python examples/talker.py [__name:=talker] [chatter:=/other]

``mrosd.run`` runs ``main`` on uvloop when installed; Ctrl-C or SIGTERM unregisters the node and exits 0.
"""

from __future__ import annotations

import asyncio

import mrosd
from mrosd.msg import get_message_class

String = get_message_class("std_msgs/String")


async def main() -> None:
    async with mrosd.Node("talker") as node:
        pub = await node.advertise("chatter", String, queue_size=10)
        count = 0
        while not node.shutdown_event.is_set():
            text = f"hello world {count}"
            node.log.info(text)  # to the console's logging and to /rosout
            await pub.publish(String(data=text))
            count += 1
            await asyncio.sleep(1.0)


if __name__ == "__main__":
    mrosd.run(main)
