"""Recording: subscribe raw, hand each body to a writer thread through a bounded queue, never block the loop.

``Recorder`` lives in the event loop. It subscribes with ``AnyMsg`` (no decode, no re-encode) to the chosen
topics, or with ``all_topics`` to every published topic, asking the master again every ``poll_interval`` for
topics that appeared. Each received body goes to ``RecordSink.put`` with the publisher's connection header
and the receipt time.

``RecordSink`` owns the files and one writer thread. Between the two sits a queue bounded in bytes (rosbag
record's ``--buffsize``, 256 MB by default): when a message would overflow it, the OLDEST queued messages are
dropped, as rosbag record does, and counted; the receiving loop never waits on the disk. The thread opens the
next file when a ``SplitPolicy`` limit is reached, and stops the recording (``on_full``) when an unsplit
recording reaches ``--size``.
"""

from __future__ import annotations

import asyncio
import collections
import logging
import os
import re
import threading
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

from mrosd import backports
from mrosd.bag.files import BagFileWriter
from mrosd.bag.model import BagError, ConnectionInfo, SplitPolicy
from mrosd.errors import MrosError

if TYPE_CHECKING:
    from mrosd.tcpros.node import Node
    from mrosd.tcpros.subscriber import RawMessage

log = logging.getLogger(__name__)

#: A queued message: topic, connection header (as received), receipt time (ns), body.
_Item = tuple[str, Any, int, "bytes | bytearray"]
#: The handle of a connection the file format refused (its messages are counted as dropped).
_REFUSED = object()


class RecordStats:
    """Counters shared by the loop (received, dropped) and the writer thread (written); plain ints."""

    def __init__(self) -> None:
        self.received = 0
        self.received_bytes = 0
        self.written = 0
        self.written_bytes = 0
        self.dropped = 0
        self.files: list[str] = []


