"""XML-RPC for every part of mrosd: the one codec (fast path included), the dispatcher, the server, the client.

Who uses what:

* The codec (``codec``: ``decode_call``/``decode_call_async``/``encode_response``/``encode_fault``/
  ``decode_response``/``encode_call``, tried after the ``fastpath``) is used by everything that speaks
  XML-RPC; ``chunks`` encodes a big value a piece at a time for the master's replies.
* ``MethodTable`` (``methods``) dispatches a decoded call to a table of async handlers (multicall, fault
  mapping); the master uses it for its multicalls and slow calls.
* ``XmlRpcServer`` (``server``) serves a ``MethodTable`` (the nodes' slave APIs) over the project's one
  HTTP/1.1 server, the master's ``mrosd.master.httpserver``.
* ``XmlRpcClient`` (``client``, asyncio streams and ``mrosd.xmlrpc.httpclient``'s framing) makes every
  outgoing call: nodes to the master and to each other, the master's callbacks to nodes, the ``mros`` CLI.

None of them imports aiohttp (a node's start-up does not pay for it). The names are re-exported here lazily,
so the pure parts (``codec``, ``fastpath``, ``chunks``) import without the HTTP side. Nothing here knows ROS
semantics.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mrosd.xmlrpc.chunks import VALUE_CHUNK, ValueEncoder, encode_value_chunks, reply_parts, response_parts
    from mrosd.xmlrpc.client import DEFAULT_TIMEOUT, XmlRpcClient
    from mrosd.xmlrpc.codec import (
        FAULT_INTERNAL_ERROR,
        FAULT_INVALID_PARAMS,
        FAULT_INVALID_REQUEST,
        FAULT_METHOD_NOT_FOUND,
        FAULT_PARSE_ERROR,
        INCREMENTAL_DECODE_SIZE,
        MAX_BODY_SIZE,
        MAX_DEPTH,
        MAX_REPLY_SIZE,
        Fault,
        decode_call,
        decode_call_async,
        decode_response,
        encode_call,
        encode_fault,
        encode_response,
    )
    from mrosd.xmlrpc.fastpath import fast_decode_call, fast_encode_response
    from mrosd.xmlrpc.methods import Handler, MethodTable
    from mrosd.xmlrpc.server import XmlRpcServer

__all__ = [
    "DEFAULT_TIMEOUT",
    "FAULT_INTERNAL_ERROR",
    "FAULT_INVALID_PARAMS",
    "FAULT_INVALID_REQUEST",
    "FAULT_METHOD_NOT_FOUND",
    "FAULT_PARSE_ERROR",
    "INCREMENTAL_DECODE_SIZE",
    "MAX_BODY_SIZE",
    "MAX_DEPTH",
    "MAX_REPLY_SIZE",
    "VALUE_CHUNK",
    "Fault",
    "Handler",
    "MethodTable",
    "ValueEncoder",
    "XmlRpcClient",
    "XmlRpcServer",
    "decode_call",
    "decode_call_async",
    "decode_response",
    "encode_call",
    "encode_fault",
    "encode_response",
    "encode_value_chunks",
    "fast_decode_call",
    "fast_encode_response",
    "reply_parts",
    "response_parts",
]

#: Where each re-exported name lives.
_EXPORTS = {
    "FAULT_INTERNAL_ERROR": "mrosd.xmlrpc.codec",
    "FAULT_INVALID_PARAMS": "mrosd.xmlrpc.codec",
    "FAULT_INVALID_REQUEST": "mrosd.xmlrpc.codec",
    "FAULT_METHOD_NOT_FOUND": "mrosd.xmlrpc.codec",
    "FAULT_PARSE_ERROR": "mrosd.xmlrpc.codec",
    "INCREMENTAL_DECODE_SIZE": "mrosd.xmlrpc.codec",
    "MAX_BODY_SIZE": "mrosd.xmlrpc.codec",
    "MAX_DEPTH": "mrosd.xmlrpc.codec",
    "MAX_REPLY_SIZE": "mrosd.xmlrpc.codec",
    "Fault": "mrosd.xmlrpc.codec",
    "decode_call": "mrosd.xmlrpc.codec",
    "decode_call_async": "mrosd.xmlrpc.codec",
    "decode_response": "mrosd.xmlrpc.codec",
    "encode_call": "mrosd.xmlrpc.codec",
    "encode_fault": "mrosd.xmlrpc.codec",
    "encode_response": "mrosd.xmlrpc.codec",
    "fast_decode_call": "mrosd.xmlrpc.fastpath",
    "fast_encode_response": "mrosd.xmlrpc.fastpath",
    "VALUE_CHUNK": "mrosd.xmlrpc.chunks",
    "ValueEncoder": "mrosd.xmlrpc.chunks",
    "encode_value_chunks": "mrosd.xmlrpc.chunks",
    "reply_parts": "mrosd.xmlrpc.chunks",
    "response_parts": "mrosd.xmlrpc.chunks",
    "Handler": "mrosd.xmlrpc.methods",
    "MethodTable": "mrosd.xmlrpc.methods",
    "XmlRpcServer": "mrosd.xmlrpc.server",
    "DEFAULT_TIMEOUT": "mrosd.xmlrpc.client",
    "XmlRpcClient": "mrosd.xmlrpc.client",
}


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # cached: later lookups never reach __getattr__
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
