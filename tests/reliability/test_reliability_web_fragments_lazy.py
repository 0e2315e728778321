"""rosbridge fragments are made one at a time and counted while sent; ``fragment_size`` has a floor.

In process (the server's state is read): a 16 MB message (more than loopback's socket buffers) to a client
with ``fragment_size: 1`` that reads a few pieces and stops.
"""

from __future__ import annotations

import asyncio
import json

import aiohttp

import mrosd
from mrosd.master import Master
from mrosd.msg import get_message_class
from mrosd.web import rosbridge as rb
from mrosd.web.server import WebServer
from tests.web.inloop import until

UInt8MultiArray = get_message_class("std_msgs/UInt8MultiArray")


async def test_fragments_of_a_big_message_are_made_lazily_and_counted(master: Master) -> None:
    async with (
        WebServer(master.uri, port=0, rosbridge_port=0, node_host="127.0.0.1") as server,
        mrosd.Node("big", master_uri=master.uri, argv=[], host="127.0.0.1") as node,
        aiohttp.ClientSession() as http,
    ):
        pub = await node.advertise("/big", UInt8MultiArray)
        ws = await http.ws_connect(server.rosbridge_url)
        await ws.send_str(json.dumps({"op": "subscribe", "topic": "/big", "fragment_size": 1}))
        await until(lambda: server.hub.sink_count("/big") == 1)
        await pub.wait_for_subscribers(1, timeout=10)
        (session,) = server.rosbridge_sessions
        await pub.publish(UInt8MultiArray(data=bytes(16 * 1024 * 1024)))
        first = json.loads((await ws.receive(timeout=10)).data)
        assert first["op"] == "fragment" and len(first["data"]) == rb.MIN_FRAGMENT_SIZE
        # the client stops reading: what the server holds for it is the one text, counted, not its fragments
        await asyncio.sleep(0.5)
        assert (first["total"] - 1) * rb.MIN_FRAGMENT_SIZE < session.held <= first["total"] * rb.MIN_FRAGMENT_SIZE
        assert server.hub.ledger.size >= session.held
        assert session._control.size < 64 * 1024
        await ws.close()
        await until(lambda: not server.rosbridge_sessions)
        assert server.hub.ledger.size == 0
