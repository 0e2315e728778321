"""XML-RPC for every part of mrosd: the one codec (fast path included), the aiohttp server, the client.

Who uses what:

* The codec (``decode_call``/``decode_call_async``/``encode_response``/``encode_fault``/
  ``decode_response``/``encode_call``) is used by everything that speaks XML-RPC.
* ``XmlRpcServer`` (aiohttp) serves the nodes' slave APIs; the master uses only its ``call`` (dispatch,
  multicall, fault mapping) and is served by its own HTTP layer, ``mrosd.master.httpserver``.
* ``XmlRpcClient`` (aiohttp) makes every outgoing call: nodes to the master and to each other, the
  master's callbacks to nodes, the ``mros`` CLI.

The full decoder is the stdlib's ``xmlrpc.client.Unmarshaller`` fed by an expat parser that refuses
any DTD (``<!DOCTYPE``, hence every entity declaration) before it is read, as rosmaster (defusedxml)
does; references to undeclared entities are expat errors. ``fast_decode_call`` answers the Master
API's usual shape (ASCII strings, ints, booleans) with one regex and accepts nothing the full decoder
would refuse or decode differently (property-tested). Bodies larger than ``INCREMENTAL_DECODE_SIZE``
are decoded in slices with the event loop running in between (``decode_call_async``), so a big request
neither stalls the loop nor delays a shutdown. This module knows nothing of ROS semantics.
"""

from __future__ import annotations

import asyncio
import io
import logging
import re
import xml.parsers.expat
import xmlrpc.client
from collections.abc import Awaitable, Callable, Iterator, Mapping
from typing import Any

import aiohttp
from aiohttp import web
from aiohttp.web_protocol import RequestHandler

from mrosd.errors import LocalProtocolError, RemoteProtocolError, XmlRpcError, XmlRpcFault
from mrosd.lograte import RateLimitedLog
from mrosd.loop import close_server

log = logging.getLogger(__name__)
_ratelog = RateLimitedLog(log)

#: Largest request or response body accepted. ROS parameter trees (robot_description URDFs,
#: rosparam-loaded YAML) reach a few MB; 64 MiB leaves room while bounding memory per call.
MAX_BODY_SIZE = 64 * 1024 * 1024

#: Largest reply the master sends (beyond: a fault naming this budget) and the largest response our client
#: reads: a whole parameter tree or a big graph may exceed a request's MAX_BODY_SIZE, and our own client
#: must read any reply our master may legally send.
MAX_REPLY_SIZE = 128 * 1024 * 1024

#: Default timeout for one outgoing call, connect included.
DEFAULT_TIMEOUT = 10.0

# Fault codes, after the xmlrpc-epi "specification for fault code interoperability", except for an unknown
# method: rosmaster and rospy's slave API (SimpleXMLRPCServer under rosgraph) answer that with code 1.
FAULT_PARSE_ERROR = -32700
FAULT_INVALID_REQUEST = -32600
FAULT_METHOD_NOT_FOUND = 1
FAULT_INVALID_PARAMS = -32602
FAULT_INTERNAL_ERROR = -32603

Handler = Callable[..., Awaitable[Any]]


#: The name this module's users know; the class lives in mrosd.errors with the rest of the tree.
Fault = XmlRpcFault


# --- pure codec -------------------------------------------------------------------------------

#: Bodies larger than this are decoded by ``decode_call_async`` in slices of this size, yielding to the
#: event loop between slices (each slice costs expat and the unmarshaller a few milliseconds at most).
INCREMENTAL_DECODE_SIZE = 64 * 1024


class _DtdRefused(Exception):
    """Raised from inside expat's doctype callback: a DTD is never read, so no entity is ever declared."""


def _refuse_dtd(*_args: object) -> None:
    raise _DtdRefused("DTDs and entity declarations are not accepted")


