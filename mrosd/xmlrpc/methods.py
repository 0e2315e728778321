"""``MethodTable``: a decoded XML-RPC call dispatched to a table of async handlers, no transport.

Owns ``system.multicall``, ``system.listMethods``, the faults for unknown methods, wrong arguments and failed
handlers, and one request body to one response body (``dispatch_body``). Used by the nodes' slave APIs
(``XmlRpcServer`` serves one over HTTP) and by the master (its multicalls and slow calls). Must not know what
the handlers mean; the bytes are ``mrosd.xmlrpc.codec``'s. Imports no HTTP stack.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable, Mapping
from typing import Any

from mrosd.errors import LocalProtocolError, RemoteProtocolError
from mrosd.lograte import RateLimitedLog
from mrosd.xmlrpc.codec import (
    FAULT_INTERNAL_ERROR,
    FAULT_INVALID_PARAMS,
    FAULT_INVALID_REQUEST,
    FAULT_METHOD_NOT_FOUND,
    FAULT_PARSE_ERROR,
    Fault,
    decode_call_async,
    encode_fault,
    encode_response,
)

log = logging.getLogger(__name__)
_ratelog = RateLimitedLog(log)

Handler = Callable[..., Awaitable[Any]]


class MethodTable:
    """A table of async handlers, called as ``await handler(*params)``.

    A handler raising ``Fault`` answers with that fault; any other exception is logged and answered with an
    internal-error fault, so a caller's bad input can never stop the server. ``system.multicall`` and
    ``system.listMethods`` are built in.
    """

    def __init__(self, methods: Mapping[str, Handler], *, name: str = "xmlrpc") -> None:
        self._methods = dict(methods)
        self._name = name

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
