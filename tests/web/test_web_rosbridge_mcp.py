"""ros-mcp (PyPI: an MCP server that lets language-model agents drive ROS robots through rosbridge and rosapi)
against mrosd's rosbridge, driven as an agent's host drives it: over MCP on stdio (issue 33, item 6).

The robot is Debian's rospy: a node subscribed to /cmd_vel that also holds an action server's five topics; an
mrosd node provides a std_srvs/SetBool service, which the agent calls with ROS 2's type name.
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import os
import sys
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

import mrosd
from mrosd.master import Master
from mrosd.msg import get_service_class
from mrosd.web.server import WebServer
from tests.rosenv import needs_ros
from tests.web.test_web_rosbridge_rosapi import rospy_listener

pytestmark = [
    needs_ros,
    pytest.mark.skipif(importlib.util.find_spec("ros_mcp") is None, reason="ros-mcp is not installed: .[dev]"),
]

SetBool = get_service_class("std_srvs/SetBool")


class Agent:
    """An MCP client session with ros-mcp's server process (stdio)."""

    def __init__(self, session: Any) -> None:
        self.session = session

    async def tool(self, tool: str, **args: Any) -> dict[str, Any]:
        result = await self.session.call_tool(tool, args)
        assert not result.isError, result.content
        if result.structuredContent is not None:
            return dict(result.structuredContent)
        return dict(json.loads(result.content[0].text))


@contextlib.asynccontextmanager
async def ros_mcp(tmp: Path) -> AsyncIterator[Agent]:
    from mcp import ClientSession, StdioServerParameters
    from mcp.client.stdio import stdio_client

    env = {**os.environ, "HOME": str(tmp)}
    params = StdioServerParameters(command=sys.executable, args=["-m", "ros_mcp.main"], env=env)
    with (tmp / "ros_mcp.stderr").open("w") as errlog:
        async with stdio_client(params, errlog=errlog) as (read, write), ClientSession(read, write) as session:
            await session.initialize()
            yield Agent(session)


async def test_ros_mcp_publishes_calls_and_lists_actions_through_mrosd(master: Master, tmp_path: Path) -> None:
    async with (
        WebServer(master.uri, port=0, rosbridge_port=0, node_host="127.0.0.1") as server,
        rospy_listener(master.uri, tmp_path, "/cmd_vel", action_ns="/fibonacci") as robot,
        mrosd.Node("switch", master_uri=master.uri, argv=[], host="127.0.0.1") as switch,
        ros_mcp(tmp_path) as agent,
    ):
        answer = SetBool._response_class
        await switch.advertise_service("/enable", SetBool, lambda r: answer(success=r.data, message="switched"))
        connected = await agent.tool("connect_to_robot", ip="127.0.0.1", port=server.rosbridge_port)
        assert connected["connectivity_test"]["port_check"]["open"], connected
        assert "warning" not in connected, connected

        # publish_once: a fresh socket that advertises, publishes, unadvertises and closes at once
        once = await agent.tool(
            "publish_once", topic="/cmd_vel", msg_type="geometry_msgs/Twist", msg={"linear": {"x": 1.0}}
        )
        assert once.get("success"), once
        assert (await robot.until("message", timeout=10))["x"] == 1.0

        # a 5 Hz burst for one second arrives whole
        burst = await agent.tool(
            "publish_for_durations",
            topic="/cmd_vel",
            msg_type="geometry_msgs/Twist",
            messages=[{"linear": {"x": 2.0}}],
            durations=[1.0],
            rate_hz=5,
        )
        assert burst.get("success") and burst["published_count"] >= 4, burst
        for _ in range(burst["published_count"]):
            assert (await robot.until("message", timeout=10))["x"] == 2.0

        called = await agent.tool(
            "call_service", service_name="/enable", service_type="std_srvs/srv/SetBool", request={"data": True}
        )
        assert called["success"] is True, called
        assert called["result"] == {"success": True, "message": "switched"}

        actions = await agent.tool("get_actions")
        assert actions["actions"] == ["/fibonacci"], actions

        topics = await agent.tool("get_topics")
        assert "/cmd_vel" in json.dumps(topics)
        # the read-only tools an agent explores with: each answers without an error
        await switch.master.set_param("/rosdistro", "noetic\n")
        for tool, args in [
            ("get_services", {}),
            ("get_service_type", {"service": "/enable"}),
            ("get_service_details", {"service": "/enable"}),
            ("get_nodes", {}),
            ("get_node_details", {"node": "/switch"}),
            ("get_topic_type", {"topic": "/cmd_vel"}),
            ("get_topic_details", {"topic": "/cmd_vel"}),
            ("get_message_details", {"message_type": "geometry_msgs/Twist"}),
            ("get_parameter", {"name": "/rosdistro"}),
            ("detect_ros_version", {}),
        ]:
            answer_of = await agent.tool(tool, **args)
            assert "error" not in answer_of, (tool, answer_of)
        assert "std_srvs/SetBool" in json.dumps(await agent.tool("get_service_type", service="/enable"))
        assert [e for e in robot.events if e["event"] == "message"] == [
            {"event": "message", "x": 1.0},
            *[{"event": "message", "x": 2.0}] * burst["published_count"],
        ]
