"""Publish ``std_msgs/String`` on ``/chatter`` at 1 Hz until Ctrl-C (the mrosd twin of rospy's talker).

    python examples/talker.py [__name:=talker] [chatter:=/other]

``mrosd.run`` runs ``main`` on uvloop when installed; Ctrl-C or SIGTERM unregisters the node and exits 0.
Each message is printed as rospy's talker prints it (``[INFO] [<seconds>]: hello world 0``): the node's log
lines go to the console as well as to /rosout.
"""

from __future__ import annotations

import asyncio
import logging
import sys

import mrosd
from mrosd.msg import get_message_class

String = get_message_class("std_msgs/String")


def log_to_console() -> None:
    """Print the nodes' log lines as rospy does: INFO and DEBUG on stdout, warnings and errors on stderr."""
    form = logging.Formatter("[%(levelname)s] [%(created)f]: %(message)s")
    out = logging.StreamHandler(sys.stdout)
    out.addFilter(lambda record: record.levelno < logging.WARNING)
    err = logging.StreamHandler(sys.stderr)
    err.setLevel(logging.WARNING)
    for handler in (out, err):
        handler.setFormatter(form)
        logging.getLogger("rosout").addHandler(handler)  # every node's logger: rosout.<node name>


async def main() -> None:
    async with mrosd.Node("talker") as node:
        pub = await node.advertise("chatter", String, queue_size=10)
        count = 0
        while not node.shutdown_event.is_set():
            text = f"hello world {count}"
            node.log.info(text)  # to the console and to /rosout
            await pub.publish(String(data=text))
            count += 1
            await asyncio.sleep(1.0)


if __name__ == "__main__":
    log_to_console()
    mrosd.run(main)
