"""Hostile peers of a node's XML-RPC: its slave API server and its client, now on the project's own HTTP/1.1.

The slave API (``XmlRpcServer``) is served by the master's hardened HTTP server: each refusal below is a status
and a closed connection, and the server goes on answering the next caller. The client (``XmlRpcClient``) meets
servers that never finish a head, claim huge bodies, send endless chunks, trickle, or close a kept-alive
connection: each is one ``XmlRpcError`` within the call's timeout, never unbounded memory or a hang.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
from collections.abc import AsyncIterator, Awaitable, Callable

import pytest

from mrosd import backports
from mrosd.errors import XmlRpcError
from mrosd.master import httpconn
from mrosd.xmlrpc import MAX_REPLY_SIZE, XmlRpcClient, XmlRpcServer, encode_call, encode_response


async def _pid() -> int:
    return 42


def _post(body: bytes, extra: bytes = b"") -> bytes:
    return b"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: %d\r\n%s\r\n%s" % (len(body), extra, body)


async def _exchange(port: int, data: bytes, *, shut: bool = False) -> bytes:
    """Send ``data``, read until the server closes (bounded)."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(data)
        if shut:
            writer.write_eof()
        return await backports.wait_for(reader.read(), 10.0)
    finally:
        writer.close()


@contextlib.asynccontextmanager
async def _slave(**kw: object) -> AsyncIterator[XmlRpcServer]:
    async with XmlRpcServer({"getPid": _pid}, "127.0.0.1", 0, name="slave /t", **kw) as srv:  # type: ignore[arg-type]
        yield srv


async def _still_answers(srv: XmlRpcServer) -> None:
    async with XmlRpcClient(timeout=5) as client:
        assert await client.call(f"http://127.0.0.1:{srv.port}/", "getPid") == 42


