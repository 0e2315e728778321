"""The two crossings between Zenoh's threads and the event loop, each bounded and never blocking the loop.

Zenoh runs its callbacks on its own threads; the loop must not wait for Zenoh either (a put on a congested
link blocks). ``Inbox`` takes samples from any thread into per-topic drop-oldest queues and wakes the loop at
most once per batch; ``Outbox`` takes bodies from the loop into per-key drop-oldest queues that one sender
thread writes to Zenoh, and repeats the discovery announcements each period from that same thread.
``ReplyFuture`` carries the outcome of one query (a service call) from Zenoh's threads into a future on the
loop; the fleet and ros2 parts both call services that way.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from mrosd.errors import ServiceError
from mrosd.fleet.keys import ANNOUNCE_PERIOD
from mrosd.fleet.limits import DropOldestQueue

log = logging.getLogger(__name__)


class ReplyFuture:
    """The first outcome of a Zenoh query, from any thread to ``future`` on the loop: a reply's body
    (``ok``) or a ``ServiceError`` (``fail``); what comes after the first is ignored, and so is everything once
    the loop is closed."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        self.future: asyncio.Future[bytes] = loop.create_future()

    def ok(self, body: bytes) -> None:
        """A reply's body (from any thread)."""
        self._hand(body, None)

    def fail(self, error: str) -> None:
        """The call failed: ``error`` is the ``ServiceError``'s text (from any thread)."""
        self._hand(None, error)

    def _hand(self, body: bytes | None, error: str | None) -> None:
        with contextlib.suppress(RuntimeError):  # the loop is closed: nobody waits any more
            self._loop.call_soon_threadsafe(self._settle, body, error)

    def _settle(self, body: bytes | None, error: str | None) -> None:
        if self.future.done():
            return
        if error is not None:
            self.future.set_exception(ServiceError(error))
        elif body is not None:
            self.future.set_result(body)


class Inbox:
    """Any thread -> the loop: ``put(name, item)``; ``deliver(name, items)`` runs on the loop in batches.

    With ``max_bytes``, bodies (``bytes``, or a tuple whose first item is one) are also bounded in bytes: at
    most ``max_bytes`` wait in all and ``max_bytes_each`` under one name. A body that does not fit drops the
    oldest of its own name first, then the oldest of the name holding most, so a peer flooding one name cannot
    push another's out; a body bigger than a name's share is refused. Memory then follows the budget, not a
    peer's sends.
    """

    def __init__(
        self,
        loop: asyncio.AbstractEventLoop,
        deliver: Callable[[str, list[Any]], None],
        maxlen: int,
        maxlen_of: dict[str, int] | None = None,
        *,
        max_bytes: int = 0,
        max_bytes_each: int = 0,
    ) -> None:
        self._loop = loop
        self._deliver = deliver
        self._maxlen = maxlen
        #: names with a bound of their own (the discovery stream: one entry per announced item, not per topic)
        self._maxlen_of = dict(maxlen_of or {})
        self._max_bytes = max_bytes
        self._max_bytes_each = min(max_bytes_each or max_bytes, max_bytes)
        #: bytes of bodies waiting, per name and in all (only with ``max_bytes``)
        self._held: dict[str, int] = {}
        self.held_bytes = 0
        #: bodies dropped for bytes under any name (``put`` says whether one of its call was)
        self._popped = 0
        self._lock = threading.Lock()
        self._queues: dict[str, DropOldestQueue[Any]] = {}
        self._scheduled = False
        self.closed = False

    def put(self, name: str, item: Any) -> bool:
        """Queue ``item`` (from any thread); the oldest of ``name`` is dropped and counted when full (in count,
        or in bytes as the class says). True if anything was dropped or refused."""
        if self.closed:
            return False
        with self._lock:
            q = self._queues.get(name)
            if q is None:
                q = self._queues[name] = DropOldestQueue(self._maxlen_of.get(name, self._maxlen))
            dropped = q.dropped + self._popped
            size = _body_size(item) if self._max_bytes else 0
            if size:
                if not self._fit(name, q, size):
                    q.dropped += 1
                    return True
            elif len(q) >= q.maxlen and self._max_bytes:
                self._forget_bytes(name, _body_size(q.items[0]))
            q.put(item)
            lost = q.dropped + self._popped != dropped
            if self._scheduled:
                return lost
            self._scheduled = True
        try:
            self._loop.call_soon_threadsafe(self._drain)
        except RuntimeError:  # the loop is closed: nothing will read this any more
            self.closed = True
        return lost

    def _fit(self, name: str, q: DropOldestQueue[Any], size: int) -> bool:
        """Make room for a body of ``size`` under ``name`` (lock held); False: it can never fit."""
        if size > self._max_bytes_each:
            return False
        held = self._held.get(name, 0)
        while q.items and (len(q) >= q.maxlen or held + size > self._max_bytes_each):
            held -= self._pop_oldest(name, q)
        while self.held_bytes + size > self._max_bytes:
            # the name holding most, this body counted with its own name, gives up its oldest
            victim = max(self._held, key=lambda n: self._held[n] + (size if n == name else 0))
            if self._held.get(name, 0) + size >= self._held[victim]:
                if not q.items:
                    return False
                victim = name
            self._pop_oldest(victim, self._queues[victim])
        self._held[name] = self._held.get(name, 0) + size
        self.held_bytes += size
        return True

    def _pop_oldest(self, name: str, q: DropOldestQueue[Any]) -> int:
        old = q.items.popleft()
        q.dropped += 1
        self._popped += 1
        size = _body_size(old)
        self._forget_bytes(name, size)
        return size

    def _forget_bytes(self, name: str, size: int) -> None:
        left = self._held.get(name, 0) - size
        if left > 0:
            self._held[name] = left
        else:
            self._held.pop(name, None)
        self.held_bytes -= size

    def _drain(self) -> None:
        with self._lock:
            batches = [(name, list(q.items)) for name, q in self._queues.items() if q.items]
            for q in self._queues.values():
                q.items.clear()
            self._held.clear()
            self.held_bytes = 0
            self._scheduled = False
        for name, items in batches:
            try:
                self._deliver(name, items)
            except Exception:
                log.exception("fleet: delivering %d item(s) of %s failed", len(items), name)

    def dropped(self, name: str) -> int:
        with self._lock:
            q = self._queues.get(name)
            return q.dropped if q is not None else 0

    def forget(self, name: str) -> None:
        with self._lock:
            q = self._queues.pop(name, None)
            if q is not None and self._max_bytes:
                self._forget_bytes(name, sum(map(_body_size, q.items)))


