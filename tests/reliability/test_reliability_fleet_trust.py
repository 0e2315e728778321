"""A stranger's Zenoh peer against the fleet part (issue 31, cases 3 and 4), with real rospy nodes.

The stranger is a bare Zenoh session that reaches the robot's Zenoh port: it announces whatever it likes,
under ``*`` (a plain bridge's namespace) or a made-up robot name, puts any body on any data key and sends any
request to an exported service. It may publish only into names the configuration imports; nothing malformed
reaches a ROS subscriber or service; garbage calls never queue an honest one.
"""

from __future__ import annotations

import asyncio
import struct
import time
from collections.abc import AsyncIterator
from contextlib import AsyncExitStack, asynccontextmanager
from pathlib import Path
from typing import Any

import pytest

import mrosd
from mrosd import backports
from mrosd.config import FleetConfig
from mrosd.fleet.bridge import FleetBridge
from mrosd.fleet.keys import ItemKind, NameFilter, RenameRule, data_key, discovery_key
from mrosd.fleet.options import fleet_options
from mrosd.master import Master
from mrosd.msg import get_message_class, get_service_class
from tests.fleet.fleetenv import bare_peer, fleet
from tests.rosenv import Processes, free_port, iter_lines_until, needs_ros, ros_env

zenoh = pytest.importorskip("zenoh", reason="the fleet tests need eclipse-zenoh (pip install 'mrosd[fleet]')")

String = get_message_class("std_msgs/String")
Twist = get_message_class("geometry_msgs/Twist")
SetBool = get_service_class("std_srvs/SetBool")

BASE_CONTROLLER = """
import sys, rospy
from geometry_msgs.msg import Twist
rospy.init_node("base_controller")
rospy.Subscriber("/cmd_vel", Twist, lambda m: (print("twist", m.linear.x), sys.stdout.flush()))
rospy.Subscriber("/evil/cmd_vel", Twist, lambda m: (print("twist", m.linear.x), sys.stdout.flush()))
print("ready"); sys.stdout.flush()
rospy.spin()
"""

LISTENER = """
import sys, rospy
from std_msgs.msg import String
rospy.init_node("listener")
rospy.Subscriber("/evil/chatter", String, lambda m: (print(m.data), sys.stdout.flush()))
print("ready"); sys.stdout.flush()
rospy.spin()
"""

SERVER = """
import sys, time, rospy
from std_srvs.srv import SetBool, SetBoolResponse
def handle(req):
    if not req.data:
        time.sleep(30)  # a slow (valid) call
    return SetBoolResponse(success=req.data, message="rospy answered")
rospy.init_node("server")
rospy.Service("/set", SetBool, handle)
print("ready"); sys.stdout.flush()
rospy.spin()
"""


