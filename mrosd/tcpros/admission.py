"""Admission before allocation: which accepted TCPROS connections a node keeps while they owe a header.

A connection that has not yet sent its connection header is anonymous: it names no topic or service and
could be anyone. Until it identifies itself it may hold only a small fixed buffer, for a few seconds, and
only so many of its kind may wait at once (per node, per remote address, and in buffered header bytes);
beyond a cap the *oldest* waiting connection is shed, so a flood displaces its own earlier connections while
a legitimate peer, which sends its header at once, passes through. Established connections are never shed
here: their cost is bounded by their endpoint's queues.

``HeaderAdmission`` is the pure bookkeeping (no sockets, no clock of its own: ``now`` is passed in); the
listener (``mrosd.tcpros.listener``) and the node act on the keys it returns.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Hashable
from typing import Generic, TypeVar

import msgspec

from mrosd.wire.header import MAX_HEADER_SIZE

__all__ = ["AdmissionLimits", "HeaderAdmission", "Verdict"]

K = TypeVar("K", bound=Hashable)


class AdmissionLimits(msgspec.Struct, frozen=True, kw_only=True):
    """Caps on a node's inbound TCPROS connections; the defaults suit a node with RLIMIT_NOFILE 1024.

    Attributes:
        header_timeout: seconds a connection may take to send its whole connection header.
        max_pending: connections waiting for their header, per node.
        max_pending_per_address: of those, from one remote address (local peers all share 127.0.0.1, so this
            stays well above what one accept burst lets in before a peer's header is read).
        max_pending_bytes: header bytes buffered by all waiting connections together; one header alone
            may be as large as ``max_header_size``.
        max_header_size: largest connection header accepted (judged on its length prefix, before buffering).
        max_connections: inbound connections in all, established ones included.
    """

    header_timeout: float = 5.0
    max_pending: int = 256
    max_pending_per_address: int = 128
    max_pending_bytes: int = 16 * 1024 * 1024
    max_header_size: int = MAX_HEADER_SIZE
    max_connections: int = 4096

    def __post_init__(self) -> None:
        if self.header_timeout <= 0:
            raise ValueError(f"header_timeout must be > 0, got {self.header_timeout}")
        for name in ("max_pending", "max_pending_per_address", "max_pending_bytes", "max_header_size"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.max_connections < 1:
            raise ValueError(f"max_connections must be >= 1, got {self.max_connections}")


class Verdict(msgspec.Struct, Generic[K], frozen=True, gc=False):
    """What ``admit`` decided: whether the new connection stays, and the waiting ones to shed for it."""

    admitted: bool
    shed: list[K]


class _Pending(msgspec.Struct, gc=False):
    address: str
    deadline: float
    nbytes: int = 0


class HeaderAdmission(Generic[K]):
    """The accepted connections of one node, those still owing a header in arrival order."""

    def __init__(self, limits: AdmissionLimits | None = None) -> None:
        self.limits = limits or AdmissionLimits()
        #: waiting connections, oldest first (dicts keep insertion order)
        self._pending: dict[K, _Pending] = {}
        self._per_address: Counter[str] = Counter()
        self._bytes = 0
        #: every admitted connection still open, waiting or established
        self._open: set[K] = set()

    @property
    def pending(self) -> int:
        """Connections waiting for their header."""
        return len(self._pending)

    @property
    def connections(self) -> int:
        """Admitted connections still open."""
        return len(self._open)

    @property
    def pending_bytes(self) -> int:
        return self._bytes

    def is_pending(self, key: K) -> bool:
        return key in self._pending

    def admit(self, key: K, address: str, now: float) -> Verdict[K]:
        """A connection was accepted from ``address``: admit it, shedding the oldest waiting ones it displaces.

        Beyond ``max_connections`` with nobody waiting to shed, the new connection itself is refused.
        """
        limits = self.limits
        shed: list[K] = []
        if len(self._open) >= limits.max_connections:
            oldest = self._oldest()
            if oldest is None:
                return Verdict(False, shed)
            shed.append(oldest)
            self._drop(oldest)
        if self._per_address[address] >= limits.max_pending_per_address:
            victim = self._oldest(address)
            if victim is not None:
                shed.append(victim)
                self._drop(victim)
        if len(self._pending) >= limits.max_pending:
            victim = self._oldest()
            if victim is not None:
                shed.append(victim)
                self._drop(victim)
        self._pending[key] = _Pending(address, now + limits.header_timeout)
        self._per_address[address] += 1
        self._open.add(key)
        return Verdict(True, shed)

    def received(self, key: K, buffered: int) -> list[K]:
        """``key`` now buffers ``buffered`` header bytes: the waiting connections to shed (oldest first, the
        key itself included when it alone is over budget) so that all together stay within the byte budget."""
        entry = self._pending.get(key)
        if entry is None:
            return []
        self._bytes += buffered - entry.nbytes
        entry.nbytes = buffered
        shed: list[K] = []
        while self._bytes > self.limits.max_pending_bytes:
            victim = self._oldest()
            if victim is None:  # pragma: no cover - key itself is pending
                break
            shed.append(victim)
            self._drop(victim)
        return shed

    def header_done(self, key: K) -> None:
        """``key`` sent its whole header: it no longer waits (and is never shed here again)."""
        if key in self._pending:
            self._drop(key)

    def closed(self, key: K) -> None:
        """``key`` is gone, whatever its state."""
        if key in self._pending:
            self._drop(key)
        self._open.discard(key)

    def expired(self, now: float) -> list[K]:
        """The waiting connections whose header deadline has passed (no longer tracked as waiting)."""
        out: list[K] = []
        for key, entry in self._pending.items():
            if entry.deadline > now:
                break  # one timeout for all: arrival order is deadline order
            out.append(key)
        for key in out:
            self._drop(key)
        return out

    def next_deadline(self) -> float | None:
        """When the oldest waiting connection's header is due, or None when nobody waits."""
        for entry in self._pending.values():
            return entry.deadline
        return None

    def shed_oldest(self, fraction: int = 4) -> list[K]:
        """The oldest ``1/fraction`` (at least one) of the waiting connections, to free descriptors."""
        count = max(1, len(self._pending) // fraction) if self._pending else 0
        out = list(self._pending)[:count]
        for key in out:
            self._drop(key)
        return out

    def _oldest(self, address: str | None = None) -> K | None:
        for key, entry in self._pending.items():
            if address is None or entry.address == address:
                return key
        return None

    def _drop(self, key: K) -> None:
        """Forget ``key`` as waiting; it stays open (counted) until ``closed``."""
        entry = self._pending.pop(key)
        self._bytes -= entry.nbytes
        left = self._per_address[entry.address] - 1
        if left:
            self._per_address[entry.address] = left
        else:
            del self._per_address[entry.address]
