"""Asynchronous delivery of the master's callbacks (publisherUpdate, paramUpdate, shutdown) to nodes.

One bounded FIFO and one worker task per target URI: calls to one node go out in the order they
were queued, one at a time, each bounded by a timeout, and a dead or slow node only ever delays its
own queue. A pending publisherUpdate for a (target, topic) is replaced in place by a newer one,
since only the latest publisher list matters. Drop policy when a queue is full: the oldest queued
call is dropped (and logged). After ``max_failures`` consecutive failed calls the target's backlog
is discarded and the worker backs off (50 ms doubling to 5 s) before its next attempt, so a dead
node costs one attempt per period, not one per notification. Idle workers exit.
"""

from __future__ import annotations

import asyncio
import logging
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from mrosd import backports
from mrosd.errors import XmlRpcError
from mrosd.lograte import RateLimitedLog
from mrosd.master.registry import Notification
from mrosd.xmlrpc import XmlRpcClient

log = logging.getLogger(__name__)
#: notifications to nodes that do not answer: any process may register at an address where nothing listens, so a
#: few lines per method and minute, then a count, never one line per failed call
_ratelog = RateLimitedLog(log, period=60.0, burst=3)

#: Caller id the master uses for its own calls, as rosmaster does.
MASTER_CALLER_ID = "/master"

#: Longest pause between attempts to a target that keeps failing.
MAX_BACKOFF = 5.0

#: Result callback: ``(notification, reply or None on failure)``.
ResultHook = Callable[[Notification, Any], None]


@dataclass(slots=True)
class _Target:
    queue: deque[Notification] = field(default_factory=deque)
    pending: dict[str, Notification] = field(default_factory=dict)
    wakeup: asyncio.Event = field(default_factory=asyncio.Event)
    task: asyncio.Task[None] | None = None
    failures: int = 0
    busy: bool = False


class Notifier:
    """Per-target ordered, bounded, coalescing delivery of master callbacks.

    Args:
        xmlrpc: the client used for the calls (its connection pool is shared by all targets).
        timeout: seconds allowed for one call, connect included.
        max_queue: most calls queued per target; beyond it the oldest is dropped.
        max_failures: consecutive failures after which a target's backlog is discarded.
        idle: seconds a worker waits for more work before it exits.
        on_result: called after every call with the reply (``None`` if it failed).
    """

    def __init__(
        self,
        xmlrpc: XmlRpcClient,
        *,
        timeout: float = 5.0,
        max_queue: int = 10_000,
        max_failures: int = 3,
        idle: float = 30.0,
        on_result: ResultHook | None = None,
    ) -> None:
        self._xmlrpc = xmlrpc
        self._timeout = timeout
        self._max_queue = max_queue
        self._max_failures = max_failures
        self._idle = idle
        self._on_result = on_result
        self._targets: dict[str, _Target] = {}
        self._adopted: set[asyncio.Task[None]] = set()
        self._closed = False
        self._progress = asyncio.Event()
        self.sent = 0
        self.failed = 0
        self.dropped = 0
        self.coalesced = 0

    def submit(self, notes: list[Notification]) -> None:
        """Queue notifications; never blocks and never raises."""
        if self._closed:
            return
        for note in notes:
            target = self._targets.get(note.api)
            if target is None:
                target = self._targets[note.api] = _Target()
            if note.coalesce is not None:
                queued = target.pending.get(note.coalesce)
                if queued is not None and queued.method == note.method:
                    queued.args = note.args
                    self.coalesced += 1
                    continue
                target.pending[note.coalesce] = note
            if len(target.queue) >= self._max_queue:
                old = target.queue.popleft()
                self._forget_pending(target, old)
                self.dropped += 1
                log.warning("notification queue for %s full: dropped %s%s", note.api, old.method, old.args[:1])
            target.queue.append(note)
            target.wakeup.set()
            if target.task is None or target.task.done():
                target.task = asyncio.get_running_loop().create_task(self._run(note.api, target))

    @staticmethod
    def _forget_pending(target: _Target, note: Notification) -> None:
        if note.coalesce is not None and target.pending.get(note.coalesce) is note:
            del target.pending[note.coalesce]

    def backlog(self, api: str | None = None) -> int:
        """Number of queued (not yet started) calls, for one target or all."""
        if api is not None:
            target = self._targets.get(api)
            return len(target.queue) if target else 0
        return sum(len(t.queue) for t in self._targets.values())

    async def drain(self, timeout: float = 10.0) -> None:
        """Wait until every queue is empty and no call is in flight (tests, shutdown)."""
        async with backports.timeout(timeout):
            while any(t.queue or t.busy for t in self._targets.values()):
                self._progress.clear()
                await self._progress.wait()

    async def _run(self, api: str, target: _Target) -> None:
        try:
            while True:
                if not target.queue:
                    target.wakeup.clear()
                    try:
                        async with backports.timeout(self._idle):
                            await target.wakeup.wait()
                    except TimeoutError:
                        if not target.queue:
                            if self._targets.get(api) is target:
                                del self._targets[api]
                            return
                    continue
                note = target.queue.popleft()
                self._forget_pending(target, note)
                target.busy = True
                try:
                    reply = await self._deliver(note)
                finally:
                    target.busy = False
                    self._progress.set()
                if reply is None:
                    target.failures += 1
                    if target.failures >= self._max_failures:
                        if target.queue:
                            self.dropped += len(target.queue)
                            log.warning(
                                "%s failed %d calls in a row: dropped %d queued calls",
                                api,
                                target.failures,
                                len(target.queue),
                            )
                            target.queue.clear()
                            target.pending.clear()
                        # Back off: a dead node costs one attempt per period, not one per notification.
                        extra = target.failures - self._max_failures
                        await asyncio.sleep(min(MAX_BACKOFF, 0.05 * 2 ** min(extra, 10)))
                else:
                    target.failures = 0
        except asyncio.CancelledError:
            raise
        except Exception:  # pragma: no cover - a bug here must not kill delivery silently
            log.exception("notifier worker for %s crashed", api)

    async def _deliver(self, note: Notification) -> Any:
        try:
            reply = await self._xmlrpc.call(note.api, note.method, MASTER_CALLER_ID, *note.args, timeout=self._timeout)
        except XmlRpcError as exc:
            self.failed += 1
            _ratelog.log(logging.INFO, note.method, "%s%s to %s failed: %s", note.method, note.args[:1], note.api, exc)
            reply = None
        except Exception as exc:  # encoding errors and the like: the caller's value, not our bug
            self.failed += 1
            _ratelog.warning(note.method + ":unsent", "%s to %s could not be sent: %s", note.method, note.api, exc)
            reply = None
        else:
            self.sent += 1
        if self._on_result is not None:
            try:
                self._on_result(note, reply)
            except Exception:
                log.exception("notification result hook failed")
        return reply

    @property
    def closed(self) -> bool:
        return self._closed

    def adopt(self, task: asyncio.Task[None]) -> None:
        """Cancel ``task`` with the workers in ``aclose()`` (the master's other background tasks)."""
        if self._closed:
            task.cancel()
            return
        self._adopted.add(task)
        task.add_done_callback(self._adopted.discard)

    async def aclose(self) -> None:
        """Cancel every worker (and adopted task); queued calls are discarded."""
        self._closed = True
        tasks = [t.task for t in self._targets.values() if t.task is not None]
        tasks.extend(self._adopted)
        for task in tasks:
            task.cancel()
        for task in tasks:
            try:
                await task
            except asyncio.CancelledError:
                pass
        self._targets.clear()
