"""A node's listener with small admission caps, in process: who is shed, in which order, and when."""

from __future__ import annotations

import asyncio
import contextlib
import struct

import mrosd
from mrosd import backports
from mrosd.msg import get_message_class
from mrosd.tcpros.admission import AdmissionLimits
from mrosd.wire.header import ConnectionHeader, encode_header
from tests.reliability.relnodes import start_master
from tests.rosenv import Processes

String = get_message_class("std_msgs/String")


async def _closed_by_peer(reader: asyncio.StreamReader, timeout: float) -> bool:
    try:
        return await backports.wait_for(reader.read(), timeout) == b""
    except ConnectionResetError:
        return True
    except TimeoutError:
        return False


async def test_the_oldest_waiting_connections_go_first_and_the_rest_at_their_deadline(procs: Processes) -> None:
    _, uri = start_master(procs)
    limits = AdmissionLimits(header_timeout=1.0, max_pending=4, max_pending_per_address=4)
    async with mrosd.Node("gate", master_uri=uri, host="127.0.0.1", argv=[], rosout=False, admission=limits) as node:
        pub = await node.advertise("/gate", String)
        idle = []
        for _ in range(6):
            idle.append(await asyncio.open_connection("127.0.0.1", node.tcpros_port))
            await asyncio.sleep(0.02)  # one at a time, so that arrival order is certain
        writer = idle[-1][1]
        writer.write(struct.pack("<I", 4 * 1024 * 1024) + b"x")  # a huge claim, one byte: still just waiting
        assert [await _closed_by_peer(r, 0.3) for r, _ in idle[:2]] == [True, True]  # the two oldest
        got: list[str] = []
        await node.subscribe("/gate", String, callback=lambda m: got.append(m.data))
        for _ in range(200):  # a subscriber that sends its header at once gets through
            await pub.publish(String(data="ok"))
            if got:
                break
            await asyncio.sleep(0.02)
        assert got[:1] == ["ok"]
        assert all([await _closed_by_peer(r, 2.0) for r, _ in idle[2:]])  # the header deadline
        for _, w in idle:
            w.close()
            with contextlib.suppress(ConnectionError):
                await w.wait_closed()


async def test_over_the_connection_cap_with_nobody_waiting_a_new_connection_is_refused(procs: Processes) -> None:
    _, uri = start_master(procs)
    limits = AdmissionLimits(max_connections=1)
    async with mrosd.Node("full", master_uri=uri, host="127.0.0.1", argv=[], rosout=False, admission=limits) as node:
        pub = await node.advertise("/full", String)
        reader, writer = await asyncio.open_connection("127.0.0.1", node.tcpros_port)
        writer.write(encode_header(ConnectionHeader(callerid="/raw", topic="/full", md5sum="*", type="*")))
        (length,) = struct.unpack("<I", await backports.wait_for(reader.readexactly(4), 5.0))
        await backports.wait_for(reader.readexactly(length), 5.0)  # the publisher's reply: established
        other_reader, other_writer = await asyncio.open_connection("127.0.0.1", node.tcpros_port)
        assert await _closed_by_peer(other_reader, 2.0)  # nobody waiting to shed: refused
        other_writer.close()
        await pub.publish(String(data="still"))
        (length,) = struct.unpack("<I", await backports.wait_for(reader.readexactly(4), 5.0))
        assert (await backports.wait_for(reader.readexactly(length), 5.0)).endswith(b"still")
        writer.close()
