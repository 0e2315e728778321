"""ROS 2 -> ROS 1 for custom types: a zenoh-ros2-sdk publisher's custom type with an array of a nested custom
type, defined only in a ROS 2 share tree, reaches an mrosd subscriber that wrote the type in ROS 1's syntax (the
md5 computed by the bridge must be genmsg's for the handshake to pass); a 300 kB body is converted off the loop."""

from __future__ import annotations

import asyncio
import contextlib
from pathlib import Path
from typing import Any

import pytest

import mrosd
from mrosd import backports
from mrosd.msg import load_type
from mrosd.ros2.bridge import Ros2Bridge, Ros2Options
from mrosd.ros2.inbound import OFFLOAD_SIZE

pytest.importorskip("zenoh")
pytest.importorskip("zenoh_ros2_sdk")

ROS2_MSGS = {
    "builtin_interfaces/msg/Time.msg": "int32 sec\nuint32 nanosec\n",
    "builtin_interfaces/msg/Duration.msg": "int32 sec\nuint32 nanosec\n",
    "std_msgs/msg/Header.msg": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "fleet_msgs/msg/Waypoint.msg": "uint8 KIND_GOAL=1\nstring name\nfloat64 x\nbuiltin_interfaces/Duration wait\n",
    "fleet_msgs/msg/Route.msg": "std_msgs/Header header\nWaypoint[] points\nint32[3] tags\nbool done\n",
    "fleet_msgs/msg/Blob.msg": "uint32 n\nuint8[] data\n",
}
ROUTE_1 = """std_msgs/Header header
fleet_msgs/Waypoint[] points
int32[3] tags
bool done
================================================================================
MSG: fleet_msgs/Waypoint
uint8 KIND_GOAL=1
string name
float64 x
duration wait
"""


async def test_a_ros2_custom_type_from_a_share_tree_reaches_an_mrosd_subscriber(
    rosmaster: str, router: int, messages_dir: Path
) -> None:
    from zenoh_ros2_sdk import ROS2Publisher, message_registry
    from zenoh_ros2_sdk.session import ZenohSession

    for rel, text in ROS2_MSGS.items():
        path = messages_dir / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    options = Ros2Options(
        domain_id=0,
        connect=(f"tcp/127.0.0.1:{router}",),
        from_ros2=("/route", "/blob"),
        ros2_share=(str(messages_dir),),
    )
    Route = load_type("fleet_msgs/Route", ROUTE_1)
    Blob = load_type("fleet_msgs/Blob", "uint32 n\nuint8[] data\n")
    routes: asyncio.Queue[Any] = asyncio.Queue(maxsize=4)
    blobs: asyncio.Queue[Any] = asyncio.Queue(maxsize=4)
    pubs: list[Any] = []
    heard = asyncio.Event()
    try:
        async with (
            Ros2Bridge(options, rosmaster) as bridge,
            mrosd.Node("listener", master_uri=rosmaster, argv=[], host="127.0.0.1") as node,
        ):
            for topic, ros2_type in (("/route", "fleet_msgs/msg/Route"), ("/blob", "fleet_msgs/msg/Blob")):
                pubs.append(
                    await asyncio.to_thread(
                        ROS2Publisher,
                        topic=topic,
                        msg_type=ros2_type,
                        domain_id=0,
                        router_ip="127.0.0.1",
                        router_port=router,
                    )
                )
            inbound = bridge.inbound
            assert inbound is not None
            await bridge.wait_until(lambda: {"/route", "/blob"} <= set(inbound.topics), 30)
            for queue_, topic, cls in ((routes, "/route", Route), (blobs, "/blob", Blob)):
                await node.subscribe(
                    topic, cls, callback=lambda m, q=queue_: q.full() or (q.put_nowait(m), heard.set())
                )
            reg = message_registry.get_registry()
            wp, dur = (
                reg.get_message_class("fleet_msgs/msg/Waypoint"),
                reg.get_message_class("builtin_interfaces/msg/Duration"),
            )
            header = reg.get_message_class("std_msgs/msg/Header")(
                stamp=reg.get_message_class("builtin_interfaces/msg/Time")(sec=3, nanosec=4), frame_id="map"
            )
            import numpy as np

            points = [wp(name="a", x=1.5, wait=dur(sec=1, nanosec=2)), wp(name="b", x=-2.5, wait=dur(sec=3, nanosec=4))]
            data = bytes(range(256)) * (OFFLOAD_SIZE // 256 + 1)

            async def keep_publishing() -> tuple[Any, Any]:
                while routes.empty() or blobs.empty():
                    await asyncio.to_thread(
                        pubs[0].publish, header=header, points=points, tags=np.array([7, 8, 9], np.int32), done=True
                    )
                    await asyncio.to_thread(pubs[1].publish, n=len(data), data=np.frombuffer(data, np.uint8))
                    with contextlib.suppress(TimeoutError):  # paces the publisher; returns on a delivery
                        await backports.wait_for(heard.wait(), 0.3)
                    heard.clear()
                return routes.get_nowait(), blobs.get_nowait()

            route, blob = await backports.wait_for(keep_publishing(), 30)
            assert route.header.frame_id == "map" and (route.header.stamp.secs, route.header.stamp.nsecs) == (3, 4)
            assert [(p.name, p.x, p.wait.secs, p.wait.nsecs) for p in route.points] == [
                ("a", 1.5, 1, 2),
                ("b", -2.5, 3, 4),
            ]
            assert list(route.tags) == [7, 8, 9] and route.done
            assert blob.n == len(data) and bytes(blob.data) == data
            rows = {row["topic"]: row for row in bridge.inbound_status()}
            assert rows["/route"]["ros2_type"] == "fleet_msgs/msg/Route" and rows["/route"]["bad"] == 0
    finally:
        for pub in pubs:
            pub.close()
        inst = ZenohSession._instance
        if inst is not None:
            inst.close()