class _Decoder:
    """An expat parser wired to the stdlib's XML-RPC unmarshaller, refusing DTDs; fed in one or more slices."""

    __slots__ = ("_parser", "_target")

    def __init__(self) -> None:
        target = xmlrpc.client.Unmarshaller(use_builtin_types=True)
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
    if isinstance(exc, _DtdRefused):
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


_PARAMS_HEAD = "<params>\n<param>\n"
_PARAMS_TAIL = "</param>\n</params>\n"

#: ``encode_value_chunks`` cuts its output into bytes objects of about this size.
VALUE_CHUNK = 256 * 1024


class _OverLimit(Exception):
    """Raised inside ``_ChunkWriter`` once its output passed its limit: the rest is not encoded."""


class _ChunkWriter:
    """Collects text pieces into bytes chunks of about ``VALUE_CHUNK``: no single join or copy of a whole value."""

    __slots__ = ("_limit", "_pending", "_size", "chunks", "total")

    def __init__(self, limit: int | None) -> None:
        self.chunks: list[bytes] = []
        self.total = 0
        self._limit = limit
        self._pending: list[str] = []
        self._size = 0

    def write(self, text: str) -> bool:
        """Add a piece; True when that completed a chunk (a good moment to let other work run)."""
        self._pending.append(text)
        self._size += len(text)
        if self._size >= VALUE_CHUNK:
            self.flush()
            return True
        return False

    def flush(self) -> None:
        if self._pending:
            chunk = "".join(self._pending).encode()
            self.chunks.append(chunk)
            self.total += len(chunk)
            self._pending = []
            self._size = 0
            if self._limit is not None and self.total > self._limit:
                raise _OverLimit


def _write_value(value: Any, w: _ChunkWriter) -> Iterator[None]:
    """The stdlib Marshaller's output for ``value``, piece by piece (its own code for any other type); yields
    after each completed chunk."""
    kind = type(value)
    if kind is str:
        if w.write("<value><string>"):
            yield
        for i in range(0, len(value), _ESCAPE_SLICE):
            if w.write(_escape(value[i : i + _ESCAPE_SLICE])):
                yield
        if w.write("</string></value>\n"):
            yield
    elif kind is bool:
        if w.write(f"<value><boolean>{int(value)}</boolean></value>\n"):
            yield
    elif kind is int:
        if not _INT_MIN <= value <= _INT_MAX:
            raise OverflowError("int exceeds XML-RPC limits")
        if w.write(f"<value><int>{value}</int></value>\n"):
            yield
    elif kind is float:
        if w.write(f"<value><double>{value!r}</double></value>\n"):
            yield
    elif value is None:
        if w.write("<value><nil/></value>"):
            yield
    elif kind is list or kind is tuple:
        w.write("<value><array><data>\n")
        for item in value:
            yield from _write_value(item, w)
        if w.write("</data></array></value>\n"):
            yield
    elif kind is dict:
        w.write("<value><struct>\n")
        for key, item in value.items():
            if not isinstance(key, str):
                raise TypeError("dictionary key must be string")
            w.write(f"<member>\n<name>{_escape(key)}</name>\n")
            yield from _write_value(item, w)
            if w.write("</member>\n"):
                yield
        if w.write("</struct></value>\n"):
            yield
    else:  # bytes, datetime, Binary, subclasses: the stdlib's own rules
        text = xmlrpc.client.dumps((value,), allow_none=True)
        if w.write(text[len(_PARAMS_HEAD) : len(text) - len(_PARAMS_TAIL)]):
            yield


