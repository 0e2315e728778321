"""``Ros2Bridge``'s modes ("all", "demand"), ``distro = "humble"`` and ``router = true``, against Debian's
rosmaster and zenoh-ros2-sdk (an rmw_zenoh peer we did not write)."""

from __future__ import annotations

import asyncio
import os
import queue
import xmlrpc.client
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

import mrosd
from mrosd import backports
from mrosd.msg import get_message_class, get_service_class
from mrosd.ros2.bridge import Ros2Bridge, Ros2Options
from mrosd.ros2.keys import EntityKind, parse_token
from tests.integration.daemon.daemonproc import DaemonRun
from tests.ros2.test_ros2_interop import _tokens
from tests.rosenv import Processes, free_port, needs_ros

pytestmark = [pytest.mark.interop, needs_ros]
zenoh = pytest.importorskip("zenoh")
sdk = pytest.importorskip("zenoh_ros2_sdk")
String = get_message_class("std_msgs/String")


@pytest.fixture
def sdk_session() -> Iterator[None]:
    """zenoh-ros2-sdk shares one session per process: closed after each test."""
    from zenoh_ros2_sdk.session import ZenohSession

    yield
    inst = ZenohSession._instance
    if inst is not None:
        inst.close()


def _string_queue() -> tuple[queue.Queue[str], Any]:
    got: queue.Queue[str] = queue.Queue(maxsize=100)
    return got, lambda msg: got.put_nowait(msg.data) if not got.full() else None


async def _publish_until(pub: Any, got: queue.Queue[str], text: str, timeout: float = 20) -> str:
    async with backports.timeout(timeout):
        while True:
            msg = String()
            msg.data = text
            await pub.publish(msg)
            try:
                return await asyncio.to_thread(got.get, True, 0.2)
            except queue.Empty:
                continue


async def test_humble_puts_its_placeholder_where_jazzy_puts_the_hash(
    rosmaster: str, router: int, messages_dir: Path, sdk_session: None
) -> None:
    from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber

    got, callback = _string_queue()
    options = Ros2Options(
        domain_id=0,
        connect=(f"tcp/127.0.0.1:{router}",),
        to_ros2=("/chatter", "/humble_flag"),
        from_ros2=("/from_humble",),
        distro="humble",
    )
    common: dict[str, Any] = {"domain_id": 0, "router_ip": "127.0.0.1", "router_port": router}
    sub = await asyncio.to_thread(
        ROS2Subscriber,
        topic="/chatter",
        msg_type="std_msgs/msg/String",
        callback=callback,
        type_hash="TypeHashNotSupported",
        **common,
    )
    pub = await asyncio.to_thread(
        ROS2Publisher, topic="/from_humble", msg_type="std_msgs/msg/String", type_hash="TypeHashNotSupported", **common
    )
    try:
        async with (
            Ros2Bridge(options, rosmaster) as bridge,
            mrosd.Node("talker", master_uri=rosmaster, argv=[], host="127.0.0.1") as node,
        ):
            set_bool = get_service_class("std_srvs/SetBool")
            await node.advertise_service("/humble_flag", set_bool, lambda req: set_bool._response_class())
            talker = await node.advertise("/chatter", String)
            assert await _publish_until(talker, got, "hello humble") == "hello humble"
            services = bridge.services
            assert services is not None
            await bridge.wait_until(
                lambda: (o := services.offered.get("/humble_flag")) is not None and o.token is not None, 20
            )
            assert services.offered["/humble_flag"].key == (
                "0/humble_flag/std_srvs::srv::dds_::SetBool_/TypeHashNotSupported"
            )
            assert bridge.topics["/chatter"].key == "0/chatter/std_msgs::msg::dds_::String_/TypeHashNotSupported"
            await bridge.wait_until(lambda: bridge.inbound is not None and "/from_humble" in bridge.inbound.topics, 20)
            ours = [t for t in map(parse_token, await asyncio.to_thread(_tokens, router)) if t.node == "mrosd_ros2"]
            assert {t.type_hash for t in ours if t.kind is not EntityKind.NODE} == {"TypeHashNotSupported"}
    finally:
        sub.close()
        pub.close()


