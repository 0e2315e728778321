"""A rospy /chatter reaches a zenoh-ros2-sdk subscriber (an rmw_zenoh peer we did not write) through
``Ros2Bridge``, against Debian's rosmaster, over an in-process Zenoh router on a loopback port."""

from __future__ import annotations

import asyncio
import queue
from pathlib import Path
from typing import Any

import pytest

from mrosd import backports
from mrosd.ros2.bridge import Ros2Bridge, Ros2Options
from mrosd.ros2.keys import EntityKind, parse_token
from tests.rosenv import Processes, needs_ros, ros_env

pytestmark = [pytest.mark.interop, needs_ros]
zenoh = pytest.importorskip("zenoh")
sdk = pytest.importorskip("zenoh_ros2_sdk")

STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"

TALKER = """
import rospy
from std_msgs.msg import String
rospy.init_node("talker")
pub = rospy.Publisher("/chatter", String, queue_size=10)
rate = rospy.Rate(20)
while not rospy.is_shutdown():
    pub.publish(String(data="hello from rospy"))
    rate.sleep()
"""


def _tokens(port: int) -> list[str]:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", f'["tcp/127.0.0.1:{port}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    try:
        return [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/**", timeout=5.0) if r.ok is not None]
    finally:
        session.close()


async def test_rospy_chatter_reaches_a_zenoh_ros2_sdk_subscriber_on_rmw_zenohs_key(
    procs: Processes, rosmaster: str, tmp_path: Path, router: int, messages_dir: Path
) -> None:
    from zenoh_ros2_sdk import ROS2Subscriber
    from zenoh_ros2_sdk.session import ZenohSession

    got: queue.Queue[Any] = queue.Queue(maxsize=100)
    options = Ros2Options(domain_id=0, connect=(f"tcp/127.0.0.1:{router}",), to_ros2=("/chatter",))
    sub = ROS2Subscriber(
        topic="/chatter",
        msg_type="std_msgs/msg/String",
        callback=lambda msg: got.put_nowait(msg.data) if not got.full() else None,
        domain_id=0,
        router_ip="127.0.0.1",
        router_port=router,
    )
    try:
        assert sub.type_hash == STRING_HASH
        async with Ros2Bridge(options, rosmaster) as bridge:
            procs.python(TALKER, ros_env(rosmaster, tmp_path))
            await bridge.wait_until(
                lambda: "/chatter" in bridge.topics and bridge.topics["/chatter"].rmw is not None, 30
            )
            assert (
                bridge.topics["/chatter"].key == sub.keyexpr == f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
            )
            data = await asyncio.to_thread(got.get, True, 20)
            assert data == "hello from rospy"
            parsed = [parse_token(t) for t in _tokens(router)]
            ours = [t for t in parsed if t.node == "mrosd_ros2"]
            assert {t.kind for t in ours} == {EntityKind.NODE, EntityKind.PUBLISHER}
            pub = next(t for t in ours if t.kind is EntityKind.PUBLISHER)
            assert (pub.topic, pub.type_name, pub.type_hash) == (
                "/chatter",
                "std_msgs::msg::dds_::String_",
                STRING_HASH,
            )
            theirs = [t for t in parsed if t.kind is EntityKind.SUBSCRIPTION]
            assert [(t.topic, t.type_hash) for t in theirs] == [("/chatter", STRING_HASH)]
            assert bridge.status()[0]["sent"] >= 1
    finally:
        sub.close()
        inst = ZenohSession._instance
        if inst is not None:
            inst.close()


LATCHER = """
import rospy
from std_msgs.msg import String
rospy.init_node("mapper")
pub = rospy.Publisher("/map", String, queue_size=1, latch=True)
pub.publish(String(data="the map from rospy"))
rospy.spin()
"""


async def test_a_latched_topic_reaches_a_late_transient_local_subscriber(
    procs: Processes, rosmaster: str, tmp_path: Path, router: int, messages_dir: Path
) -> None:
    from zenoh_ros2_sdk import ROS2Subscriber
    from zenoh_ros2_sdk.qos import QosDurability, QosProfile
    from zenoh_ros2_sdk.session import ZenohSession

    got: queue.Queue[Any] = queue.Queue(maxsize=100)
    options = Ros2Options(domain_id=0, connect=(f"tcp/127.0.0.1:{router}",), to_ros2=("/map",))
    sub = None
    try:
        async with Ros2Bridge(options, rosmaster) as bridge:
            procs.python(LATCHER, ros_env(rosmaster, tmp_path))

            def sent() -> bool:
                bt = bridge.topics.get("/map")
                return bt is not None and bt.rmw is not None and bt.rmw.sent >= 1

            await bridge.wait_until(sent, 30)
            assert bridge.status()[0]["latched"]
            # the only message was put before any ROS 2 subscriber existed
            sub = await asyncio.to_thread(
                ROS2Subscriber,
                topic="/map",
                msg_type="std_msgs/msg/String",
                callback=lambda msg: got.put_nowait(msg.data) if not got.full() else None,
                domain_id=0,
                router_ip="127.0.0.1",
                router_port=router,
                qos=QosProfile(durability=QosDurability.TRANSIENT_LOCAL, history_depth=1),
            )
            data = await asyncio.to_thread(got.get, True, 20)
            assert data == "the map from rospy"
            pub = next(
                t for t in map(parse_token, _tokens(router)) if t.kind is EntityKind.PUBLISHER and t.topic == "/map"
            )
            assert pub.qos is not None and (pub.qos.durability, pub.qos.depth) == (1, 1)
    finally:
        if sub is not None:
            sub.close()
        inst = ZenohSession._instance
        if inst is not None:
            inst.close()


async def test_a_zenoh_ros2_sdk_publisher_reaches_rostopic_echo(
    procs: Processes, rosmaster: str, tmp_path: Path, router: int, messages_dir: Path
) -> None:
    from zenoh_ros2_sdk import ROS2Publisher
    from zenoh_ros2_sdk.session import ZenohSession

    options = Ros2Options(domain_id=0, connect=(f"tcp/127.0.0.1:{router}",), from_ros2=("/from_ros2",))
    pub = None
    try:
        async with Ros2Bridge(options, rosmaster) as bridge:
            pub = await asyncio.to_thread(
                ROS2Publisher,
                topic="/from_ros2",
                msg_type="std_msgs/msg/String",
                domain_id=0,
                router_ip="127.0.0.1",
                router_port=router,
            )
            await bridge.wait_until(lambda: bridge.inbound is not None and "/from_ros2" in bridge.inbound.topics, 30)
            echo = procs.start(["rostopic", "echo", "-n", "1", "/from_ros2"], ros_env(rosmaster, tmp_path))

            async def keep_publishing() -> None:
                while echo.poll() is None:
                    await asyncio.to_thread(pub.publish, data="hello from ROS 2")
                    await asyncio.sleep(0.1)

            await backports.wait_for(keep_publishing(), 30)
            out, err = echo.communicate(timeout=5)
            assert echo.returncode == 0, err
            assert "hello from ROS 2" in out.decode()
            parsed = [parse_token(t) for t in _tokens(router)]
            assert any(t.kind is EntityKind.SUBSCRIPTION and t.node == "mrosd_ros2" for t in parsed)
    finally:
        if pub is not None:
            pub.close()
        inst = ZenohSession._instance
        if inst is not None:
            inst.close()
