"""A web client that subscribes to a latched topic another client already holds gets the latched message.

The hub shares one TCPROS subscription per topic, and a publisher sends its latched message once, as that
connection opens; a second client (a second page on the TF tab: /tf_static; the Reconfigure tab:
parameter_descriptions) would wait for a message that never comes again. rosbridge_server opens a new
subscriber for such a client for the same reason. Real sockets, a real master, a real latched publisher.
"""

from __future__ import annotations

import json
import struct

import aiohttp

import mrosd
from mrosd import backports
from mrosd.master import Master
from mrosd.msg import get_message_class
from mrosd.web.server import WebServer

String = get_message_class("std_msgs/String")


async def _first_message(
    http: aiohttp.ClientSession, url: str, topic: str
) -> tuple[bytes, aiohttp.ClientWebSocketResponse]:
    ws = await http.ws_connect(url, protocols=["foxglove.websocket.v1"])
    async with backports.timeout(5):
        while True:
            msg = await ws.receive()
            if msg.type == aiohttp.WSMsgType.TEXT:
                op = json.loads(msg.data)
                if op["op"] == "advertise":
                    for ch in op["channels"]:
                        if ch["topic"] == topic:
                            await ws.send_str(
                                json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": ch["id"]}]})
                            )
            elif msg.type == aiohttp.WSMsgType.BINARY and msg.data[0] == 1:
                assert struct.unpack_from("<I", msg.data, 1)[0] == 7
                return bytes(msg.data[13:]), ws
            else:
                raise AssertionError(f"unexpected {msg}")


async def test_a_second_client_of_a_latched_topic_gets_the_latched_message(master: Master) -> None:
    async with (
        WebServer(master.uri, port=0, node_host="127.0.0.1") as server,
        mrosd.Node("static_tf", master_uri=master.uri, argv=[], host="127.0.0.1") as node,
        aiohttp.ClientSession() as http,
    ):
        pub = await node.advertise("/latched", String, latch=True)
        await pub.publish(String(data="once"))
        first, ws1 = await _first_message(http, server.url, "/latched")
        assert String.deserialize(first).data == "once"
        second, ws2 = await _first_message(http, server.url, "/latched")  # the shared subscription is open
        assert second == first
        await ws1.close()
        await ws2.close()
