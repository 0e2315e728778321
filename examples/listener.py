"""Print every ``std_msgs/String`` on ``/chatter`` until Ctrl-C (the mrosd twin of rospy's listener).

    python examples/listener.py [__name:=listener] [chatter:=/other]

The callback does the work; ``await node.spin()`` waits, as ``rospy.spin()``, until ``rosnode kill`` or a
signal (``mrosd.run`` turns Ctrl-C and SIGTERM into a clean, quiet exit with status 0).
"""

from __future__ import annotations

import mrosd
from mrosd.msg import get_message_class

String = get_message_class("std_msgs/String")


async def main() -> None:
    async with mrosd.Node("listener") as node:
        await node.subscribe("chatter", String, callback=lambda msg: print(f"I heard {msg.data}", flush=True))
        await node.spin()


if __name__ == "__main__":
    mrosd.run(main)
