"""A lean HTTP/1.1 transport for the master's XML-RPC: an ``asyncio.Protocol``, no web framework.

Why: the master answers thousands of tiny calls per second and aiohttp's request machinery cost more
than the XML-RPC work itself (profiled). This module only frames HTTP; the XML-RPC codec and
dispatch stay in ``mrosd.xmlrpc`` (``decode_call``/``encode_response``/``encode_fault`` and
``XmlRpcServer.call`` for everything that is not a plain synchronous master method).

Supported: POST with Content-Length, keep-alive (HTTP/1.1 default, HTTP/1.0 with the header),
pipelined requests answered in order, ``Expect: 100-continue``. Backpressure: a client that does
not read its responses (transport write buffer full) is not read from until it does. Refused with a status and a closed
connection: other methods (405), chunked bodies (411), bodies over ``MAX_BODY_SIZE`` (413), header
blocks over ``MAX_HEADER_SIZE`` (431), garbage (400), and peers outside the allow-list (403).
"""

from __future__ import annotations

import asyncio
import functools
import ipaddress
import logging
import re
import socket
from collections.abc import Callable, Coroutine
from typing import Any, cast

from mrosd.errors import LocalProtocolError, RemoteProtocolError
from mrosd.xmlrpc import (
    FAULT_INTERNAL_ERROR,
    FAULT_PARSE_ERROR,
    MAX_BODY_SIZE,
    Fault,
    XmlRpcServer,
    decode_call,
    encode_fault,
    encode_response,
)

log = logging.getLogger(__name__)

#: Largest request line + headers accepted.
MAX_HEADER_SIZE = 64 * 1024

#: Largest body a client outside the allow-list may send before its 403 (it is read, never handled).
MAX_REFUSED_BYTES = 64 * 1024

#: Time a client has to complete a request once its first byte arrived (slowloris defence). Idle keep-alive
#: connections with nothing pending are not timed out: rospy and roscpp keep theirs open between calls.
REQUEST_TIMEOUT = 30.0

# Header fields, matched on the lower-cased header block (which starts with the line break).
_CONTENT_LENGTH = re.compile(rb"\r\ncontent-length:[ \t]*(?:([0-9]{1,12})[ \t]*(?=\r\n|$)|.*)")
_CONNECTION = re.compile(rb"\r\nconnection:[ \t]*(close|keep-alive)[ \t]*(?=\r\n|$)")

Network = ipaddress.IPv4Network | ipaddress.IPv6Network
SyncHandler = Callable[..., Any]

_REASONS = {
    400: b"Bad Request",
    403: b"Forbidden",
    405: b"Method Not Allowed",
    408: b"Request Timeout",
    411: b"Length Required",
    413: b"Payload Too Large",
    431: b"Request Header Fields Too Large",
}


def allowed(networks: list[Network] | None, host: str | None) -> bool:
    """Whether a peer address is inside one of ``networks`` (None allows everyone)."""
    if networks is None:
        return True
    if not host:
        return False
    try:
        addr = ipaddress.ip_address(host.split("%", 1)[0])
    except ValueError:
        return False
    if isinstance(addr, ipaddress.IPv6Address) and addr.ipv4_mapped is not None:
        addr = addr.ipv4_mapped
    return any(addr in net for net in networks)


# --- fast path for the master's typical calls -------------------------------------------------
# Profiling showed expat parser construction in xmlrpc.client.loads dominating the master's CPU per
# call. Nearly every Master API call carries only short ASCII strings, so those exact shapes are
# matched here; anything else (other types, entities, CDATA, comments, non-ASCII, odd whitespace)
# returns None and goes through mrosd.xmlrpc.decode_call. Tests check both give identical results.

_WS = rb"[ \t\n\r]*"
_TEXT = rb"[\t\n\x20-\x25\x27-\x3b\x3d-\x5c\x5e-\x7e]*"  # printable ASCII without < & ]
# One parameter and the whitespace after it. Every run of whitespace is followed by a literal ``<``
# (which it cannot contain), so a failing match backtracks linearly, never exponentially.