class ValueEncoder:
    """Encodes one value a chunk per ``step()``, so an event loop can run other work in between.

    The result is the value's ``<value>...</value>`` exactly as the stdlib writes it inside any reply, as
    ``chunks`` of about ``VALUE_CHUNK`` bytes (``size`` in all): a big value encoded once and spliced into the
    replies of many callers (``reply_parts``) is never joined or copied whole. Past ``limit`` bytes encoding
    stops with ``over_limit`` set (memory never follows a value further).
    """

    __slots__ = ("_steps", "_writer", "over_limit")

    def __init__(self, value: Any, limit: int | None = None) -> None:
        self._writer = _ChunkWriter(limit)
        self._steps = _write_value(value, self._writer)
        self.over_limit = False

    @property
    def chunks(self) -> list[bytes]:
        return self._writer.chunks

    @property
    def size(self) -> int:
        return self._writer.total

    def step(self) -> bool:
        """Encode about one more chunk; False once done (or over the limit).

        Raises:
            LocalProtocolError: the value cannot be represented in XML-RPC.
            RuntimeError: a dict or list of the value changed size while it was being encoded.
        """
        try:
            next(self._steps)
            return True
        except StopIteration:
            self._writer.flush()
        except _OverLimit:
            self.over_limit = True
            self._writer.chunks.clear()
        except (OverflowError, TypeError, RecursionError) as exc:
            raise LocalProtocolError(f"cannot encode XML-RPC response: {exc}") from exc
        return False


def encode_value_chunks(value: Any, limit: int | None = None) -> tuple[list[bytes], int]:
    """``ValueEncoder`` run to the end: ``(chunks, size)``; past ``limit``, ``([], size so far)``.

    Raises:
        LocalProtocolError: the value cannot be represented in XML-RPC.
    """
    encoder = ValueEncoder(value, limit)
    while encoder.step():
        pass
    return encoder.chunks, encoder.size


def response_parts() -> tuple[bytes, bytes]:
    """``(prefix, suffix)``: ``prefix + b"".join(encode_value_chunks(v)[0]) + suffix`` is ``encode_response(v)``."""
    return _RESPONSE_HEAD.encode(), _RESPONSE_TAIL.encode()


def reply_parts(code: int, status: str) -> tuple[bytes, bytes]:
    """``(prefix, suffix)``: ``prefix + b"".join(encode_value_chunks(v)[0]) + suffix`` is
    ``encode_response([code, status, v])``."""
    head = [_RESPONSE_HEAD, "<value><array><data>\n"]
    if not (_dump(code, head) and _dump(status, head)):
        raise LocalProtocolError(f"cannot encode reply status {code!r}, {status!r}")
    return "".join(head).encode(), ("</data></array></value>\n" + _RESPONSE_TAIL).encode()


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


# --- fast path for the Master API's typical calls and replies ---------------------------------
# Profiling showed expat parser construction dominating the master's CPU per call. Nearly every Master
# API call carries only short ASCII strings, so those exact shapes are matched here; anything else
# (other types, entities, CDATA, comments, DTDs, non-ASCII, CR, odd whitespace) returns None and goes
# through the full decoder. Property tests check the fast path never accepts what the full decoder
# refuses and never decodes differently.

_WS = rb"[ \t\n\r]*"
# Printable ASCII and tab/LF, without < & ] (markup) and CR (expat turns CR and CRLF into LF).
_TEXT = rb"[\t\n\x20-\x25\x27-\x3b\x3d-\x5c\x5e-\x7e]*"
# Every run of whitespace is followed by a literal ``<`` (which it cannot contain), so a failing match
# backtracks linearly, never exponentially.


def _one_param(group: bytes) -> bytes:
    """One parameter and the whitespace after it; ``group`` opens the value groups (capturing or not)."""
    return (
        rb"<param>" + _WS + rb"<value>(?:<string>" + group + _TEXT + rb")</string>"
        rb"|<i4>" + group + rb"[-+]?[0-9]{1,9})</i4>"
        rb"|<int>" + group + rb"[-+]?[0-9]{1,9})</int>"
        rb"|<boolean>" + group + rb"[01])</boolean>|" + group + _TEXT + rb"))</value>" + _WS + rb"</param>" + _WS
    )


