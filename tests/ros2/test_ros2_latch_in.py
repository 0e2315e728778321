"""TRANSIENT_LOCAL comes back as latched: a ROS 2 publisher made as rmw_zenoh makes a TRANSIENT_LOCAL one (an
advanced publisher with a cache and publisher detection, its ``MP`` token's QoS and key built by zenoh-ros2-sdk,
its attachment by zenoh's own serializer) publishes before the bridge subscribes; a late ``rostopic echo``
(Debian's) still prints it. A VOLATILE publisher's topic is not latched."""

from __future__ import annotations

import asyncio
import struct
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from mros_cli.ros2 import format_status

from mrosd import backports
from mrosd.ros2.bridge import Ros2Bridge, Ros2Options
from mrosd.ros2.keys import EntityKind, parse_token
from mrosd.tcpros.node import Node
from mrosd.tcpros.subscriber import AnyMsg, RawMessage
from tests.rosenv import Processes, needs_ros, ros_env

pytestmark = [pytest.mark.interop, needs_ros]
zenoh = pytest.importorskip("zenoh")
zenoh_ext = pytest.importorskip("zenoh.ext")
sdk = pytest.importorskip("zenoh_ros2_sdk")

STRING = "std_msgs::msg::dds_::String_"
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"


def string_cdr(text: str) -> bytes:
    """std_msgs/msg/String in CDR (little-endian encapsulation), written out by hand."""
    data = text.encode() + b"\0"
    return b"\x00\x01\x00\x00" + struct.pack("<I", len(data)) + data


class Ros2Side:
    """An rmw_zenoh-style ROS 2 node in a Zenoh client session: publishers as rmw_zenoh declares them."""

    def __init__(self, port: int) -> None:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", f'["tcp/127.0.0.1:{port}"]')
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("timestamping/enabled", "true")  # rmw_zenoh's session config; the cache needs it
        self.session = zenoh.open(conf)
        self.entities: list[Any] = []
        self.next_id = 1

    def publisher(self, topic: str, *, transient_local: bool, depth: int = 5) -> Any:
        from zenoh_ros2_sdk.entity import EndpointEntity, NodeEntity
        from zenoh_ros2_sdk.entity import EntityKind as SdkKind
        from zenoh_ros2_sdk.keyexpr import endpoint_liveliness_keyexpr, topic_keyexpr
        from zenoh_ros2_sdk.qos import QosDurability, QosProfile

        key = topic_keyexpr(0, topic, STRING, STRING_HASH)
        if transient_local:
            # rmw_publisher_data.cpp: publisher detection, a cache of `depth`, sporadic heartbeats when RELIABLE
            pub = zenoh_ext.declare_advanced_publisher(
                self.session,
                key,
                cache=zenoh_ext.CacheConfig(depth),
                publisher_detection=True,
                sample_miss_detection=zenoh_ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=0.5),
            )
        else:
            pub = self.session.declare_publisher(key)
        qos = QosProfile(
            durability=QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
            history_depth=depth,
        )
        node = NodeEntity(domain_id=0, session_id=str(self.session.zid()), node_id=0, node_name="ros2_talker")
        self.next_id += 1
        token_key = endpoint_liveliness_keyexpr(
            EndpointEntity(
                node=node,
                entity_id=self.next_id,
                kind=SdkKind.PUBLISHER,
                name=topic,
                dds_type_name=STRING,
                type_hash=STRING_HASH,
                qos=qos.encode(),
            )
        )
        self.entities.append(pub)
        return pub, token_key

    def announce(self, token_key: str) -> None:
        self.entities.append(self.session.liveliness().declare_token(token_key))

    def put(self, pub: Any, text: str, seq: int) -> None:
        attachment = zenoh_ext.z_serialize((zenoh_ext.Int64(seq), zenoh_ext.Int64(time.time_ns()), bytes(16)))
        pub.put(string_cdr(text), attachment=attachment)

    def close(self) -> None:
        for entity in reversed(self.entities):
            entity.undeclare()
        self.session.close()


