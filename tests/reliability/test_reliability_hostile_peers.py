"""A node's TCPROS listener facing hostile peers: giant length claims, garbage headers, half-open connections.

Each bad connection is closed on its own; the publisher keeps serving a well-behaved subscriber throughout.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import struct

import pytest

import mrosd
from mrosd import backports
from mrosd.msg import get_message_class
from tests.reliability.relnodes import start_master
from tests.rosenv import Processes

String = get_message_class("std_msgs/String")

HOSTILE = [
    struct.pack("<I", 0xFFFFFFF0),  # a 4 GB header claim
    struct.pack("<I", 12) + struct.pack("<I", 100) + b"abcdefgh",  # a field running past the header's end
    struct.pack("<I", 8) + struct.pack("<I", 4) + b"noeq",  # a field without '='
    struct.pack("<I", 9) + struct.pack("<I", 5) + b"a=\xff\xfe\xfd",  # not UTF-8
    struct.pack("<I", 0),  # an empty header: no topic, no md5
    b"GET / HTTP/1.1\r\nHost: x\r\n\r\n",  # a web client on the wrong port
]


async def test_hostile_connections_are_closed_and_the_publisher_keeps_serving(procs: Processes) -> None:
    _, uri = start_master(procs)
    async with mrosd.Node("target", master_uri=uri, host="127.0.0.1", argv=[]) as node:
        pub = await node.advertise("/safe", String)
        got: list[str] = []
        await node.subscribe("/safe", String, callback=lambda m: got.append(m.data))
        idle = []
        for payload in HOSTILE:
            reader, writer = await asyncio.open_connection("127.0.0.1", node.tcpros_port)
            writer.write(payload)
            await writer.drain()
            # either an error header then EOF, or EOF at once; never a hang
            rest = await backports.wait_for(reader.read(), 5.0)
            assert b"md5sum=" not in rest
            writer.close()
        for _ in range(20):  # connections that never send a byte must not stop anyone else
            idle.append(await asyncio.open_connection("127.0.0.1", node.tcpros_port))
        for _ in range(250):
            await pub.publish(String(data="ok"))
            if got:
                break
            await asyncio.sleep(0.02)
        assert got and got[0] == "ok"
        for _, w in idle:
            w.close()
        for _, w in idle:
            with contextlib.suppress(ConnectionError):
                await w.wait_closed()


async def test_connections_that_never_send_a_header_are_closed_with_the_node(procs: Processes) -> None:
    """asyncio's Server.close() leaves accepted connections open: the node closes those it owns no endpoint for."""
    _, uri = start_master(procs)
    node = mrosd.Node("silent_target", master_uri=uri, host="127.0.0.1", argv=[], rosout=False)
    await node.start()
    try:
        idle = [await asyncio.open_connection("127.0.0.1", node.tcpros_port) for _ in range(5)]
        for _ in range(500):  # at most 5 s until the node accepted them all (private: the state under test)
            if len(node._inbound) >= len(idle):
                break
            await asyncio.sleep(0.01)
        else:
            raise AssertionError("the node did not accept the connections")
    finally:
        await node.aclose()
    for reader, writer in idle:
        try:
            assert await backports.wait_for(reader.read(), 5.0) == b""  # EOF: the node closed its end
        except ConnectionResetError:
            pass  # or a reset: closed all the same
        finally:
            writer.close()
            with contextlib.suppress(ConnectionError):
                await writer.wait_closed()  # before the test's loop ends, or the transport is reported unclosed


async def test_connections_arriving_while_the_node_closes_are_all_closed(procs: Processes) -> None:
    """Peers (the master's publisherUpdate, a subscriber) connect while the node is closing: asyncio makes an
    accepted connection's transport turns later, in a task, and closing the listener in between must not leave
    that socket open and owned by no one (its peer would wait for an answer that never comes)."""
    _, uri = start_master(procs)
    await _connect_while_the_node_closes(uri)


def test_the_same_on_uvloop_which_calls_connection_made_a_turn_late(procs: Processes) -> None:
    uvloop = pytest.importorskip("uvloop")
    _, uri = start_master(procs)
    uvloop.run(_connect_while_the_node_closes(uri))


async def _connect_while_the_node_closes(uri: str) -> None:
    loop = asyncio.get_running_loop()
    node = mrosd.Node("closing_target", master_uri=uri, host="127.0.0.1", argv=[], rosout=False)
    await node.start()
    ports = (node.tcpros_port, int(node.uri.rsplit(":", 1)[1].strip("/")))  # TCPROS and the slave API
    closing = asyncio.ensure_future(node.aclose())
    socks: list[socket.socket] = []
    try:
        while not closing.done():  # one new connection to each port on every loop turn until the node is gone
            for port in ports:
                sock = socket.socket()
                sock.setblocking(False)
                socks.append(sock)
                with contextlib.suppress(BlockingIOError, ConnectionRefusedError):
                    sock.connect(("127.0.0.1", port))
            await asyncio.sleep(0)
        await closing
        assert len(socks) > 20
        for sock in socks:  # EOF, or a reset or refusal, at once: the node closed its end of every one
            with contextlib.suppress(ConnectionError):
                assert await backports.wait_for(loop.sock_recv(sock, 1), 5.0) == b"", "a connection was left open"
    finally:
        for sock in socks:
            sock.close()
