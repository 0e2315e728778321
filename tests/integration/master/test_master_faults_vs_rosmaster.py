"""Faults a client sees, from our master and from Debian's rosmaster in the same test, through our client."""

from __future__ import annotations

from collections.abc import AsyncIterator

import aiohttp
import pytest

from mrosd.errors import RemoteProtocolError
from mrosd.master import Master
from mrosd.xmlrpc import Fault, XmlRpcClient, decode_response
from tests.rosenv import needs_ros

pytestmark = needs_ros


@pytest.fixture
async def ours() -> AsyncIterator[str]:
    async with Master("127.0.0.1", 0, advertise="127.0.0.1") as m:
        yield m.uri


async def test_an_unknown_method_is_fault_1_on_both_masters(ours: str, rosmaster: str) -> None:
    async with XmlRpcClient() as client:
        seen = {}
        for uri in (ours, rosmaster):
            with pytest.raises(Fault) as info:
                await client.call(uri, "noSuchMethod", "/c")
            assert 'method "noSuchMethod" is not supported' in info.value.message
            seen[uri] = info.value.code
            out = await client.call(uri, "system.multicall", [{"methodName": "nope", "params": []}])
            assert out[0]["faultCode"] == seen[uri]
        assert seen[ours] == seen[rosmaster] == 1


BAD_BODIES = [
    b'<?xml version="1.0"?><!DOCTYPE m [<!ENTITY e "x">]><methodCall><methodName>getPid</methodName>'
    b"<params><param><value>&e;</value></param></params></methodCall>",
    b"<methodCall><methodName>getPid</methodName><params><param><value><i4>5</int></value></param>"
    b"</params></methodCall>",
]


@pytest.mark.parametrize("body", BAD_BODIES, ids=["entity", "mismatched-tag"])
async def test_dtds_and_malformed_xml_are_refused_by_both_masters(ours: str, rosmaster: str, body: bytes) -> None:
    async with aiohttp.ClientSession() as http:
        for uri in (ours, rosmaster):
            async with http.post(uri, data=body, headers={"Content-Type": "text/xml"}) as resp:
                assert resp.status == 200
                with pytest.raises(Fault):
                    decode_response(await resp.read())
    with pytest.raises(RemoteProtocolError):
        decode_response(BAD_BODIES[0])
