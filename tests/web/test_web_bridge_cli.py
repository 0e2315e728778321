"""``mros bridge`` alone against Debian's rosmaster (the graph is polled) with a rospy publisher and service."""

from __future__ import annotations

import asyncio
import json
import os
import re
import struct
import subprocess
import sys
from pathlib import Path

import aiohttp
import pytest

from mrosd import backports
from mrosd.msg import get_message_class, get_service_class
from tests.rosenv import Processes, needs_ros, ros_env

String = get_message_class("std_msgs/String")

ROSPY_TALKER = """
import rospy
from std_msgs.msg import String
from std_srvs.srv import Trigger, TriggerResponse
rospy.init_node("rospy_talker")
pub = rospy.Publisher("/chatter", String, queue_size=10)
rospy.Service("/trigger", Trigger, lambda req: TriggerResponse(success=True, message="fired"))
print("up", flush=True)
while not rospy.is_shutdown():
    pub.publish(String(data="hello from rospy"))
    rospy.sleep(0.05)
"""


def test_bridge_refuses_to_listen_off_loopback_without_a_token() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "mros_cli.main", "bridge", "--host", "0.0.0.0"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert out.returncode == 2
    assert "token" in out.stderr


@pytest.mark.interop
@needs_ros
def test_mros_bridge_serves_rosmaster_graph(procs: Processes, rosmaster: str, tmp_path: Path) -> None:
    env = ros_env(rosmaster, tmp_path)
    talker = procs.python(ROSPY_TALKER, env)
    assert talker.stdout is not None
    assert talker.stdout.readline().strip() == b"up"
    # Our interpreter with this tree's code (ros_env drops PYTHON*, which a worktree checkout relies on).
    ours = {**env, "PYTHONPATH": os.environ.get("PYTHONPATH", "")}
    bridge = procs.our_python(["-m", "mros_cli.main", "bridge", "--port", "0", "--rosbridge-port", "0"], ours)
    assert bridge.stderr is not None
    line = bridge.stderr.readline().decode()
    match = re.search(r"serving (ws://\S+/)", line)
    assert match, line
    asyncio.run(_check(match.group(1)))


async def _check(url: str) -> None:
    async with aiohttp.ClientSession() as http, http.ws_connect(url, protocols=["foxglove.websocket.v1"]) as ws:
        channel = None
        service = None
        async with backports.timeout(20):
            while channel is None or service is None:
                msg = json.loads((await ws.receive()).data)
                if msg["op"] == "advertise":
                    channel = next((c for c in msg["channels"] if c["topic"] == "/chatter"), channel)
                if msg["op"] == "advertiseServices":
                    service = next((s for s in msg["services"] if s["name"] == "/trigger"), service)
        assert channel["schemaName"] == "std_msgs/String"
        assert service["type"] == "std_srvs/Trigger"
        await ws.send_str(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": channel["id"]}]}))
        await ws.send_bytes(struct.pack("<BIII", 2, service["id"], 9, 4) + b"ros1")
        got_message = got_response = False
        async with backports.timeout(20):
            while not (got_message and got_response):
                msg = await ws.receive()
                if msg.type != aiohttp.WSMsgType.BINARY:
                    continue
                data = bytes(msg.data)
                if data[0] == 1:
                    assert String.deserialize(data[13:]).data == "hello from rospy"
                    got_message = True
                elif data[0] == 3:
                    assert data[13:17] == b"ros1"
                    got_response = b"fired" in data[17:]


@pytest.mark.interop
@needs_ros
async def test_a_rosbridge_call_right_after_a_service_registers_finds_it_as_rosbridge_does(rosmaster: str) -> None:
    """Against rosmaster the bridge polls the graph (0.5 s): a call that comes first looks the type up then."""
    import mrosd
    from mrosd.web.server import WebServer

    set_bool = get_service_class("std_srvs/SetBool")
    async with (
        WebServer(rosmaster, port=0, rosbridge_port=0, node_host="127.0.0.1") as server,
        mrosd.Node("robot", master_uri=rosmaster, argv=[], host="127.0.0.1") as robot,
        aiohttp.ClientSession() as http,
        http.ws_connect(server.rosbridge_url) as ws,
    ):
        await robot.advertise_service("/enable", set_bool, lambda r: set_bool._response_class(success=r.data))
        assert "/enable" not in server.hub.services  # the next poll has not come yet
        call = {"op": "call_service", "service": "/enable", "args": {"data": True}, "id": "c1"}
        await ws.send_str(json.dumps(call))
        async with backports.timeout(10):
            while (reply := json.loads((await ws.receive()).data))["op"] != "service_response":
                pass
        assert reply["result"] is True, reply
        assert reply["values"]["success"] is True
