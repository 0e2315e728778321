"""A web client that drives a robot and vanishes: the daemon stops the robot itself (the dead-man switch).

A browser's teleop publishes ``geometry_msgs/Twist`` at 10 Hz; when its connection drops (Wi-Fi gone, laptop
lid shut, the browser killed) it can no longer send the zero that stops the robot. The web server sends one
zero of the same type on the same topic for a client that was driving (a non-zero command within the last
second) when its connection ends. Real sockets, a real master, a real mrosd subscriber.
"""

from __future__ import annotations

import asyncio
import json
import struct
from typing import Any

import aiohttp
import pytest

import mrosd
from mrosd import backports
from mrosd.master import Master
from mrosd.msg import get_message_class
from mrosd.web.server import WebServer
from tests.web.inloop import node, rosbridge_and_node

Twist = get_message_class("geometry_msgs/Twist")
TwistStamped = get_message_class("geometry_msgs/TwistStamped")


async def _received(topic: str, cls: Any, robot: mrosd.Node) -> asyncio.Queue[Any]:
    got: asyncio.Queue[Any] = asyncio.Queue()
    await robot.subscribe(topic, cls, got.put_nowait)
    return got


async def _next(got: asyncio.Queue[Any], timeout: float = 5.0) -> Any:
    async with backports.timeout(timeout):
        return await got.get()


async def _until_received(got: asyncio.Queue[Any], send: Any) -> Any:
    """Send at 20 Hz (as a teleop does) until the subscriber has one: it connects after the advertise."""
    async with backports.timeout(10):
        while got.empty():
            await send()
            await asyncio.sleep(0.05)
    return got.get_nowait()


async def _foxglove_drive(
    server: WebServer, http: aiohttp.ClientSession, got: asyncio.Queue[Any], cls: Any, msg: Any
) -> tuple[Any, Any]:
    ws = await http.ws_connect(server.url, protocols=["foxglove.websocket.v1"])
    channel = {"id": 1, "topic": "/cmd_vel", "encoding": "ros1", "schemaName": cls._type}
    await ws.send_str(json.dumps({"op": "advertise", "channels": [channel]}))
    first = await _until_received(got, lambda: ws.send_bytes(struct.pack("<BI", 1, 1) + msg.serialize()))
    await asyncio.sleep(0.1)
    while not got.empty():  # what was in flight as the first arrived
        got.get_nowait()
    return ws, first


@pytest.mark.parametrize("cls", [Twist, TwistStamped], ids=["Twist", "TwistStamped"])
async def test_a_foxglove_client_that_drops_while_driving_is_followed_by_one_zero(master: Master, cls: Any) -> None:
    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1") as server,
        node("robot", master.uri) as robot,
        aiohttp.ClientSession() as http,
    ):
        got = await _received("/cmd_vel", cls, robot)
        drive = cls()
        twist = drive if cls is Twist else drive.twist
        twist.linear.x, twist.angular.z = 0.5, -0.25
        if cls is TwistStamped:
            drive.header.frame_id = "base_link"
        ws, first = await _foxglove_drive(server, http, got, cls, drive)
        assert (first if cls is Twist else first.twist).linear.x == 0.5
        # The connection drops without a close handshake (the browser process killed, the network gone).
        assert ws._response.connection is not None
        ws._response.connection.transport.abort()  # type: ignore[union-attr]
        zero = await _next(got)
        moving = zero if cls is Twist else zero.twist
        assert (moving.linear.x, moving.linear.y, moving.angular.z) == (0.0, 0.0, 0.0)
        if cls is TwistStamped:
            assert zero.header.frame_id == "base_link" and zero.header.stamp.secs > 0
        await asyncio.sleep(0.3)
        assert got.empty(), "one zero, not more"
        await http.close()


async def test_a_client_that_had_stopped_gets_no_zero(master: Master) -> None:
    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1") as server,
        node("robot", master.uri) as robot,
        aiohttp.ClientSession() as http,
    ):
        got = await _received("/cmd_vel", Twist, robot)
        # Already stopped: its last command was a zero.
        ws, _ = await _foxglove_drive(server, http, got, Twist, Twist())
        await ws.close()
        await asyncio.sleep(0.3)
        assert got.empty()


async def test_a_rosbridge_client_that_drops_while_driving_is_followed_by_one_zero(master: Master) -> None:
    async with rosbridge_and_node(master.uri, "robot") as (server, robot, http):
        got = await _received("/cmd_vel", Twist, robot)
        ws = await http.ws_connect(server.rosbridge_url)
        await ws.send_str(json.dumps({"op": "advertise", "topic": "/cmd_vel", "type": "geometry_msgs/Twist"}))
        drive = {"linear": {"x": 0.4, "y": 0, "z": 0}, "angular": {"x": 0, "y": 0, "z": 1.0}}
        publish = json.dumps({"op": "publish", "topic": "/cmd_vel", "msg": drive})
        assert (await _until_received(got, lambda: ws.send_str(publish))).linear.x == 0.4
        await asyncio.sleep(0.1)
        while not got.empty():
            got.get_nowait()
        assert ws._response.connection is not None
        ws._response.connection.transport.abort()  # type: ignore[union-attr]
        zero = await _next(got)
        assert (zero.linear.x, zero.angular.z) == (0.0, 0.0)
        await asyncio.sleep(0.3)
        assert got.empty()


async def test_the_zero_reaches_a_subscriber_that_was_behind_when_the_client_dropped(
    master: Master, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The zero queues behind what the subscriber has not read yet; releasing the client's publisher right
    after must not throw it away (a publisher's close drops what it still queues)."""
    monkeypatch.setenv("MROSD_SHM", "0")  # TCPROS, as to a robot's rospy or roscpp node
    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1") as server,
        node("robot", master.uri) as robot,
        aiohttp.ClientSession() as http,
    ):
        got = await _received("/cmd_vel", TwistStamped, robot)
        drive = TwistStamped()
        drive.header.frame_id = "x" * (1024 * 1024)  # big commands fill the socket buffers in a few messages
        drive.twist.linear.x = 0.5
        ws, _ = await _foxglove_drive(server, http, got, TwistStamped, drive)
        (sub,) = robot.subscribers.values()
        (link,) = sub.links.values()
        assert link.proto is not None and link.proto.transport is not None
        link.proto.transport.pause_reading()  # the robot falls behind
        frame = struct.pack("<BI", 1, 1) + drive.serialize()
        for _ in range(40):
            await ws.send_bytes(frame)
        (pub,) = [p for p in server.hub.node.publishers.values() if p.topic == "/cmd_vel"]
        async with backports.timeout(10):
            while not any(lk.queue for lk in pub.links):  # noqa: ASYNC110 - the publisher's state, no event
                await asyncio.sleep(0.01)
        assert ws._response.connection is not None
        ws._response.connection.transport.abort()  # type: ignore[union-attr]
        await asyncio.sleep(0.3)  # the session ends and queues its zero behind what the robot has not read
        link.proto.transport.resume_reading()
        last = None
        async with backports.timeout(10):
            while last is None or last.twist.linear.x != 0.0:
                last = await got.get()
        assert last.header.frame_id == drive.header.frame_id
