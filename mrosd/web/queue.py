"""A byte-bounded drop-oldest queue: what one browser client may hold of one subscription.

Why bytes and not messages: a queue of 10 messages is 10 KiB on one topic and 80 MiB on an 8 MB image
topic; what a stalled browser tab may cost the daemon is a number of bytes. The bound is soft by exactly
one item: an item larger than the bound is still queued when the queue is empty, so a topic whose messages
are bigger than the bound still flows (one message at a time) instead of dropping everything. Pure data, no
I/O; the WebSocket shells drain it.
"""

from __future__ import annotations

import collections
from typing import Any, Generic, TypeVar

__all__ = ["ByteQueue", "ControlQueue", "Ledger", "trim_to_budget"]

T = TypeVar("T")


class Ledger:
    """The bytes held by many queues together (every client's queues of one server), kept up to date by them."""

    __slots__ = ("size",)

    def __init__(self) -> None:
        self.size = 0


class ControlQueue:
    """Frames a session sends in order, ahead of subscription data (replies, statuses, advertisements).

    Each frame carries the session's own flag (text or binary). ``size`` counts the bytes pushed and not yet
    popped; ``push`` reports when it passes ``max_bytes``: the client does not read what it asked for, and the
    session disconnects it. Pieces put in front (a message's later fragments) are that message's bytes, already
    bounded by its subscription queue: they are not counted, and popping them gives nothing back.
    """

    __slots__ = ("_items", "max_bytes", "size")

    def __init__(self, max_bytes: int) -> None:
        self._items: collections.deque[tuple[bool, bytes, int]] = collections.deque()
        self.max_bytes = max_bytes
        self.size = 0

    def __len__(self) -> int:
        return len(self._items)

    def push(self, flag: bool, data: bytes) -> bool:
        """Queue a frame at the end; False once the queued bytes exceed ``max_bytes``."""
        self._items.append((flag, data, len(data)))
        self.size += len(data)
        return self.size <= self.max_bytes

    def push_front(self, frames: list[tuple[bool, bytes]]) -> None:
        """Put ``frames``, in their order, ahead of everything queued; they are not counted."""
        self._items.extendleft((flag, data, 0) for flag, data in reversed(frames))

    def pop(self) -> tuple[bool, bytes]:
        flag, data, counted = self._items.popleft()
        self.size -= counted
        return flag, data


class ByteQueue(Generic[T]):
    """FIFO of ``(item, size)`` whose total size stays within ``max_bytes`` (plus one oversized item).

    ``dropped``/``dropped_bytes`` count what ``put`` pushed out (drop-oldest); ``unreported`` is the part of
    ``dropped`` nobody has reported to the client yet (``take_unreported`` resets it). ``big``: the queue holds
    a big topic's messages (camera frames): its sender keeps only the newest once the client fell behind
    (``keep_newest``), and what it holds back from the hub counts as its newest message only (``backlog``).
    """

    __slots__ = ("_items", "big", "dropped", "dropped_bytes", "ledger", "max_bytes", "size", "unreported")

    def __init__(self, max_bytes: int, ledger: Ledger | None = None) -> None:
        if max_bytes < 1:
            raise ValueError(f"max_bytes must be >= 1, got {max_bytes}")
        self.max_bytes = max_bytes
        #: where the bytes held are also counted (the server-wide total), or None
        self.ledger = ledger
        self._items: collections.deque[tuple[T, int]] = collections.deque()
        self.size = 0
        self.dropped = 0
        self.dropped_bytes = 0
        self.unreported = 0
        self.big = False

    def __len__(self) -> int:
        return len(self._items)

    def put(self, item: T, size: int) -> int:
        """Queue ``item`` (``size`` bytes), dropping the oldest items until it fits; returns how many dropped."""
        items = self._items
        dropped = 0
        before = self.size
        while items and self.size + size > self.max_bytes:
            _, old = items.popleft()
            self.size -= old
            self.dropped_bytes += old
            dropped += 1
        items.append((item, size))
        self.size += size
        if self.ledger is not None:
            self.ledger.size += self.size - before
        self.dropped += dropped
        self.unreported += dropped
        return dropped

    def peek_size(self) -> int | None:
        """The size of the oldest item, None when empty."""
        return self._items[0][1] if self._items else None

    def backlog(self) -> int:
        """Bytes this queue holds back from its client, as the hub's pause sees them: a big queue counts its
        newest message only (the older ones go when the client falls behind, they are not a backlog)."""
        if self.big and self._items:
            return self._items[-1][1]
        return self.size

    def keep_newest(self) -> None:
        """Drop every item but the newest, counted as dropped."""
        while len(self._items) > 1:
            self.drop_oldest()

    def get(self) -> T:
        """The oldest item. Raises IndexError when empty."""
        item, size = self._items.popleft()
        self.size -= size
        if self.ledger is not None:
            self.ledger.size -= size
        return item

    def drop_oldest(self) -> int:
        """Drop the oldest item as ``put`` would (counted); returns its size. Raises IndexError when empty."""
        _, size = self._items.popleft()
        self.size -= size
        if self.ledger is not None:
            self.ledger.size -= size
        self.dropped += 1
        self.dropped_bytes += size
        self.unreported += 1
        return size

    def clear(self) -> None:
        """Forget every item (not counted as dropped: the client asked for it, by unsubscribing)."""
        self._items.clear()
        if self.ledger is not None:
            self.ledger.size -= self.size
        self.size = 0

    def take_unreported(self) -> int:
        """Drops since the last call (for one status message per period, not one per drop)."""
        count, self.unreported = self.unreported, 0
        return count


def trim_to_budget(queues: list[ByteQueue[Any]], budget: int, newest: ByteQueue[Any]) -> None:
    """Drop the oldest items of the fullest queues until all of them together hold at most ``budget`` bytes.

    One client's queues share one budget: without it a client subscribed to N topics could hold N times
    the per-queue bound. The item just put on ``newest`` stays when it is all that queue holds, so a topic
    whose one message exceeds the budget still flows, one message at a time.
    """
    total = sum(q.size for q in queues)
    while total > budget:
        victim = max(queues, key=lambda q: q.size)
        if victim is newest and len(victim) <= 1:
            others = [q for q in queues if q is not newest and len(q)]
            if not others:
                return
            victim = max(others, key=lambda q: q.size)
        total -= victim.drop_oldest()