async def test_mode_all_follows_the_ros1_graph_both_ways(
    rosmaster: str, router: int, messages_dir: Path, sdk_session: None
) -> None:
    from zenoh_ros2_sdk import ROS2Publisher

    # "all" sends every ROS 1 topic; from ROS 2 it takes what from_ros2 lists, as every mode does
    options = Ros2Options(domain_id=0, connect=(f"tcp/127.0.0.1:{router}",), mode="all", from_ros2=("/**",))
    pub = await asyncio.to_thread(
        ROS2Publisher,
        topic="/ros2_side",
        msg_type="std_msgs/msg/String",
        domain_id=0,
        router_ip="127.0.0.1",
        router_port=router,
    )
    try:
        async with (
            Ros2Bridge(options, rosmaster) as bridge,
            mrosd.Node("talker", master_uri=rosmaster, argv=[], host="127.0.0.1") as node,
        ):
            talker = await node.advertise("/anything/at_all", String)
            msg = String()
            msg.data = "x"

            def crossing() -> bool:
                bt = bridge.topics.get("/anything/at_all")
                return bt is not None and bt.rmw is not None

            async def keep_publishing() -> None:
                while not crossing():
                    await talker.publish(msg)
                    await asyncio.sleep(0.05)

            await backports.wait_for(keep_publishing(), 20)
            await bridge.wait_until(lambda: bridge.inbound is not None and "/ros2_side" in bridge.inbound.topics, 20)
            await talker.aclose()  # the graph changes: the topic is dropped
            await bridge.wait_until(lambda: "/anything/at_all" not in bridge.topics, 20)
            pub.close()  # the only ROS 2 publisher goes: so does its ROS 1 publisher
            await bridge.wait_until(
                lambda: bridge.inbound is not None and "/ros2_side" not in bridge.inbound.topics, 20
            )
            assert "/ros2_side" not in bridge.node.publishers
    finally:
        pub.close()


async def test_mode_demand_bridges_only_while_the_other_side_subscribes(
    rosmaster: str, router: int, messages_dir: Path, sdk_session: None
) -> None:
    from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber

    got, callback = _string_queue()
    options = Ros2Options(domain_id=0, connect=(f"tcp/127.0.0.1:{router}",), mode="demand", from_ros2=("/dem/**",))
    common: dict[str, Any] = {"domain_id": 0, "router_ip": "127.0.0.1", "router_port": router}
    ros2_pub = await asyncio.to_thread(ROS2Publisher, topic="/dem/in", msg_type="std_msgs/msg/String", **common)
    try:
        async with (
            Ros2Bridge(options, rosmaster) as bridge,
            mrosd.Node("talker", master_uri=rosmaster, argv=[], host="127.0.0.1") as node,
        ):
            # ROS 1 -> ROS 2: nothing crosses until a ROS 2 subscriber exists
            talker = await node.advertise("/dem/out", String)
            reads = bridge.graph_reads
            await bridge.wait_until(lambda: bridge.graph_reads >= reads + 2, 10)
            assert "/dem/out" not in bridge.topics
            sub = await asyncio.to_thread(
                ROS2Subscriber, topic="/dem/out", msg_type="std_msgs/msg/String", callback=callback, **common
            )
            try:
                assert await _publish_until(talker, got, "on demand") == "on demand"
            finally:
                sub.close()
            await bridge.wait_until(lambda: "/dem/out" not in bridge.topics, 10)

            # ROS 2 -> ROS 1: on the master (rostopic list) at once, on Zenoh only while ROS 1 subscribes
            inbound = bridge.inbound
            assert inbound is not None
            await bridge.wait_until(lambda: "/dem/in" in inbound.topics, 20)
            with xmlrpc.client.ServerProxy(rosmaster) as api:
                _code, _msg, (pubs, _subs, _srvs) = await asyncio.to_thread(api.getSystemState, "/test")
            assert any(topic == "/dem/in" for topic, _nodes in pubs)
            assert inbound.topics["/dem/in"].subscriber is None
            heard: queue.Queue[str] = queue.Queue(maxsize=100)
            listener = await node.subscribe("/dem/in", String, callback=lambda m: heard.put_nowait(m.data))
            await bridge.wait_until(lambda: inbound.topics["/dem/in"].subscriber is not None, 10)

            async def keep_publishing() -> str:
                while True:
                    await asyncio.to_thread(ros2_pub.publish, data="from ROS 2")
                    try:
                        return await asyncio.to_thread(heard.get, True, 0.2)
                    except queue.Empty:
                        continue

            assert await backports.wait_for(keep_publishing(), 20) == "from ROS 2"
            await listener.aclose()
            await bridge.wait_until(lambda: inbound.topics["/dem/in"].subscriber is None, 10)
    finally:
        ros2_pub.close()


