"""mrosd's master and nodes with zenoh-bridge-ros1 beside them: what the bridge does to a master, checked.

The bridge polls getSystemState every 100 ms, registers its publishers with the type ``*`` when it has not
learned one, and subscribes with ``md5sum=*``/``type=*``. These tests pin that mrosd stays correct and cheap
under that (no change was needed in mrosd/master or mrosd/tcpros for them).
"""

from __future__ import annotations

import asyncio
import struct
import time

import mrosd
from mrosd import backports
from mrosd.master import Master
from mrosd.msg import get_message_class
from mrosd.wire.header import decode_header, encode_header

String = get_message_class("std_msgs/String")


def node(name: str, uri: str) -> mrosd.Node:
    return mrosd.Node(name, master_uri=uri, argv=[], host="127.0.0.1")


async def test_a_star_typed_registration_does_not_overwrite_the_known_type() -> None:
    async with Master(host="127.0.0.1", port=0) as m, node("talker", m.uri) as a, node("bridge", m.uri) as z:
        await a.advertise("/chatter", String)
        await z.master.call("registerPublisher", "/chatter", "*", z.uri)
        types = dict(await z.master.call("getTopicTypes"))
        assert types["/chatter"] == "std_msgs/String"


async def test_get_system_state_at_10hz_with_200_topics_stays_cheap() -> None:
    async with Master(host="127.0.0.1", port=0) as m, node("probe", m.uri) as n:
        for i in range(200):
            await n.master.call("registerPublisher", f"/t{i}", "std_msgs/String", n.uri)
        took = []
        for _ in range(30):
            t0 = time.perf_counter()
            await n.master.call("getSystemState")
            took.append(time.perf_counter() - t0)
            await asyncio.sleep(0.1)
        took.sort()
        assert took[len(took) // 2] < 0.02, f"median getSystemState {took[len(took) // 2] * 1e3:.1f} ms"


async def test_a_wildcard_subscriber_gets_the_real_type_and_the_messages() -> None:
    async with Master(host="127.0.0.1", port=0) as m, node("talker", m.uri) as a:
        pub = await a.advertise("/chatter", String)
        reader, writer = await asyncio.open_connection("127.0.0.1", a.tcpros_port)
        try:
            writer.write(encode_header({"callerid": "/zenoh_bridge", "topic": "/chatter", "md5sum": "*", "type": "*"}))
            (size,) = struct.unpack("<I", await reader.readexactly(4))
            header = decode_header(await reader.readexactly(size))
            assert (header["type"], header["md5sum"]) == ("std_msgs/String", String._md5sum)
            await pub.wait_for_subscribers(1, 10)
            pub.publish_nowait(String(data="hi"))
            (length,) = struct.unpack("<I", await backports.wait_for(reader.readexactly(4), 10))
            assert await reader.readexactly(length) == b"\x02\x00\x00\x00hi"
        finally:
            writer.close()
