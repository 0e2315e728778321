"""Playback: advertise every stored connection and publish its stored bytes at the recorded pace.

Each topic (after ``/from:=/to`` remapping) gets one publisher with the type, md5sum and definition the bag
stored, latched when a stored connection was latched; messages go out through ``publish_serialized``, the
bytes unchanged. ``ReplaySchedule`` turns bag time into wall time for a rate and a start offset; with
``clock`` the player publishes rosgraph_msgs/Clock on /clock at ``clock_hz`` with the bag time. Several bags
play merged in time order. The bag is read on the loop's thread, one chunk at a time (about 1 MB), which
takes far less than the spacing of any real message stream.
"""

from __future__ import annotations

import asyncio
import heapq
import logging
import sys
from collections.abc import Callable, Iterator, Sequence
from typing import TYPE_CHECKING, Any, TextIO

from mrosd import backports
from mrosd.bag.files import BagReader
from mrosd.bag.model import DEFAULT_CLOCK_HZ, BagError, ConnectionInfo, ReplaySchedule
from mrosd.errors import MrosError

if TYPE_CHECKING:
    from mrosd.tcpros.node import Node
    from mrosd.tcpros.publisher import Publisher

log = logging.getLogger(__name__)

#: How long the player waits at the end for subscribers to be sent what is queued for them.
DRAIN_TIMEOUT = 5.0
#: rosbag play's default publisher queue size.
PLAY_QUEUE_SIZE = 100


def stored_type(conn: ConnectionInfo) -> type:
    """A stand-in message class for a stored connection: what a ``Publisher`` needs to advertise it."""
    return type(
        "Stored_" + conn.type.replace("/", "_"),
        (),
        {"_type": conn.type, "_md5sum": conn.md5sum, "_full_text": conn.message_definition},
    )


class PlayStats:
    """What was published, for the status line and the tests."""

    def __init__(self) -> None:
        self.published = 0
        self.bytes = 0
        self.loops = 0
        self.bag_time_ns = 0