_CALL = re.compile(
    rb"(?:<\?xml version=(?:'1\.0'|\"1\.0\")(?: encoding=(?:'(?i:utf-8)'|\"(?i:utf-8)\"))?\?>)?"
    + _WS
    + rb"<methodCall>"
    + _WS
    + rb"<methodName>([A-Za-z0-9_.]{1,200})</methodName>"
    + _WS
    + rb"(?:<params>"
    + _WS
    + rb"((?:"
    + _one_param(b"(?:")
    + rb")*)</params>"
    + _WS
    + rb"|<params/>"
    + _WS
    + rb")?</methodCall>"
    + _WS,
    re.S,
)
_PARAM = re.compile(_one_param(b"("))


def fast_decode_call(body: bytes) -> tuple[str, tuple[Any, ...]] | None:
    """Decode a methodCall made only of ASCII strings, ints and booleans; None for anything else.

    One regex validates the whole call; ``findall`` then walks the (already validated) parameters.
    """
    call = _CALL.fullmatch(body)
    if call is None:
        return None
    text = call.group(2)
    if not text:
        return call.group(1).decode(), ()
    params: list[Any] = []
    for s, i4, i, b, untyped in _PARAM.findall(text):
        if i4 or i:
            params.append(int(i4 or i))
        elif b:
            params.append(b == b"1")
        else:  # <string> or untyped text (an empty string leaves both groups empty)
            params.append((s or untyped).decode())
    return call.group(1).decode(), tuple(params)


_RESPONSE_HEAD = "<?xml version='1.0'?>\n<methodResponse>\n<params>\n<param>\n"
_RESPONSE_TAIL = "</param>\n</params>\n</methodResponse>\n"
_INT_MIN, _INT_MAX = -(2**31), 2**31 - 1


def _escape(text: str) -> str:
    if "&" in text:
        text = text.replace("&", "&amp;")
    if "<" in text:
        text = text.replace("<", "&lt;")
    if ">" in text:
        text = text.replace(">", "&gt;")
    return text


#: Strings longer than this are escaped slice by slice: a thread encoding a 100 MB value then holds the GIL
#: for one slice at a time, not for a whole-string ``replace`` (escaping is per character, so slices agree).
_ESCAPE_SLICE = 256 * 1024


def _dump(value: Any, out: list[str]) -> bool:
    if isinstance(value, str):
        if len(value) > _ESCAPE_SLICE:
            out.append("<value><string>")
            out.extend(_escape(value[i : i + _ESCAPE_SLICE]) for i in range(0, len(value), _ESCAPE_SLICE))
            out.append("</string></value>\n")
            return True
        out.append(f"<value><string>{_escape(value)}</string></value>\n")
    elif value is True or value is False:
        out.append(f"<value><boolean>{int(value)}</boolean></value>\n")
    elif type(value) is int:
        if not _INT_MIN <= value <= _INT_MAX:
            return False
        out.append(f"<value><int>{value}</int></value>\n")
    elif type(value) is list or type(value) is tuple:
        out.append("<value><array><data>\n")
        for item in value:
            if not _dump(item, out):
                return False
        out.append("</data></array></value>\n")
    else:
        return False
    return True


def fast_encode_response(value: Any) -> bytes | None:
    """The stdlib's exact response bytes for strings, ints, booleans and (nested) lists; None otherwise."""
    out = [_RESPONSE_HEAD]
    try:
        if not _dump(value, out):
            return None
    except RecursionError:
        return None
    out.append(_RESPONSE_TAIL)
    return "".join(out).encode()


# --- server -----------------------------------------------------------------------------------


#: Seconds a request being handled when the server closes may take to finish (slave API calls take milliseconds).
_SHUTDOWN_TIMEOUT = 2.0