def _body_size(item: Any) -> int:
    """The bytes an inbox item holds: a body, or a ``(body, ...)`` tuple (the fleet's samples); else none."""
    if isinstance(item, bytes):
        return len(item)
    if isinstance(item, tuple) and item and isinstance(item[0], bytes):
        return len(item[0])
    return 0


class Outbox:
    """The loop -> Zenoh: one sender thread, per-key drop-oldest queues, announcements every period.

    ``publisher.put`` may block while a link is congested (reliable data, as the bridge sends it): only this
    thread waits, the queues keep the newest ``maxlen`` bodies of each key, and what falls out is counted.
    """

    def __init__(
        self, session: Any, maxlen: int, announce_options: dict[str, Any], period: float = ANNOUNCE_PERIOD
    ) -> None:
        self._session = session
        #: keyword arguments of each announcement's put (the bridge's: best effort, background, remote only)
        self._announce_options = announce_options
        self._maxlen = maxlen
        self._period = period
        self._cv = threading.Condition()
        self._queues: dict[str, DropOldestQueue[bytes]] = {}
        self._publishers: dict[str, Any] = {}
        #: keys whose puts carry an attachment (the latched marker of mrosd/fleet/keys.py)
        self._attachments: dict[str, bytes] = {}
        self._ready: deque[str] = deque()
        self._closed = False
        #: Discovery keys repeated every period (replaced whole from the loop; read by the sender thread).
        self.announcements: frozenset[str] = frozenset()
        self.put_errors = 0
        self._thread = threading.Thread(target=self._run, name="mrosd-fleet-send", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def put(self, key: str, publisher: Any, body: bytes, attachment: bytes | None = None) -> None:
        """Queue ``body`` for ``publisher`` (on ``key``), with ``attachment`` if given; never blocks."""
        with self._cv:
            if attachment is not None:
                self._attachments[key] = attachment
            q = self._queues.get(key)
            if q is None:
                q = self._queues[key] = DropOldestQueue(self._maxlen)
            self._publishers[key] = publisher
            q.put(body)
            if len(q) == 1:
                self._ready.append(key)
            self._cv.notify()

    def dropped(self, key: str) -> int:
        with self._cv:
            q = self._queues.get(key)
            return q.dropped if q is not None else 0

    def forget(self, key: str) -> None:
        with self._cv:
            self._queues.pop(key, None)
            self._publishers.pop(key, None)
            self._attachments.pop(key, None)

    def close(self, timeout: float = 2.0) -> None:
        with self._cv:
            self._closed = True
            self._cv.notify()
        if self._thread.is_alive():
            self._thread.join(timeout)

    def _run(self) -> None:
        next_announce = time.monotonic()
        while True:
            body: bytes | None = None
            publisher: Any = None
            attachment: bytes | None = None
            with self._cv:
                while not self._closed and not self._ready:
                    wait = next_announce - time.monotonic()
                    if wait <= 0:
                        break
                    self._cv.wait(wait)
                if self._closed:
                    return
                if self._ready:
                    key = self._ready.popleft()
                    q = self._queues.get(key)
                    if q is not None:
                        body = q.pop()
                        publisher = self._publishers.get(key)
                        attachment = self._attachments.get(key)
                        if len(q):
                            self._ready.append(key)  # round-robin: one body per key in turn
            if body is not None and publisher is not None:
                try:
                    if attachment is None:
                        publisher.put(body)
                    else:
                        publisher.put(body, attachment=attachment)
                except Exception as exc:  # undeclared meanwhile, or the session closed
                    self.put_errors += 1
                    log.debug("fleet: put failed: %s", exc)
            if time.monotonic() >= next_announce:
                self._announce()
                next_announce = time.monotonic() + self._period

    def _announce(self) -> None:
        for key in self.announcements:
            try:
                self._session.put(key, b"", **self._announce_options)
            except Exception as exc:
                self.put_errors += 1
                log.debug("fleet: announcing %s failed: %s", key, exc)
