"""A request whose sender shuts its write side (``shutdown(SHUT_WR)``) right after sending is executed and answered.

rosmaster (SimpleXMLRPCServer) reads the whole request, runs it and answers whatever the size. Ours once
answered only requests handled within the read that delivered them: a 100 KB setParam (decoded in slices, a
task) met the EOF first, the transport closed itself and the call was cancelled, neither run nor answered.
The same holds for the nodes' slave API server (``XmlRpcServer``, on the same HTTP server).
"""

from __future__ import annotations

import asyncio
import logging
import socket

import pytest

from mrosd import backports
from mrosd.xmlrpc import XmlRpcServer, decode_response, encode_call
from tests.reliability.test_reliability_master_http import MasterProcess, get_pid
from tests.rosenv import Processes, needs_ros, start_rosmaster

SIZES = [1024, 100 * 1024, 2 * 1024 * 1024]


def request(method: str, *params: object) -> bytes:
    body = encode_call(method, params)
    return b"POST / HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: text/xml\r\nContent-Length: %d\r\n\r\n%s" % (
        len(body),
        body,
    )


def split_response(data: bytes) -> tuple[bytes, bytes]:
    head, _, body = data.partition(b"\r\n\r\n")
    return head.split(b"\r\n", 1)[0], body


def half_closed(port: int, data: bytes) -> bytes:
    """Send ``data`` in one go, shut the write side, read until the server closes (what came back)."""
    with socket.create_connection(("127.0.0.1", port), timeout=20) as s:
        s.sendall(data)
        s.shutdown(socket.SHUT_WR)
        chunks = []
        while chunk := s.recv(1 << 16):
            chunks.append(chunk)
    return b"".join(chunks)


def set_param_half_closed(uri: str, key: str, size: int) -> None:
    port = int(uri.rstrip("/").rsplit(":", 1)[1])
    status, body = split_response(half_closed(port, request("setParam", "/hc", key, "x" * size)))
    assert status == b"HTTP/1.1 200 OK", f"{size} B setParam: no answer ({status!r})"
    assert decode_response(body)[0] == 1
    port_get = request("getParam", "/hc", key)
    status, body = split_response(half_closed(port, port_get))
    assert status == b"HTTP/1.1 200 OK"
    assert decode_response(body) == [1, f"Parameter [{key}]", "x" * size], f"{size} B setParam not executed"


@pytest.mark.parametrize("loop", ["asyncio", "uvloop"])
@pytest.mark.parametrize("size", SIZES)
def test_the_master_executes_and_answers_a_half_closed_request(procs: Processes, size: int, loop: str) -> None:
    master = MasterProcess(procs, loop=loop)
    set_param_half_closed(master.uri, f"/p{size}", size)
    assert get_pid(master.uri) == master.proc.pid


@needs_ros
@pytest.mark.interop
@pytest.mark.parametrize("size", SIZES)
def test_rosmaster_executes_and_answers_a_half_closed_request(procs: Processes, size: int) -> None:
    set_param_half_closed(start_rosmaster(procs), f"/p{size}", size)


async def test_a_partial_request_then_eof_is_closed_without_an_answer(procs: Processes) -> None:
    """Half a body then EOF can never complete: the connection closes at once, nothing runs."""
    master = MasterProcess(procs)
    whole = request("setParam", "/hc", "/partial", "x" * 100_000)
    reply = await asyncio.to_thread(half_closed, master.port, whole[:50_000])
    assert reply == b""
    _, body = split_response(await asyncio.to_thread(half_closed, master.port, request("hasParam", "/hc", "/p")))
    assert decode_response(body) == [1, "/p", False]


@pytest.mark.parametrize("size", SIZES)
async def test_a_slave_api_server_executes_and_answers_a_half_closed_request(size: int) -> None:
    seen: list[int] = []

    async def store(value: str) -> int:
        seen.append(len(value))
        return len(value)

    async with XmlRpcServer({"store": store}, "127.0.0.1", 0) as server:
        reply = await asyncio.to_thread(half_closed, server.port, request("store", "y" * size))
    status, body = split_response(reply)
    assert status == b"HTTP/1.1 200 OK", f"{size} B call: no answer ({status!r})"
    assert decode_response(body) == size
    assert seen == [size]


async def test_a_slave_api_server_closes_a_request_cut_short_by_eof(caplog: pytest.LogCaptureFixture) -> None:
    """Closed unexecuted, and quietly: aiohttp logged a traceback for each such connection."""
    called: list[str] = []

    async def store(value: str) -> int:
        called.append(value)
        return len(value)

    async with XmlRpcServer({"store": store}, "127.0.0.1", 0) as server:
        whole = request("store", "y" * 100_000)
        reply = await backports.wait_for(asyncio.to_thread(half_closed, server.port, whole[:50_000]), 10)
        assert reply == b"" and called == []
        _, body = split_response(await asyncio.to_thread(half_closed, server.port, request("store", "z")))
        assert decode_response(body) == 1
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING], caplog.text


async def test_malformed_requests_to_a_slave_api_are_logged_at_a_bounded_rate(caplog: pytest.LogCaptureFixture) -> None:
    """aiohttp logged a traceback (about 15 lines) for each request without a Host header, for instance; the
    slave API now shares the master's HTTP server (which, as rosmaster, needs no Host): a malformed field here."""

    async def ping() -> int:
        return 1

    async with XmlRpcServer({"ping": ping}, "127.0.0.1", 0) as server:
        bad = request("ping").replace(b"Host: 127.0.0.1\r\n", b"Host : 127.0.0.1\r\n")
        for _ in range(200):
            reply = await asyncio.to_thread(half_closed, server.port, bad)
            assert reply.startswith(b"HTTP/1.") and b" 400 " in reply.split(b"\r\n", 1)[0]
        _, body = split_response(await asyncio.to_thread(half_closed, server.port, request("ping")))
        assert decode_response(body) == 1
    lines = caplog.text.splitlines()
    assert len(lines) <= 10, caplog.text[:2000]