def _one_param(group: bytes) -> bytes:
    """One parameter and the whitespace after it; ``group`` opens the value groups (capturing or not)."""
    return (
        rb"<param>" + _WS + rb"<value>(?:<string>" + group + _TEXT + rb")</string>"
        rb"|<(?:i4|int)>" + group + rb"[-+]?[0-9]{1,9})</(?:i4|int)>"
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
    for s, i, b, untyped in _PARAM.findall(text):
        if i:
            params.append(int(i))
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


def _dump(value: Any, out: list[str]) -> bool:
    if isinstance(value, str):
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
    if not _dump(value, out):
        return None
    out.append(_RESPONSE_TAIL)
    return "".join(out).encode()


#: Bounds of ``XmlRpcHttpHandler``'s reply cache: entries, total reply bytes, largest request body kept.
#: When full, new replies are simply not kept until the next change of state empties the cache.
REPLY_CACHE_SIZE = 1024
REPLY_CACHE_BYTES = 16 * 1024 * 1024
REPLY_CACHE_MAX_BODY = 4096


class XmlRpcHttpHandler:
    """Turns one request body into one response body: sync fast path, else the shared XmlRpcServer.

    Replies of read-only methods (``cacheable``) are kept, keyed by the exact request body, for as
    long as ``state_version()`` returns the same value: a repeated getSystemState/lookupNode/getParam
    is answered without decoding, running or encoding anything. Any change of state empties the cache.
    """

    def __init__(
        self,
        sync_methods: dict[str, SyncHandler],
        fallback: XmlRpcServer,
        *,
        cacheable: frozenset[str] = frozenset(),
        state_version: Callable[[], object] | None = None,
    ) -> None:
        self.sync_methods = sync_methods
        self.fallback = fallback
        self._cacheable = cacheable if state_version is not None else frozenset()
        self._state_version = state_version
        self._cache: dict[bytes, bytes] = {}
        self._cache_bytes = 0
        self._cache_version: object = None

    def handle(self, body: bytes) -> bytes | Coroutine[Any, Any, bytes]:
        """The response body, or a coroutine producing it for calls that need the event loop."""
        if self._state_version is not None:
            version = self._state_version()
            if version != self._cache_version:
                self._cache.clear()
                self._cache_bytes = 0
                self._cache_version = version
            else:
                hit = self._cache.get(body)
                if hit is not None:
                    return hit
        fast = fast_decode_call(body)
        try:
            method, params = fast if fast is not None else decode_call(body)
        except RemoteProtocolError as exc:
            log.info("master: %s", exc)
            return encode_fault(FAULT_PARSE_ERROR, str(exc))
        handler = self.sync_methods.get(method)
        if handler is None:
            return self._slow(method, params)
        try:
            reply = handler(*params)
            out = fast_encode_response(reply) or encode_response(reply)
        except LocalProtocolError as exc:
            return encode_fault(FAULT_INTERNAL_ERROR, str(exc))
        except Exception as exc:  # the handlers catch their own errors; this is the last guard
            log.exception("master: %s failed", method)
            return encode_fault(FAULT_INTERNAL_ERROR, f"{method}: internal error: {exc!r}")
        if (
            method in self._cacheable
            and len(body) <= REPLY_CACHE_MAX_BODY
            and len(self._cache) < REPLY_CACHE_SIZE
            and self._cache_bytes + len(out) <= REPLY_CACHE_BYTES
        ):
            self._cache[body] = out
            self._cache_bytes += len(out)
        return out

    async def _slow(self, method: str, params: tuple[Any, ...]) -> bytes:
        try:
            return encode_response(await self.fallback.call(method, params))
        except Fault as exc:
            return encode_fault(exc.code, exc.message)
        except LocalProtocolError as exc:
            return encode_fault(FAULT_INTERNAL_ERROR, str(exc))


class _Request:
    """A parsed header block; ``body_start`` counts from the first byte of the request."""

    __slots__ = ("body_start", "keep_alive", "length")

    def __init__(self, body_start: int, length: int, keep_alive: bool) -> None:
        self.body_start = body_start
        self.length = length
        self.keep_alive = keep_alive


class _Refused(Exception):
    def __init__(self, status: int, text: bytes) -> None:
        super().__init__(status)
        self.status = status
        self.text = text


def parse_head(head: bytes) -> tuple[int, bool, bool]:
    """``(content_length, keep_alive, expect_continue)`` of a header block (without the blank line).

    A pure function of the bytes, so short header blocks are cached (``_parse_short_head``):
    clients repeat the same headers call after call.

    Raises:
        _Refused: the status and text to answer with before closing.
    """
    line_end = head.find(b"\r\n")
    parts = (head if line_end < 0 else head[:line_end]).split()
    if len(parts) != 3 or not parts[2].startswith(b"HTTP/1."):
        raise _Refused(400, b"malformed request line\n")
    if parts[0] != b"POST":
        raise _Refused(405, b"only POST is supported\n")
    keep_alive = parts[2] != b"HTTP/1.0"
    length: int | None = None
    expect_continue = False
    fields = head[line_end:].lower() if line_end >= 0 else b""
    if fields:
        if b"\r\ntransfer-encoding" in fields:
            raise _Refused(411, b"chunked bodies are not supported; send Content-Length\n")
        m = _CONTENT_LENGTH.search(fields)
        if m is not None:
            if m.group(1) is None:
                raise _Refused(400, b"bad Content-Length\n")
            length = int(m.group(1))
        m = _CONNECTION.search(fields)
        if m is not None:
            keep_alive = m.group(1) == b"keep-alive"
        expect_continue = b"\r\nexpect:" in fields and b"100-continue" in fields
    if length is None:
        raise _Refused(411, b"Content-Length required\n")
    if length > MAX_BODY_SIZE:
        raise _Refused(413, b"request body too large\n")
    return length, keep_alive, expect_continue


#: Header blocks up to this size are looked up in ``_parse_short_head``'s cache (256 entries).
_CACHED_HEAD_SIZE = 1024
_parse_short_head = functools.lru_cache(maxsize=256)(parse_head)


class HttpProtocol(asyncio.Protocol):
    """One client connection: parse requests, answer them in order."""

    def __init__(
        self, handler: XmlRpcHttpHandler, networks: list[Network] | None, live: set[asyncio.Transport]
    ) -> None:
        self._handler = handler
        self._live = live
        self._networks = networks
        self._buf = bytearray()
        self._transport: asyncio.Transport | None = None
        self._request: _Request | None = None
        self._busy = False
        self._closed = False
        self._reading_paused = False
        self._timer: asyncio.TimerHandle | None = None
        self._refused = False

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._transport = cast(asyncio.Transport, transport)  # uvloop's transports are not subclasses
        self._live.add(self._transport)
        peer = transport.get_extra_info("peername")
        host = peer[0] if isinstance(peer, tuple) and peer else None
        if not allowed(self._networks, host):
            # Answered once its request is in (closing at once races the client's send into a broken pipe
            # instead of a readable 403); MAX_REFUSED_BYTES bounds what such a client may send first.
            log.warning("master: refusing connection from %s (not in the allow-list)", host)
            self._refused = True
            return
        sock = transport.get_extra_info("socket")
        if sock is not None:
            try:
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            except OSError:
                pass

    def connection_lost(self, exc: Exception | None) -> None:
        if self._transport is not None:
            self._live.discard(self._transport)
        self._closed = True
        self._buf.clear()
        self._disarm()

    def data_received(self, data: bytes) -> None:
        if self._closed:
            return
        if self._buf or self._busy:
            self._buf += data
            self._process()
        else:  # the usual case: whole requests in one read, answered straight from ``data``
            pos = self._consume(data)
            if pos < len(data) and not self._closed:
                self._buf += memoryview(data)[pos:]
        if self._buf and self._timer is None and not self._closed:
            # Armed once per pending request, not per byte: trickling bytes cannot extend it.
            self._timer = asyncio.get_running_loop().call_later(REQUEST_TIMEOUT, self._timed_out)
        if self._busy and len(self._buf) > MAX_HEADER_SIZE and self._transport is not None:
            self._transport.pause_reading()  # a pipelining client waits while a slow call runs
            self._reading_paused = True

    def _disarm(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _timed_out(self) -> None:
        self._timer = None
        if self._closed or not self._buf:
            return
        if self._busy:  # the pending bytes wait on our own slow call, not on the client
            self._timer = asyncio.get_running_loop().call_later(REQUEST_TIMEOUT, self._timed_out)
            return
        peer = self._transport.get_extra_info("peername") if self._transport is not None else None
        log.info("master: closing %s: request incomplete after %g s", peer, REQUEST_TIMEOUT)
        self._fail(408, b"request not completed in time\n")

    def pause_writing(self) -> None:
        # The client does not read its responses: stop reading its requests until it does.
        if self._transport is not None and not self._closed:
            self._transport.pause_reading()

    def resume_writing(self) -> None:
        if self._transport is not None and not self._closed and not self._reading_paused:
            self._transport.resume_reading()

    def _fail(self, status: int, text: bytes) -> None:
        if self._transport is None or self._closed:
            return
        head = b"HTTP/1.1 %d %s\r\nContent-Type: text/plain\r\nContent-Length: %d\r\nConnection: close\r\n\r\n" % (
            status,
            _REASONS.get(status, b"Error"),
            len(text),
        )
        self._transport.write(head + text)
        self._transport.close()
        self._closed = True
        self._buf.clear()

    def _parse_head(self, buf: bytes | bytearray, pos: int) -> _Request | None:
        """Parse the header block starting at ``buf[pos]``; None while incomplete (or after failing)."""
        end = buf.find(b"\r\n\r\n", pos, pos + MAX_HEADER_SIZE + 4)
        if end < 0:
            if len(buf) - pos > MAX_HEADER_SIZE:
                self._fail(431, b"header block too large\n")
            return None
        try:
            head = bytes(buf[pos:end])
            parse = _parse_short_head if len(head) <= _CACHED_HEAD_SIZE else parse_head
            length, keep_alive, expect_continue = parse(head)
        except _Refused as exc:
            self._fail(exc.status, exc.text)
            return None
        if expect_continue and self._transport is not None:
            self._transport.write(b"HTTP/1.1 100 Continue\r\n\r\n")
        return _Request(end + 4 - pos, length, keep_alive)

    def _process(self) -> None:
        """Answer the complete requests in the buffer (after a slow call, or with a partial request)."""
        if self._busy or self._closed or not self._buf:
            return
        pos = self._consume(self._buf)
        if pos and not self._closed:
            del self._buf[:pos]

    def _consume(self, buf: bytes | bytearray) -> int:
        """Answer every complete request at the start of ``buf``, in order; returns the bytes used.

        Stops at an incomplete request (kept in ``self._request`` once its head is parsed), at a
        call that needs the event loop (``self._busy``), or when the connection fails.
        """
        pos = 0
        size = len(buf)
        handle = self._handler.handle
        while pos < size and not self._busy and not self._closed:
            req = self._request
            if req is None:
                req = self._parse_head(buf, pos)
                if req is None:
                    return pos
                self._request = req
            start = pos + req.body_start
            stop = start + req.length
            if self._refused and (size >= stop or req.length > MAX_REFUSED_BYTES):
                self._fail(403, b"client address not allowed\n")
                return pos
            if size < stop:
                return pos
            body = bytes(buf[start:stop])
            pos = stop
            self._request = None
            if self._timer is not None:
                self._disarm()
            result = handle(body)
            if type(result) is bytes:
                self._respond(result, req.keep_alive)
            else:
                self._busy = True
                task = asyncio.get_running_loop().create_task(cast(Coroutine[Any, Any, bytes], result))
                task.add_done_callback(functools.partial(self._finished, keep_alive=req.keep_alive))
        return pos

    def _finished(self, task: asyncio.Task[bytes], *, keep_alive: bool) -> None:
        self._busy = False
        if self._reading_paused and self._transport is not None and not self._closed:
            self._reading_paused = False
            self._transport.resume_reading()
        if task.cancelled():
            return
        exc = task.exception()
        out = encode_fault(FAULT_INTERNAL_ERROR, f"internal error: {exc!r}") if exc else task.result()
        self._respond(out, keep_alive)
        self._process()

    def _respond(self, body: bytes, keep_alive: bool) -> None:
        if self._transport is None or self._closed:
            return
        conn = b"keep-alive" if keep_alive else b"close"
        self._transport.write(
            b"HTTP/1.1 200 OK\r\nContent-Type: text/xml\r\nContent-Length: %d\r\nConnection: %s\r\n\r\n%s"
            % (len(body), conn, body)
        )
        if not keep_alive:
            self._transport.close()
            self._closed = True


class HttpServer:
    """The listening socket plus every open connection (so closing really closes them all)."""

    def __init__(self, handler: XmlRpcHttpHandler, networks: list[Network] | None) -> None:
        self._handler = handler
        self._networks = networks
        self._live: set[asyncio.Transport] = set()
        self._server: asyncio.Server | None = None
        self.port = 0

    async def start(self, host: str, port: int, backlog: int = 1024) -> None:
        """Bind and listen; ``.port`` is the bound port afterwards."""
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(
            lambda: HttpProtocol(self._handler, self._networks, self._live),
            host,
            port,
            backlog=backlog,
            reuse_address=True,
        )
        self.port = int(self._server.sockets[0].getsockname()[1])

    async def aclose(self) -> None:
        """Stop listening and abort every open connection."""
        if self._server is not None:
            self._server.close()
            for transport in list(self._live):
                transport.abort()
            self._live.clear()
            await self._server.wait_closed()
            self._server = None
