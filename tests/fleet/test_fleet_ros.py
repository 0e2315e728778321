"""Two mrosd masters linked over Zenoh, real ROS on each: rospy nodes on robot1, rostopic/rosservice on robot2."""

from __future__ import annotations

import asyncio
import subprocess
from pathlib import Path

import pytest

from tests.fleet.fleetenv import fleet
from tests.interop.tcpros.test_tcpros_interop import roscpp_node
from tests.rosenv import Processes, needs_ros, ros_env

pytestmark = [pytest.mark.interop, needs_ros]
__all__ = ["roscpp_node"]  # the session fixture that compiles the roscpp node (tests/interop/tcpros)

TALKER = """
import rospy
from std_msgs.msg import String
from std_srvs.srv import SetBool, SetBoolResponse
rospy.init_node("talker")
pub = rospy.Publisher("/chatter", String, queue_size=10)
latched = rospy.Publisher("/map", String, queue_size=1, latch=True)
latched.publish(String(data="the map from rospy"))
rospy.Service("/set", SetBool, lambda req: SetBoolResponse(success=req.data, message="rospy on robot1"))
rate = rospy.Rate(20)
while not rospy.is_shutdown():
    pub.publish(String(data="hello from rospy"))
    rate.sleep()
"""


async def _run(procs: Processes, argv: list[str], env: dict[str, str], timeout: float) -> str:
    proc = procs.start(argv, env)
    try:
        out, err = await asyncio.to_thread(proc.communicate, None, timeout)
    except subprocess.TimeoutExpired:
        procs.stop(proc)
        raise AssertionError(f"{argv} did not finish within {timeout} s") from None
    assert proc.returncode == 0, (argv, out, err)
    return out.decode()


async def test_rospy_to_rostopic_echo_service_and_latched_map(procs: Processes, tmp_path: Path) -> None:
    async with fleet("robot1", "robot2") as (r1, r2):
        procs.python(TALKER, ros_env(r1.master.uri, tmp_path))
        await r2.bridge.wait_until(
            lambda: (
                {"/robot1/chatter", "/robot1/map"} <= set(r2.bridge.received)
                and "/robot1/set" in r2.bridge.received_services
            ),
            30,
        )
        env2 = ros_env(r2.master.uri, tmp_path)
        out = await _run(procs, ["rostopic", "echo", "-n", "1", "/robot1/chatter"], env2, 30)
        assert "hello from rospy" in out
        # the latched map was published once, before robot2 had any subscriber
        out = await _run(procs, ["rostopic", "echo", "-n", "1", "/robot1/map"], env2, 30)
        assert "the map from rospy" in out
        out = await _run(procs, ["rosservice", "call", "/robot1/set", "data: true"], env2, 30)
        assert "success: True" in out and "rospy on robot1" in out


async def test_three_robots_rospy_roscpp_and_rostopic(procs: Processes, tmp_path: Path, roscpp_node: str) -> None:
    """robot1's rospy /chatter -> robot3's roscpp echo node -> robot2's rostopic, over two fleet hops."""
    async with fleet("robot1", "robot2", "robot3") as (r1, r2, r3):
        procs.python(TALKER, ros_env(r1.master.uri, tmp_path / "r1"))
        await r3.bridge.wait_until(lambda: "/robot1/chatter" in r3.bridge.received, 30)
        procs.start(
            [roscpp_node, "echo", "string", "/ping:=/robot1/chatter", "/pong:=/echoed"],
            ros_env(r3.master.uri, tmp_path / "r3"),
        )
        await r2.bridge.wait_until(lambda: "/robot3/echoed" in r2.bridge.received, 30)
        out = await _run(procs, ["rostopic", "echo", "-n", "1", "/robot3/echoed"], ros_env(r2.master.uri, tmp_path), 30)
        assert "hello from rospy" in out
        # robot2 also sees robot1 directly, under robot1's name, and nothing of its own comes back renamed
        assert "/robot1/chatter" in r2.bridge.received
        assert not [t for t in r1.bridge.received if t.startswith("/robot1/")]
