"""rosbridge and rosapi as rosbridge_suite's ROS 1 code answers (issue 33, items 5 and 6).

Each expected value here was read off rosbridge_suite's ``ros1`` branch (rosapi's proxy.py, objectutils.py
and rosapi_node; rosbridge_library's publishers.py and service_response.py). Real sockets, a real master, the
server in the test's loop; roslibpy as a client process.
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib.util
import json
import subprocess
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from mrosd import backports
from mrosd.errors import MasterError
from mrosd.master import Master
from mrosd.msg import TypeStore, get_message_class, get_service_class
from mrosd.web import rosbridge_publishers
from mrosd.web.server import WebServer
from tests.rosenv import ROS_PYTHON, needs_ros, ros_env
from tests.web.inloop import node, rosbridge_and_node
from tests.web.test_web_real_clients import NodeClient
from tests.web.test_web_rosbridge_types import bridge_process, make_workspace, roslibpy_client, wait_for_service

HERE = Path(__file__).resolve().parent
String = get_message_class("std_msgs/String")
Goal = get_message_class("actionlib_msgs/GoalID")
Status = get_message_class("actionlib_msgs/GoalStatusArray")
SetBool = get_service_class("std_srvs/SetBool")


async def call(ws: aiohttp.ClientWebSocketResponse, service: str, args: Any = None, **extra: Any) -> dict[str, Any]:
    op_id = f"{service}:{id(args)}"
    await ws.send_str(json.dumps({"op": "call_service", "service": service, "args": args or {}, "id": op_id, **extra}))
    async with backports.timeout(10):
        while True:
            msg = json.loads((await ws.receive()).data)
            if msg.get("op") == "service_response" and msg.get("id") == op_id:
                return msg


async def values(ws: aiohttp.ClientWebSocketResponse, service: str, args: Any = None) -> dict[str, Any]:
    reply = await call(ws, service, args)
    assert reply["result"] is True, reply
    return dict(reply["values"])


@pytest.mark.skipif(importlib.util.find_spec("roslibpy") is None, reason="roslibpy is not installed")
async def test_a_roslibpy_handler_returning_false_answers_the_ros_caller_with_its_values(
    master: Master, tmp_path: Path
) -> None:
    """roslibpy's own ROS 1 test: the handler fills the sum and returns False; rosbridge ignores ``result``."""
    workspace = make_workspace(tmp_path / "ws")
    add = get_service_class("my_pkg/AddTwoInts", TypeStore(ros_package_path=str(workspace)))
    async with (
        bridge_process(master.uri, workspace) as url,
        node("caller", master.uri) as caller,
    ):
        provider = await roslibpy_client(url)
        try:
            await provider.send(cmd="advertise", service="/add", type="my_pkg/AddTwoInts", result=False)
            await provider.until("advertised")
            await wait_for_service(caller, "/add")
            response = await caller.service_proxy("/add", add).call(add._request_class(a=40, b=2), timeout=10)
            assert response.sum == 42
        finally:
            await provider.close()


async def test_call_service_ignores_the_clients_type_and_asks_the_service(master: Master) -> None:
    async with rosbridge_and_node(master.uri, "robot") as (server, robot, http):
        answer = SetBool._response_class
        await robot.advertise_service("/enable", SetBool, lambda r: answer(success=r.data, message="ok"))
        async with http.ws_connect(server.rosbridge_url) as ws:
            reply = await call(ws, "/enable", {"data": True}, type="std_srvs/srv/SetBool")
            assert reply["result"] is True, reply
            assert reply["values"] == {"success": True, "message": "ok"}


