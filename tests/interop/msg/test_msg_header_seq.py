"""header.seq is the publisher's counter, as rospy and roscpp fill it, seen by a real rospy subscriber.

roscpp numbers every publish call from 0 and sends a latched message with the seq it was published with;
rospy counts from 1, only while a subscriber is connected, and re-numbers a latched message for each new
subscriber. mrosd follows roscpp (the numbering does not depend on when subscribers connect).
"""

from __future__ import annotations

import asyncio
import os
import select
import subprocess
import time

import mrosd
from mrosd.msg import get_message_class
from tests.rosenv import ROS_PYTHON, Processes, needs_ros, ros_env

PointStamped = get_message_class("geometry_msgs/PointStamped")

LISTENER = """
import sys, rospy
from geometry_msgs.msg import PointStamped
rospy.init_node("seq_listener", anonymous=True)
rospy.Subscriber(sys.argv[1], PointStamped, lambda m: print(m.header.seq, m.point.x, flush=True))
rospy.spin()
"""


def listener(procs: Processes, master: str, topic: str) -> subprocess.Popen[bytes]:
    env = ros_env(master, procs.tmp)
    return procs.start([ROS_PYTHON, "-c", LISTENER, topic], env, stderr=subprocess.DEVNULL)


def read_lines(proc: subprocess.Popen[bytes], count: int, timeout: float) -> list[str]:
    """``count`` stdout lines, read from the pipe itself: several lines may arrive in one read."""
    assert proc.stdout is not None
    fd = proc.stdout.fileno()
    data = b""
    deadline = time.monotonic() + timeout
    while data.count(b"\n") < count:
        remaining = deadline - time.monotonic()
        if remaining <= 0 or not select.select([fd], [], [], remaining)[0]:
            raise TimeoutError(f"fewer than {count} lines within {timeout} s: {data!r}")
        chunk = os.read(fd, 65536)
        if not chunk:
            raise EOFError(f"process ended after {data!r}")
        data += chunk
    return data.decode().splitlines()[:count]


async def lines(proc: subprocess.Popen[bytes], count: int) -> list[str]:
    return await asyncio.to_thread(read_lines, proc, count, 30)


def point(x: float) -> object:
    msg = PointStamped()
    msg.header.seq = 99  # whatever the user set is overwritten
    msg.point.x = x
    return msg


@needs_ros
async def test_a_rospy_subscriber_sees_our_counter_in_header_seq(procs: Processes, rosmaster: str) -> None:
    async with mrosd.Node("seq_talker", master_uri=rosmaster, argv=[], host="127.0.0.1") as node:
        pub = await node.advertise("/seq", PointStamped)
        unheard = point(0.5)
        await pub.publish(unheard)  # nobody listens yet: still numbered (roscpp's rule)
        assert unheard.header.seq == 0  # type: ignore[attr-defined]
        proc = listener(procs, rosmaster, "/seq")
        await pub.wait_for_subscribers(1, 30)
        for x in (1.5, 2.5, 3.5):
            await pub.publish(point(x))
        assert await lines(proc, 3) == ["1 1.5", "2 2.5", "3 3.5"]


@needs_ros
async def test_a_latched_message_keeps_the_seq_it_was_published_with(procs: Processes, rosmaster: str) -> None:
    async with mrosd.Node("seq_latcher", master_uri=rosmaster, argv=[], host="127.0.0.1") as node:
        pub = await node.advertise("/seq_latched", PointStamped, latch=True)
        for x in (1.0, 2.0, 3.0):
            await pub.publish(point(x))
        proc = listener(procs, rosmaster, "/seq_latched")
        assert await lines(proc, 1) == ["2 3.0"]
        later = listener(procs, rosmaster, "/seq_latched")
        assert await lines(later, 1) == ["2 3.0"]  # the same bytes for every late subscriber, as roscpp does


async def test_messages_without_a_header_are_left_alone(procs: Processes) -> None:
    from tests.reliability.relnodes import start_master

    _, master = start_master(procs)
    String = get_message_class("std_msgs/String")
    Header = get_message_class("std_msgs/Header")
    async with mrosd.Node("seq_plain", master_uri=master, argv=[], host="127.0.0.1") as node:
        pub = await node.advertise("/plain", Header)  # a Header itself is not a message *with* a header
        hdr = Header(seq=42)
        sub = await node.subscribe("/plain", Header)
        await sub.wait_for_publishers(1, 10)
        await pub.wait_for_subscribers(1, 10)
        await pub.publish(hdr)
        received = await sub.next(10)
        assert received.seq == 42  # type: ignore[attr-defined]
        assert pub.seq == 0
        assert not String._has_header and not Header._has_header