class XmlRpcServer:
    """An aiohttp XML-RPC server dispatching to a table of async handlers.

    Handlers are called as ``await handler(*params)``. A handler raising ``Fault`` answers with that
    fault; any other exception is logged and answered with an internal-error fault, so a caller's
    bad input can never stop the server. ``system.multicall`` and ``system.listMethods`` are built in.
    """

    def __init__(
        self,
        methods: Mapping[str, Handler],
        host: str = "0.0.0.0",
        port: int = 0,
        *,
        name: str = "xmlrpc",
        backlog: int = 1024,
        reuse_address: bool = True,
    ) -> None:
        self._methods = dict(methods)
        self._host = host
        self._port = port
        self._name = name
        self._backlog = backlog
        self._reuse_address = reuse_address
        self._runner: web.ServerRunner | None = None
        self._site: web.TCPSite | None = None
        self.port = 0

    async def start(self) -> None:
        """Bind and start serving; ``self.port`` holds the bound port afterwards."""
        server = _HalfCloseServer(self._handle_http, request_factory=_make_request, access_log=None)
        self._runner = web.ServerRunner(server, handle_signals=False, shutdown_timeout=_SHUTDOWN_TIMEOUT)
        await self._runner.setup()
        self._site = web.TCPSite(
            self._runner,
            self._host,
            self._port,
            backlog=self._backlog,
            reuse_address=self._reuse_address,
        )
        await self._site.start()
        listener = self._site._server
        sockets = getattr(listener, "sockets", None) or []
        self.port = sockets[0].getsockname()[1] if sockets else self._port

    async def aclose(self) -> None:
        """Stop serving and close every connection, the one accepted as the listener closed included."""
        runner, site = self._runner, self._site
        if runner is None:
            return
        self._runner = self._site = None
        listener = getattr(site, "_server", None)
        if listener is not None:
            await close_server(listener)  # what it accepted reaches aiohttp before aiohttp closes the connections
        await runner.cleanup()

    async def __aenter__(self) -> XmlRpcServer:
        await self.start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()

    async def _handle_http(self, request: web.BaseRequest) -> web.Response:
        if request.method != "POST":
            return web.Response(status=405, text="only POST is supported\n", headers={"Allow": "POST"})
        try:
            body = await request.read()
        except ConnectionError:  # the peer went away mid-body (aiohttp would log a traceback per connection)
            return web.Response(status=400, text="request cut short\n")
        except web.HTTPRequestEntityTooLarge:
            return _xml_response(encode_fault(FAULT_INVALID_REQUEST, f"request body exceeds {MAX_BODY_SIZE} bytes"))
        return _xml_response(await self.dispatch_body(body))

    async def dispatch_body(self, body: bytes) -> bytes:
        """Answer one request body with a response body; never raises."""
        try:
            method, params = await decode_call_async(body)
        except RemoteProtocolError as exc:
            log.warning("%s: %s", self._name, exc)
            return encode_fault(FAULT_PARSE_ERROR, str(exc))
        try:
            result = await self.call(method, params)
            return encode_response(result)
        except Fault as exc:
            return encode_fault(exc.code, exc.message)
        except LocalProtocolError as exc:
            log.warning("%s: %s returned an unencodable value: %s", self._name, method, exc)
            return encode_fault(FAULT_INTERNAL_ERROR, str(exc))

    async def call(self, method: str, params: tuple[Any, ...]) -> Any:
        """Dispatch one decoded call.

        Raises:
            Fault: unknown method, wrong arguments, or the handler failed.
        """
        if method == "system.multicall":
            return await self._multicall(params)
        if method == "system.listMethods":
            return sorted([*self._methods, "system.multicall", "system.listMethods"])
        handler = self._methods.get(method)
        if handler is None:
            raise Fault(FAULT_METHOD_NOT_FOUND, f'method "{method}" is not supported')
        try:
            return await handler(*params)
        except Fault:
            raise
        except TypeError as exc:
            # Wrong arity or argument types reaching a handler are the caller's fault.
            log.info("%s: bad call to %s: %s", self._name, method, exc)
            raise Fault(FAULT_INVALID_PARAMS, f"{method}: invalid parameters: {exc}") from exc
        except Exception as exc:
            log.exception("%s: handler %s failed", self._name, method)
            raise Fault(FAULT_INTERNAL_ERROR, f"{method}: internal error: {exc!r}") from exc

    async def _multicall(self, params: tuple[Any, ...]) -> list[Any]:
        if len(params) != 1 or not isinstance(params[0], list):
            raise Fault(FAULT_INVALID_PARAMS, "system.multicall takes one array of calls")
        results: list[Any] = []
        for entry in params[0]:
            if not isinstance(entry, dict) or not isinstance(entry.get("methodName"), str):
                results.append({"faultCode": FAULT_INVALID_PARAMS, "faultString": "malformed multicall entry"})
                continue
            if entry["methodName"] == "system.multicall":
                results.append({"faultCode": FAULT_INVALID_REQUEST, "faultString": "recursive multicall"})
                continue
            sub_params = entry.get("params", [])
            if not isinstance(sub_params, list):
                results.append({"faultCode": FAULT_INVALID_PARAMS, "faultString": "params must be an array"})
                continue
            try:
                results.append([await self.call(entry["methodName"], tuple(sub_params))])
            except Fault as exc:
                results.append({"faultCode": exc.code, "faultString": exc.message})
        return results


