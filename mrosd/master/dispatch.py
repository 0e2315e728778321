"""The master's request bodies to response bodies: a sync fast path, a reply cache, ``XmlRpcServer`` for the rest.

No HTTP and no sockets: ``mrosd.master.httpserver`` hands over each complete body and writes what comes back
(bytes, or a coroutine for calls that need the event loop). The XML-RPC codec is ``mrosd.xmlrpc``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Coroutine
from typing import Any, cast

from mrosd.errors import LocalProtocolError, RemoteProtocolError
from mrosd.lograte import RateLimitedLog
from mrosd.xmlrpc import (
    FAULT_INTERNAL_ERROR,
    FAULT_PARSE_ERROR,
    INCREMENTAL_DECODE_SIZE,
    Fault,
    XmlRpcServer,
    decode_call,
    decode_call_async,
    encode_fault,
    encode_response,
)

log = logging.getLogger(__name__)
_ratelog = RateLimitedLog(log)

SyncHandler = Callable[..., Any]

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
        if len(body) > INCREMENTAL_DECODE_SIZE:
            return self._large(body)
        try:
            method, params = decode_call(body)
        except RemoteProtocolError as exc:
            _ratelog.log(logging.INFO, "parse", "master: %s", exc)
            return encode_fault(FAULT_PARSE_ERROR, str(exc))
        return self._run(body, method, params)

    def _run(self, body: bytes, method: str, params: tuple[Any, ...]) -> bytes | Coroutine[Any, Any, bytes]:
        handler = self.sync_methods.get(method)
        if handler is None:
            return self._slow(method, params)
        try:
            reply = handler(*params)
            out = encode_response(reply)
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

    async def _large(self, body: bytes) -> bytes:
        """A big body: decoded in slices (the loop keeps running, a close cancels it), then run as usual."""
        try:
            method, params = await decode_call_async(body)
        except RemoteProtocolError as exc:
            _ratelog.log(logging.INFO, "parse", "master: %s", exc)
            return encode_fault(FAULT_PARSE_ERROR, str(exc))
        out = self._run(body, method, params)
        return out if type(out) is bytes else await cast(Coroutine[Any, Any, bytes], out)

    async def _slow(self, method: str, params: tuple[Any, ...]) -> bytes:
        try:
            return encode_response(await self.fallback.call(method, params))
        except Fault as exc:
            return encode_fault(exc.code, exc.message)
        except LocalProtocolError as exc:
            return encode_fault(FAULT_INTERNAL_ERROR, str(exc))
