"""Interop both ways with Debian's rospy and a roscpp node compiled here: topics, types, latching, services."""

from __future__ import annotations

import asyncio
import logging
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

import mrosd
from mrosd import backports
from mrosd.errors import ServiceError
from mrosd.msg import Time, get_message_class, get_service_class, load_type
from tests.rosenv import ROS_PYTHON, Processes, iter_lines_until, needs_ros, ros_env

pytestmark = needs_ros

DATA = Path(__file__).resolve().parents[2] / "data" / "tcpros"
ROSPY_NODE = str(DATA / "rospy_node.py")
String = get_message_class("std_msgs/String")
Image = get_message_class("sensor_msgs/Image")
SetBool = get_service_class("std_srvs/SetBool")
Coordinate = load_type("mros_bench/Coordinate", (DATA / "msg" / "Coordinate.msg").read_text())
CLASSES: dict[str, Any] = {"string": String, "image": Image, "coordinate": Coordinate}


def known(kind: str) -> Any:
    """The message rospy_node.py's ``talk`` sends, and ``describe`` of it."""
    if kind == "string":
        return String(data="hello from rospy"), "hello from rospy"
    if kind == "image":
        return Image(height=2, width=3, encoding="mono8", step=3, data=bytes(range(6))), "2 3 mono8 000102030405"
    return Coordinate(x=1.5, y=2.5, z=-3.0, time=Time(7, 8)), "1.5 2.5 -3 7 8"


def describe(kind: str, m: Any) -> str:
    if kind == "string":
        return str(m.data)
    if kind == "image":
        return f"{m.height} {m.width} {m.encoding} {bytes(m.data).hex()}"
    return f"{m.x:g} {m.y:g} {m.z:g} {m.time.secs} {m.time.nsecs}"


def rospy_node(procs: Processes, master: str, *args: str) -> subprocess.Popen[bytes]:
    proc = procs.start([ROS_PYTHON, ROSPY_NODE, *args], ros_env(master, procs.tmp), stderr=subprocess.DEVNULL)
    return proc


async def lines(proc: subprocess.Popen[bytes], count: int, timeout: float = 30.0) -> list[str]:
    return await asyncio.to_thread(lambda: list(iter_lines_until(proc, count, timeout)))


def our_node(name: str, master: str) -> mrosd.Node:
    return mrosd.Node(name, master_uri=master, argv=[], host="127.0.0.1")


@pytest.fixture(scope="session")
def roscpp_node(tmp_path_factory: pytest.TempPathFactory) -> str:
    """The roscpp echo node, compiled once per session."""
    if shutil.which("g++") is None or shutil.which("pkg-config") is None:
        pytest.skip("g++ or pkg-config is not installed")
    flags = subprocess.run(
        ["pkg-config", "--cflags", "--libs", "roscpp", "std_msgs", "sensor_msgs"],
        capture_output=True,
        text=True,
        check=False,
    )
    if flags.returncode != 0:
        pytest.skip(f"roscpp development files are missing: {flags.stderr.strip()}")
    out = tmp_path_factory.mktemp("roscpp") / "rosnode_echo"
    build = subprocess.run(
        ["g++", "-O2", "-o", str(out), str(DATA / "rosnode_echo.cpp"), *flags.stdout.split()],
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )
    if build.returncode != 0:
        pytest.skip(f"cannot compile the roscpp test node: {build.stderr[-500:]}")
    return str(out)


@pytest.mark.parametrize("kind", ["string", "coordinate", "image"])
async def test_we_receive_what_rospy_publishes(procs: Processes, rosmaster: str, kind: str) -> None:
    talker = rospy_node(procs, rosmaster, "talk", kind, "/from_rospy", "0")
    assert await lines(talker, 1) == ["up"]
    async with our_node("listener", rosmaster) as node:
        sub = await node.subscribe("/from_rospy", CLASSES[kind])
        msg = await sub.next(timeout=20)
        assert describe(kind, msg) == known(kind)[1]


@pytest.mark.parametrize("kind", ["string", "coordinate", "image"])
async def test_rospy_receives_what_we_publish(procs: Processes, rosmaster: str, kind: str) -> None:
    async with our_node("talker", rosmaster) as node:
        pub = await node.advertise("/to_rospy", CLASSES[kind])
        listener = rospy_node(procs, rosmaster, "listen", kind, "/to_rospy", "1")
        assert await lines(listener, 1) == ["up"]
        await pub.wait_for_subscribers(1, timeout=20)
        got = asyncio.ensure_future(lines(listener, 1))
        while not got.done():
            await pub.publish(known(kind)[0])
            await asyncio.wait([got], timeout=0.05)
        assert got.result() == [known(kind)[1]]


