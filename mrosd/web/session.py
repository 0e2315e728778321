"""What a Foxglove and a rosbridge session have in common: the client's socket, the frames queued for it ahead
of subscription data, the sender's wake-up, and the disconnect of a client that does not read what it asked.

The protocols differ in everything they say; they do not differ in how a client that stops reading is
bounded, so that is written once, here.
"""

from __future__ import annotations

import asyncio
import logging
from typing import TYPE_CHECKING, Any, ClassVar

from mrosd.lograte import RateLimitedLog
from mrosd.web.queue import ControlQueue

if TYPE_CHECKING:
    from aiohttp import web

    from mrosd.web.hub import WebHub
    from mrosd.web.limits import SessionLimits

log = logging.getLogger(__name__)
#: a client can make these at will (connect, ask, never read): at most a few lines per period
_ratelog = RateLimitedLog(log)


class ClientSession:
    """The shared state of one WebSocket client's session; the protocol subclasses add theirs."""

    #: how the log names such a client
    KIND: ClassVar[str] = "client"
    #: the client's subscriptions (set by each protocol's session), each with its byte-bounded ``queue``
    subs: dict[Any, Any]

    def __init__(self, hub: WebHub, ws: web.WebSocketResponse, limits: SessionLimits, peer: str) -> None:
        self.hub = hub
        self.ws = ws
        self.limits = limits
        self.peer = peer
        #: (the protocol's frame flag, frame) to send ahead of subscription data
        self._control = ControlQueue(limits.control_bytes)
        self._wake = asyncio.Event()
        self._closed = False
        self._calls: set[asyncio.Task[None]] = set()
        self._close_task: asyncio.Task[bool] | None = None
        #: bytes of a message taken off its queue but still being sent in pieces (rosbridge fragments): counted
        #: in the hub's ledger (the server-wide budget) until the last piece is sent
        self.held = 0

    # --- what the hub asks of every client (never blocks) ------------------------------------------

    def queued(self) -> int:
        """Bytes queued for this client over all its subscriptions."""
        return sum(s.queue.size for s in self.subs.values())

    def shed_oldest(self) -> None:
        """Drop the oldest message of the fullest subscription (the hub is over its total budget)."""
        fullest = max(self.subs.values(), key=lambda s: s.queue.size, default=None)
        if fullest is not None and len(fullest.queue):
            fullest.queue.drop_oldest()

    def _hold(self, size: int) -> None:
        """Count ``size`` bytes being sent in pieces in the server-wide budget (one message at a time)."""
        self._unhold()
        self.held = size
        self.hub.ledger.size += size

    def _unhold(self) -> None:
        self.hub.ledger.size -= self.held
        self.held = 0

    def _queue_control(self, flag: bool, data: bytes) -> None:
        """Queue a frame for the sender; a client past its control budget is not reading what it asked for
        (replies, statuses): it is disconnected rather than allowed to grow the queue."""
        if self._closed:
            return
        if not self._control.push(flag, data):
            _ratelog.warning(
                "slow", "web: %s %s does not read its control messages; disconnecting it", self.KIND, self.peer
            )
            self._closed = True
            self._close_task = asyncio.get_running_loop().create_task(
                self.ws.close(code=1008, message=b"client too slow")
            )
        self._wake.set()