async def test_rosapi_is_in_the_graph_under_rosapis_types(master: Master) -> None:
    topics = get_service_class("rosapi/Topics")
    async with rosbridge_and_node(master.uri, "robot") as (server, robot, http):
        await robot.advertise("/chatter", String)
        with pytest.raises(MasterError):  # not before a web client comes (tests/web/test_web_graph_footprint.py)
            await robot.master.lookup_service("/rosapi/topics")
        async with http.ws_connect(server.rosbridge_url) as ws:
            uri = await robot.master.lookup_service("/rosapi/topics")  # in the graph before the first op is read
            assert uri.startswith("rosrpc://127.0.0.1:")
            response = await robot.service_proxy("/rosapi/topics", topics).call(topics._request_class(), timeout=10)
            assert "/chatter" in response.topics
            srv_type = await values(ws, "/rosapi/service_type", {"service": "/rosapi/topics"})
            assert srv_type == {"type": "rosapi/Topics"}
            assert (await values(ws, "/rosapi/service_host", {"service": "/rosapi/topics"})) == {"host": "127.0.0.1"}
            assert (await values(ws, "/rosapi/service_host", {"service": "/nope"})) == {"host": ""}


async def test_action_servers_ros_version_and_full_text_of_a_subscribed_topic(master: Master) -> None:
    async with rosbridge_and_node(master.uri, "robot") as (server, robot, http):
        for leaf, cls in [("goal", Goal), ("cancel", Goal), ("status", Status), ("feedback", Goal), ("result", Goal)]:
            await robot.advertise(f"/fibonacci/{leaf}", cls)
        await robot.advertise("/half/goal", Goal)  # not all five: not an action server
        await robot.subscribe("/only_subscribed", String)
        await robot.master.set_param("/rosdistro", "melodic\n")
        async with http.ws_connect(server.rosbridge_url) as ws:
            async with backports.timeout(10):
                while "/only_subscribed" not in (await values(ws, "/rosapi/topics"))["topics"]:  # noqa: ASYNC110
                    await asyncio.sleep(0.05)
            assert (await values(ws, "/rosapi/action_servers")) == {"action_servers": ["/fibonacci"]}
            assert (await values(ws, "/rosapi/get_ros_version")) == {"version": 1, "distro": "melodic"}
            raw = await values(ws, "/rosapi/topics_and_raw_types")
            text = dict(zip(raw["topics"], raw["typedefs_full_text"], strict=True))
            assert text["/only_subscribed"] == String._full_text


async def test_message_details_as_rosapi_gives_them(master: Master) -> None:
    async with (
        WebServer(master.uri, port=0, rosbridge_port=0, node_host="127.0.0.1") as server,
        aiohttp.ClientSession() as http,
        http.ws_connect(server.rosbridge_url) as ws,
    ):
        pose = (await values(ws, "/rosapi/message_details", {"type": "geometry_msgs/PoseStamped"}))["typedefs"]
        order = ["geometry_msgs/PoseStamped", "std_msgs/Header", "time", "geometry_msgs/Pose"]
        assert [d["type"] for d in pose] == [*order, "geometry_msgs/Point", "geometry_msgs/Quaternion"]
        header, stamp, point = pose[1], pose[2], pose[4]
        assert header["fieldtypes"] == ["uint32", "time", "string"]
        assert header["examples"] == ["0", "{}", ""]
        assert stamp == {
            "type": "time",
            "fieldnames": ["secs", "nsecs"],
            "fieldtypes": ["int32", "int32"],
            "fieldarraylen": [-1, -1],
            "examples": ["0", "0"],
            "constnames": [],
            "constvalues": [],
        }
        assert point["examples"] == ["0.0", "0.0", "0.0"]
        (status,) = (await values(ws, "/rosapi/message_details", {"type": "sensor_msgs/NavSatStatus"}))["typedefs"]
        assert status["constnames"] == sorted(status["constnames"])
        assert status["constnames"][:2] == ["SERVICE_COMPASS", "SERVICE_GALILEO"]
        assert status["constvalues"][:2] == ["4", "8"]
        request = await values(ws, "/rosapi/service_request_details", {"type": "std_srvs/SetBool"})
        assert request["typedefs"][0]["type"] == "std_srvs/SetBoolRequest"
        assert request["typedefs"][0]["examples"] == ["False"]
        fix = (await values(ws, "/rosapi/message_details", {"type": "sensor_msgs/NavSatFix"}))["typedefs"][0]
        assert fix["examples"] == ["{}", "{}", "0.0", "0.0", "0.0", "[]", "0"]
        assert fix["fieldarraylen"] == [-1, -1, -1, -1, -1, 9, -1]