class RecordSink:
    """The writer thread and its bounded queue; ``put`` from the loop, ``close`` once at the end.

    Args:
        opener: ``opener(index)`` creates file number ``index`` (0, 1, ... when splitting, else only 0); the
            first is created by the constructor, so a bad name or directory raises there.
        buffer_bytes: bound of the queue in bytes (0: unbounded, as rosbag's ``-b 0``).
        split: limits of one file; with ``splitting`` False reaching them ends the recording instead.
        max_splits: keep at most this many files, deleting the oldest (rosbag's ``--max-splits``).
        on_full: called from the writer thread when an unsplit recording reached its limit.
    """

    def __init__(
        self,
        opener: Callable[[int], BagFileWriter],
        *,
        buffer_bytes: int,
        split: SplitPolicy | None = None,
        splitting: bool = False,
        max_splits: int | None = None,
        on_full: Callable[[], None] | None = None,
    ) -> None:
        self.opener = opener
        self.buffer_bytes = buffer_bytes
        self.split = split or SplitPolicy()
        self.splitting = splitting
        self.max_splits = max_splits
        self.on_full = on_full
        self.stats = RecordStats()
        self.error: BaseException | None = None
        self._queue: collections.deque[_Item] = collections.deque()
        self._held_bytes = 0
        self._cond = threading.Condition()
        self._closing = False
        self._full = False
        self._writer: BagFileWriter | None = None
        self._index = 0
        self._first_ns: int | None = None
        self._handles: dict[tuple[Any, ...], Any] = {}
        # The first file is created here, in the caller's thread, so that a bad name fails at once.
        self._writer = self._open()
        self._thread = threading.Thread(target=self._run, name="bag writer", daemon=True)
        self._thread.start()

    # --- loop side -------------------------------------------------------------------------------

    def put(self, topic: str, header: Any, t_ns: int, data: bytes | bytearray) -> None:
        """Queue one message; drops the oldest queued ones when the buffer would overflow. Never blocks long."""
        size = len(data)
        stats = self.stats
        stats.received += 1
        stats.received_bytes += size
        with self._cond:
            if self._full or self._closing:
                return  # after the end of the recording (size reached, or the writer failed: reported)
            limit = self.buffer_bytes
            if limit:
                # Bytes held = queued + the batch the writer is on: memory stays within the limit.
                while self._queue and self._held_bytes + size > limit:
                    old = self._queue.popleft()
                    self._held_bytes -= len(old[3])
                    self._dropped(limit)
                if self._held_bytes + size > limit:  # the writer's batch alone fills it: drop this one
                    self._dropped(limit)
                    return
            self._queue.append((topic, header, t_ns, data))
            self._held_bytes += size
            if len(self._queue) == 1:
                self._cond.notify()

    def _dropped(self, limit: int) -> None:
        stats = self.stats
        stats.dropped += 1
        if stats.dropped == 1 or stats.dropped % 1000 == 0:
            log.warning("record buffer of %d bytes exceeded: dropped %d oldest message(s)", limit, stats.dropped)

    def close(self, timeout: float = 60.0) -> None:
        """Write what is queued, close the last file and stop the thread (bounded by ``timeout``).

        Raises:
            BagError: the writer failed (disk full, permission...), with the first error.
        """
        with self._cond:
            self._closing = True
            self._cond.notify()
        self._thread.join(timeout)
        if self._thread.is_alive():
            raise BagError(f"the bag writer did not finish within {timeout} s")
        if self.error is not None:
            raise BagError(f"writing the bag failed: {self.error or repr(self.error)}") from self.error

    @property
    def held_bytes(self) -> int:
        """Bytes received and not yet written (queued, or in the batch being written)."""
        return self._held_bytes

    # --- writer thread ---------------------------------------------------------------------------

    def _run(self) -> None:
        try:
            while True:
                with self._cond:
                    while not self._queue and not self._closing:
                        self._cond.wait()
                    batch = self._queue
                    self._queue = collections.deque()
                    closing = self._closing
                while batch:
                    item = batch.popleft()
                    written = self._write(item)
                    with self._cond:
                        self._held_bytes -= len(item[3])
                        if not written:  # the recording is complete: the rest came after its end
                            self._held_bytes -= sum(len(i[3]) for i in batch)
                            batch.clear()
                if closing and not self._queue:
                    break
        except BaseException as exc:  # reported by close(); the loop keeps receiving
            log.error("bag writer failed: %r", exc)
            self.error = exc
            with self._cond:
                self._full = True
                self._queue.clear()
                self._held_bytes = 0
            if self.on_full is not None:
                self.on_full()
        finally:
            if self._writer is not None:
                try:
                    self._writer.close()
                except Exception as exc:
                    if self.error is None:
                        self.error = exc
                self._writer = None

    def _open(self) -> BagFileWriter:
        writer = self.opener(self._index)
        self.stats.files.append(writer.path)
        self._handles = {}
        self._first_ns = None
        if self.max_splits is not None and len(self.stats.files) > self.max_splits:
            old = self.stats.files.pop(0)
            try:
                os.unlink(old)
            except OSError as exc:
                log.warning("cannot remove old split %s: %s", old, exc)
        return writer

    def _write(self, item: _Item) -> bool:
        topic, header, t_ns, data = item
        writer = self._writer
        assert writer is not None
        if self.split.full(writer.written, self._first_ns, t_ns):
            if not self.splitting:
                with self._cond:
                    self._full = True
                    self._held_bytes -= sum(len(i[3]) for i in self._queue)
                    self._queue.clear()
                if self.on_full is not None:
                    self.on_full()
                return False
            writer.close()
            self._index += 1
            writer = self._writer = self._open()
        key = (topic, header.type, header.md5sum, header.callerid, header.latching, header.message_definition)
        handle = self._handles.get(key)
        if handle is None:
            conn = ConnectionInfo(
                topic=topic,
                type=header.type or "*",
                md5sum=header.md5sum or "*",
                message_definition=header.message_definition or "",
                callerid=header.callerid or "",
                latching=header.flag("latching"),
            )
            try:
                handle = writer.add_connection(conn)
            except BagError as exc:  # a peer's bad header costs its messages, never the recording
                log.warning("%s", exc)
                handle = _REFUSED
            self._handles[key] = handle
        if handle is _REFUSED:
            with self._cond:
                self.stats.dropped += 1
            return True
        if self._first_ns is None:
            self._first_ns = t_ns
        writer.write(handle, t_ns, data)
        self.stats.written += 1
        self.stats.written_bytes += len(data)
        return True


