"""Real clients, not ours: @foxglove/ws-protocol from node against mrosd's Foxglove WebSocket server.

The publishers are real too: rospy from Debian (under /usr/bin/python3) and an mrosd node. An 8 MB
sensor_msgs/Image must arrive byte-identical (sha256 of what the publisher serialized == sha256 of the
messageData payload the node client got). The npm packages come from tests/web/package-lock.json
(``npm ci --prefix tests/web``); without node or them the test is skipped with that instruction.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import importlib.util
import json
import os
import random
import shutil
import subprocess
import sys
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest

from mrosd import backports
from mrosd.master import Master
from mrosd.msg import get_message_class, get_service_class
from mrosd.web.server import WebServer
from tests.rosenv import ROS_PYTHON, ros_available, ros_env
from tests.web.inloop import node

HERE = Path(__file__).resolve().parent
NODE = shutil.which("node")
HAVE_PACKAGES = (HERE / "node_modules" / "@foxglove" / "ws-protocol").is_dir() and (
    HERE / "node_modules" / "ws"
).is_dir()

needs_node = pytest.mark.skipif(
    NODE is None or not HAVE_PACKAGES,
    reason="node or the npm packages are missing: install nodejs (scripts/install-system-deps.sh), "
    "then run `npm ci --prefix tests/web`",
)

Image = get_message_class("sensor_msgs/Image")
String = get_message_class("std_msgs/String")
SetBool = get_service_class("std_srvs/SetBool")

#: 8 MB of RGBA pixels (2048x1024), every byte value present.
WIDTH, HEIGHT = 2048, 1024
PIXELS = bytes(range(256)) * (WIDTH * HEIGHT * 4 // 256)

ROSPY_CAMERA = f"""
import hashlib, io, rospy
from sensor_msgs.msg import Image
rospy.init_node("rospy_camera")
pub = rospy.Publisher("/rospy_image", Image, queue_size=1)
img = Image(height={HEIGHT}, width={WIDTH}, encoding="rgba8", step={WIDTH * 4})
img.data = bytes(range(256)) * ({WIDTH * HEIGHT * 4 // 256})
while not rospy.is_shutdown():
    img.header.stamp = rospy.Time.now()
    pub.publish(img)  # sets img.header.seq: serializing it again gives the bytes sent
    buf = io.BytesIO()
    img.serialize(buf)
    print(hashlib.sha256(buf.getvalue()).hexdigest(), flush=True)
    rospy.sleep(0.3)
"""


class NodeClient:
    """tests/web/foxglove_client.mjs as a subprocess: commands in, JSON events out."""

    def __init__(self, proc: asyncio.subprocess.Process) -> None:
        self.proc = proc
        self.events: list[dict[str, Any]] = []

    @classmethod
    async def start(cls, url: str) -> NodeClient:
        assert NODE is not None
        proc = await asyncio.create_subprocess_exec(
            NODE,
            str(HERE / "foxglove_client.mjs"),
            url,
            cwd=HERE,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            limit=1 << 20,
        )
        return cls(proc)

    async def send(self, **cmd: Any) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write((json.dumps(cmd) + "\n").encode())
        await self.proc.stdin.drain()

    async def until(self, event: str, timeout: float = 20.0, **match: Any) -> dict[str, Any]:
        """The next event ``event`` with fields ``match``; channels, services and asset responses (which come
        in any order) also from the past."""
        if event in ("channel", "service", "fetchAssetResponse"):
            for ev in self.events:
                if ev["event"] == event and all(ev.get(k) == v for k, v in match.items()):
                    return ev
        try:
            async with backports.timeout(timeout):
                return await self._until(event, match)
        except TimeoutError:
            raise AssertionError(f"no {event} {match} within {timeout} s; last events {self.events[-5:]}") from None

    async def _until(self, event: str, match: dict[str, Any]) -> dict[str, Any]:
        assert self.proc.stdout is not None
        while True:
            line = await self.proc.stdout.readline()
            if not line:
                raise AssertionError(f"the node client exited waiting for {event}; saw {self.events[-5:]}")
            ev = json.loads(line)
            self.events.append(ev)
            if ev["event"] == event and all(ev.get(k) == v for k, v in match.items()):
                return ev

    async def close(self) -> None:
        if self.proc.returncode is None:
            self.proc.kill()
        await self.proc.wait()


@pytest.fixture
async def client_of(master: Master) -> AsyncIterator[Any]:
    clients: list[NodeClient] = []

    async def start(server: WebServer) -> NodeClient:
        c = await NodeClient.start(server.url)
        clients.append(c)
        await c.until("serverInfo")
        return c

    try:
        yield start
    finally:
        for c in clients:
            await c.close()


@needs_node
async def test_foxglove_client_subscribes_publishes_calls_and_reads_a_parameter(master: Master, client_of: Any) -> None:
    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1") as server,
        node("robot", master.uri) as robot,
    ):
        await robot.set_param("/robot/name", "mrosd-bot")
        await robot.advertise_service("/enable", SetBool, lambda r: SetBool._response_class(success=r.data))
        cam = await robot.advertise("/mrosd_image", Image)
        listener = await robot.subscribe("/from_node", String)
        client = await client_of(server)

        # An 8 MB image from an mrosd publisher, byte-identical.
        await client.until("channel", topic="/mrosd_image")
        await client.send(cmd="subscribe", topic="/mrosd_image")
        await client.until("subscribed")
        await cam.wait_for_subscribers(1, timeout=10)
        img = Image(height=HEIGHT, width=WIDTH, encoding="rgba8", step=WIDTH * 4, data=PIXELS)
        await cam.publish(img)
        sent = hashlib.sha256(img.serialize()).hexdigest()
        got = await client.until("message", topic="/mrosd_image")
        assert (got["len"], got["sha256"]) == (len(img.serialize()), sent)

        # Publish from the browser side to a ROS subscriber.
        await client.send(cmd="advertise", topic="/from_node", schemaName="std_msgs/String")
        channel = (await client.until("advertised"))["channel"]
        await listener.wait_for_publishers(1, timeout=10)
        await client.send(cmd="publish", channel=channel, hex=String(data="from node").serialize().hex())
        assert (await listener.next(timeout=10)).data == "from node"

        # A parameter and a service call.
        await client.send(cmd="getParameters", names=["/robot/name"], id="p")
        values = await client.until("parameterValues", id="p", timeout=5)
        assert values["parameters"] == [{"name": "/robot/name", "value": "mrosd-bot"}]
        await client.until("service", name="/enable")
        await client.send(cmd="callService", service="/enable", hex=SetBool._request_class(data=True).serialize().hex())
        response = await client.until("serviceResponse")
        assert SetBool._response_class.deserialize(bytes.fromhex(response["hex"])).success is True


@needs_node
@pytest.mark.interop
@pytest.mark.skipif(not ros_available(), reason="Debian ROS 1 (rospy) is not installed: scripts/install-system-deps.sh")
async def test_foxglove_client_gets_rospys_8mb_image_byte_identical(
    master: Master, client_of: Any, tmp_path: Path
) -> None:
    rospy_proc = await asyncio.create_subprocess_exec(
        ROS_PYTHON, "-c", ROSPY_CAMERA, env=ros_env(master.uri, tmp_path), stdout=subprocess.PIPE
    )
    try:
        async with WebServer(master.uri, port=0, node_host="127.0.0.1") as server:
            client = await client_of(server)
            await client.until("channel", topic="/rospy_image")
            await client.send(cmd="subscribe", topic="/rospy_image")
            got = await client.until("message", topic="/rospy_image", timeout=30)
            assert got["len"] > 8 * 1024 * 1024
            # Every hash rospy printed up to now: the one received must be among them.
            assert rospy_proc.stdout is not None
            published: set[str] = set()
            async with backports.timeout(20):
                while got["sha256"] not in published:
                    published.add((await rospy_proc.stdout.readline()).decode().strip())
    finally:
        rospy_proc.kill()
        await rospy_proc.wait()


ROSLIBPY = importlib.util.find_spec("roslibpy") is not None


@contextlib.asynccontextmanager
async def rosbridge_robot(master: Master, listen: str) -> AsyncIterator[tuple[WebServer, Any, Any]]:
    """What both rosbridge clients talk to: a bridge, and a robot node with a parameter, a service, an image
    publisher and a subscriber of ``listen``; yields (bridge, image publisher, subscriber)."""
    async with (
        WebServer(master.uri, port=0, rosbridge_port=0, node_host="127.0.0.1") as server,
        node("robot", master.uri) as robot,
    ):
        await robot.set_param("/robot/name", "mrosd-bot")
        await robot.advertise_service("/enable", SetBool, lambda r: SetBool._response_class(success=r.data))
        cam = await robot.advertise("/image", Image)
        listener = await robot.subscribe(listen, String)
        yield server, cam, listener


async def exercise_rosbridge_client(
    client: Any, server: Any, cam: Any, listener: Any, label: str, *, image_timeout: float, publish_first: bool
) -> None:
    """The script both rosbridge clients run through mrosd: an 8 MB image in, a publish out, a service call,
    a parameter read. ``publish_first``: roslib advertises on its first publish, before any subscriber sees it."""
    await cam.wait_for_subscribers(1, timeout=10)
    img = Image(height=HEIGHT, width=WIDTH, encoding="rgba8", step=WIDTH * 4, data=PIXELS)
    await cam.publish(img)
    got = await client.until("image", timeout=image_timeout)
    assert (got["len"], got["sha256"]) == (len(PIXELS), hashlib.sha256(PIXELS).hexdigest())
    if publish_first:
        await client.send(cmd="publish", data=label)
    await listener.wait_for_publishers(1, timeout=10)
    await client.send(cmd="publish", data=label)
    assert (await listener.next(timeout=10)).data == label
    async with backports.timeout(10):
        while "/enable" not in server.hub.services:  # noqa: ASYNC110 - the hub probes the type
            await asyncio.sleep(0.01)
    await client.send(cmd="call")
    assert (await client.until("response"))["values"]["success"] is True
    await client.send(cmd="param")
    assert (await client.until("param"))["value"] == "mrosd-bot"


@pytest.mark.skipif(not ROSLIBPY, reason="roslibpy is not installed: pip install -e '.[dev]'")
async def test_roslibpy_subscribes_publishes_calls_and_reads_a_parameter(master: Master) -> None:
    async with rosbridge_robot(master, "/from_roslibpy") as (server, cam, listener):
        proc = await asyncio.create_subprocess_exec(
            sys.executable,
            str(HERE / "roslibpy_client.py"),
            "127.0.0.1",
            str(server.rosbridge_port),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            limit=1 << 20,
        )
        client = NodeClient(proc)  # the same JSON-lines driver
        try:
            await client.until("subscribed")
            await exercise_rosbridge_client(
                client, server, cam, listener, "from roslibpy", image_timeout=30, publish_first=False
            )
        finally:
            await client.close()


CHROMIUM = Path(os.environ.get("CHROMIUM", "/usr/bin/chromium"))
HAVE_BROWSER_PACKAGES = all((HERE / "node_modules" / p).is_dir() for p in ("roslib", "playwright-core"))

needs_chromium = pytest.mark.skipif(
    NODE is None or not HAVE_BROWSER_PACKAGES or not CHROMIUM.exists(),
    reason="node, chromium or the npm packages are missing: scripts/install-system-deps.sh "
    "(nodejs, chromium, then `npm ci --prefix tests/web`)",
)


@contextlib.asynccontextmanager
async def roslib_in_chromium(server: WebServer) -> AsyncIterator[NodeClient]:
    """tests/web/roslib_page.html (the real roslib) in headless Chromium, connected to ``server``'s rosbridge
    port; the page is served here, with roslib and its dependencies from tests/web/node_modules."""
    from aiohttp import web

    async def page(_request: web.Request) -> web.FileResponse:
        return web.FileResponse(HERE / "roslib_page.html")

    app = web.Application()
    app.router.add_get("/", page)
    app.router.add_static("/node_modules/", HERE / "node_modules")
    runner = web.AppRunner(app, handle_signals=False, access_log=None, shutdown_timeout=1.0)
    await runner.setup()
    try:
        site = web.TCPSite(runner, "127.0.0.1", 0)
        await site.start()
        page_port = site._server.sockets[0].getsockname()[1]  # type: ignore[union-attr]
        # this page is another origin than the server's own: allowed as [web] allowed_origins would
        server.gate.allowed_origins |= {f"http://127.0.0.1:{page_port}"}
        assert NODE is not None
        proc = await asyncio.create_subprocess_exec(
            NODE,
            str(HERE / "roslib_browser.mjs"),
            f"http://127.0.0.1:{page_port}/",
            server.rosbridge_url,
            cwd=HERE,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            limit=1 << 20,
        )
        client = NodeClient(proc)
        try:
            await client.until("subscribed", timeout=60)
            yield client
            await client.send(cmd="close")
        finally:
            await client.close()
    finally:
        await runner.cleanup()


@needs_chromium
async def test_roslib_in_headless_chromium_subscribes_publishes_calls_and_reads_a_parameter(master: Master) -> None:
    async with (
        rosbridge_robot(master, "/from_browser") as (server, cam, listener),
        roslib_in_chromium(server) as client,
    ):
        await exercise_rosbridge_client(
            client, server, cam, listener, "from chromium", image_timeout=60, publish_first=True
        )


@needs_chromium
async def test_roslib_in_headless_chromium_reads_png_compression_whole_and_in_fragments(master: Master) -> None:
    """roslib decodes ``png`` ops itself (fast-png in roslib 2.x) and joins ``fragment`` ops: a camera image
    through both must reach its callback byte-identical."""
    pixels = random.Random(22).randbytes(640 * 480 * 3)  # noise, as a camera's: the PNG stays about 1.6 MB
    img = Image(height=480, width=640, encoding="rgb8", step=1920, data=pixels)
    async with (
        WebServer(master.uri, port=0, rosbridge_port=0, node_host="127.0.0.1") as server,
        node("camera", master.uri) as camera,
        roslib_in_chromium(server) as client,
    ):
        for topic, fragment_size in (("/png_image", 0), ("/png_image_cut", 100_000)):
            cam = await camera.advertise(topic, Image)
            await client.send(cmd="subscribe_png", topic=topic, fragment_size=fragment_size)
            await client.until("subscribed_png", topic=topic)
            await cam.wait_for_subscribers(1, timeout=10)
            await cam.publish(img)
            got = await client.until("png_image", topic=topic, timeout=60)
            assert (got["len"], got["sha256"], got["width"]) == (len(pixels), hashlib.sha256(pixels).hexdigest(), 640)
            (session,) = server.rosbridge_sessions
            assert session.subs[topic].compression == "png"  # what roslib read were png ops, not JSON


@needs_node
async def test_a_foxglove_client_that_never_reads_costs_a_bound_and_the_other_keeps_up(
    master: Master, client_of: Any
) -> None:
    from mrosd.web.foxglove_server import SessionLimits

    limits = SessionLimits(queue_bytes=4 * 1024 * 1024, client_bytes=8 * 1024 * 1024)
    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1", limits=limits) as server,
        node("camera", master.uri) as camera,
    ):
        cam = await camera.advertise("/image", Image)
        stalled, live = await client_of(server), await client_of(server)
        for c in (stalled, live):
            await c.until("channel", topic="/image")
            await c.send(cmd="subscribe", topic="/image")
            await c.until("subscribed")
        await stalled.send(cmd="pause")
        await stalled.until("paused")
        await cam.wait_for_subscribers(1, timeout=10)
        # both subscriptions have reached the server (a client's "subscribed" is only what it sent): a frame
        # published before the live one's joined never reaches it
        async with backports.timeout(10):
            while server.hub.sink_count("/image") < 2:  # noqa: ASYNC110 - the server's own state
                await asyncio.sleep(0.01)
        img = Image(height=1000, width=1000, encoding="mono8", step=1000, data=bytes(1000 * 1000))
        received = 0
        async with backports.timeout(60):
            for _ in range(60):  # 60 MB published; the live client reads them as they come
                await cam.publish(img)
                await live.until("message", topic="/image")
                received += 1
        assert received == 60
        paused = next(s for s in server.sessions if any(q.queue.dropped for q in s.subs.values()))
        assert sum(q.queue.size for q in paused.subs.values()) <= limits.client_bytes + 1_000_100


URDF = """<robot name="r"><link name="base"><visual><geometry>
<mesh filename="package://robot_description/meshes/base.STL"/></geometry></visual></link></robot>
"""


def robot_description(ws: Path) -> tuple[bytes, bytes]:
    """A package in ``ws`` as a robot's description is shipped: package.xml, a URDF and its binary mesh."""
    pkg = ws / "robot_description"
    (pkg / "meshes").mkdir(parents=True)
    (pkg / "urdf").mkdir()
    (pkg / "package.xml").write_text("<package><name>robot_description</name></package>\n")
    (pkg / "config.yaml").write_text("secret: 1\n")
    mesh = os.urandom(3 * 1024 * 1024)
    (pkg / "meshes" / "base.STL").write_bytes(mesh)
    (pkg / "urdf" / "robot.urdf").write_text(URDF)
    return mesh, URDF.encode()


@needs_node
def test_foxglove_client_fetches_a_robots_mesh_and_urdf_from_the_daemon(procs: Any, tmp_path: Path) -> None:
    """The daemon as shipped (default ``[web] assets``) finds the package on ROS_PACKAGE_PATH; what the
    @foxglove/ws-protocol client receives is the files' bytes; what the allow-list leaves out is an error."""
    import re

    from tests.integration.daemon.daemonproc import DaemonRun, daemon_env

    mesh, urdf = robot_description(tmp_path / "ws")
    run = DaemonRun(procs, tmp_path, env=daemon_env(tmp_path, ROS_PACKAGE_PATH=str(tmp_path / "ws")))

    async def fetch(url: str) -> None:
        client = await NodeClient.start(url)
        try:
            info = await client.until("serverInfo")
            assert "assets" in info["capabilities"]
            asks = {
                1: "package://robot_description/meshes/base.STL",
                2: "package://robot_description/urdf/robot.urdf",
                3: "package://robot_description/config.yaml",
                4: "package://robot_description/../../etc/passwd.png",
            }
            for rid, uri in asks.items():
                await client.send(cmd="fetchAsset", uri=uri, id=rid)
            got = {rid: await client.until("fetchAssetResponse", requestId=rid) for rid in asks}
            for rid, data in ((1, mesh), (2, urdf)):
                assert (got[rid]["status"], got[rid]["len"]) == (0, len(data)), got[rid]
                assert got[rid]["sha256"] == hashlib.sha256(data).hexdigest()
            assert got[3]["status"] == 1 and "allow-list" in got[3]["error"]
            assert got[4]["status"] == 1 and "'..'" in got[4]["error"]
        finally:
            await client.close()

    try:
        status = run.ready()
        match = re.search(r"foxglove (ws://\S+/)", status)
        assert match, status
        asyncio.run(fetch(match.group(1)))
        assert run.stop()[0] == 0, run.stderr()
    finally:
        run.close()


@needs_node
async def test_sim_time_follows_use_sim_time_as_it_changes(master: Master, client_of: Any) -> None:
    """/use_sim_time false, then true, then false, while clients are connected; a real /clock publisher.

    Capabilities are declared once per connection: a client that connected under wall time is told to
    reconnect; one that connects under sim time is offered ``time``, gets /clock's time and its messages
    stamped with it; when sim time ends the server leaves /clock and that client is told."""
    Clock = get_message_class("rosgraph_msgs/Clock")

    def clock_at(secs: int, nsecs: int) -> Any:
        msg = Clock()
        msg.clock.secs, msg.clock.nsecs = secs, nsecs
        return msg

    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1") as server,
        node("sim", master.uri) as sim,
    ):
        clock = await sim.advertise("/clock", Clock)
        chatter = await sim.advertise("/chatter", String)
        wall = await client_of(server)
        assert "time" not in wall.events[-1]["capabilities"]

        await sim.set_param("/use_sim_time", True)
        status = await wall.until("status", timeout=10)
        assert "/use_sim_time is now true: reconnect" in status["message"]
        simulated = await client_of(server)
        assert "time" in simulated.events[-1]["capabilities"]
        await clock.wait_for_subscribers(1, timeout=10)
        await clock.publish(clock_at(12, 345))
        assert (await simulated.until("time"))["timestamp"] == "12000000345"
        await simulated.until("channel", topic="/chatter")
        await simulated.send(cmd="subscribe", topic="/chatter")
        await chatter.wait_for_subscribers(1, timeout=10)
        await chatter.publish(String(data="at sim time"))
        assert (await simulated.until("message", topic="/chatter"))["timestamp"] == "12000000345"

        await sim.set_param("/use_sim_time", False)
        status = await simulated.until("status", timeout=10)
        assert "/use_sim_time is now false" in status["message"]
        async with backports.timeout(10):
            while clock.get_num_connections():  # noqa: ASYNC110 - the server leaves /clock
                await asyncio.sleep(0.01)
        assert not server.hub.time_listeners
        later = await client_of(server)
        assert "time" not in later.events[-1]["capabilities"]
        assert not [e for e in (*wall.events, *later.events) if e["event"] == "time"]
