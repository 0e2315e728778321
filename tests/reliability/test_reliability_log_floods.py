"""A peer's mistakes cost the robot's log one line per kind and period, never one line per mistake.

Any process that reaches a node's TCPROS port can repeat a refused handshake (a wrong md5) as fast as it
connects, any publisher can send bodies that do not decode, and any service client can send requests that make
the handler raise. Each of these was one warning per occurrence: a peer filled the journal at its own pace.
"""

from __future__ import annotations

import asyncio
import logging
import struct

import pytest

import mrosd
from mrosd import backports
from mrosd.msg import get_message_class, get_service_class
from mrosd.wire.header import encode_header
from tests.reliability.relnodes import start_master
from tests.rosenv import Processes

String = get_message_class("std_msgs/String")
SetBool = get_service_class("std_srvs/SetBool")

#: Repetitions of each mistake; at most a handful of lines may come of them.
REPEATS = 200
MAX_LINES = 10


async def _refused_handshakes(port: int, header: dict[str, str]) -> None:
    for _ in range(REPEATS):
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        writer.write(encode_header(header))
        await writer.drain()
        await backports.wait_for(reader.read(), 5.0)  # the error header, then EOF
        writer.close()


def _lines(caplog: pytest.LogCaptureFixture, text: str) -> int:
    return sum(text in r.getMessage() for r in caplog.records if r.levelno >= logging.INFO)


async def test_refused_subscribers_and_service_clients_are_a_few_lines(
    procs: Processes, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="mrosd")
    _, uri = start_master(procs)
    async with mrosd.Node("target", master_uri=uri, host="127.0.0.1", argv=[]) as node:
        await node.advertise("/chatter", String)
        await node.advertise_service("/set", SetBool, lambda req: {"success": True})
        wrong = "0" * 32
        await _refused_handshakes(
            node.tcpros_port, {"topic": "/chatter", "md5sum": wrong, "callerid": "/evil", "type": "std_msgs/String"}
        )
        await _refused_handshakes(node.tcpros_port, {"service": "/set", "md5sum": wrong, "callerid": "/evil"})
    assert 0 < _lines(caplog, "refusing subscriber") <= MAX_LINES
    assert 0 < _lines(caplog, "refusing client") <= MAX_LINES


async def test_a_handler_raising_for_every_request_is_a_few_lines(
    procs: Processes, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="mrosd")
    _, uri = start_master(procs)

    def handler(req: object) -> object:
        raise ValueError("no such thing")

    async with mrosd.Node("target", master_uri=uri, host="127.0.0.1", argv=[]) as node:
        await node.advertise_service("/set", SetBool, handler)
        proxy = node.service_proxy("/set", SetBool, persistent=True)
        for _ in range(REPEATS):
            with pytest.raises(mrosd.MrosError):
                await proxy.call(SetBool._request_class(data=True))
        await proxy.aclose()
    assert 0 < _lines(caplog, "handler raised") <= MAX_LINES


async def test_a_publisher_of_bodies_that_do_not_decode_is_a_few_lines(
    procs: Processes, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="mrosd")
    _, uri = start_master(procs)
    async with (
        mrosd.Node("evil", master_uri=uri, host="127.0.0.1", argv=[]) as evil,
        mrosd.Node("victim", master_uri=uri, host="127.0.0.1", argv=[]) as victim,
    ):
        got: list[str] = []
        last = asyncio.Event()

        def on_message(msg: object) -> None:
            got.append(msg.data)  # type: ignore[attr-defined]
            last.set()

        pub = await evil.advertise("/chatter", String)
        sub = await victim.subscribe("/chatter", String, callback=on_message)
        await pub.wait_for_subscribers(1, timeout=10)
        for _ in range(REPEATS):
            pub.publish_serialized(struct.pack("<I", 0x7FFFFFFF))  # a string of 2 GiB, in 4 bytes
        pub.publish_serialized(String(data="last").serialize())
        await backports.wait_for(last.wait(), 10)
        await sub.aclose()
    assert got == ["last"]
    assert 0 < _lines(caplog, "does not decode") <= MAX_LINES


async def test_failed_notifications_are_a_few_lines(caplog: pytest.LogCaptureFixture) -> None:
    """The daemon logs at INFO by default: 200 subscribers registered at an address where nothing answers (each
    then fails its publisherUpdate) were 200 lines."""
    from mrosd.master import Master
    from mrosd.xmlrpc import XmlRpcClient

    caplog.set_level(logging.INFO, logger="mrosd")
    async with Master("127.0.0.1", 0, cleanup_interval=0) as master:
        client = XmlRpcClient()
        try:
            for i in range(REPEATS):  # the discard port of 200 loopback addresses: refused at once
                dead = f"http://127.0.0.{i + 2}:9/"
                await client.call(master.uri, "registerSubscriber", f"/ghost{i}", "/t", "std_msgs/String", dead)
            await client.call(master.uri, "registerPublisher", "/pub", "/t", "std_msgs/String", "http://127.0.0.1:9/")
            async with backports.timeout(20):
                while master.api.notifier.failed < REPEATS:  # noqa: ASYNC110 - a counter, no event to wait on
                    await asyncio.sleep(0.05)
        finally:
            await client.aclose()
    assert 0 < _lines(caplog, "publisherUpdate") <= MAX_LINES