class Recorder:
    """Subscribes raw to topics and feeds a ``RecordSink``; ``run`` returns when ``stop`` is set.

    Args:
        topics: names (resolved by the node) or, with ``regex``, patterns matched against published topics.
        all_topics: record every published topic, now and as they appear.
        exclude: a pattern; matching topics are never recorded (with ``all_topics`` or ``regex``).
        poll_interval: seconds between two asks to the master for new topics (``all_topics``/``regex``).
        limit: record at most this many messages per topic (rosbag's ``-l``); None for no limit. Named topics
            that all reached it end the recording.
    """

    def __init__(
        self,
        node: Node,
        sink: RecordSink,
        topics: Sequence[str] = (),
        *,
        all_topics: bool = False,
        regex: bool = False,
        exclude: str | None = None,
        poll_interval: float = 1.0,
        limit: int | None = None,
    ) -> None:
        if not topics and not all_topics:
            raise BagError("give topics to record, or -a for all topics")
        self.node = node
        self.sink = sink
        self.all_topics = all_topics
        self.patterns = [re.compile(t) for t in topics] if regex else []
        self.names = [] if regex else [node.resolve_name(t) for t in topics]
        self.exclude = re.compile(exclude) if exclude else None
        self.poll_interval = poll_interval
        self.limit = limit
        self.recorded: set[str] = set()
        self._counts: dict[str, int] = {}
        self.topic_added = asyncio.Event()
        self._stop: asyncio.Event | None = None

    def _callback(self, topic: str) -> Callable[[RawMessage], None]:
        put = self.sink.put
        now = time.time_ns
        if self.limit is None:
            return lambda raw: put(topic, raw.header, now(), raw.data)
        counts = self._counts
        limit = self.limit

        def limited(raw: RawMessage) -> None:
            n = counts.get(topic, 0)
            if n < limit:
                counts[topic] = n + 1
                put(topic, raw.header, now(), raw.data)
                if n + 1 == limit:
                    self._topic_complete()

        return limited

    def _topic_complete(self) -> None:
        # As rosbag record -l: once every named topic has its N messages, the recording ends (never with
        # -a or -e, where more topics may come).
        if self._stop is None or self.all_topics or self.patterns:
            return
        if all(self._counts.get(t, 0) >= (self.limit or 0) for t in self.names):
            self._stop.set()

    async def _add(self, topic: str) -> None:
        from mrosd.tcpros.subscriber import AnyMsg

        if topic in self.recorded:
            return
        self.recorded.add(topic)
        try:
            await self.node.subscribe(topic, AnyMsg, callback=self._callback(topic))
        except MrosError as exc:
            self.recorded.discard(topic)
            log.warning("cannot subscribe to %s: %s", topic, exc)
            return
        log.info("Subscribing to %s", topic)
        self.topic_added.set()

    def _wanted(self, topic: str) -> bool:
        if self.exclude is not None and self.exclude.search(topic):
            return False
        if self.all_topics:
            return True
        return any(p.fullmatch(topic) for p in self.patterns)

    async def _poll(self) -> None:
        while True:
            try:
                published = await self.node.master.get_published_topics("")
                for topic, _type in published:
                    if self._wanted(str(topic)):
                        await self._add(str(topic))
            except MrosError as exc:
                log.warning("cannot list published topics: %s", exc)
            await asyncio.sleep(self.poll_interval)

    async def run(self, stop: asyncio.Event, duration: float | None = None) -> None:
        """Record until ``stop`` is set, ``duration`` seconds pass, or every named topic reached ``limit``."""
        self._stop = stop
        for name in self.names:
            await self._add(name)
        poller = None
        if self.all_topics or self.patterns:
            poller = asyncio.get_running_loop().create_task(self._poll(), name="bag record poll")
        try:
            if duration is None:
                await stop.wait()
            else:
                try:
                    await backports.wait_for(stop.wait(), duration)
                except TimeoutError:
                    pass
        finally:
            if poller is not None:
                poller.cancel()
                try:
                    await poller
                except asyncio.CancelledError:
                    pass
