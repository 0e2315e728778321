"""A restarted master must never cut data that is flowing.

rospy nodes do not register again with a restarted rosmaster, so the fresh master's answer to our
subscriber's re-registration lists no publisher. rospy subscribers keep their live connections (they only
ever add publishers from such a list); ours must too. Real rosmaster, restarted on the same port, and a
real rospy publisher at 20 Hz.
"""

from __future__ import annotations

import asyncio
import subprocess
import time
import xmlrpc.client
from pathlib import Path

import pytest

import mrosd
from mrosd.msg import get_message_class
from tests.rosenv import ROS_PYTHON, Processes, free_port, needs_ros, ros_env, start_rosmaster_on

pytestmark = [needs_ros, pytest.mark.interop]

ROSPY_NODE = str(Path(__file__).resolve().parents[2] / "data" / "tcpros" / "rospy_node.py")
String = get_message_class("std_msgs/String")


def subscribers_of(master: str, topic: str) -> list[str]:
    with xmlrpc.client.ServerProxy(master) as proxy:
        _, _, (_, subs, _) = proxy.getSystemState("/test")
    return [n for t, nodes in subs if t == topic for n in nodes]


async def test_a_master_restart_keeps_a_rospy_publishers_data_flowing(procs: Processes) -> None:
    port = free_port()
    master = f"http://127.0.0.1:{port}/"
    first = start_rosmaster_on(procs, port)
    talker = procs.start(
        [ROS_PYTHON, ROSPY_NODE, "talk", "string", "/flow", "0"], ros_env(master, procs.tmp), stderr=subprocess.DEVNULL
    )
    assert talker.stdout is not None
    await asyncio.to_thread(talker.stdout.readline)  # "up": registered with the first master
    got: list[str] = []
    async with mrosd.Node("listener", master_uri=master, argv=[], host="127.0.0.1", watchdog_interval=0.2) as node:
        sub = await node.subscribe("/flow", String, callback=lambda m: got.append(m.data))
        await sub.wait_for_publishers(1, timeout=20)

        procs.stop(first)
        start_rosmaster_on(procs, port)
        # The watchdog notices the new master and registers again; its publisher list is empty.
        deadline = time.monotonic() + 20
        while "/listener" not in await asyncio.to_thread(subscribers_of, master, "/flow"):
            assert time.monotonic() < deadline, "the subscriber did not register with the new master"
            await asyncio.sleep(0.1)
        await asyncio.sleep(0.5)  # let the registration's answer reach the subscriber

        got.clear()
        deadline = time.monotonic() + 10
        while len(got) < 20:
            assert time.monotonic() < deadline, f"data stopped after the master restart ({len(got)} messages)"
            await asyncio.sleep(0.05)
        assert sub.get_num_connections() == 1
