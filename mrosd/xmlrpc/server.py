"""``XmlRpcServer``: the aiohttp server of the nodes' slave APIs, and the dispatch the master reuses.

Owns the HTTP side (POST only, body bound, a half-closed request still answered, one rate-limited line per
malformed request) and the dispatch of a decoded call to a table of async handlers (``system.multicall``,
``system.listMethods``, faults for unknown methods and failed handlers). Must not know what the handlers
mean; the bytes are ``mrosd.xmlrpc.codec``'s.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable, Mapping
from typing import Any

import aiohttp
from aiohttp import web
from aiohttp.web_protocol import RequestHandler

from mrosd.errors import LocalProtocolError, RemoteProtocolError
from mrosd.lograte import RateLimitedLog
from mrosd.loop import close_server
from mrosd.xmlrpc.codec import (
    FAULT_INTERNAL_ERROR,
    FAULT_INVALID_PARAMS,
    FAULT_INVALID_REQUEST,
    FAULT_METHOD_NOT_FOUND,
    FAULT_PARSE_ERROR,
    MAX_BODY_SIZE,
    Fault,
    decode_call_async,
    encode_fault,
    encode_response,
)

log = logging.getLogger(__name__)
_ratelog = RateLimitedLog(log)

Handler = Callable[..., Awaitable[Any]]


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
            _ratelog.warning("parse", "%s: %s", self._name, exc)  # any peer can send these: bounded
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
