"""permessage-deflate and the delivery counts on the Foxglove server, in-process with real sockets and aiohttp's
client (which offers permessage-deflate unless told not to). The shaped-link behaviour is in tests/netns."""

from __future__ import annotations

import asyncio

import aiohttp
import pytest

from mrosd.master import Master
from mrosd.msg import get_message_class
from mrosd.web.foxglove_sender import REPORT_PERIOD
from mrosd.web.server import WebServer
from tests.web.inloop import node
from tests.web.test_web_foxglove_integration import Client, server

__all__ = ["server"]  # the fixtures this module shares with the Foxglove integration tests

String = get_message_class("std_msgs/String")
CompressedImage = get_message_class("sensor_msgs/CompressedImage")


async def test_deflated_and_uncompressed_frames_interleave_and_a_client_without_deflate_gets_the_same(
    server: WebServer, master: Master
) -> None:
    """Text-like messages are deflated, a JPEG body goes uncompressed (RSV1 clear) on the same connection: the
    client's inflater must stay in step across them; a client that offers no deflate reads plain frames."""
    async with node("cam", master.uri) as cam, aiohttp.ClientSession() as http:
        text_pub = await cam.advertise("/text", String)
        jpeg_pub = await cam.advertise("/cam/compressed", CompressedImage)
        clients = []
        for compress in (15, 0):
            ws = await http.ws_connect(
                server.url, protocols=["foxglove.websocket.v1"], max_msg_size=0, compress=compress
            )
            assert ws.compress == compress
            client = Client(ws)
            ids = [(await client.until_channel(t))["id"] for t in ("/text", "/cam/compressed")]
            await client.send(op="subscribe", subscriptions=[{"id": i + 1, "channelId": c} for i, c in enumerate(ids)])
            clients.append(client)
        await text_pub.wait_for_subscribers(1, timeout=10)
        await jpeg_pub.wait_for_subscribers(1, timeout=10)
        sent = []
        for i in range(3):
            text = String(data="odometry-like text " * 20 + str(i))
            jpeg = CompressedImage(format="jpeg", data=bytes(range(256)) * 40)
            await text_pub.publish(text)
            await jpeg_pub.publish(jpeg)
            sent += [(1, text.serialize()), (2, jpeg.serialize())]
        for client in clients:
            got = []
            while len(got) < len(sent):
                frame = await client.until_binary()
                got.append((int.from_bytes(frame[1:5], "little"), frame[13:]))
            assert sorted(got) == sorted(sent)
            await client.ws.close()


async def test_each_client_is_told_per_subscription_what_was_sent_and_dropped(
    server: WebServer, master: Master
) -> None:
    async with node("talker", master.uri) as talker, aiohttp.ClientSession() as http:
        pub = await talker.advertise("/chatter", String)
        ws = await http.ws_connect(server.url, protocols=["foxglove.websocket.v1"], max_msg_size=0)
        client = Client(ws)
        channel = await client.until_channel("/chatter")
        await client.send(op="x-mrosd.subscribeDelivery")
        await client.send(op="subscribe", subscriptions=[{"id": 3, "channelId": channel["id"]}])
        await pub.wait_for_subscribers(1, timeout=10)
        for i in range(5):
            await pub.publish(String(data=str(i)))
        for _ in range(5):
            await client.until_binary()
        report = await client.until_json("x-mrosd.delivery", timeout=5.0)
        assert report["subscriptions"] == [
            {"topic": "/chatter", "sent": 5, "dropped": 0, "queued": 0, "subscriptionId": 3}
        ]
        await ws.close()


async def test_a_client_that_did_not_ask_gets_no_delivery_op(server: WebServer, master: Master) -> None:
    """Foxglove's own clients (Studio, @foxglove/ws-protocol) report an op they do not know as an error: mrosd's
    delivery counts go only to a client that asked for them (the page does, with ``x-mrosd.subscribeDelivery``)."""
    async with node("talker", master.uri) as talker, aiohttp.ClientSession() as http:
        pub = await talker.advertise("/chatter", String)
        ws = await http.ws_connect(server.url, protocols=["foxglove.websocket.v1"], max_msg_size=0)
        client = Client(ws)
        channel = await client.until_channel("/chatter")
        await client.send(op="subscribe", subscriptions=[{"id": 3, "channelId": channel["id"]}])
        await pub.wait_for_subscribers(1, timeout=10)
        await pub.publish(String(data="x"))
        await client.until_binary()
        with pytest.raises((TimeoutError, asyncio.TimeoutError)):
            await client.until_json("x-mrosd.delivery", timeout=2.5 * REPORT_PERIOD)
        await ws.close()


def test_the_daemon_status_names_what_was_dropped_for_each_slow_client() -> None:
    from mros_cli.daemon import part_lines

    from mrosd.runstatus import ClientDrops, DaemonStatus, WebStatus

    drops = [ClientDrops(client="Foxglove client 10.0.0.2", dropped={"/camera/image_raw": 120, "/scan": 3})]
    web = WebStatus(page="http://10.0.0.1:8765/", foxglove=["ws://10.0.0.1:8765/"], drops=drops)
    st = DaemonStatus(pid=1, version="0", master_uri="http://10.0.0.1:11311/", state="running", web=web)
    assert "web: dropped for Foxglove client 10.0.0.2: /camera/image_raw 120, /scan 3" in part_lines(st)
