"""The master's HTTP framing over real sockets: keep-alive, pipelining, refusals, multicall, bounded queues."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator

import pytest

from mrosd import backports
from mrosd.master import Master
from mrosd.master.notifier import Notifier
from mrosd.master.registry import publisher_update
from mrosd.xmlrpc import XmlRpcClient, decode_response, encode_call
from tests.rosenv import free_port


@pytest.fixture
async def master() -> AsyncIterator[Master]:
    async with Master("127.0.0.1", 0, advertise="127.0.0.1") as m:
        yield m


def request(body: bytes, version: bytes = b"HTTP/1.1", extra: bytes = b"") -> bytes:
    return b"POST / %s\r\nContent-Type: text/xml\r\n%sContent-Length: %d\r\n\r\n%s" % (
        version,
        extra,
        len(body),
        body,
    )


async def read_response(reader: asyncio.StreamReader) -> tuple[bytes, bytes]:
    head = await backports.wait_for(reader.readuntil(b"\r\n\r\n"), 5)
    length = next(
        int(line.split(b":", 1)[1]) for line in head.split(b"\r\n") if line.lower().startswith(b"content-length")
    )
    return head, await backports.wait_for(reader.readexactly(length), 5)


async def test_pipelined_requests_on_one_connection_are_answered_in_order(master: Master) -> None:
    reader, writer = await asyncio.open_connection("127.0.0.1", master.port)
    try:
        writer.write(
            request(encode_call("setParam", ("/c", "/x", 1)))
            + request(encode_call("getParam", ("/c", "/x")))
            + request(encode_call("getParam", ("/c", "/missing")))
        )
        codes = [decode_response((await read_response(reader))[1])[0] for _ in range(3)]
        assert codes == [1, 1, -1]
    finally:
        writer.close()


async def test_http_1_0_requests_are_answered_then_closed(master: Master) -> None:
    reader, writer = await asyncio.open_connection("127.0.0.1", master.port)
    try:
        writer.write(request(encode_call("getUri", ("/c",)), version=b"HTTP/1.0"))
        head, body = await read_response(reader)
        assert b"200 OK" in head and decode_response(body)[2] == master.uri
        assert await backports.wait_for(reader.read(), 5) == b""
    finally:
        writer.close()


@pytest.mark.parametrize(
    ("raw", "status"),
    [
        (b"GET / HTTP/1.1\r\nHost: x\r\n\r\n", b"405"),
        (b"POST / HTTP/1.1\r\nTransfer-Encoding: chunked\r\n\r\n", b"411"),
        (b"POST / HTTP/1.1\r\nHost: x\r\n\r\n", b"411"),
        (b"POST / HTTP/1.1\r\nContent-Length: 99999999999\r\n\r\n", b"413"),
        (b"POST / HTTP/1.1\r\nContent-Length: -3\r\n\r\n", b"400"),
        (b"garbage\r\n\r\n", b"400"),
        (b"POST / HTTP/1.1\r\nX: " + b"a" * 70000 + b"\r\n\r\n", b"431"),
        # request smuggling: which length frames the body is ambiguous
        (b"POST / HTTP/1.1\r\nContent-Length: 4\r\nContent-Length: 40\r\n\r\nabcd", b"400"),
        (b"POST / HTTP/1.1\r\nContent-Length: 4\r\nTransfer-Encoding: chunked\r\n\r\n0\r\n\r\n", b"400"),
        (b"POST / HTTP/1.1\r\nContent-Length : 4\r\n\r\nabcd", b"400"),
    ],
)
async def test_bad_http_is_refused_with_a_status_and_the_master_keeps_serving(
    master: Master, raw: bytes, status: bytes
) -> None:
    reader, writer = await asyncio.open_connection("127.0.0.1", master.port)
    try:
        writer.write(raw)
        head = await backports.wait_for(reader.readuntil(b"\r\n\r\n"), 5)
        assert head.split(b" ")[1] == status
    finally:
        writer.close()
    async with XmlRpcClient() as client:
        assert (await client.call(master.uri, "getUri", "/c"))[2] == master.uri


async def test_multicall_goes_through_the_shared_dispatcher(master: Master) -> None:
    async with XmlRpcClient() as client:
        calls = [
            {"methodName": "setParam", "params": ["/c", "/m", 5]},
            {"methodName": "getParam", "params": ["/c", "/m"]},
            {"methodName": "nope", "params": []},
        ]
        out = await client.call(master.uri, "system.multicall", calls)
        assert out[1] == [[1, "Parameter [/m]", 5]]
        assert out[2]["faultCode"] == 1  # as rosmaster: every fault has code 1


async def test_a_full_notification_queue_drops_its_oldest_entries() -> None:
    async with XmlRpcClient() as client:
        notifier = Notifier(client, timeout=0.5, max_queue=3, max_failures=100)
        dead = f"http://127.0.0.1:{free_port()}/"
        notifier.submit([publisher_update(dead, f"/t{i}", []) for i in range(10)])
        assert notifier.backlog(dead) <= 3
        assert notifier.dropped >= 6
        await notifier.drain()
        await notifier.aclose()


async def test_a_dead_target_is_backed_off_instead_of_retried_for_every_notification() -> None:
    async with XmlRpcClient() as client:
        notifier = Notifier(client, timeout=0.5, max_failures=2)
        dead = f"http://127.0.0.1:{free_port()}/"
        for i in range(40):
            notifier.submit([publisher_update(dead, f"/t{i}", [])])
            await asyncio.sleep(0.005)
        assert notifier.failed < 20
        await notifier.aclose()


async def test_a_client_trickling_a_request_is_cut_off_while_idle_keep_alive_clients_stay(
    master: Master, monkeypatch: pytest.MonkeyPatch
) -> None:
    from mrosd.master import httpconn

    monkeypatch.setattr(httpconn, "REQUEST_TIMEOUT", 0.3)
    slow_reader, slow_writer = await asyncio.open_connection("127.0.0.1", master.port)
    idle_reader, idle_writer = await asyncio.open_connection("127.0.0.1", master.port)
    try:
        idle_writer.write(request(encode_call("getUri", ("/c",))))
        await read_response(idle_reader)
        for chunk in (b"POST / HTTP/1.1\r\n", b"Content-Le", b"ngth: 10\r\n"):
            slow_writer.write(chunk)
            await asyncio.sleep(0.1)
        head = await backports.wait_for(slow_reader.readuntil(b"\r\n\r\n"), 5)
        assert head.split(b" ")[1] == b"408"
        # read() returning at all means the server closed the connection after its explanation
        assert await backports.wait_for(slow_reader.read(), 5) == b"request not completed in time\n"
        # the idle keep-alive connection had nothing pending: it is still served
        idle_writer.write(request(encode_call("getUri", ("/c",))))
        _, body = await read_response(idle_reader)
        assert decode_response(body)[2] == master.uri
    finally:
        slow_writer.close()
        idle_writer.close()


async def test_requests_split_at_every_byte_and_pipelined_with_a_slow_call_keep_their_order(master: Master) -> None:
    calls = [
        request(encode_call("setParam", ("/c", "/split", 7))),
        request(encode_call("system.multicall", ([{"methodName": "getParam", "params": ["/c", "/split"]}],))),
        request(encode_call("getParam", ("/c", "/split"))),
        request(encode_call("hasParam", ("/c", "/nope"))),
    ]
    stream = b"".join(calls)
    reader, writer = await asyncio.open_connection("127.0.0.1", master.port)
    try:
        for i in range(0, len(stream), 7):  # odd chunks: heads and bodies cut anywhere
            writer.write(stream[i : i + 7])
            await writer.drain()
        replies = [decode_response((await read_response(reader))[1]) for _ in calls]
        assert replies[0][0] == 1
        assert replies[1] == [[[1, "Parameter [/split]", 7]]]
        assert replies[2][2] == 7
        assert replies[3][2] is False
    finally:
        writer.close()


async def test_repeated_read_calls_see_every_change_of_state(master: Master) -> None:
    reader, writer = await asyncio.open_connection("127.0.0.1", master.port)

    async def call(method: str, *params: object) -> list[object]:
        writer.write(request(encode_call(method, ("/c", *params))))
        return list(decode_response((await read_response(reader))[1]))

    try:
        api = "http://127.0.0.1:9/"
        assert (await call("getSystemState"))[2] == [[], [], []]
        assert (await call("getSystemState"))[2] == [[], [], []]  # answered again, unchanged
        await call("registerPublisher", "/t", "std_msgs/String", api)
        assert (await call("getSystemState"))[2][0] == [["/t", ["/c"]]]
        assert (await call("getPublishedTopics", ""))[2] == [["/t", "std_msgs/String"]]
        await call("registerPublisher", "/t", "std_msgs/Int32", api)  # same node, new type
        assert (await call("getPublishedTopics", ""))[2] == [["/t", "std_msgs/Int32"]]
        await call("unregisterPublisher", "/t", api)
        assert (await call("getSystemState"))[2] == [[], [], []]
        assert (await call("lookupNode", "/c"))[0] == -1
        await call("setParam", "/p", 1)
        assert (await call("getParam", "/p"))[2] == 1
        await call("setParam", "/p", 2)
        assert (await call("getParam", "/p"))[2] == 2
        await call("deleteParam", "/p")
        assert (await call("getParam", "/p"))[0] == -1
        assert (await call("hasParam", "/p"))[2] is False
    finally:
        writer.close()