@pytest.mark.parametrize(
    ("request_bytes", "status"),
    [
        (b"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: 999999999999\r\n\r\n", b"413"),
        (b"POST / HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n5\r\nhello\r\n0\r\n\r\n", b"411"),
        (b"POST / HTTP/1.1\r\nContent-Length: 4\r\nContent-Length: 5\r\n\r\nxxxx", b"400"),
        (b"POST / HTTP/1.1\r\nContent-Length: 4\r\nTransfer-Encoding: chunked\r\n\r\nxxxx", b"400"),
        (b"GET / HTTP/1.1\r\nHost: x\r\n\r\n", b"405"),
        (b"POST / HTTP/1.1\r\nX: " + b"a" * (70 * 1024) + b"\r\n\r\n", b"431"),
        (b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03" + b"\0" * 64 + b"\r\n\r\n", b"400"),
    ],
    ids=["huge-length", "chunked", "two-lengths", "smuggling", "get", "big-head", "tls-hello"],
)
async def test_the_slave_api_refuses_bad_framing_with_a_status_and_goes_on(request_bytes: bytes, status: bytes) -> None:
    async with _slave() as srv:
        answer = await _exchange(srv.port, request_bytes)
        assert answer.split(b"\r\n", 1)[0].split()[1] == status
        await _still_answers(srv)


async def test_the_slave_api_caps_its_connections() -> None:
    async with _slave(max_connections=4, max_connections_per_host=4) as srv:
        held = [await asyncio.open_connection("127.0.0.1", srv.port) for _ in range(4)]
        try:
            for reader, writer in held:  # each admitted and served
                writer.write(_post(encode_call("getPid", ())))
                assert (await backports.wait_for(reader.readuntil(b"\r\n\r\n"), 10)).startswith(b"HTTP/1.1 200")
            answer = await _exchange(srv.port, _post(encode_call("getPid", ())))
            assert answer.startswith(b"HTTP/1.1 503")
        finally:
            for _, writer in held:
                writer.close()


async def test_a_slowloris_on_the_slave_api_is_cut_off(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(httpconn, "REQUEST_TIMEOUT", 0.3)
    async with _slave() as srv:
        reader, writer = await asyncio.open_connection("127.0.0.1", srv.port)
        try:
            writer.write(b"POST / HTTP/1.1\r\nHost: x\r\nContent-Le")
            answer = await backports.wait_for(reader.read(4096), 10.0)
            assert answer.startswith(b"HTTP/1.1 408")
        finally:
            writer.close()
        await _still_answers(srv)


async def test_a_request_then_eof_is_answered_and_pipelined_requests_in_order() -> None:
    async with _slave() as srv:
        one = _post(encode_call("getPid", ()))
        answer = await _exchange(srv.port, one + one + one, shut=True)
        assert answer.count(b"HTTP/1.1 200") == 3
        assert answer.count(encode_response(42)) == 3


# --- the client against hostile servers -----------------------------------------------------------------------


@contextlib.asynccontextmanager
async def _server(
    answer: Callable[[asyncio.StreamReader, asyncio.StreamWriter], Awaitable[None]],
) -> AsyncIterator[str]:
    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            with contextlib.suppress(OSError, asyncio.IncompleteReadError, asyncio.LimitOverrunError):
                await reader.readuntil(b"\r\n\r\n")
                await answer(reader, writer)
        finally:
            writer.close()

    server = await asyncio.start_server(handle, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    try:
        yield f"http://127.0.0.1:{port}/"
    finally:
        server.close()
        with contextlib.suppress(TimeoutError):
            await backports.wait_for(server.wait_closed(), 2)


async def _endless_head(_: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
    w.write(b"HTTP/1.1 200 OK\r\n")
    for _ in range(200):
        w.write(b"X: " + b"a" * 1000 + b"\r\n")
        await w.drain()


async def _huge_length(_: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
    w.write(b"HTTP/1.1 200 OK\r\nContent-Length: %d\r\n\r\n" % (MAX_REPLY_SIZE + 1))
    await w.drain()


async def _endless_chunks(_: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
    w.write(b"HTTP/1.1 200 OK\r\nTransfer-Encoding: chunked\r\n\r\n")
    piece = b"100000\r\n" + b"a" * 0x100000 + b"\r\n"
    for _ in range(MAX_REPLY_SIZE // 0x100000 + 2):
        w.write(piece)
        await w.drain()


async def _endless_body(_: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
    w.write(b"HTTP/1.0 200 OK\r\n\r\n")
    piece = b"a" * 0x100000
    for _ in range(MAX_REPLY_SIZE // 0x100000 + 2):
        w.write(piece)
        await w.drain()


async def _trickle(_: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
    w.write(b"HTTP/1.1 200 OK\r\nContent-Length: 100\r\n\r\n")
    for _ in range(100):
        w.write(b"a")
        await w.drain()
        await asyncio.sleep(0.1)


async def _smuggling(_: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
    w.write(b"HTTP/1.1 200 OK\r\nContent-Length: 3\r\nContent-Length: 4\r\n\r\nabcd")
    await w.drain()


@pytest.mark.parametrize(
    ("answer", "match"),
    [
        (_endless_head, "head over"),
        (_huge_length, "MAX_REPLY_SIZE"),
        (_endless_chunks, "MAX_REPLY_SIZE"),
        (_endless_body, "MAX_REPLY_SIZE"),
        (_trickle, "no answer within"),
        (_smuggling, "more than one Content-Length"),
    ],
    ids=["endless-head", "huge-length", "endless-chunks", "endless-body", "trickle", "two-lengths"],
)
async def test_the_client_bounds_what_a_hostile_server_sends(
    answer: Callable[[asyncio.StreamReader, asyncio.StreamWriter], Awaitable[None]], match: str
) -> None:
    async with _server(answer) as uri, XmlRpcClient(timeout=3) as client:
        with pytest.raises(XmlRpcError, match=match):
            await client.call(uri, "getPid", "/c", timeout=1.0 if answer is _trickle else 10.0)


async def test_the_client_reuses_its_connection_and_survives_the_server_closing_it() -> None:
    async with _slave(idle_timeout=60) as srv, XmlRpcClient(timeout=5) as client:
        uri = f"http://127.0.0.1:{srv.port}/"
        assert await client.call(uri, "getPid") == 42
        assert await client.call(uri, "getPid") == 42
        assert srv.connections == 1  # kept alive, reused
        for conn in list(srv._http._live):  # type: ignore[union-attr]  # the server drops its idle connection
            conn.close()
        await asyncio.sleep(0)
        assert await client.call(uri, "getPid") == 42


async def test_the_client_answers_an_unreachable_server_with_one_error() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    async with XmlRpcClient(timeout=3) as client:
        with pytest.raises(XmlRpcError, match=r"getPid at http://127\.0\.0\.1"):
            await client.call(f"http://127.0.0.1:{port}/", "getPid")
