"""A publisher that completes the handshake and then sends garbage must not be re-dialled every 0.1 s.

The fake publisher is real sockets all the way: an XML-RPC slave API answering requestTopic, and a TCP
server that answers the subscriber's header with a valid publisher header and then a 4 GiB length claim.
Each dial ends in a protocol error; the subscriber must back off (0.1 s doubling) and keep its log quiet.
"""

from __future__ import annotations

import asyncio
import logging
import struct
from typing import Any

import pytest

import mrosd
from mrosd.msg import get_message_class
from mrosd.wire.header import ConnectionHeader, encode_header
from mrosd.xmlrpc import XmlRpcClient, XmlRpcServer
from tests.rosenv import needs_ros

pytestmark = needs_ros

String = get_message_class("std_msgs/String")
WINDOW = 3.0


class GarbagePublisher:
    """Answers every subscriber with a valid header, then a frame claiming 4 GiB; counts the dials."""

    def __init__(self) -> None:
        self.dials = 0
        self.server: asyncio.Server | None = None
        self.slave: XmlRpcServer | None = None

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.dials += 1
        try:
            (length,) = struct.unpack("<I", await reader.readexactly(4))
            await reader.readexactly(length)
            reply = ConnectionHeader(
                callerid="/garbage", md5sum=String._md5sum, type=String._type, message_definition=String._full_text
            )
            writer.write(encode_header(reply) + struct.pack("<I", 0xFFFFFFFF) + b"\xde\xad" * 8)
            await writer.drain()
            await reader.read()  # until the subscriber hangs up
        except (OSError, asyncio.IncompleteReadError):
            pass
        finally:
            writer.close()

    async def request_topic(self, caller_id: str, topic: str, protocols: Any) -> list[Any]:
        assert self.server is not None
        return [1, "", ["TCPROS", "127.0.0.1", self.server.sockets[0].getsockname()[1]]]

    async def __aenter__(self) -> str:
        self.server = await asyncio.start_server(self._serve, "127.0.0.1", 0)
        self.slave = XmlRpcServer({"requestTopic": self.request_topic}, host="127.0.0.1", port=0)
        await self.slave.start()
        return f"http://127.0.0.1:{self.slave.port}/"

    async def __aexit__(self, *exc: object) -> None:
        if self.slave is not None:
            await self.slave.aclose()
        if self.server is not None:
            self.server.close()


async def test_a_publisher_sending_garbage_after_the_handshake_is_redialled_with_backoff(
    rosmaster: str, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING)
    fake = GarbagePublisher()
    async with fake as fake_uri, mrosd.Node("victim", master_uri=rosmaster, host="127.0.0.1", argv=[]) as node:
        await node.subscribe("/garbage", String)
        client = XmlRpcClient()
        try:
            code, _, _ = await client.call(node.uri, "publisherUpdate", "/master", "/garbage", [fake_uri])
        finally:
            await client.aclose()
        assert code == 1
        await asyncio.sleep(WINDOW)
        dials = fake.dials
        warnings = [r for r in caplog.records if r.levelno >= logging.WARNING and r.name.startswith("mrosd")]
    # Backoff 0.1, 0.2, 0.4, 0.8, 1.6 s: about 5 dials in 3 s (every 0.1 s would be about 30).
    assert 2 <= dials <= 7, f"{dials} dials in {WINDOW} s"
    assert len(warnings) <= 4, [r.getMessage() for r in warnings]