async def test_our_latched_message_reaches_a_rospy_subscriber_that_comes_later(
    procs: Processes, rosmaster: str
) -> None:
    async with our_node("talker", rosmaster) as node:
        pub = await node.advertise("/latched", String, latch=True)
        await pub.publish(String(data="latched by mrosd"))
        listener = rospy_node(procs, rosmaster, "listen", "string", "/latched", "1")
        assert await lines(listener, 2) == ["up", "latched by mrosd"]


async def test_a_rospy_latched_message_reaches_our_late_subscriber(procs: Processes, rosmaster: str) -> None:
    talker = rospy_node(procs, rosmaster, "talk", "coordinate", "/latched_c", "1")
    assert await lines(talker, 1) == ["up"]
    async with our_node("listener", rosmaster) as node:
        sub = await node.subscribe("/latched_c", mrosd.AnyMsg)
        raw = await sub.next(timeout=20)
        assert raw.header.latching == "1"
        cls = load_type(raw.header.type or "", raw.header.message_definition or "")
        assert describe("coordinate", cls.deserialize(raw.data)) == "1.5 2.5 -3 7 8"


async def test_a_wrong_md5_against_rospy_is_reported_clearly_on_our_side(
    procs: Processes, rosmaster: str, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.ERROR)
    talker = rospy_node(procs, rosmaster, "talk", "string", "/typed", "0")
    assert await lines(talker, 1) == ["up"]
    async with our_node("listener", rosmaster) as node:
        sub = await node.subscribe("/typed", Coordinate)
        async with backports.timeout(20):
            while not sub.errors:
                sub._changed.clear()
                await sub._changed.wait()
        assert "refused [/typed]" in sub.errors[0]
        # rospy names the mismatch it found first (types here); the publisher's URI says who refused.
        assert "do not match" in sub.errors[0]
        assert "http://" in sub.errors[0]
        assert any("/typed" in r.getMessage() for r in caplog.records)


async def test_we_call_a_rospy_service_and_see_its_error_text(procs: Processes, rosmaster: str) -> None:
    server = rospy_node(procs, rosmaster, "server", "/rospy_set")
    assert await lines(server, 1) == ["up"]
    async with our_node("client", rosmaster) as node:
        proxy = node.service_proxy("/rospy_set", SetBool)
        await proxy.wait_for_service(timeout=20)
        resp = await proxy.call(SetBool._request_class(data=True))
        assert (resp.success, resp.message) == (True, "rospy got True")
        with pytest.raises(ServiceError, match="no from rospy"):
            await proxy.call(SetBool._request_class(data=False))
        async with node.service_proxy("/rospy_set", SetBool, persistent=True) as persistent:
            for _ in range(3):
                assert (await persistent.call(SetBool._request_class(data=True))).success


async def test_rospy_calls_our_service_and_sees_our_error_text(procs: Processes, rosmaster: str) -> None:
    def handle(req: Any) -> Any:
        if not req.data:
            raise ValueError("no from mrosd")
        return SetBool._response_class(success=True, message="mrosd got True")

    async with our_node("server", rosmaster) as node:
        await node.advertise_service("/our_set", SetBool, handle)
        client = rospy_node(procs, rosmaster, "client", "/our_set")
        out = await lines(client, 2)
        assert out[0] == "OK True mrosd got True"
        assert out[1].startswith("ERROR") and "no from mrosd" in out[1]


async def test_rosservice_and_rosnode_see_our_node(procs: Processes, rosmaster: str) -> None:
    async with our_node("server", rosmaster) as node:
        await node.advertise_service("/our_set", SetBool, lambda r: SetBool._response_class(success=True))
        await node.advertise("/chatter", String)
        env = ros_env(rosmaster, procs.tmp)

        def run(*argv: str) -> str:
            return subprocess.run(argv, env=env, capture_output=True, text=True, timeout=30, check=False).stdout

        info = await asyncio.to_thread(run, "rosservice", "info", "/our_set")
        assert "Type: std_srvs/SetBool" in info
        assert "Args: data" in info
        node_info = await asyncio.to_thread(run, "rosnode", "info", "/server")
        assert "/chatter [std_msgs/String]" in node_info


@pytest.mark.parametrize("kind", ["string", "image"])
async def test_a_roscpp_node_echoes_our_messages_back_to_us(
    procs: Processes, rosmaster: str, roscpp_node: str, kind: str
) -> None:
    procs.start([roscpp_node, "echo", kind], ros_env(rosmaster, procs.tmp), stdout=subprocess.DEVNULL)
    msg = known(kind)[0]
    async with our_node("pinger", rosmaster) as node:
        pub = await node.advertise("/ping", CLASSES[kind])
        sub = await node.subscribe("/pong", CLASSES[kind])
        await pub.wait_for_subscribers(1, timeout=20)
        await sub.wait_for_publishers(1, timeout=20)
        for _ in range(3):
            await pub.publish(msg)
            assert describe(kind, await sub.next(timeout=10)) == known(kind)[1]
