"""XML-RPC values nested without end: refused at decode, in one clear fault, before any handler sees them.

expat and the stdlib's unmarshaller keep their own stacks, so a 5000-deep array decodes without a
RecursionError; the trouble came after. The master stored it, and from then on every reply that had to
encode it (getParam of it or of ``/``, so ``rosparam dump`` for everyone) failed with "maximum recursion
depth exceeded": one request poisoned the parameter tree for good. A node's slave API handed such values to
its handlers. The decoder now counts arrays and structs as it reads them and refuses past ``MAX_DEPTH``.
"""

from __future__ import annotations

import logging

import aiohttp
import pytest

from mrosd.errors import RemoteProtocolError
from mrosd.master import Master
from mrosd.xmlrpc import MAX_DEPTH, Fault, XmlRpcClient, XmlRpcServer, decode_call, decode_response

ARRAY = ("<value><array><data>", "</data></array></value>")
STRUCT = ("<value><struct><member><name>a</name>", "</member></struct></value>")


def nested_call(method: str, kind: tuple[str, str], depth: int) -> bytes:
    """``method("/caller", "/deep", value)`` with ``value`` ``depth`` arrays or structs deep around an int."""
    opening, closing = kind
    return (
        f"<?xml version='1.0'?><methodCall><methodName>{method}</methodName><params>"
        "<param><value><string>/caller</string></value></param><param><value><string>/deep</string></value></param>"
        "<param>" + opening * depth + "<value><int>1</int></value>" + closing * depth + "</param>"
        "</params></methodCall>"
    ).encode()


@pytest.mark.parametrize("kind", [ARRAY, STRUCT], ids=["arrays", "structs"])
def test_the_decoder_takes_max_depth_and_refuses_one_more(kind: tuple[str, str]) -> None:
    method, params = decode_call(nested_call("setParam", kind, MAX_DEPTH))
    assert method == "setParam" and len(params) == 3
    with pytest.raises(RemoteProtocolError, match=rf"nested deeper than {MAX_DEPTH}"):
        decode_call(nested_call("setParam", kind, MAX_DEPTH + 1))


@pytest.mark.parametrize("kind", [ARRAY, STRUCT], ids=["arrays", "structs"])
async def test_a_value_nested_5000_deep_is_refused_and_the_parameter_tree_stays_readable(
    kind: tuple[str, str], caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.DEBUG)
    async with Master(host="127.0.0.1", port=0) as master, aiohttp.ClientSession() as http:
        async with http.post(master.uri, data=nested_call("setParam", kind, 5000)) as resp:
            body = await resp.read()
        with pytest.raises(Fault, match="nested deeper than"):
            decode_response(body)
        async with XmlRpcClient() as client:
            code, _, tree = await client.call(master.uri, "getParam", "/caller", "/")
        assert code == 1 and "deep" not in tree
    assert not [r for r in caplog.records if r.exc_info], "a traceback was logged"


async def test_a_slave_api_handler_never_sees_a_value_nested_5000_deep(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG)
    seen: list[object] = []

    async def handler(*params: object) -> int:
        seen.append(params)
        return 1

    async with XmlRpcServer({"setParam": handler}, host="127.0.0.1") as server, aiohttp.ClientSession() as http:
        url = f"http://127.0.0.1:{server.port}/"
        async with http.post(url, data=nested_call("setParam", ARRAY, 5000)) as resp:
            body = await resp.read()
    with pytest.raises(Fault, match="nested deeper than"):
        decode_response(body)
    assert not seen
    assert not [r for r in caplog.records if r.exc_info], "a traceback was logged"