TALKER = """
import sys, time
from zenoh_ros2_sdk import ROS2Publisher, message_registry
message_registry._registry = message_registry.MessageRegistry(sys.argv[2])
pub = ROS2Publisher(topic="/laptop_chat", msg_type="std_msgs/msg/String", domain_id=0,
                    router_ip="127.0.0.1", router_port=int(sys.argv[1]))
while True:
    pub.publish(data="laptop to laptop")
    time.sleep(0.05)
"""


async def test_the_daemon_is_the_router_two_ros2_client_peers_use(
    procs: Processes, tmp_path: Path, messages_dir: Path, sdk_session: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``[ros2] router = true``: no rmw_zenohd anywhere; two zenoh-ros2-sdk sessions in client mode (one in
    another process) reach each other and the ROS 1 side through the daemon's router only."""
    from mros_cli.ros2 import fetch_status, format_status
    from zenoh_ros2_sdk import ROS2Subscriber
    from zenoh_ros2_sdk.session import ZenohSession

    port = free_port()
    monkeypatch.setenv("ZENOH_CONFIG_OVERRIDE", 'mode="client"')
    cfg = tmp_path / "mrosd.toml"
    cfg.write_text(
        "[ixm]\nenabled = false\n[rosout]\nenabled = false\n"
        f'[ros2]\nenabled = true\ndomain_id = 0\nrouter = true\nlisten = ["tcp/127.0.0.1:{port}"]\n'
        'to_ros2 = ["/chatter"]\n'
    )
    (tmp_path / "d").mkdir()
    daemon = DaemonRun(procs, tmp_path / "d", "--config", str(cfg))
    got, callback = _string_queue()
    laptop, from_robot = _string_queue()
    subs: list[Any] = []
    try:
        status_line = await asyncio.to_thread(daemon.ready)
        assert f"ros2 router tcp/127.0.0.1:{port}" in status_line, status_line
        common: dict[str, Any] = {"domain_id": 0, "router_ip": "127.0.0.1", "router_port": port}
        for topic, cb in (("/laptop_chat", callback), ("/chatter", from_robot)):
            subs.append(
                await asyncio.to_thread(
                    ROS2Subscriber, topic=topic, msg_type="std_msgs/msg/String", callback=cb, **common
                )
            )
        env = dict(os.environ, ZENOH_CONFIG_OVERRIDE='mode="client"')
        procs.our_python(["-c", TALKER, str(port), str(messages_dir)], env)
        assert await asyncio.to_thread(got.get, True, 30) == "laptop to laptop"
        async with mrosd.Node("talker", master_uri=daemon.uri, argv=[], host="127.0.0.1") as node:
            talker = await node.advertise("/chatter", String)
            assert await _publish_until(talker, laptop, "robot to laptop") == "robot to laptop"
            status = await fetch_status(daemon.uri)
        # the SDK's session is a client whose one router is the daemon's ros2 part
        routers = [str(z) for z in ZenohSession.get_instance().session.info.routers_zid()]
        assert routers == [status["zid"]] and status["router"]
        assert "mode listed, jazzy, router" in format_status(status)
    finally:
        for sub in subs:
            sub.close()
        await asyncio.to_thread(daemon.stop)
        daemon.notify.close()