class Player:
    """Plays ``readers`` on ``node``; ``run`` returns at the end (or never with ``loop``, until ``stop``).

    Args:
        rate: playback speed factor (``-r``).
        start_offset: seconds into the bag to start from (``-s``).
        duration: play only this many seconds of bag time (``-u``).
        remaps: topic remappings, absolute names.
        clock: publish /clock with the bag time (``--clock``) at ``clock_hz``.
        delay: seconds to wait after advertising, for subscribers to connect (rosbag play's ``-d``).
        wait_for_subscribers: before playing, wait until every topic has a subscriber.
        status: a stream for rosbag play's one-line progress (``\\r``-refreshed), or None.
    """

    def __init__(
        self,
        node: Node,
        readers: Sequence[BagReader],
        *,
        rate: float = 1.0,
        loop: bool = False,
        start_offset: float = 0.0,
        duration: float | None = None,
        remaps: dict[str, str] | None = None,
        clock: bool = False,
        clock_hz: float = DEFAULT_CLOCK_HZ,
        delay: float = 0.2,
        wait_for_subscribers: bool = False,
        status: TextIO | None = None,
        topics: Sequence[str] = (),
    ) -> None:
        if rate <= 0:
            raise BagError(f"rate {rate} must be positive")
        if clock_hz <= 0:
            raise BagError(f"clock rate {clock_hz} must be positive")
        self.node = node
        self.readers = list(readers)
        self.rate = rate
        self.loop = loop
        self.start_offset = start_offset
        self.duration = duration
        self.remaps = dict(remaps or {})
        self.clock = clock
        self.clock_hz = clock_hz
        self.delay = delay
        self.wait_for_subscribers = wait_for_subscribers
        self.status = status
        self.only = set(topics)
        self.stats = PlayStats()
        self.publishers: dict[ConnectionInfo, Publisher] = {}
        self._clock_pub: Publisher | None = None
        self._clock_cls: Any = None
        self._last_clock_ns = 0
        starts = [r.start_ns for r in self.readers if r.start_ns is not None]
        ends = [r.end_ns for r in self.readers if r.end_ns is not None]
        self.bag_start_ns = min(starts) if starts else 0
        self.bag_end_ns = max(ends) if ends else 0

    # --- set-up ----------------------------------------------------------------------------------

    def topic_of(self, conn: ConnectionInfo) -> str:
        return self.remaps.get(conn.topic, conn.topic)

    async def advertise(self) -> None:
        """One publisher per played topic (latched if any stored connection was), plus /clock."""
        by_topic: dict[str, Publisher] = {}
        conns = [c for r in self.readers for c in r.connections if not self.only or c.topic in self.only]
        latched = {self.topic_of(c) for c in conns if c.latching}
        for conn in conns:
            topic = self.topic_of(conn)
            pub = by_topic.get(topic)
            if pub is None:
                try:
                    pub = await self.node.advertise(
                        topic, stored_type(conn), latch=topic in latched, queue_size=PLAY_QUEUE_SIZE
                    )
                except MrosError as exc:
                    log.warning("not playing %s: %s", topic, exc)
                    continue
                by_topic[topic] = pub
            elif pub.md5sum != conn.md5sum:
                log.warning("not playing a connection of %s: type %s, the topic was advertised as %s",
                            topic, conn.type, pub.type)  # fmt: skip
                continue
            self.publishers[conn] = pub
        if self.clock:
            from mrosd.msg import get_message_class

            self._clock_cls = get_message_class("rosgraph_msgs/Clock")
            self._clock_pub = await self.node.advertise("/clock", self._clock_cls, queue_size=PLAY_QUEUE_SIZE)
        if self.wait_for_subscribers:
            for pub in set(by_topic.values()):
                await pub.wait_for_subscribers(1, timeout=3600.0)
        if self.delay > 0:
            await asyncio.sleep(self.delay)

    # --- playing ---------------------------------------------------------------------------------

    def _messages(self) -> Iterator[tuple[int, ConnectionInfo, bytes]]:
        start = self.bag_start_ns + int(self.start_offset * 1e9)
        stop = None if self.duration is None else start + int(self.duration * 1e9)
        streams = [((t, conn, data) for conn, t, data in r.messages(start)) for r in self.readers]
        merged: Iterator[tuple[int, ConnectionInfo, bytes]] = (
            heapq.merge(*streams, key=lambda m: m[0]) if len(streams) > 1 else streams[0]
        )
        for item in merged:
            if stop is not None and item[0] >= stop:
                return
            yield item

    def _publish_clock(self, t_ns: int) -> None:
        if self._clock_pub is None:
            return
        from mrosd.msg import Time

        # Never backwards within a pass (wall-to-bag float rounding can land 1 ns before the last stamp).
        t_ns = max(t_ns, self._last_clock_ns)
        self._last_clock_ns = t_ns
        self._clock_pub.publish_nowait(self._clock_cls(clock=Time.from_nsec(t_ns)))

    async def _wait_until(self, due: float, schedule: ReplaySchedule, now: Callable[[], float]) -> None:
        period = 1.0 / self.clock_hz
        while True:
            remaining = due - now()
            if remaining <= 0:
                return
            if self._clock_pub is not None:
                self._publish_clock(schedule.bag_time(now()))
                await asyncio.sleep(min(remaining, period))
            else:
                await asyncio.sleep(remaining)

    async def run(self) -> PlayStats:
        """Advertise, then play (again and again with ``loop``); returns what was published."""
        if not self.readers:
            raise BagError("no bag to play")
        await self.advertise()
        loop = asyncio.get_running_loop()
        now = loop.time
        start = self.bag_start_ns + int(self.start_offset * 1e9)
        schedule = ReplaySchedule(start, self.rate, now())
        last_status = 0.0
        while True:
            since_yield = 0
            for t_ns, conn, data in self._messages():
                pub = self.publishers.get(conn)
                if pub is None:
                    continue
                due = schedule.due(t_ns)
                if due > now():
                    await self._wait_until(due, schedule, now)
                    since_yield = 0
                else:
                    since_yield += 1
                    if since_yield >= 64:  # behind schedule: still let the sockets drain
                        await asyncio.sleep(0)
                        since_yield = 0
                self._publish_clock(t_ns)
                pub.publish_serialized(data)
                self.stats.published += 1
                self.stats.bytes += len(data)
                self.stats.bag_time_ns = t_ns
                if self.status is not None and now() - last_status >= 0.1:
                    last_status = now()
                    self._show_status(t_ns)
            self.stats.loops += 1
            if not self.loop or self.stats.published == 0:
                break
            schedule.restart(now())
            self._last_clock_ns = 0  # a new pass starts the bag time again
        if self.status is not None:
            self._show_status(self.stats.bag_time_ns)
            self.status.write("\nDone.\n")
            self.status.flush()
        await self.drain()
        return self.stats

    def _show_status(self, t_ns: int) -> None:
        assert self.status is not None
        elapsed = (t_ns - self.bag_start_ns) / 1e9
        total = (self.bag_end_ns - self.bag_start_ns) / 1e9
        self.status.write(f"\r [RUNNING]  Bag Time: {t_ns / 1e9:13.6f}   Duration: {elapsed:.6f} / {total:.6f}   ")
        self.status.flush()

    async def drain(self, timeout: float = DRAIN_TIMEOUT) -> None:
        """Wait (bounded) until every subscriber was sent what is queued for it."""
        pubs = set(self.publishers.values())
        if self._clock_pub is not None:
            pubs.add(self._clock_pub)

        def pending() -> bool:
            return any(
                link.queue or (link.proto.transport is not None and link.proto.transport.get_write_buffer_size())
                for pub in pubs
                for link in pub.links
            )

        try:
            async with backports.timeout(timeout):
                # No event exists for "write buffer empty" (drain() stops at the low-water mark): poll.
                while True:
                    if not pending():
                        return
                    await asyncio.sleep(0.01)
        except TimeoutError:
            log.warning("some subscribers did not take every message within %.0f s", timeout)


def status_stream(enabled: bool | None) -> TextIO | None:
    """stderr for the progress line when asked, or by default when stderr is a terminal."""
    if enabled is None:
        enabled = sys.stderr.isatty()
    return sys.stderr if enabled else None
