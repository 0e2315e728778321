"""A rospy publisher answers our shared-memory offer with TCPROS, as it answers any protocol it does not know;
a rospy subscriber of a topic whose messages are loaned gets them over TCPROS, sent from the slot."""

from __future__ import annotations

import asyncio
import subprocess
import time
import xmlrpc.client
from pathlib import Path
from typing import Any

import pytest

import mrosd
from mrosd.msg import get_message_class
from mrosd.shm import local_identity, parse_answer, subscriber_offer
from tests.rosenv import ROS_PYTHON, Processes, iter_lines_until, needs_ros, ros_env

pytestmark = [needs_ros, pytest.mark.interop]

ROSPY_NODE = str(Path(__file__).resolve().parents[2] / "data" / "tcpros" / "rospy_node.py")


def test_rospy_answers_tcpros_to_an_offer_of_shared_memory_first(procs: Processes, rosmaster: str) -> None:
    procs.start(
        [ROS_PYTHON, ROSPY_NODE, "talk", "string", "/shm_offer", "0"],
        ros_env(rosmaster, procs.tmp),
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 30
    uris: list[str] = []
    with xmlrpc.client.ServerProxy(rosmaster) as master:
        while not uris:
            assert time.monotonic() < deadline, "the rospy talker did not register"
            reply: Any = master.registerSubscriber("/shm_probe", "/shm_offer", "std_msgs/String", "http://127.0.0.1:1/")
            assert reply[0] == 1
            uris = list(reply[2])
            if not uris:
                time.sleep(0.1)
    me = local_identity()
    assert me is not None
    with xmlrpc.client.ServerProxy(uris[0]) as talker:
        answer: Any = talker.requestTopic("/shm_probe", "/shm_offer", [subscriber_offer(me), ["TCPROS"]])
    code, params = answer[0], answer[2]
    assert code == 1 and params[0] == "TCPROS"
    assert parse_answer(params) is None


async def test_a_rospy_subscriber_gets_loaned_images_sent_from_the_slot(procs: Processes, rosmaster: str) -> None:
    image = get_message_class("sensor_msgs/Image")
    listener = procs.start(
        [ROS_PYTHON, ROSPY_NODE, "listen", "image", "/loaned", "3"],
        ros_env(rosmaster, procs.tmp),
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
    )
    assert list(iter_lines_until(listener, 1, 30)) == ["up"]
    async with mrosd.Node("camera", master_uri=rosmaster, argv=[], host="127.0.0.1") as node:
        pub = await node.advertise("/loaned", image, max_message_size=1 << 16)
        await pub.wait_for_subscribers(1, timeout=30)
        assert pub.shm is not None and pub.shm.endpoint is not None  # a pool, though its subscriber is TCPROS
        for i in range(3):
            msg = pub.loan(data=4)
            assert msg._shm_loan.in_place
            msg.data[:] = bytes([i, i, i, 255])
            msg.height, msg.width, msg.encoding = 1, 1, "rgba8"
            await pub.publish(msg)
            await asyncio.sleep(0.05)
        lines = await asyncio.get_running_loop().run_in_executor(None, lambda: list(iter_lines_until(listener, 3, 30)))
    assert lines == [f"1 1 rgba8 {bytes([i, i, i, 255]).hex()}" for i in range(3)]
