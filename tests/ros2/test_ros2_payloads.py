"""A 1080p rgb8 image and a custom type with an array of a nested custom type reach zenoh-ros2-sdk intact."""

from __future__ import annotations

import asyncio
import queue
from pathlib import Path
from typing import Any

import pytest

import mrosd
from mrosd import backports
from mrosd.msg import get_message_class, load_type
from mrosd.ros2.bridge import Ros2Bridge, Ros2Options

pytest.importorskip("zenoh")
pytest.importorskip("zenoh_ros2_sdk")

#: the ROS 2 definitions zenoh-ros2-sdk reads from its folder (written here: it would clone them otherwise)
ROS2_MSGS = {
    "builtin_interfaces/msg/Time.msg": "int32 sec\nuint32 nanosec\n",
    "std_msgs/msg/Header.msg": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "sensor_msgs/msg/Image.msg": (
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\n"
        "uint32 step\nuint8[] data\n"
    ),
    "my_pkg/msg/Point.msg": "float64 x\nstring[] names\n",
    "my_pkg/msg/Cloud.msg": "std_msgs/Header header\nPoint[] pts\nbuiltin_interfaces/Time t\nuint8 c\nint8 b\n",
}
CLOUD_ROS1 = "Header header\nPoint[] pts\ntime t\nchar c\nbyte b\n"
POINT_ROS1 = "float64 x\nstring[] names\n"
CLOUD_FULL = (
    CLOUD_ROS1
    + "=" * 80
    + "\nMSG: std_msgs/Header\nuint32 seq\ntime stamp\nstring frame_id\n"
    + "=" * 80
    + "\nMSG: my_pkg/Point\n"
    + POINT_ROS1
)


@pytest.fixture
def ros2_msgs(messages_dir: Path) -> Path:
    for rel, text in ROS2_MSGS.items():
        path = messages_dir / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return messages_dir


async def _cross(rosmaster: str, router: int, topic: str, cls: Any, msg: Any, ros2_type: str) -> Any:
    from zenoh_ros2_sdk import ROS2Subscriber
    from zenoh_ros2_sdk.session import ZenohSession

    got: queue.Queue[Any] = queue.Queue(maxsize=4)
    options = Ros2Options(domain_id=0, connect=(f"tcp/127.0.0.1:{router}",), to_ros2=(topic,))
    sub = await asyncio.to_thread(
        ROS2Subscriber,
        topic=topic,
        msg_type=ros2_type,
        callback=lambda m: got.put_nowait(m) if not got.full() else None,
        domain_id=0,
        router_ip="127.0.0.1",
        router_port=router,
    )
    try:
        async with (
            Ros2Bridge(options, rosmaster) as bridge,
            mrosd.Node("talker", master_uri=rosmaster, argv=[], host="127.0.0.1") as node,
        ):
            pub = await node.advertise(topic, cls)
            async with backports.timeout(30):
                while True:
                    await pub.publish(msg)
                    try:
                        return await asyncio.to_thread(got.get, True, 0.3)
                    except queue.Empty:
                        assert not any(row["problem"] for row in bridge.status()), bridge.status()
    finally:
        sub.close()
        inst = ZenohSession._instance
        if inst is not None:
            inst.close()


async def test_a_1080p_rgb8_image_crosses_intact(rosmaster: str, router: int, ros2_msgs: Path) -> None:
    Image = get_message_class("sensor_msgs/Image")
    img = Image()
    img.header.seq, img.header.frame_id = 9, "camera"
    img.header.stamp.secs, img.header.stamp.nsecs = 12, 34
    img.height, img.width, img.encoding, img.step = 1080, 1920, "rgb8", 5760
    img.data = bytes(range(256)) * (1920 * 1080 * 3 // 256)
    got = await _cross(rosmaster, router, "/camera/image", Image, img, "sensor_msgs/msg/Image")
    assert (got.height, got.width, got.encoding, got.step) == (1080, 1920, "rgb8", 5760)
    assert (got.header.frame_id, got.header.stamp.sec, got.header.stamp.nanosec) == ("camera", 12, 34)
    assert bytes(got.data) == img.data


async def test_a_custom_type_with_an_array_of_a_nested_custom_type_crosses(
    rosmaster: str, router: int, ros2_msgs: Path
) -> None:
    Cloud = load_type("my_pkg/Cloud", CLOUD_FULL)
    Point = load_type("my_pkg/Point", POINT_ROS1)
    msg = Cloud()
    msg.header.frame_id = "odom"
    p1, p2 = Point(), Point()
    p1.x, p1.names = 1.5, ["a"]
    p2.x, p2.names = -2.0, ["b", "cd"]
    msg.pts = [p1, p2]
    msg.c, msg.b = 200, -3
    got = await _cross(rosmaster, router, "/cloud", Cloud, msg, "my_pkg/msg/Cloud")
    assert got.header.frame_id == "odom"
    assert [(p.x, list(p.names)) for p in got.pts] == [(1.5, ["a"]), (-2.0, ["b", "cd"])]
    assert (got.c, got.b) == (200, -3)
