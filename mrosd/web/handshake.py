"""The aiohttp side of admission: the ``Host``/``Origin`` middleware of both web ports, and the first op of a
rosbridge client that authenticates with rosbridge's ``auth`` op, read within a deadline and a small frame.

The rules themselves are pure, in ``mrosd.web.admission``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable
from typing import Any

from aiohttp import WSMsgType, web
from aiohttp._websocket import reader_py
from aiohttp.http_exceptions import HttpProcessingError

from mrosd.lograte import RateLimitedLog
from mrosd.web import rosbridge as rb
from mrosd.web.admission import OriginGate

log = logging.getLogger(__name__)
_ratelog = RateLimitedLog(log)

__all__ = ["AUTH_FRAME", "AUTH_TIMEOUT", "AuthFirstResponse", "PeerErrorLog", "gate_middleware", "read_auth"]

#: Seconds a client that has not authenticated may take to send its ``auth`` op: a script or a browser on the
#: robot's network sends it in its first round trip; a stranger holding the connection open is closed.
AUTH_TIMEOUT = 5.0
#: Largest frame read before a client has authenticated. roslibjs's auth op (mac, client, dest, rand, t,
#: level, end) is a few hundred bytes; 16 KiB leaves room for long tokens and a few small ops a client may
#: send right after it, and bounds what a stranger makes the daemon hold (x the pending connections).
AUTH_FRAME = 16 * 1024


class PeerErrorLog(logging.LoggerAdapter):  # type: ignore[type-arg]
    """The logger aiohttp's request handler writes to (``AppRunner(logger=...)``): a request it cannot parse
    (a header line over 8 KiB, a malformed header, a bad chunk) is the peer's doing, and aiohttp logs each with
    its traceback at ERROR; here it is one line, rate-limited over all peers. Any other error (ours) keeps
    its traceback."""

    def __init__(self) -> None:
        super().__init__(logging.getLogger("aiohttp.server"), {})

    def exception(self, msg: object, *args: object, exc_info: Any = True, **kwargs: Any) -> None:
        if isinstance(exc_info, HttpProcessingError):
            remote = str(args[0]) if args else "?"
            _ratelog.warning(
                "malformed http", "web: refused a malformed HTTP request from %s: %s", remote, _reason(exc_info)
            )
            return
        super().exception(msg, *args, exc_info=exc_info, **kwargs)


def _reason(exc: HttpProcessingError) -> str:
    """The error on one line, at most 200 characters (aiohttp's message quotes what the peer sent)."""
    return " ".join(f"{exc.code} {type(exc).__name__} {exc.message}".split())[:200]


def gate_middleware(gate: OriginGate, page_port: Callable[[], int]) -> Any:
    """Refuse (403) any request whose ``Host`` we do not answer to, and any WebSocket handshake or
    state-changing request whose ``Origin`` is a page other than ours (``OriginGate``)."""

    @web.middleware
    async def middleware(
        request: web.Request, handler: Callable[[web.Request], Awaitable[web.StreamResponse]]
    ) -> web.StreamResponse:
        upgrade = request.headers.get("Upgrade", "").lower() == "websocket"
        checks_origin = upgrade or request.method not in ("GET", "HEAD", "OPTIONS")
        origin = request.headers.get("Origin") if checks_origin else None
        why = gate.refusal(request.headers.get("Host"), origin, page_port())
        if why is not None:
            _ratelog.warning("gate", "web: refused %s from %s: %s", request.path[:100], request.remote, why)
            raise web.HTTPForbidden(text=why + "\n")
        return await handler(request)

    return middleware


class _AuthReader(reader_py.WebSocketReader):
    """aiohttp's pure-Python frame reader, which lifts its own frame limit at the frame that authenticates.

    It must be the reader, not the handler reading its messages: a client may send a big op right behind its
    auth op, in the same TCP segment, and the reader parses both before the handler sees the first.
    """

    #: (the limit to lift to, the token check) until a frame authenticates; None after
    lift: tuple[int, Callable[[str], bool]] | None = None

    def _handle_frame(self, fin: bool, opcode: int, payload: bytes | bytearray, compressed: int) -> None:
        super()._handle_frame(fin, opcode, payload, compressed)
        if self.lift is None or not fin or opcode != 0x1 or len(payload) > AUTH_FRAME:
            return
        max_frame, token_ok = self.lift
        try:
            op = rb.decode_auth(bytes(payload))
        except rb.RosbridgeRefusal:
            return
        if op.op == "auth" and token_ok(op.mac):
            self.lift = None
            self._max_msg_size = max_frame
            self._max_fragments = max(1024, max_frame // 256) if max_frame else 0


class AuthFirstResponse(web.WebSocketResponse):
    """A WebSocket whose frame limit is ``AUTH_FRAME`` until the client's ``auth`` op, then ``max_frame``.

    aiohttp's compiled frame reader fixes its limit when the socket opens; this response reads with aiohttp's
    pure-Python reader (the same parser, its limit an attribute), which lifts the limit itself at the frame
    that authenticates (``_AuthReader``).
    """

    def __init__(self, *, max_frame: int, token_ok: Callable[[str], bool], **kwargs: Any) -> None:
        super().__init__(max_msg_size=AUTH_FRAME, **kwargs)
        self._lift = (max_frame, token_ok)
        #: the reader lifts its limit (False: an aiohttp whose internals differ; the limit then stays)
        self.liftable = False

    def _post_start(self, request: Any, protocol: str | None, writer: Any) -> None:
        super()._post_start(request, protocol, writer)
        try:
            queue = reader_py.WebSocketDataQueue(request._protocol, 2**16, loop=asyncio.get_running_loop())
            parser = _AuthReader(
                queue,  # type: ignore[arg-type]
                self._max_msg_size,
                compress=bool(self._compress),
                decode_text=self._decode_text,
            )
            if request.protocol._payload_parser is not self._parser:
                return
        except (AttributeError, TypeError):
            return
        parser.lift = self._lift
        self._reader = queue  # type: ignore[assignment]
        self._parser = parser  # type: ignore[assignment]
        # the one aiohttp just installed has read nothing yet (the handshake reply is not even sent)
        request.protocol._payload_parser = parser
        self.liftable = True

    def check_lifted(self) -> None:
        """After the auth op: warn when this aiohttp could not lift the limit."""
        if not self.liftable:
            _ratelog.warning(
                "lift",
                "web: this aiohttp's WebSocket reader keeps the %d-byte limit after an auth op; "
                "clients that send big ops should give the token in the URL",
                AUTH_FRAME,
            )


#: Ops a client may send before its ``auth`` op, each answered with a status (roslibjs may queue a subscribe
#: ahead of it); one more and the connection is closed.
AUTH_TRIES = 8


async def read_auth(ws: web.WebSocketResponse, token_ok: Callable[[str], bool]) -> bool:
    """Read a fresh connection's ops until one is ``auth`` with the right mac, within ``AUTH_TIMEOUT`` and
    ``AUTH_TRIES`` ops, each decoded only as far as its name, id and mac (``rb.decode_auth``); any other is
    answered with a status. False (the connection closed, with a reason) when it does not authenticate."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + AUTH_TIMEOUT
    for _ in range(AUTH_TRIES):
        try:
            msg = await ws.receive(timeout=max(0.001, deadline - loop.time()))
        except TimeoutError:
            break
        if msg.type != WSMsgType.TEXT:
            if msg.type != WSMsgType.BINARY:
                return False  # a close, an error (a frame over AUTH_FRAME: aiohttp closed it with 1009)
            why, op_id = "binary ops: authenticate first (op auth with the token)", None
        else:
            try:
                op = rb.decode_auth(msg.data)
            except rb.RosbridgeRefusal as exc:
                why, op_id = str(exc), None
            else:
                if op.op == "auth" and token_ok(op.mac):
                    return True
                op_id = None if op.id is None else str(op.id)
                why = (
                    "auth: wrong token"
                    if op.op == "auth"
                    else f"{op.op[:64]}: authenticate first (op auth with the token)"
                )
        with contextlib.suppress(ConnectionError):
            await ws.send_str(rb.op_json("status", level="error", msg=why, id=op_id).decode())
    await ws.close(code=1008, message=f"authenticate within {AUTH_TIMEOUT:g} s (op auth with the token)".encode())
    return False


def refuse_later(ws: web.WebSocketResponse, why: str) -> None:
    """Close a pending connection evicted for a newer one (from a sync context)."""
    asyncio.get_running_loop().create_task(ws.close(code=1013, message=why.encode()[:120]))
