"""Per-topic rate and bandwidth limits and the bounded drop-oldest queue of a link: pure.

A thin link (Wi-Fi at the edge of range, cellular) must not be filled by one topic, and a stalled link must
never make the master or a local node wait: what cannot be sent is dropped, oldest first, and counted.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Generic, TypeVar

T = TypeVar("T")

MiB = 1024 * 1024
#: What another robot's bodies may hold here, in bytes, whatever it sends: bodies waiting for the loop, in all
#: and per topic (drop-oldest, the fullest topic first: ``handoff.Inbox``); a body or request over
#: ``MAX_BODY_BYTES`` is refused before it is copied out of Zenoh, and Zenoh itself rebuilds no message over
#: ``MAX_MESSAGE_SIZE`` (its default is 1 GiB: a peer could make it hold that much per link); calls from other
#: robots hold at most ``MAX_CALL_BYTES`` of requests in flight; the queue of a slow local subscriber of a
#: received topic at most ``LINK_BYTES`` (besides ``queue_size`` messages: the newest is always kept).
INBOX_BYTES = 64 * MiB
INBOX_BYTES_EACH = 32 * MiB
MAX_BODY_BYTES = INBOX_BYTES_EACH
MAX_MESSAGE_SIZE = 64 * MiB
MAX_CALL_BYTES = 64 * MiB
LINK_BYTES = 16 * MiB


@dataclass
class RateLimit:
    """Token buckets for messages per second and bytes per second (0 = unlimited).

    A bucket holds at most one second's worth (at least one message, or the message at hand for bytes), so
    a burst after a quiet spell is bounded by the limit itself, not by how long the topic was quiet.
    """

    max_hz: float = 0.0
    max_bytes_per_s: float = 0.0
    _msg_tokens: float = 1.0
    _byte_tokens: float = 0.0
    _last: float | None = None
    passed: int = 0
    limited: int = 0

    def admit(self, now: float, size: int) -> bool:
        """True if a message of ``size`` bytes may go now (its tokens are then taken)."""
        if self._last is None:
            self._msg_tokens = 1.0
            self._byte_tokens = max(self.max_bytes_per_s, float(size))
        else:
            dt = max(0.0, now - self._last)
            if self.max_hz > 0:
                self._msg_tokens = min(max(1.0, self.max_hz), self._msg_tokens + dt * self.max_hz)
            if self.max_bytes_per_s > 0:
                cap = max(self.max_bytes_per_s, float(size))
                self._byte_tokens = min(cap, self._byte_tokens + dt * self.max_bytes_per_s)
        self._last = now
        ok = (self.max_hz <= 0 or self._msg_tokens >= 1.0) and (self.max_bytes_per_s <= 0 or self._byte_tokens >= size)
        if ok:
            if self.max_hz > 0:
                self._msg_tokens -= 1.0
            if self.max_bytes_per_s > 0:
                self._byte_tokens -= size
            self.passed += 1
        else:
            self.limited += 1
        return ok


@dataclass
class DropOldestQueue(Generic[T]):
    """A FIFO of at most ``maxlen`` entries; a put into a full queue drops the oldest and counts it."""

    maxlen: int
    items: deque[T] = field(default_factory=deque)
    dropped: int = 0

    def put(self, item: T) -> None:
        if len(self.items) >= self.maxlen:
            self.items.popleft()
            self.dropped += 1
        self.items.append(item)

    def pop(self) -> T | None:
        return self.items.popleft() if self.items else None

    def __len__(self) -> int:
        return len(self.items)


@dataclass
class RateMeter:
    """Messages per second lately: an exponentially decaying count (``tau`` seconds), O(1) per message.

    ``mros fleet status`` shows what a topic does now, not its average since the daemon started.
    """

    tau: float = 2.0
    _rate: float = 0.0
    _last: float | None = None

    def tick(self, now: float) -> None:
        if self._last is not None:
            self._rate *= math.exp(-max(0.0, now - self._last) / self.tau)
        self._rate += 1.0 / self.tau
        self._last = now

    def rate(self, now: float) -> float:
        if self._last is None:
            return 0.0
        return self._rate * math.exp(-max(0.0, now - self._last) / self.tau)
