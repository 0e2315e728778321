"""Service calls over real sockets: large answers, and servers that lie about their answers."""

from __future__ import annotations

import asyncio
import contextlib
import struct
from collections.abc import AsyncIterator, Awaitable, Callable

import pytest

import mrosd
from mrosd import backports
from mrosd.errors import ServiceError
from mrosd.msg import get_service_class
from mrosd.wire.framing import FrameDecoder, encode_frame
from mrosd.wire.header import ConnectionHeader, encode_header
from mrosd.xmlrpc import XmlRpcClient
from tests.rosenv import needs_ros

pytestmark = needs_ros

SetBool = get_service_class("std_srvs/SetBool")
Answer = Callable[[asyncio.StreamReader, asyncio.StreamWriter], Awaitable[None]]


def node(name: str, master: str) -> mrosd.Node:
    return mrosd.Node(name, master_uri=master, argv=[], host="127.0.0.1")


async def test_a_large_answer_arrives_whole_and_calls_go_on_on_a_persistent_connection(rosmaster: str) -> None:
    text = "".join(chr(65 + i % 26) for i in range(3_000_000))  # several reads, the decoder's large-frame path
    async with node("server", rosmaster) as a, node("client", rosmaster) as b:
        await a.advertise_service("/big", SetBool, lambda r: SetBool._response_class(r.data, text if r.data else ""))
        async with b.service_proxy("/big", SetBool, persistent=True) as proxy:
            for data in (True, False, True):
                resp = await proxy(SetBool._request_class(data=data))
                assert (resp.success, resp.message) == (data, text if data else "")


@contextlib.asynccontextmanager
async def _liar(answer: Answer) -> AsyncIterator[str]:
    """A service server that accepts the handshake, reads one request, then answers with ``answer``."""

    async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        decoder = FrameDecoder()
        try:
            frames: list[bytes | bytearray] = []
            while len(frames) < 2:  # the client's connection header, then its request
                data = await reader.read(65536)
                if not data:
                    return
                frames += decoder.feed_frames(data)
                if len(frames) == 1:
                    writer.write(encode_header(ConnectionHeader(callerid="/liar", md5sum=SetBool._md5sum)))
            await answer(reader, writer)
            await writer.drain()
        finally:
            writer.close()

    server = await asyncio.start_server(serve, "127.0.0.1", 0)
    async with server:
        yield f"rosrpc://127.0.0.1:{server.sockets[0].getsockname()[1]}"


async def _sends(writer: asyncio.StreamWriter, data: bytes) -> None:
    writer.write(data)


async def _sends_and_waits(reader: asyncio.StreamReader, writer: asyncio.StreamWriter, data: bytes) -> None:
    """Keeps the connection open until the client closes it: the client must not wait for the rest."""
    writer.write(data)
    await writer.drain()
    async with backports.timeout(20):
        await reader.read()


_OK = SetBool._response_class(success=True, message="ok").serialize()
CASES: dict[str, tuple[Answer, str]] = {
    "a 4 GB claim": (lambda r, w: _sends_and_waits(r, w, b"\x01" + struct.pack("<I", 0xFFFFFFF0)), "the limit is"),
    "two answers to one request": (lambda r, w: _sends(w, encode_frame(_OK, ok=True) * 2), "more than one answer"),
    "no answer": (lambda r, w: _sends(w, b""), "closed the connection before answering"),
    "half an answer": (lambda r, w: _sends(w, encode_frame(_OK, ok=True)[:-1]), "closed the connection before"),
}


@pytest.mark.parametrize("case", sorted(CASES))
async def test_a_lying_server_costs_the_caller_one_clear_error(rosmaster: str, case: str) -> None:
    answer, text = CASES[case]
    async with node("client", rosmaster) as b, _liar(answer) as uri:
        master = XmlRpcClient()
        try:
            code, msg, _ = await master.call(rosmaster, "registerService", "/liar", "/lie", uri, "http://127.0.0.1:9/")
            assert code == 1, msg
        finally:
            await master.aclose()
        proxy = b.service_proxy("/lie", SetBool)
        with pytest.raises(ServiceError, match=text) as err:
            await proxy.call(SetBool._request_class(data=True), timeout=10)
        assert "\n" not in str(err.value)
        assert proxy._conn is None  # the connection is dropped, never reused
