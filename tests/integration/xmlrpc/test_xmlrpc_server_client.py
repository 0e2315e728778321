"""The shared XML-RPC server and client over real loopback sockets."""

from __future__ import annotations

import asyncio
import contextlib
import io
import socket
import xmlrpc.client
from collections.abc import AsyncIterator

import aiohttp
import pytest

from mrosd import backports
from mrosd.errors import XmlRpcError
from mrosd.xmlrpc import (
    FAULT_INVALID_PARAMS,
    FAULT_METHOD_NOT_FOUND,
    FAULT_PARSE_ERROR,
    MAX_BODY_SIZE,
    Fault,
    XmlRpcClient,
    XmlRpcServer,
    decode_response,
)


async def _add(a: int, b: int) -> int:
    return a + b


async def _boom() -> None:
    raise RuntimeError("handler bug")


@pytest.fixture
async def server() -> AsyncIterator[XmlRpcServer]:
    async with XmlRpcServer({"add": _add, "boom": _boom}, "127.0.0.1", 0) as srv:
        yield srv


async def test_a_call_round_trips_through_server_and_client(server: XmlRpcServer) -> None:
    async with XmlRpcClient() as client:
        assert await client.call(f"http://127.0.0.1:{server.port}/", "add", 2, 3) == 5


async def test_unknown_method_wrong_arity_and_handler_bugs_become_faults(server: XmlRpcServer) -> None:
    uri = f"http://127.0.0.1:{server.port}/"
    async with XmlRpcClient() as client:
        with pytest.raises(Fault) as info:
            await client.call(uri, "nope")
        assert info.value.code == FAULT_METHOD_NOT_FOUND
        with pytest.raises(Fault) as info:
            await client.call(uri, "add", 1)
        assert info.value.code == FAULT_INVALID_PARAMS
        with pytest.raises(Fault, match="handler bug"):
            await client.call(uri, "boom")
        # the server still works afterwards
        assert await client.call(uri, "add", 1, 1) == 2


async def test_garbage_and_oversized_bodies_get_faults_not_crashes(server: XmlRpcServer) -> None:
    uri = f"http://127.0.0.1:{server.port}/"
    async with aiohttp.ClientSession() as session:
        async with session.post(uri, data=b"<methodCall><methodName>add</methodName><params><par") as resp:
            with pytest.raises(Fault) as info:
                decode_response(await resp.read())
            assert info.value.code == FAULT_PARSE_ERROR
        try:
            async with session.post(uri, data=io.BytesIO(b"x" * (MAX_BODY_SIZE + 10))) as resp:
                assert resp.status in (200, 413)
                if resp.status == 200:
                    with pytest.raises(Fault):
                        decode_response(await resp.read())
        except aiohttp.ClientError:
            pass  # the server may close the connection before reading the whole body; that is fine too
    async with XmlRpcClient() as client:
        assert await client.call(uri, "add", 40, 2) == 42


async def test_multicall_answers_each_call_separately(server: XmlRpcServer) -> None:
    uri = f"http://127.0.0.1:{server.port}/"
    async with XmlRpcClient() as client:
        calls = [{"methodName": "add", "params": [1, 2]}, {"methodName": "nope", "params": []}]
        result = await client.call(uri, "system.multicall", calls)
    assert result[0] == [3]
    assert result[1]["faultCode"] == FAULT_METHOD_NOT_FOUND


async def test_the_stdlib_client_in_a_thread_talks_to_the_server(server: XmlRpcServer) -> None:
    import asyncio

    with xmlrpc.client.ServerProxy(f"http://127.0.0.1:{server.port}") as proxy:
        assert await asyncio.to_thread(proxy.add, 20, 22) == 42


async def test_an_unreachable_server_is_a_clear_error() -> None:
    from tests.rosenv import free_port

    async with XmlRpcClient(timeout=2) as client:
        with pytest.raises(XmlRpcError, match=r"ping at http://127\.0\.0\.1"):
            await client.call(f"http://127.0.0.1:{free_port()}/", "ping")


@pytest.mark.parametrize("turns", [0, 1, 2, 3, 4])
async def test_aclose_closes_a_connection_accepted_as_it_was_closing(turns: int) -> None:
    """asyncio accepts a connection in one loop turn and hands it to its protocol in later ones (a task of
    its own); one that reaches aiohttp after its shutdown listed the connections must be closed all the same."""
    loop = asyncio.get_running_loop()
    srv = XmlRpcServer({"add": _add}, "127.0.0.1", 0)
    await srv.start()
    with socket.create_connection(("127.0.0.1", srv.port), timeout=5) as sock:  # the kernel completes it
        sock.setblocking(False)
        for _ in range(turns):  # let the server's loop get as far as accepting it, or further
            await asyncio.sleep(0)
        await srv.aclose()
        # the server's end is closed: EOF (or a reset) at once, not when this client gives up
        with contextlib.suppress(ConnectionResetError):
            assert await backports.wait_for(loop.sock_recv(sock, 1), 5.0) == b""