class _HalfCloseHandler(RequestHandler):
    """aiohttp's connection protocol, except that a request followed by the peer's EOF is still answered.

    A client may send its request and shut its write side (``shutdown(SHUT_WR)``) before reading the answer;
    rosmaster and rospy's servers execute and answer it. aiohttp closes the transport on EOF, cancelling a
    request it has received whole. Here, when every received request is whole, the write side stays open,
    they are answered in order, then the connection closes; a request cut short by the EOF can never be
    answered, so the connection closes at once as before.
    """

    __slots__ = ("last_body",)

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        #: The body of the request handed to the handler last (set by ``_make_request``): between aiohttp taking
        #: a request off its queue and starting its handler, no other attribute shows it.
        self.last_body: aiohttp.StreamReader | None = None

    def eof_received(self) -> bool | None:  # type: ignore[override]  # asyncio.Protocol allows True
        # ``_messages`` and ``_waiter`` are aiohttp's own (checked against the version pinned in [dev]); an
        # aiohttp without them gets its plain behaviour (close on EOF), never an AttributeError per connection.
        messages = getattr(self, "_messages", None)
        if messages is None or not hasattr(self, "_waiter"):
            return super().eof_received()  # type: ignore[no-any-return]
        bodies = [payload for _, payload in messages]
        if self.last_body is not None:
            bodies.append(self.last_body)
        if not all(body.is_eof() for body in bodies):
            return None  # a request cut short: close at once, as aiohttp does
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            return None  # idle between requests: nothing to answer
        self.close()  # answer what was received whole, then close
        return True

    def log_exception(self, *args: Any, **kw: Any) -> None:
        """aiohttp logs a traceback for every malformed request (a missing Host header, bad framing): one line
        each, at a bounded rate, since any peer can send them."""
        exc = kw.get("exc_info")
        text = args[0] % args[1:] if args and isinstance(args[0], str) else "error"
        detail = str(exc).replace("\n", " ").strip() if isinstance(exc, BaseException) else ""
        _ratelog.warning("http", "xmlrpc server: %s: %s", text, detail[:200] or type(exc).__name__)


class _HalfCloseServer(web.Server):
    """aiohttp's low-level server building ``_HalfCloseHandler`` protocols."""

    def __call__(self) -> RequestHandler:
        return _HalfCloseHandler(self, loop=self._loop, **self._kwargs)


def _make_request(
    message: Any, payload: aiohttp.StreamReader, protocol: RequestHandler, writer: Any, task: asyncio.Task[None]
) -> web.BaseRequest:
    """A request whose body may be as large as ``MAX_BODY_SIZE`` (aiohttp's default is 1 MiB)."""
    if isinstance(protocol, _HalfCloseHandler):
        protocol.last_body = payload
    return web.BaseRequest(
        message, payload, protocol, writer, task, asyncio.get_running_loop(), client_max_size=MAX_BODY_SIZE
    )


