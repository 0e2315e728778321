"""The slave API answers exactly as rospy's: every check of ros_comm's client_verification/test_slave_api.py.

Each call goes to a real rospy node and to one of ours, in the same test, against the same real rosmaster;
the answer expected is the one rospy gives (a status code, or ``fault`` where the call cannot be answered
with one). The upstream expectations are asserted too, so a regression in both cannot pass unnoticed.
"""

from __future__ import annotations

import asyncio
import subprocess
import xmlrpc.client
from collections.abc import AsyncIterator
from typing import Any

import pytest

import mrosd
from mrosd.msg import get_message_class
from tests.rosenv import ROS_PYTHON, Processes, needs_ros, ros_env, wait_for_xmlrpc

pytestmark = [needs_ros, pytest.mark.interop]

String = get_message_class("std_msgs/String")
CALLER = "/test_harness"

ROSPY_PROBE = """
import rospy
from std_msgs.msg import String
rospy.init_node("rospy_probe")
rospy.Publisher("/chatter", String, queue_size=1)
rospy.Subscriber("/heard", String, lambda m: None)
print("up", flush=True)
rospy.spin()
"""


def call(uri: str, method: str, *args: Any) -> Any:
    """The raw answer of one slave API call, or 'fault'."""
    with xmlrpc.client.ServerProxy(uri) as proxy:
        try:
            return getattr(proxy, method)(*args)
        except xmlrpc.client.Fault:
            return "fault"


def code(answer: Any) -> Any:
    return answer if answer == "fault" else answer[0]


def lookup(master: str, name: str) -> str:
    with xmlrpc.client.ServerProxy(master) as proxy:
        status, msg, uri = proxy.lookupNode(CALLER, name)
    assert status == 1, msg
    return str(uri)


class Pair:
    """The rospy node's and our node's slave URIs, called alike."""

    def __init__(self, rospy_uri: str, ours_uri: str) -> None:
        self.uris = (rospy_uri, ours_uri)

    async def both(self, method: str, *args: Any) -> tuple[Any, Any]:
        theirs, ours = await asyncio.gather(*(asyncio.to_thread(call, u, method, *args) for u in self.uris))
        return theirs, ours

    async def same_code(self, method: str, *args: Any) -> Any:
        theirs, ours = await self.both(method, *args)
        assert code(ours) == code(theirs), f"{method}{args!r}: rospy answered {theirs!r}, mrosd {ours!r}"
        return code(ours)


@pytest.fixture
async def pair(rosmaster: str, procs: Processes) -> AsyncIterator[tuple[Pair, str]]:
    proc = procs.start([ROS_PYTHON, "-c", ROSPY_PROBE], ros_env(rosmaster, procs.tmp), stderr=subprocess.DEVNULL)
    assert proc.stdout is not None
    async with mrosd.Node("mrosd_probe", master_uri=rosmaster, argv=[], host="127.0.0.1") as node:
        await node.advertise("/chatter", String)
        await node.subscribe("/heard", String)
        assert (await asyncio.to_thread(proc.stdout.readline)).strip() == b"up"
        rospy_uri = await asyncio.to_thread(lookup, rosmaster, "/rospy_probe")
        await asyncio.to_thread(wait_for_xmlrpc, rospy_uri)
        yield Pair(rospy_uri, node.uri), rosmaster


async def test_get_pid_and_its_arity(pair: tuple[Pair, str]) -> None:
    p, _ = pair
    theirs, ours = await p.both("getPid", CALLER)
    assert theirs[0] == ours[0] == 1 and ours[2] > 0
    assert await p.same_code("getPid") in (-1, "fault")


async def test_both_publish_rosout_and_do_not_subscribe_clock_without_sim_time(pair: tuple[Pair, str]) -> None:
    p, _ = pair
    theirs, ours = await p.both("getPublications", CALLER)
    assert (
        dict(map(tuple, ours[2]))
        == dict(map(tuple, theirs[2]))
        == {
            "/chatter": "std_msgs/String",
            "/rosout": "rosgraph_msgs/Log",
        }
    )
    theirs, ours = await p.both("getSubscriptions", CALLER)
    assert dict(map(tuple, ours[2])) == dict(map(tuple, theirs[2])) == {"/heard": "std_msgs/String"}
    for args in ((), (CALLER, "something extra")):
        assert await p.same_code("getPublications", *args) in (-1, "fault")
        assert await p.same_code("getSubscriptions", *args) in (-1, "fault")


