"""A rospy publisher answers our shared-memory offer with TCPROS, as it answers any protocol it does not know."""

from __future__ import annotations

import subprocess
import time
import xmlrpc.client
from pathlib import Path
from typing import Any

import pytest

from mrosd.shm import local_identity, parse_answer, subscriber_offer
from tests.rosenv import ROS_PYTHON, Processes, needs_ros, ros_env

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