@pytest.fixture
def ros2_side(router: int) -> Iterator[Ros2Side]:
    side = Ros2Side(router)
    try:
        yield side
    finally:
        side.close()


async def test_a_transient_local_publisher_is_latched_for_a_late_rostopic_echo_and_a_volatile_one_is_not(
    procs: Processes, rosmaster: str, tmp_path: Path, router: int, ros2_side: Ros2Side
) -> None:
    # (a) published, twice, and announced before the bridge exists: only the publisher's cache has it
    latched_pub, latched_token = ros2_side.publisher("/latched", transient_local=True)
    ros2_side.put(latched_pub, "old", 1)
    ros2_side.put(latched_pub, "the last one", 2)
    ros2_side.announce(latched_token)
    volatile_pub, volatile_token = ros2_side.publisher("/volatile", transient_local=False)
    ros2_side.announce(volatile_token)

    options = Ros2Options(domain_id=0, connect=(f"tcp/127.0.0.1:{router}",), from_ros2=("/latched", "/volatile"))
    async with Ros2Bridge(options, rosmaster) as bridge:
        inbound = bridge.inbound
        assert inbound is not None

        def ready() -> bool:  # both republished on ROS 1 and subscribed on Zenoh, the cached message received
            latched, volatile = inbound.topics.get("/latched"), inbound.topics.get("/volatile")
            if latched is None or volatile is None:
                return False
            return latched.subscriber is not None and volatile.subscriber is not None and latched.received >= 1

        await bridge.wait_until(ready, 20)
        latched, volatile = inbound.topics["/latched"], inbound.topics["/volatile"]
        assert latched.latched and latched.publisher.latch
        assert not volatile.latched and not volatile.publisher.latch
        rows = {row["topic"]: row for row in bridge.inbound_status()}
        assert rows["/latched"]["latched"] and not rows["/volatile"]["latched"]
        shown = format_status({"zid": "z", "domain_id": 0, "to_ros2": [], "from_ros2": list(rows.values())})
        assert "/latched  std_msgs/msg/String (latched)" in shown and "/volatile  std_msgs/msg/String  " in shown
        # the bridge's subscriber is announced as rmw_zenoh's TRANSIENT_LOCAL one
        tokens = [
            parse_token(str(r.ok.key_expr))
            for r in ros2_side.session.liveliness().get("@ros2_lv/**", timeout=5.0)
            if r.ok is not None
        ]
        ours = {t.topic: t for t in tokens if t.kind is EntityKind.SUBSCRIPTION and t.node == "mrosd_ros2"}
        assert ours["/latched"].qos is not None and ours["/latched"].qos.durability == 1
        assert ours["/volatile"].qos is not None and ours["/volatile"].qos.durability == 2

        # a rostopic echo started after all of it prints the last message
        echo = procs.start(["rostopic", "echo", "-n", "1", "/latched"], ros_env(rosmaster, tmp_path))
        out, err = await asyncio.to_thread(echo.communicate, None, 20)
        assert echo.returncode == 0, err
        assert 'data: "the last one"' in out.decode()

        # (b) VOLATILE: a ROS 1 subscriber that joins after a message does not get it
        early_node, late_node = Node("/latch_test_early", rosmaster), Node("/latch_test_late", rosmaster)
        await early_node.start()
        await late_node.start()
        try:
            first: asyncio.Queue[bytes] = asyncio.Queue()
            late: asyncio.Queue[bytes] = asyncio.Queue()
            headers: list[Any] = []

            def heard_first(msg: RawMessage) -> None:
                headers.append(msg.header)
                first.put_nowait(bytes(msg.data))

            await early_node.subscribe("/volatile", AnyMsg, callback=heard_first)
            await bridge.wait_until(lambda: volatile.publisher.get_num_connections() >= 1, 10)
            # put until the early subscriber hears one (the bridge's Zenoh subscription may lag the token), then
            # one more it must hear: everything put before it has then reached ROS 1
            async with backports.timeout(10):
                while first.empty():
                    ros2_side.put(volatile_pub, "before", 1)
                    await asyncio.sleep(0.05)
            ros2_side.put(volatile_pub, "sync", 2)
            async with backports.timeout(10):
                while b"sync" not in await first.get():
                    pass
            assert headers[0].latching != "1"
            await late_node.subscribe("/volatile", AnyMsg, callback=lambda msg: late.put_nowait(bytes(msg.data)))
            await bridge.wait_until(lambda: volatile.publisher.get_num_connections() >= 2, 10)
            ros2_side.put(volatile_pub, "after", 3)
            assert b"after" in await backports.wait_for(late.get(), 10)  # its first message: nothing replayed

            # a TRANSIENT_LOCAL publisher joins the VOLATILE topic, with a message only its cache holds: the
            # topic is latched from then on and the bridge queries that cache
            so_far = volatile.received
            joined_pub, joined_token = ros2_side.publisher("/volatile", transient_local=True, depth=1)
            ros2_side.put(joined_pub, "cached", 1)
            ros2_side.announce(joined_token)
            await bridge.wait_until(lambda: volatile.latched and volatile.received > so_far, 10)
            assert volatile.publisher.latch
            later: asyncio.Queue[RawMessage] = asyncio.Queue()
            later_node = Node("/latch_test_later", rosmaster)
            await later_node.start()
            try:
                await later_node.subscribe("/volatile", AnyMsg, callback=later.put_nowait)
                msg = await backports.wait_for(later.get(), 10)
                assert b"cached" in bytes(msg.data) and msg.header.latching == "1"
            finally:
                await later_node.aclose()
        finally:
            await late_node.aclose()
            await early_node.aclose()


