"""The one XML-RPC codec: call and response bodies <-> Python values, with every limit a peer meets.

Owns the size limits (``MAX_BODY_SIZE``, ``MAX_REPLY_SIZE``), the nesting limit (``MAX_DEPTH``), the fault
codes, and the full decoder: the stdlib's ``xmlrpc.client.Unmarshaller`` fed by an expat parser that refuses
any DTD (``<!DOCTYPE``, hence every entity declaration) before it is read, as rosmaster (defusedxml) does;
references to undeclared entities are expat errors. Arrays and structs are counted as they open, so a value
nested past ``MAX_DEPTH`` is refused while it is read: expat and the unmarshaller keep their own stacks and
never raise RecursionError, but every encoder after them (our replies, a handler's) would. The fast path
(``mrosd.xmlrpc.fastpath``) is tried first and defers anything it does not match. Bodies larger than
``INCREMENTAL_DECODE_SIZE`` are decoded in slices with the event loop running in between
(``decode_call_async``), so a big request neither stalls the loop nor delays a shutdown. Must not know ROS
semantics, HTTP or sockets: pure but for that one ``asyncio.sleep(0)``.
"""

from __future__ import annotations

import asyncio
import xml.parsers.expat
import xmlrpc.client
from typing import Any

from mrosd.errors import LocalProtocolError, RemoteProtocolError, XmlRpcFault
from mrosd.xmlrpc.fastpath import fast_decode_call, fast_encode_response

#: Largest request or response body accepted. ROS parameter trees (robot_description URDFs,
#: rosparam-loaded YAML) reach a few MB; 64 MiB leaves room while bounding memory per call.
MAX_BODY_SIZE = 64 * 1024 * 1024

#: Largest reply the master sends (beyond: a fault naming this budget) and the largest response our client
#: reads: a whole parameter tree or a big graph may exceed a request's MAX_BODY_SIZE, and our own client
#: must read any reply our master may legally send.
MAX_REPLY_SIZE = 128 * 1024 * 1024

#: Deepest nesting of arrays and structs a value may have. rosparam's YAML trees are a few levels deep; the
#: stdlib's encoder spends three Python frames per level, so rosmaster itself cannot answer with a value much
#: deeper than 300 under the default recursion limit of 1000, and any reply holding it would fail for good.
MAX_DEPTH = 100

# Fault codes, after the xmlrpc-epi "specification for fault code interoperability", except for an unknown
# method: rosmaster and rospy's slave API (SimpleXMLRPCServer under rosgraph) answer that with code 1.
FAULT_PARSE_ERROR = -32700
FAULT_INVALID_REQUEST = -32600
FAULT_METHOD_NOT_FOUND = 1
FAULT_INVALID_PARAMS = -32602
FAULT_INTERNAL_ERROR = -32603


#: The name this module's users know; the class lives in mrosd.errors with the rest of the tree.
Fault = XmlRpcFault


#: Bodies larger than this are decoded by ``decode_call_async`` in slices of this size, yielding to the
#: event loop between slices (each slice costs expat and the unmarshaller a few milliseconds at most).
INCREMENTAL_DECODE_SIZE = 64 * 1024


class _DtdRefused(Exception):
    """Raised from inside expat's doctype callback: a DTD is never read, so no entity is ever declared."""


class _TooDeep(Exception):
    """Raised from inside expat's start-element callback once arrays and structs nest past ``MAX_DEPTH``."""


def _refuse_dtd(*_args: object) -> None:
    raise _DtdRefused("DTDs and entity declarations are not accepted")


class _Marks(list[int]):
    """The unmarshaller's stack of open arrays and structs (its ``_marks``), refusing to grow past ``MAX_DEPTH``.

    ``xmlrpc.client.Unmarshaller`` (Python 3.0 to 3.13) appends to ``_marks`` when an array or struct opens and
    pops when it closes, and never replaces the list: so the check costs one call per array or struct opened
    and nothing per other element (a check in every start-element callback cost the full decoder 10%).
    """

    __slots__ = ()

    def append(self, mark: int) -> None:
        if len(self) >= MAX_DEPTH:
            raise _TooDeep(f"a value nested deeper than {MAX_DEPTH} arrays and structs (MAX_DEPTH)")
        super().append(mark)


class _Decoder:
    """An expat parser wired to the stdlib's XML-RPC unmarshaller, refusing DTDs; fed in one or more slices."""

    __slots__ = ("_parser", "_target")

    def __init__(self) -> None:
        target = xmlrpc.client.Unmarshaller(use_builtin_types=True)
        target._marks = _Marks()  # type: ignore[attr-defined]
        parser = xml.parsers.expat.ParserCreate()
        parser.SetParamEntityParsing(xml.parsers.expat.XML_PARAM_ENTITY_PARSING_NEVER)
        parser.StartDoctypeDeclHandler = _refuse_dtd
        parser.EntityDeclHandler = _refuse_dtd
        parser.UnparsedEntityDeclHandler = _refuse_dtd
        parser.ExternalEntityRefHandler = _refuse_dtd  # type: ignore[assignment]
        parser.StartElementHandler = target.start
        parser.EndElementHandler = target.end
        parser.CharacterDataHandler = target.data
        parser.buffer_text = True
        target.xml(None, None)  # type: ignore[arg-type]  # str data: no decoding (as ExpatParser does)
        self._parser = parser
        self._target = target

    def feed(self, data: bytes | memoryview) -> None:
        self._parser.Parse(data, False)

    def close(self) -> tuple[tuple[Any, ...], str | None]:
        """Finish; ``(params, method name)``; raises ``xmlrpc.client.Fault`` for a fault response."""
        self._parser.Parse(b"", True)
        params = self._target.close()
        return params, self._target.getmethodname()


