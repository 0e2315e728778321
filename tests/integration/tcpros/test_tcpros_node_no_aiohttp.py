"""A node started, publishing, subscribing (requestTopic and publisherUpdate over XML-RPC) and closed never
imports aiohttp: its XML-RPC client and slave API run on the project's own HTTP/1.1 framing."""

from __future__ import annotations

import asyncio
import subprocess
import sys

from mrosd import backports
from mrosd.master import Master

PROBE = """
import asyncio, sys
from mrosd.msg import get_message_class
from mrosd.tcpros.node import Node

async def main(uri):
    String = get_message_class("std_msgs/String")
    node = Node("/no_aiohttp", uri, argv=[], rosout=False, logger_services=False)
    await node.start()
    try:
        got = asyncio.get_running_loop().create_future()
        await node.subscribe("/chatter", String, lambda m: got.done() or got.set_result(m.data))
        pub = await node.advertise("/chatter", String, latch=True)
        await pub.publish(String(data="hi"))
        print(await asyncio.wait_for(got, 20))
    finally:
        await node.aclose()
    print("aiohttp" in sys.modules)

asyncio.run(main(sys.argv[1]))
"""


async def test_a_node_talking_to_itself_through_the_master_imports_no_aiohttp() -> None:
    master = Master(host="127.0.0.1", port=0)
    await master.start()
    try:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-c", PROBE, master.uri, stdout=subprocess.PIPE, stderr=subprocess.PIPE
        )
        out, err = await backports.wait_for(proc.communicate(), 60)
    finally:
        await master.aclose()
    assert proc.returncode == 0, err.decode()
    assert out.decode().split() == ["hi", "False"]
