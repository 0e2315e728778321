"""XML-RPC over aiohttp: the one server and the one client shared by the master and slave APIs.

The stdlib ``xmlrpc.client.loads``/``dumps`` are the pure codec; this module wraps them with size
limits and fault mapping, and adds the aiohttp transport. It knows nothing of ROS semantics.
"""

from __future__ import annotations

import asyncio
import logging
import xml.parsers.expat
import xmlrpc.client
from collections.abc import Awaitable, Callable, Mapping
from typing import Any

import aiohttp
from aiohttp import web

from mrosd.errors import LocalProtocolError, RemoteProtocolError, XmlRpcError

log = logging.getLogger(__name__)

#: Largest request or response body accepted. ROS parameter trees (robot_description URDFs,
#: rosparam-loaded YAML) reach a few MB; 64 MiB leaves room while bounding memory per call.
MAX_BODY_SIZE = 64 * 1024 * 1024

#: Default timeout for one outgoing call, connect included.
DEFAULT_TIMEOUT = 10.0

# Fault codes, after the xmlrpc-epi "specification for fault code interoperability".
FAULT_PARSE_ERROR = -32700
FAULT_INVALID_REQUEST = -32600
FAULT_METHOD_NOT_FOUND = -32601
FAULT_INVALID_PARAMS = -32602
FAULT_INTERNAL_ERROR = -32603

Handler = Callable[..., Awaitable[Any]]


class Fault(XmlRpcError):
    """An XML-RPC fault: raised by a handler to answer with it, or by the client when a server sent one."""

    def __init__(self, code: int, message: str) -> None:
        self.code = code
        self.message = message
        super().__init__(f"XML-RPC fault {code}: {message}")


# --- pure codec -------------------------------------------------------------------------------

#: Everything the stdlib parser raises on hostile input: expat errors, bad values (ValueError, OverflowError),
#: unknown encodings (LookupError), structural surprises (TypeError/KeyError/IndexError/AttributeError),
#: and xmlrpc.client.Error for responses/faults where a call was expected.
_DECODE_ERRORS = (
    xml.parsers.expat.ExpatError,
    ValueError,
    OverflowError,
    LookupError,
    TypeError,
    AttributeError,
    xmlrpc.client.Error,
)



def decode_call(body: bytes) -> tuple[str, tuple[Any, ...]]:
    """Parse a methodCall body.

    Raises:
        RemoteProtocolError: the body is not a well-formed methodCall.
    """
    if len(body) > MAX_BODY_SIZE:
        raise RemoteProtocolError(f"XML-RPC request of {len(body)} bytes exceeds {MAX_BODY_SIZE}")
    try:
        params, method = xmlrpc.client.loads(body, use_builtin_types=True)
    except _DECODE_ERRORS as exc:
        # A fault or response sent as a request lands here too (xmlrpc.client.Error).
        raise RemoteProtocolError(f"malformed XML-RPC request: {exc!r}") from exc
    if not method:
        raise RemoteProtocolError("XML-RPC request has no methodName")
    return method, params


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
    """Serialize a successful methodResponse.

    Raises:
        LocalProtocolError: the value cannot be represented in XML-RPC.
    """
    try:
        return xmlrpc.client.dumps((value,), methodresponse=True, allow_none=True).encode()
    except (OverflowError, TypeError) as exc:
        raise LocalProtocolError(f"cannot encode XML-RPC response: {exc}") from exc


def encode_fault(code: int, message: str) -> bytes:
    """Serialize a fault methodResponse."""
    return xmlrpc.client.dumps(xmlrpc.client.Fault(code, message), methodresponse=True).encode()


def decode_response(body: bytes) -> Any:
    """Parse a methodResponse body.

    Raises:
        Fault: the peer answered with a fault.
        RemoteProtocolError: the body is not a well-formed methodResponse.
    """
    if len(body) > MAX_BODY_SIZE:
        raise RemoteProtocolError(f"XML-RPC response of {len(body)} bytes exceeds {MAX_BODY_SIZE}")
    try:
        params, _ = xmlrpc.client.loads(body, use_builtin_types=True)
    except xmlrpc.client.Fault as exc:
        if not isinstance(exc.faultCode, int):
            raise RemoteProtocolError(f"malformed XML-RPC fault: code {exc.faultCode!r}") from exc
        raise Fault(exc.faultCode, str(exc.faultString)) from exc
    except _DECODE_ERRORS as exc:
        raise RemoteProtocolError(f"malformed XML-RPC response: {exc!r}") from exc
    if len(params) != 1:
        raise RemoteProtocolError(f"XML-RPC response carries {len(params)} values, expected 1")
    return params[0]


# --- server -----------------------------------------------------------------------------------


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
        self._runner: web.AppRunner | None = None
        self._site: web.TCPSite | None = None
        self.port = 0

    async def start(self) -> None:
        """Bind and start serving; ``self.port`` holds the bound port afterwards."""
        app = web.Application(client_max_size=MAX_BODY_SIZE)
        app.router.add_route("POST", "/{tail:.*}", self._handle_http)
        self._runner = web.AppRunner(app, access_log=None, handle_signals=False)
        await self._runner.setup()
        self._site = web.TCPSite(
            self._runner,
            self._host,
            self._port,
            backlog=self._backlog,
            reuse_address=self._reuse_address,
        )
        await self._site.start()
        server = self._site._server
        sockets = getattr(server, "sockets", None) or []
        self.port = sockets[0].getsockname()[1] if sockets else self._port

    async def aclose(self) -> None:
        """Stop serving and close every connection."""
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None

    async def __aenter__(self) -> XmlRpcServer:
        await self.start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()

    async def _handle_http(self, request: web.Request) -> web.Response:
        try:
            body = await request.read()
        except web.HTTPRequestEntityTooLarge:
            return _xml_response(encode_fault(FAULT_INVALID_REQUEST, f"request body exceeds {MAX_BODY_SIZE} bytes"))
        return _xml_response(await self.dispatch_body(body))

    async def dispatch_body(self, body: bytes) -> bytes:
        """Answer one request body with a response body; never raises."""
        try:
            method, params = decode_call(body)
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
            raise Fault(FAULT_METHOD_NOT_FOUND, f"method {method!r} is not supported")
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


def _xml_response(body: bytes) -> web.Response:
    return web.Response(body=body, content_type="text/xml", charset="utf-8")


# --- client -----------------------------------------------------------------------------------


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
        try:
            async with asyncio.timeout(limit):
                async with session.post(uri, data=body) as resp:
                    if resp.status != 200:
                        raise XmlRpcError(f"{method} at {uri}: HTTP status {resp.status}")
                    if resp.content_length is not None and resp.content_length > MAX_BODY_SIZE:
                        raise XmlRpcError(f"{method} at {uri}: response of {resp.content_length} bytes is too big")
                    data = await resp.content.read(MAX_BODY_SIZE + 1)
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