def _describe(exc: BaseException) -> str:
    """A one-line description of why untrusted XML was refused."""
    if isinstance(exc, _DtdRefused | _TooDeep):
        return str(exc)
    text = str(exc).splitlines()[0] if str(exc) else ""
    return f"{type(exc).__name__}: {text}"[:300]


def _loads(body: bytes) -> tuple[tuple[Any, ...], str | None]:
    decoder = _Decoder()
    decoder.feed(body)
    return decoder.close()


def _checked_call(result: tuple[tuple[Any, ...], str | None]) -> tuple[str, tuple[Any, ...]]:
    params, method = result
    if not method:
        raise RemoteProtocolError("XML-RPC request has no methodName")
    return method, params


def _check_size(body: bytes, what: str) -> None:
    if len(body) > MAX_BODY_SIZE:
        raise RemoteProtocolError(f"XML-RPC {what} of {len(body)} bytes exceeds {MAX_BODY_SIZE}")


def decode_call(body: bytes) -> tuple[str, tuple[Any, ...]]:
    """Parse a methodCall body (fast path first).

    Raises:
        RemoteProtocolError: the body is not a well-formed methodCall, or it carries a DTD.
    """
    fast = fast_decode_call(body)
    if fast is not None:
        return fast
    _check_size(body, "request")
    try:
        result = _loads(body)
    except Exception as exc:  # anything hostile XML makes expat or the unmarshaller raise
        # A fault or response sent as a request lands here too (xmlrpc.client.Fault, no method name).
        raise RemoteProtocolError(f"malformed XML-RPC request: {_describe(exc)}") from exc
    return _checked_call(result)


async def decode_call_async(body: bytes) -> tuple[str, tuple[Any, ...]]:
    """``decode_call`` that lets the event loop run (and a cancellation land) between slices of a big body.

    Raises:
        RemoteProtocolError: as ``decode_call``.
    """
    if len(body) <= INCREMENTAL_DECODE_SIZE:
        return decode_call(body)
    _check_size(body, "request")
    view = memoryview(body)
    try:
        decoder = _Decoder()
        for start in range(0, len(body), INCREMENTAL_DECODE_SIZE):
            decoder.feed(view[start : start + INCREMENTAL_DECODE_SIZE])
            await asyncio.sleep(0)
        result = decoder.close()
    except Exception as exc:
        raise RemoteProtocolError(f"malformed XML-RPC request: {_describe(exc)}") from exc
    return _checked_call(result)


def encode_call(method: str, params: tuple[Any, ...]) -> bytes:
    """Serialize a methodCall body.

    Raises:
        LocalProtocolError: a parameter cannot be represented in XML-RPC (e.g. int beyond 32 bits).
    """
    try:
        return xmlrpc.client.dumps(params, method, allow_none=True).encode()
    except (OverflowError, TypeError) as exc:
        raise LocalProtocolError(f"cannot encode XML-RPC call {method}: {exc}") from exc


def encode_response(value: Any) -> bytes:
    """Serialize a successful methodResponse (fast path first; same bytes as the stdlib's).

    Raises:
        LocalProtocolError: the value cannot be represented in XML-RPC.
    """
    fast = fast_encode_response(value)
    if fast is not None:
        return fast
    try:
        return xmlrpc.client.dumps((value,), methodresponse=True, allow_none=True).encode()
    except (OverflowError, TypeError, RecursionError) as exc:
        raise LocalProtocolError(f"cannot encode XML-RPC response: {exc}") from exc


def encode_fault(code: int, message: str) -> bytes:
    """Serialize a fault methodResponse."""
    return xmlrpc.client.dumps(xmlrpc.client.Fault(code, message), methodresponse=True).encode()


def decode_response(body: bytes) -> Any:
    """Parse a methodResponse body.

    Raises:
        Fault: the peer answered with a fault.
        RemoteProtocolError: the body is not a well-formed methodResponse, or it carries a DTD.
    """
    if len(body) > MAX_REPLY_SIZE:
        raise RemoteProtocolError(f"XML-RPC response of {len(body)} bytes exceeds MAX_REPLY_SIZE ({MAX_REPLY_SIZE})")
    try:
        params, _ = _loads(body)
    except xmlrpc.client.Fault as exc:
        if not isinstance(exc.faultCode, int):
            raise RemoteProtocolError(f"malformed XML-RPC fault: code {exc.faultCode!r}") from exc
        raise Fault(exc.faultCode, str(exc.faultString)) from exc
    except Exception as exc:
        raise RemoteProtocolError(f"malformed XML-RPC response: {_describe(exc)}") from exc
    if len(params) != 1:
        raise RemoteProtocolError(f"XML-RPC response carries {len(params)} values, expected 1")
    return params[0]