@contextlib.asynccontextmanager
async def rospy_listener(master_uri: str, tmp: Path, topic: str, action_ns: str = "") -> AsyncIterator[NodeClient]:
    """tests/web/rospy_listener.py under Debian's rospy, subscribed to ``topic`` (Twist) once it is ready."""
    argv = [str(HERE / "rospy_listener.py"), topic, *([action_ns] if action_ns else [])]
    proc = await asyncio.create_subprocess_exec(
        ROS_PYTHON, *argv, env=ros_env(master_uri, tmp), stdin=subprocess.PIPE, stdout=subprocess.PIPE
    )
    client = NodeClient(proc)
    try:
        await client.until("ready", timeout=30)
        yield client
    finally:
        await client.close()


@needs_ros
async def test_publish_on_a_fresh_socket_that_closes_at_once_reaches_rospy(
    master: Master, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """advertise, publish, close at once (ros-mcp's publish_once): rospy, subscribed before, connects to the new
    publisher only after the message went out; the first second is re-sent to it, and the publisher stays for
    UNREGISTER_TIMEOUT after its client (shortened here), then is withdrawn."""
    monkeypatch.setattr(rosbridge_publishers, "UNREGISTER_TIMEOUT", 3.0)
    async with (
        WebServer(master.uri, port=0, rosbridge_port=0, node_host="127.0.0.1") as server,
        rospy_listener(master.uri, tmp_path, "/cmd_vel") as listener,
        node("robot", master.uri) as robot,
        aiohttp.ClientSession() as http,
    ):
        async with http.ws_connect(server.rosbridge_url) as ws:
            await ws.send_str(json.dumps({"op": "advertise", "topic": "/cmd_vel", "type": "geometry_msgs/Twist"}))
            await ws.send_str(json.dumps({"op": "publish", "topic": "/cmd_vel", "msg": {"linear": {"x": 0.5}}}))
            await ws.send_str(json.dumps({"op": "unadvertise", "topic": "/cmd_vel"}))
            await values(ws, "/rosapi/get_time")  # every op before is handled
        assert (await listener.until("message", timeout=5))["x"] == 0.5
        pubs, _, _ = await robot.master.get_system_state()
        assert "/cmd_vel" in dict(pubs)
        async with backports.timeout(10):
            while "/cmd_vel" in dict((await robot.master.get_system_state())[0]):  # noqa: ASYNC110
                await asyncio.sleep(0.1)
        assert [e for e in listener.events if e["event"] == "message"] == [{"event": "message", "x": 0.5}]


async def test_lingering_publishers_are_bounded(master: Master, monkeypatch: pytest.MonkeyPatch) -> None:
    """A client that advertises and leaves: at most MAX_LINGERING publishers stay; the others go at once."""
    monkeypatch.setattr(rosbridge_publishers, "MAX_LINGERING", 2)
    async with rosbridge_and_node(master.uri, "robot") as (server, robot, http):
        async with http.ws_connect(server.rosbridge_url) as ws:
            for i in range(5):
                await ws.send_str(json.dumps({"op": "advertise", "topic": f"/t{i}", "type": "std_msgs/String"}))
            await values(ws, "/rosapi/get_time")
        async with backports.timeout(10):
            while len([t for t in dict((await robot.master.get_system_state())[0]) if t.startswith("/t")]) != 2:  # noqa: ASYNC110
                await asyncio.sleep(0.05)
        assert len(server.hub._publishers) == 2