async def test_param_update_of_an_unsubscribed_or_invalid_key_is_an_error(pair: tuple[Pair, str]) -> None:
    p, _ = pair
    assert await p.same_code("paramUpdate", CALLER, "/good_key", "good_value") == -1
    assert await p.same_code("paramUpdate", CALLER, "", "bad") == -1
    assert await p.same_code("paramUpdate", CALLER, "no_namespace", "bad") == -1
    assert await p.same_code("paramUpdate", CALLER, "/bad_key") in (-1, "fault")
    assert await p.same_code("paramUpdate", CALLER) in (-1, "fault")


async def test_get_master_uri_is_the_master(pair: tuple[Pair, str]) -> None:
    p, master = pair
    theirs, ours = await p.both("getMasterUri", CALLER)
    assert theirs[0] == ours[0] == 1
    assert ours[2] == theirs[2] == master
    assert await p.same_code("getMasterUri", CALLER, "bad") in (-1, "fault")
    assert await p.same_code("getMasterUri") in (-1, "fault")


async def test_publisher_update_succeeds_for_any_topic_and_checks_its_arguments(pair: tuple[Pair, str]) -> None:
    p, _ = pair
    uris = ["http://localhost:1234", "http://localhost:5678"]
    assert await p.same_code("publisherUpdate", CALLER, "/fake_topic", uris) == 1
    assert await p.same_code("publisherUpdate", CALLER, "/fake_topic", []) == 1
    assert await p.same_code("publisherUpdate", CALLER, "/probe_topic", ["http://unroutablefakeservice:1234"]) == 1
    assert await p.same_code("publisherUpdate", CALLER, "/probe_topic", []) == 1
    for bad in ("bad", 2, False, ["bad"]):
        assert await p.same_code("publisherUpdate", CALLER, "/bad_topic", bad) == -1
    assert await p.same_code("publisherUpdate") in (-1, "fault")
    assert await p.same_code("getBusStats", CALLER, "bad") in (-1, "fault")
    assert await p.same_code("getBusStats") in (-1, "fault")


async def test_request_topic_offers_tcpros_and_refuses_bad_arguments(pair: tuple[Pair, str]) -> None:
    p, _ = pair
    for protocols in ([["TCPROS"]], [["FakeTransport", 1234, 5678], ["TCPROS"], ["AnotherFakeTransport"]]):
        theirs, ours = await p.both("requestTopic", CALLER, "/chatter", protocols)
        assert theirs[0] == ours[0] == 1
        assert len(ours[2]) == len(theirs[2]) == 3 and ours[2][0] == theirs[2][0] == "TCPROS"
    protocols = [["TCPROS"]]
    for args in (
        (CALLER, "/chatter", protocols, "extra stuff"),
        (CALLER, "/chatter"),
        (CALLER,),
        (),
        (CALLER, 1, protocols),
        (CALLER, "", protocols),
        (CALLER, "/fake_topic", protocols),
    ):
        assert await p.same_code("requestTopic", *args) in (-1, "fault")
    # A protocol list that is a string: ros_comm's test_slave_api wants -1 (a bad argument); rospy answers 0.
    theirs, ours = await p.both("requestTopic", CALLER, "/chatter", "fake-protocols")
    assert (code(theirs), code(ours)) == (0, -1)


async def test_get_bus_info_arity(pair: tuple[Pair, str]) -> None:
    p, _ = pair
    theirs, ours = await p.both("getBusInfo", CALLER)
    assert theirs[0] == ours[0] == 1
    assert await p.same_code("getBusInfo", CALLER, "bad") in (-1, "fault")
    assert await p.same_code("getBusInfo") in (-1, "fault")


async def test_both_nodes_are_registered_for_their_topics(pair: tuple[Pair, str]) -> None:
    _, master = pair

    def state() -> Any:
        with xmlrpc.client.ServerProxy(master) as proxy:
            return proxy.getSystemState(CALLER)[2]

    pubs, subs, srvs = await asyncio.to_thread(state)
    for name in ("/rospy_probe", "/mrosd_probe"):
        assert name in dict(pubs)["/chatter"] and name in dict(pubs)["/rosout"]
        assert name in dict(subs)["/heard"]
        assert f"{name}/get_loggers" in dict(srvs) and f"{name}/set_logger_level" in dict(srvs)
