"""Fair delivery to one client: which of its subscriptions sends next, as a pure deficit round robin by bytes.

Why bytes and not messages: one message per subscription per round (what both servers did) gives a 100 Hz
topic of 16-byte messages the rate of a camera of 2.7 MB frames, because each round waits for a frame to
cross the link: behind 20 Mbit/s, about one round a second. Deficit round robin (Shreedhar and Varghese, 1995)
gives every backlogged subscription ``quantum`` bytes of credit per round and lets it send while its next
message fits its credit: a small topic's whole backlog (up to ``quantum`` bytes) goes out in the round in which
the camera sends one frame, and over time every backlogged subscription gets the same share of bytes.

A subscription that has nothing to send now (empty, throttled, or a big message held back until the link is
clear: the caller decides) banks no credit. When nothing fits, the rounds that would only add credit are
skipped in one step (``pick`` never loops per quantum: a 2.7 MB frame over a 64 KiB quantum is 43 rounds).

Pure data, no I/O and no clock: the sessions' senders (``mrosd.web.fairsend``) ask it, per message, which
subscription goes next, and tell it each subscription's next message size.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Hashable, Sequence
from typing import Generic, TypeVar

__all__ = ["BIG_MESSAGE_BYTES", "QUANTUM_BYTES", "DeficitRoundRobin"]

K = TypeVar("K", bound=Hashable)

#: Credit per subscription per round. Large enough that a small topic's backlog of one round trip goes out in
#: one visit (a 100 Hz Float64 is 2 KiB/s of frames, odometry at 50 Hz 37 KiB/s), small enough that a big
#: topic's frame costs other backlogged topics at most one quantum of wait per round.
QUANTUM_BYTES = 64 * 1024

#: A subscription whose message reaches this size is "big" from then on: it keeps only its newest message
#: (a camera frame waiting for the link is replaced by the next one, the drop counted), and its next message
#: is handed to the socket only when the link is clear (``mrosd.web.fairsend``). 256 KiB is 0.1 s of a
#: 20 Mbit/s link: a message that size or bigger is one of a stream (images, point clouds, maps) where the
#: newest is what a viewer wants; smaller ones (odometry, transforms, diagnostics) each count.
BIG_MESSAGE_BYTES = 256 * 1024


class DeficitRoundRobin(Generic[K]):
    """The round-robin state of one client: whose visit it is, and each subscription's credit in bytes."""

    __slots__ = ("_current", "_deficit", "quantum")

    def __init__(self, quantum: int = QUANTUM_BYTES) -> None:
        if quantum < 1:
            raise ValueError(f"quantum must be >= 1, got {quantum}")
        self.quantum = quantum
        self._deficit: dict[K, int] = {}
        #: the subscription whose visit is under way (it keeps sending while its next message fits its credit)
        self._current: K | None = None

    def credit(self, key: K) -> int:
        """Bytes ``key`` may still send in the current round (for tests and status)."""
        return self._deficit.get(key, 0)

    def pick(self, keys: Collection[K], head: Callable[[K], int | None]) -> K | None:
        """The subscription whose next message goes now, its size charged to its credit; None: nothing to send.

        ``keys``: the client's subscriptions in a stable order (a dict: its membership test is O(1));
        ``head(key)``: the size of the message ``key`` would send next, or None when it has nothing it may
        send now.
        """
        deficit = self._deficit
        current = self._current
        if current is not None and current not in keys:
            deficit.pop(current, None)  # unsubscribed during its visit
            current = None
        if current is not None:
            size = head(current)
            if size is not None and size <= deficit.get(current, 0):
                deficit[current] -= size
                return current
            if size is None:
                deficit.pop(current, None)  # an idle subscription banks no credit
        listed = list(keys)
        n = len(listed)
        if n == 0:
            self._current = None
            deficit.clear()
            return None
        start = 0 if current is None else listed.index(current) + 1
        order = [listed[(start + i) % n] for i in range(n)]
        sizes = [head(k) for k in order]
        if all(s is None for s in sizes):
            self._current = None
            deficit.clear()
            return None
        # the rounds in which every waiting subscription only gains credit, skipped at once
        waiting = [(k, s) for k, s in zip(order, sizes, strict=True) if s is not None]
        rounds = min(-(-(s - deficit.get(k, 0)) // self.quantum) for k, s in waiting)
        bonus = max(0, rounds - 1) * self.quantum
        for key, size in zip(order, sizes, strict=True):
            if size is None:
                deficit.pop(key, None)
                continue
            credit = deficit.get(key, 0) + bonus + self.quantum
            if size <= credit:
                deficit[key] = credit - size
                self._current = key
                self._forget_gone(listed)
                return key
            deficit[key] = credit
        raise AssertionError("unreachable: the skipped rounds leave a subscription whose message fits")

    def _forget_gone(self, keys: Sequence[K]) -> None:
        """Credit of subscriptions no longer listed (unsubscribed) is dropped once it could matter for memory."""
        if len(self._deficit) > 2 * len(keys) + 8:
            alive = set(keys)
            for key in [k for k in self._deficit if k not in alive]:
                del self._deficit[key]
