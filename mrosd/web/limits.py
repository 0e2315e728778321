"""``SessionLimits``: what one WebSocket client (Foxglove or rosbridge) may make the daemon hold.

Its own module: both protocols' sessions and their shared base (``mrosd.web.session``) read it, and none of
them owns it.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["SessionLimits"]


@dataclass(frozen=True, slots=True)
class SessionLimits:
    """What one client may make the daemon hold."""

    #: bytes queued per subscription (drop-oldest beyond; one larger message still passes when empty)
    queue_bytes: int = 16 * 1024 * 1024
    #: bytes queued for one client over all its subscriptions: without it a client subscribed to N topics
    #: could hold N x queue_bytes; beyond it the oldest message of its fullest queue goes first
    client_bytes: int = 64 * 1024 * 1024
    #: bytes of control messages waiting for a client that does not read; beyond it the client is dropped
    control_bytes: int = 4 * 1024 * 1024
    #: subscriptions, client channels and parameter watches per client
    max_subscriptions: int = 1024
    #: service calls in flight per client, and how long each may take
    max_calls: int = 16
    call_timeout: float = 10.0
    #: rosbridge ``fragment`` ops: bytes of one client's unfinished fragmented messages (as much as one whole
    #: client frame may carry), how many at once, and how long one may go without a new piece
    fragment_bytes: int = 64 * 1024 * 1024
    max_fragmented: int = 16
    fragment_timeout: float = 30.0
