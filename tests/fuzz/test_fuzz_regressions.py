"""Crashes the fuzzers found, pinned as tests. Strict xfails are bugs reported to the owning part.

When one is fixed its test passes, strict xfail turns that into a failure: delete the marker (and the matching
entry of KNOWN_*_ESCAPES in tests/fuzz/targets.py) in the same commit.
"""

from __future__ import annotations

import asyncio
import math
import socket
from pathlib import Path

import aiohttp
import pytest

from mrosd import backports
from mrosd.errors import RemoteProtocolError
from mrosd.xmlrpc import XmlRpcServer, decode_call, decode_response, encode_call, encode_fault

FAULT_AS_REQUEST = encode_fault(1, "x")
UNKNOWN_ENCODING = b'<?xml version="1.0" encoding="x-unknown"?><methodCall><methodName>a</methodName></methodCall>'
IXM_BAD_UTF8_TAG = b"\x82\xa2op\xa5\x80hello\xa4name\xa1n"  # {"op": b"\x80hello"...}: invalid UTF-8 in the tag


def test_a_fault_response_sent_as_a_request_is_a_protocol_error() -> None:
    with pytest.raises(RemoteProtocolError):
        decode_call(FAULT_AS_REQUEST)


def test_an_unknown_xml_encoding_is_a_protocol_error_both_ways() -> None:
    with pytest.raises(RemoteProtocolError):
        decode_call(UNKNOWN_ENCODING)
    with pytest.raises(RemoteProtocolError):
        decode_response(UNKNOWN_ENCODING.replace(b"methodCall", b"methodResponse"))


async def test_the_xmlrpc_server_answers_those_bodies_with_a_fault_not_an_http_500() -> None:
    async def get_pid(caller: str) -> list[object]:
        return [1, "", 42]

    async with XmlRpcServer({"getPid": get_pid}, "127.0.0.1", 0) as server, aiohttp.ClientSession() as http:
        url = f"http://127.0.0.1:{server.port}/"
        for body in (FAULT_AS_REQUEST, UNKNOWN_ENCODING):
            async with http.post(url, data=body, timeout=aiohttp.ClientTimeout(total=5)) as reply:
                assert reply.status == 200


async def test_the_xmlrpc_server_keeps_answering_after_those_bodies() -> None:
    async def get_pid(caller: str) -> list[object]:
        return [1, "", 42]

    async with XmlRpcServer({"getPid": get_pid}, "127.0.0.1", 0) as server, aiohttp.ClientSession() as http:
        url = f"http://127.0.0.1:{server.port}/"
        for body in (FAULT_AS_REQUEST, UNKNOWN_ENCODING, encode_call("getPid", ("/a",))):
            async with http.post(url, data=body, timeout=aiohttp.ClientTimeout(total=5)) as reply:
                last = await reply.read()
        assert decode_response(last) == [1, "", 42]


def test_an_ixm_request_with_invalid_utf8_is_a_protocol_error() -> None:
    from mrosd.ixm.protocol import decode_reply, decode_request

    with pytest.raises(RemoteProtocolError):
        decode_request(IXM_BAD_UTF8_TAG)
    with pytest.raises(RemoteProtocolError):
        decode_reply(IXM_BAD_UTF8_TAG)


async def test_the_ixm_daemon_disconnects_a_client_sending_invalid_utf8(tmp_path: Path) -> None:
    import struct

    from mrosd.ixm.server import IxmServer

    path = str(tmp_path / "ixm.sock")
    async with IxmServer(path):
        loop = asyncio.get_running_loop()
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as bad:
            bad.setblocking(False)
            await loop.sock_connect(bad, path)
            await loop.sock_sendall(bad, struct.pack("<I", len(IXM_BAD_UTF8_TAG)) + IXM_BAD_UTF8_TAG)
            assert await backports.wait_for(loop.sock_recv(bad, 100), 2.0) == b""


def test_a_message_definition_with_an_infinite_or_nan_float_constant_loads() -> None:
    from mrosd.msg import load_type

    cls = load_type("fz/InfConst", "float64 BIG=1e400\nfloat64 NOTHING=nan\nint32 x")
    assert math.inf == cls.BIG
