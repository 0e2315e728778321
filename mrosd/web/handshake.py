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

from mrosd.lograte import RateLimitedLog
from mrosd.web import rosbridge as rb
from mrosd.web.admission import OriginGate

log = logging.getLogger(__name__)
_ratelog = RateLimitedLog(log)

__all__ = ["AUTH_FRAME", "AUTH_TIMEOUT", "AuthFirstResponse", "gate_middleware", "read_auth"]

#: Seconds a client that has not authenticated may take to send its ``auth`` op: a script or a browser on the
#: robot's network sends it in its first round trip; a stranger holding the connection open is closed.
AUTH_TIMEOUT = 5.0
#: Largest frame read before a client has authenticated. roslibjs's auth op (mac, client, dest, rand, t,
#: level, end) is a few hundred bytes; 16 KiB leaves room for long tokens and a few small ops a client may
#: send right after it, and bounds what a stranger makes the daemon hold (x the pending connections).
AUTH_FRAME = 16 * 1024


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


class AuthFirstResponse(web.WebSocketResponse):
    """A WebSocket whose frame limit starts small (``AUTH_FRAME``) and is raised once the client authenticated.

    aiohttp's compiled frame reader fixes its limit when the socket opens; this response reads with aiohttp's
    pure-Python reader (the same parser, the limit an attribute) so that ``raise_frame_limit`` can lift it.
    """

    def _post_start(self, request: Any, protocol: str | None, writer: Any) -> None:
        super()._post_start(request, protocol, writer)
        queue = reader_py.WebSocketDataQueue(request._protocol, 2**16, loop=asyncio.get_running_loop())
        self._reader = queue  # type: ignore[assignment]
        parser = reader_py.WebSocketReader(
            self._reader,  # type: ignore[arg-type]
            self._max_msg_size,
            compress=bool(self._compress),
            decode_text=self._decode_text,
        )
        self._parser = parser  # type: ignore[assignment]
        # the one aiohttp just installed has read nothing yet (the handshake reply is not even sent)
        request.protocol._payload_parser = parser

    def raise_frame_limit(self, max_frame: int) -> None:
        parser: Any = self._parser
        parser._max_msg_size = max_frame
        parser._max_fragments = max(1024, max_frame // 256) if max_frame else 0


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
