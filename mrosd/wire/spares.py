"""``SparePool``: the large receive buffers one process keeps for reuse, bounded over all its connections.

A multi-megabyte buffer fresh from the kernel costs page faults and zero-filling as it is first written (glibc
maps big blocks anew and unmaps them on free), more than the copy into it. So a frame decoder that finished a
large frame (and the shared-memory subscriber that copied one out) keeps its buffer here, and the next large
frame of any connection is received into a kept buffer that nobody refers to any more: a steady stream of
images costs no allocation per frame, even where the application holds a few frames at a time.

What a kept buffer costs is its bytes while nothing else holds it, so the pool follows data in use, not the
number of connections: at most ``SPARE_BYTES`` and ``SPARES`` buffers for the whole process (oldest dropped
first), none larger than ``MAX_SPARE`` (a rare huge message is not worth keeping resident), and none kept
once ``SPARE_IDLE`` seconds passed without reuse (``release_idle``, which the asyncio shell also calls on a
timer so that a process gone quiet gives them back). Before, each connection kept its newest buffer however
large: six publishers latching 40 MiB held 240 MiB in a bridge after the messages were sent and dropped.

A buffer is reused only when its reference count says that no message, view or caller still holds it (the
``FrameBuffer`` rule: a delivered buffer is never written again while anyone can see it). The pool is shared
by every event loop of the process, so its list is guarded by a lock (held for a few list operations, never
across I/O). No sockets, no asyncio.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable
from typing import Any, Protocol

from mrosd.msg.runtime import FrameBuffer

__all__ = ["MAX_SPARE", "SPARES", "SPARE_BYTES", "SPARE_IDLE", "SparePool", "Timers", "spare_pool"]

#: Buffers kept for the whole process. A bridge that holds a few 8 MB frames while its clients read them
#: needs about four for one camera (docs/web.md); more cameras share them.
SPARES = 8
#: Bytes of kept buffers for the whole process, whether or not someone still uses them.
SPARE_BYTES = 64 * 1024 * 1024
#: Larger buffers are never kept: glibc gives them back to the kernel on free, and a message this big is rare
#: enough that faulting its pages in again costs little next to receiving it (40 MiB: about 10 ms).
MAX_SPARE = 32 * 1024 * 1024
#: Seconds a kept buffer waits for reuse before it is dropped (a stream slower than this allocates per frame).
SPARE_IDLE = 2.0


#: A timer fires this much after a buffer's idle time is up (so that the buffer is due by then).
_TIMER_SLACK = 0.05


def _measure_free_refs() -> int:
    """``sys.getrefcount`` of a kept buffer nobody else holds, in ``SparePool.take``'s loop (measured)."""
    spares = [(FrameBuffer(), 0.0)]
    for i in range(len(spares) - 1, -1, -1):
        spare = spares[i][0]
        return sys.getrefcount(spare)
    raise AssertionError  # pragma: no cover


#: what ``sys.getrefcount`` says of a kept buffer that only the pool holds, in ``take``'s loop
_FREE_REFS = _measure_free_refs()


class Timers(Protocol):
    """What ``SparePool.watch`` needs of an event loop (an asyncio loop is one)."""

    def call_later(self, delay: float, callback: Callable[..., object], *args: Any) -> object: ...

    def is_closed(self) -> bool: ...


class SparePool:
    """Large ``FrameBuffer`` s kept for reuse, newest last, bounded in count, bytes, size and idle time."""

    __slots__ = ("_lock", "_spares", "_timers", "clock", "idle", "max_bytes", "max_count", "max_spare", "size")

    def __init__(
        self,
        *,
        max_count: int = SPARES,
        max_bytes: int = SPARE_BYTES,
        max_spare: int = MAX_SPARE,
        idle: float = SPARE_IDLE,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.max_count = max_count
        self.max_bytes = max_bytes
        self.max_spare = min(max_spare, max_bytes)
        self.idle = idle
        self.clock = clock
        #: bytes of the buffers kept (in use elsewhere or not)
        self.size = 0
        #: (buffer, when it was kept), oldest first
        self._spares: list[tuple[FrameBuffer, float]] = []
        self._lock = threading.Lock()
        #: the loop whose timer calls ``release_idle`` (None: no timer pending)
        self._timers: Timers | None = None

    def __len__(self) -> int:
        return len(self._spares)

    def keep(self, buf: FrameBuffer) -> None:
        """Offer a large buffer just delivered (its receiver may still hold it): kept unless too large; the
        oldest go while the pool is over its bounds, and any that waited ``idle`` seconds."""
        if len(buf) > self.max_spare:
            return
        now = self.clock()
        with self._lock:
            spares = self._spares
            spares.append((buf, now))
            self.size += len(buf)
            while len(spares) > self.max_count or self.size > self.max_bytes:
                self.size -= len(spares.pop(0)[0])
            self._drop_idle(now)

    def take(self, capacity: int) -> FrameBuffer | None:
        """A kept buffer of at least ``capacity`` bytes that nobody else refers to (the newest such), taken out
        of the pool; None if there is none."""
        if capacity > self.max_spare or not self._spares:
            return None
        with self._lock:
            spares = self._spares
            for i in range(len(spares) - 1, -1, -1):
                spare = spares[i][0]
                # The entry, ``spare`` and getrefcount's argument: any other reference is a holder outside.
                if len(spare) >= capacity and sys.getrefcount(spare) == _FREE_REFS:
                    del spares[i]
                    self.size -= len(spare)
                    return spare
        return None

    def copy(self, data: memoryview) -> FrameBuffer:
        """A FrameBuffer holding a copy of ``data`` (a shared-memory slot): a free kept one refilled, else a new
        one; either way kept for reuse afterwards."""
        n = len(data)
        buf = self.take(n)
        if buf is None:
            buf = FrameBuffer(data)
        else:
            if len(buf) > n:
                del buf[n:]
            with memoryview(buf) as view:
                view[:] = data
        self.keep(buf)
        return buf

    def release_idle(self) -> float | None:
        """Drop the buffers that waited ``idle`` seconds; return in how many seconds the next one will have
        (None: the pool is empty), for the shell's timer."""
        now = self.clock()
        with self._lock:
            self._drop_idle(now)
            if not self._spares:
                return None
            return max(0.0, self._spares[0][1] + self.idle - now)

    def watch(self, loop: Timers) -> None:
        """Have ``loop`` call ``release_idle`` until the pool is empty, so that a process gone quiet gives its
        kept buffers back. One timer for the process: armed by the first caller, handed on to the next
        caller's loop if the loop that held it was closed meanwhile."""
        timers = self._timers
        if timers is not None and not timers.is_closed():
            return
        self._timers = loop
        loop.call_later(self.idle, self._release_on, loop)

    def _release_on(self, loop: Timers) -> None:
        delay = self.release_idle()
        if delay is None:
            self._timers = None
        else:
            loop.call_later(delay + _TIMER_SLACK, self._release_on, loop)

    def clear(self) -> None:
        """Drop every kept buffer."""
        with self._lock:
            self._spares.clear()
            self.size = 0

    def _drop_idle(self, now: float) -> None:
        spares = self._spares
        cutoff = now - self.idle
        while spares and spares[0][1] <= cutoff:
            self.size -= len(spares.pop(0)[0])


_POOL = SparePool()


def spare_pool() -> SparePool:
    """The process's pool, shared by every frame decoder and shared-memory subscriber."""
    return _POOL