LATCHER = """
import rospy
from std_msgs.msg import String
rospy.init_node("mapper")
pub = rospy.Publisher("/map", String, queue_size=1, latch=True)
pub.publish(String(data="the map from rospy"))
rospy.spin()
"""


async def test_a_latched_rospy_topic_reaches_a_late_subscriber_made_as_rmw_zenohs_transient_local_one(
    procs: Processes, rosmaster: str, tmp_path: Path, router: int, ros2_side: Ros2Side
) -> None:
    """The other way, with rmw_zenoh's TRANSIENT_LOCAL subscriber (``rmw_subscription_data.cpp``: an advanced
    subscriber detecting late publishers, history of its depth, heartbeat recovery when RELIABLE) rather than
    zenoh-ros2-sdk's one-off query (tests/ros2/test_ros2_interop.py)."""
    got: asyncio.Queue[bytes] = asyncio.Queue()
    loop = asyncio.get_running_loop()
    options = Ros2Options(domain_id=0, connect=(f"tcp/127.0.0.1:{router}",), to_ros2=("/map",))
    async with Ros2Bridge(options, rosmaster) as bridge:
        procs.python(LATCHER, ros_env(rosmaster, tmp_path))

        def sent() -> bool:
            bt = bridge.topics.get("/map")
            return bt is not None and bt.rmw is not None and bt.rmw.sent >= 1

        await bridge.wait_until(sent, 20)
        sub = zenoh_ext.declare_advanced_subscriber(
            ros2_side.session,
            bridge.topics["/map"].key,
            lambda sample: loop.call_soon_threadsafe(got.put_nowait, sample.payload.to_bytes()),
            history=zenoh_ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
            recovery=zenoh_ext.RecoveryConfig(periodic_queries=None, heartbeat=True),
            subscriber_detection=True,
        )
        ros2_side.entities.append(sub)
        assert await backports.wait_for(got.get(), 10) == string_cdr("the map from rospy")