def _xml_response(body: bytes) -> web.Response:
    return web.Response(body=body, content_type="text/xml", charset="utf-8")


# --- client -----------------------------------------------------------------------------------


#: Request bodies from this size on are handed to aiohttp as a stream (written in chunks).
_LARGE_REQUEST = 1024 * 1024


async def _read_body(content: aiohttp.StreamReader) -> bytes | None:
    """The whole response body (every read until EOF, not just the first chunk); None beyond MAX_REPLY_SIZE."""
    chunks: list[bytes] = []
    size = 0
    while True:
        chunk = await content.read(MAX_REPLY_SIZE + 1 - size)
        if not chunk:
            return b"".join(chunks)
        chunks.append(chunk)
        size += len(chunk)
        if size > MAX_REPLY_SIZE:
            return None


class XmlRpcClient:
    """One aiohttp session for all outgoing XML-RPC calls of a process part.

    Create it inside a running event loop (or let the first call do so) and ``aclose()`` it.
    """

    def __init__(self, timeout: float = DEFAULT_TIMEOUT, limit: int = 256) -> None:
        self._timeout = timeout
        self._limit = limit
        self._session: aiohttp.ClientSession | None = None

    def _get_session(self) -> aiohttp.ClientSession:
        if self._session is None or self._session.closed:
            connector = aiohttp.TCPConnector(limit=self._limit, limit_per_host=0, force_close=False)
            self._session = aiohttp.ClientSession(
                connector=connector,
                headers={"Content-Type": "text/xml", "User-Agent": "mrosd"},
            )
        return self._session

    async def call(self, uri: str, method: str, *params: Any, timeout: float | None = None) -> Any:
        """Call ``method`` on the server at ``uri`` and return its single result value.

        Raises:
            Fault: the server answered with a fault.
            XmlRpcError: the server is unreachable, timed out, or answered with garbage.
        """
        body = encode_call(method, params)
        session = self._get_session()
        limit = self._timeout if timeout is None else timeout
        # aiohttp warns that big bytes bodies block the loop; a BytesIO is written in chunks instead.
        data_out: bytes | io.BytesIO = body if len(body) < _LARGE_REQUEST else io.BytesIO(body)
        try:
            async with asyncio.timeout(limit):
                async with session.post(uri, data=data_out) as resp:
                    if resp.status != 200:
                        raise XmlRpcError(f"{method} at {uri}: HTTP status {resp.status}")
                    if resp.content_length is not None and resp.content_length > MAX_REPLY_SIZE:
                        raise XmlRpcError(
                            f"{method} at {uri}: response of {resp.content_length} bytes exceeds the"
                            f" {MAX_REPLY_SIZE >> 20} MiB any mrosd master sends (MAX_REPLY_SIZE)"
                        )
                    data = await _read_body(resp.content)
                    if data is None:
                        raise XmlRpcError(
                            f"{method} at {uri}: response exceeds the {MAX_REPLY_SIZE >> 20} MiB any mrosd master"
                            " sends (MAX_REPLY_SIZE)"
                        )
        except TimeoutError as exc:
            raise XmlRpcError(f"{method} at {uri}: no answer within {limit:g} s") from exc
        except (aiohttp.ClientError, OSError, ValueError) as exc:
            raise XmlRpcError(f"{method} at {uri}: {exc or type(exc).__name__}") from exc
        try:
            return decode_response(data)
        except RemoteProtocolError as exc:
            raise XmlRpcError(f"{method} at {uri}: {exc}") from exc

    async def aclose(self) -> None:
        """Close the session and its pooled connections."""
        if self._session is not None:
            await self._session.close()
            self._session = None

    async def __aenter__(self) -> XmlRpcClient:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()