@asynccontextmanager
async def default_robot(**fleet_keys: Any) -> AsyncIterator[tuple[Master, FleetBridge, str]]:
    """A master and its fleet part configured as docs/fleet.md's example (``[fleet]`` defaults plus keys)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    section = FleetConfig(enabled=True, robot="robot1", listen=[endpoint], **fleet_keys)
    async with AsyncExitStack() as stack:
        master = await stack.enter_async_context(Master(host="127.0.0.1", port=0))
        bridge = FleetBridge(fleet_options(section), master.uri, host="127.0.0.1")
        await stack.enter_async_context(bridge)
        yield master, bridge, endpoint


async def _lines(proc: Any, count: int, timeout: float) -> list[str]:
    return await asyncio.to_thread(lambda: list(iter_lines_until(proc, count, timeout)))


async def _matched(publisher: Any, timeout: float) -> None:
    """Return once a Zenoh subscriber matches ``publisher`` (the peer knows where to send)."""
    loop = asyncio.get_running_loop()
    matched = asyncio.Event()

    def on_status(status: Any) -> None:
        if status.matching:
            loop.call_soon_threadsafe(matched.set)

    listener = publisher.declare_matching_listener(on_status)
    try:
        if publisher.matching_status.matching:
            matched.set()
        async with backports.timeout(timeout):
            await matched.wait()
    finally:
        listener.undeclare()


def _announce(peer: Any, kind: ItemKind, msg_type: str, md5: str, namespace: str, name: str) -> None:
    peer.put(discovery_key(kind, msg_type, md5, namespace, name), b"")


def test_receive_defaults_import_nothing() -> None:
    opts = fleet_options(FleetConfig(enabled=True, robot="robot1"))
    assert "/cmd_vel" not in opts.receive_topics and "/robot2/odom" not in opts.receive_topics
    assert "/set" not in opts.receive_services and "/robot2/set" not in opts.receive_services


@needs_ros
async def test_a_stranger_cannot_drive_cmd_vel_on_the_documented_config(procs: Processes, tmp_path: Path) -> None:
    async with default_robot(send_topics=["/odom"]) as (master, bridge, endpoint):
        base = procs.python(BASE_CONTROLLER, ros_env(master.uri, tmp_path))
        assert await _lines(base, 1, 30) == ["ready"]
        peer = await asyncio.to_thread(bare_peer, endpoint)
        try:
            twist = Twist()
            twist.linear.x = 1.0
            body = twist.serialize()
            for ns in ("*", "evil"):
                _announce(peer, ItemKind.PUBLISHER, Twist._type, Twist._md5sum, ns, "/cmd_vel")
            await bridge.wait_until(lambda: len(bridge.presence.items()) >= 2, 15)
            deadline = time.monotonic() + 2.0
            while time.monotonic() < deadline:  # 100 Twists on both keys, announced all along
                for ns in ("*", "evil"):
                    _announce(peer, ItemKind.PUBLISHER, Twist._type, Twist._md5sum, ns, "/cmd_vel")
                    peer.put(data_key(Twist._type, Twist._md5sum, ns, "/cmd_vel"), body)
                await asyncio.sleep(0.02)
            assert bridge.received == {}
            with pytest.raises(TimeoutError):
                await _lines(base, 1, 0.5)
        finally:
            peer.close()


async def test_items_under_star_keep_no_local_name_unless_mapped() -> None:
    everything = NameFilter(include=("/**",))
    md5 = Twist._md5sum
    async with fleet("robot1", receive_topics=everything) as (r1,):
        peer = await asyncio.to_thread(bare_peer, r1.endpoint)
        try:
            _announce(peer, ItemKind.PUBLISHER, Twist._type, md5, "*", "/cmd_vel")
            _announce(peer, ItemKind.PUBLISHER, Twist._type, md5, "evil", "/cmd_vel")
            await r1.bridge.wait_until(lambda: "/evil/cmd_vel" in r1.bridge.received, 15)
            assert "/cmd_vel" not in r1.bridge.received
        finally:
            peer.close()
    async with fleet("robot1", receive_topics=everything, rename=RenameRule(wildcard_robot="legacy")) as (r1,):
        peer = await asyncio.to_thread(bare_peer, r1.endpoint)
        try:
            _announce(peer, ItemKind.PUBLISHER, Twist._type, md5, "*", "/cmd_vel")
            await r1.bridge.wait_until(lambda: "/legacy/cmd_vel" in r1.bridge.received, 15)
            assert "/cmd_vel" not in r1.bridge.received
        finally:
            peer.close()


@needs_ros
async def test_a_lying_length_prefix_never_reaches_a_rospy_subscriber(procs: Processes, tmp_path: Path) -> None:
    async with default_robot(receive_topics=["/evil/**"]) as (master, bridge, endpoint):
        listener = procs.python(LISTENER, ros_env(master.uri, tmp_path))
        assert await _lines(listener, 1, 30) == ["ready"]
        peer = await asyncio.to_thread(bare_peer, endpoint)
        try:
            _announce(peer, ItemKind.PUBLISHER, String._type, String._md5sum, "evil", "/chatter")
            await bridge.wait_until(
                lambda: "/evil/chatter" in bridge.received and bridge.received["/evil/chatter"].subscriber is not None,
                30,
            )
            key = data_key(String._type, String._md5sum, "evil", "/chatter")
            publisher = peer.declare_publisher(key)
            await _matched(publisher, 15)
            bad = [
                struct.pack("<I", 1_000_000) + b"lies",  # a length prefix past the body
                struct.pack("<I", 2) + b"ok" + b"trailing",  # bytes after the message
                b"\x01\x00",  # shorter than the length prefix itself
            ]
            for body in bad:
                publisher.put(body)
            for i in range(23):
                publisher.put(String(data=f"valid {i}").serialize())
                await asyncio.sleep(0.02)
            got = await _lines(listener, 23, 15)
            assert got == [f"valid {i}" for i in range(23)]
            status = bridge.status()
            assert status["received"]["/evil/chatter"]["refused"] == len(bad)
            assert status["malformed"] >= len(bad)
        finally:
            peer.close()


@needs_ros
async def test_an_honest_call_is_answered_while_garbage_and_slow_calls_are_in_flight(
    procs: Processes, tmp_path: Path
) -> None:
    """robot1 exports a rospy service; a stranger sends it garbage and slow valid calls; robot2 calls it."""
    async with AsyncExitStack() as stack:
        master, bridge, endpoint = await stack.enter_async_context(default_robot(send_services=["/set"]))
        server = procs.python(SERVER, ros_env(master.uri, tmp_path))
        assert await _lines(server, 1, 30) == ["ready"]
        await bridge.wait_until(lambda: bool(bridge.sent_services.get("/set") and bridge.sent_services["/set"].key), 30)
        key = bridge.sent_services["/set"].key
        master2 = await stack.enter_async_context(Master(host="127.0.0.1", port=0))
        robot2 = fleet_options(
            FleetConfig(
                enabled=True,
                robot="robot2",
                listen=[f"tcp/127.0.0.1:{free_port()}"],
                connect=[endpoint],
                receive_services=["/robot1/set"],
            )
        )
        bridge2 = await stack.enter_async_context(FleetBridge(robot2, master2.uri, host="127.0.0.1"))
        await bridge2.wait_until(
            lambda: (
                "/robot1/set" in bridge2.received_services
                and bridge2.received_services["/robot1/set"].service is not None
            ),
            30,
        )
        caller = mrosd.Node("caller", master_uri=master2.uri, argv=[], host="127.0.0.1")
        await stack.enter_async_context(caller)
        peer = await asyncio.to_thread(bare_peer, endpoint)
        stack.callback(peer.close)
        garbage: list[Any] = []
        for body in (b"", b"\x01\x02\x03", b"\xff" * 100):
            for _ in range(4):
                peer.get(key, garbage.append, payload=body, timeout=20)
        slow: list[Any] = []
        for _ in range(10):  # valid requests the server holds for 30 s
            peer.get(key, slow.append, payload=SetBool._request_class(data=False).serialize(), timeout=20)
        await asyncio.sleep(0.3)
        t0 = time.monotonic()
        proxy = caller.service_proxy("/robot1/set", SetBool)
        answer = await proxy.call(SetBool._request_class(data=True), timeout=10)
        took = time.monotonic() - t0
        assert answer.success and answer.message == "rospy answered"
        assert took < 3.0, f"the honest call took {took:.1f} s"
        assert len(garbage) == 12 and all(r.err is not None for r in garbage)
        assert bridge.status()["malformed"] == 12
        assert bridge.status()["services_sent"]["/set"]["refused"] == 12


async def test_a_garbage_response_never_reaches_the_local_caller() -> None:
    async with fleet("robot1", receive_services=NameFilter(include=("/evil/**",))) as (r1,), r1.node("caller") as n:
        peer = await asyncio.to_thread(bare_peer, r1.endpoint)
        try:
            key = data_key(SetBool._type, SetBool._md5sum, "evil", "/set")
            queryable = peer.declare_queryable(key, lambda q: q.reply(key, b"\x01\xff\xff\xff\x7fnot"))
            _announce(peer, ItemKind.SERVICE, SetBool._type, SetBool._md5sum, "evil", "/set")
            await r1.bridge.wait_until(
                lambda: (
                    "/evil/set" in r1.bridge.received_services
                    and r1.bridge.received_services["/evil/set"].service is not None
                ),
                15,
            )
            proxy = n.service_proxy("/evil/set", SetBool)
            from mrosd.errors import ServiceError

            with pytest.raises(ServiceError):
                await proxy.call(SetBool._request_class(data=True), timeout=10)
            assert r1.bridge.status()["malformed"] >= 1
            queryable.undeclare()
        finally:
            peer.close()


async def test_types_this_robot_cannot_check_are_not_received() -> None:
    """Unknown here, or another md5 than ours: the bodies could not be checked, so nothing is published."""
    everything = NameFilter(include=("/**",))
    async with fleet("robot1", receive_topics=everything, receive_services=everything) as (r1,):
        peer = await asyncio.to_thread(bare_peer, r1.endpoint)
        try:
            _announce(peer, ItemKind.PUBLISHER, "evil_pkg/Unknown", "0" * 32, "evil", "/unknown")
            _announce(peer, ItemKind.PUBLISHER, String._type, "1" * 32, "evil", "/other_md5")
            _announce(peer, ItemKind.SERVICE, "evil_pkg/Nope", "2" * 32, "evil", "/nope")
            _announce(peer, ItemKind.PUBLISHER, String._type, String._md5sum, "evil", "/fine")
            await r1.bridge.wait_until(
                lambda: (
                    r1.bridge.status()["unchecked_types"] >= 3
                    and r1.bridge.received.get("/evil/fine") is not None
                    and r1.bridge.received["/evil/fine"].publisher is not None
                ),
                15,
            )
            assert "/evil/unknown" not in r1.bridge.received and "/evil/other_md5" not in r1.bridge.received
            assert r1.bridge.received_services["/evil/nope"].service is None
            state = await r1.bridge.node.master_call("getSystemState")
            assert not [t for t, _ in state[0] if t in ("/evil/unknown", "/evil/other_md5")]
            assert not [s for s, _ in state[2] if s == "/evil/nope"]
        finally:
            peer.close()
