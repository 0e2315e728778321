"""A publisher that declares ``max_message_size`` gets its ring at start, every page faulted in, and its
subscribers map it whole at once (issue 25 (a)): the first message pays for no fresh memory on either side."""

from __future__ import annotations

import asyncio
import os

from mrosd import backports
from mrosd.shm import ShmPublisherEndpoint, ShmSubscriberConnection, parse_answer
from mrosd.shm import publisher as shm_publisher
from mrosd.shm.ring import POPULATED
from mrosd.shm.segment import RingSegment
from mrosd.wire.header import ConnectionHeader

HEADER = ConnectionHeader(callerid="/listener", topic="/pool", md5sum="*", type="*")


def resident_kib(label: str) -> int:
    """Resident KiB of this process's mappings of the memfd named ``label`` (from /proc/self/smaps)."""
    total, inside = 0, False
    with open("/proc/self/smaps") as f:
        for line in f:
            if line[:1].isalnum() and "-" in line.split()[0] and len(line.split()) >= 5:
                inside = label in line
            elif inside and line.startswith("Rss:"):
                total += int(line.split()[1])
    return total


def test_a_populated_segment_is_resident_and_says_so() -> None:
    seg = RingSegment("pool-unit-a", 2, 1 << 20, populate=True)
    lazy = RingSegment("pool-unit-b", 2, 1 << 20)
    try:
        assert seg.layout.flags & POPULATED and not lazy.layout.flags & POPULATED
        assert resident_kib("mrosd-shm-pool-unit-a") >= 2 * 1024
        assert resident_kib("mrosd-shm-pool-unit-b") < 64
    finally:
        seg.close()
        lazy.close()


async def test_declared_size_makes_the_pool_at_start_and_subscribers_map_it_whole() -> None:
    size = 2 << 20
    ep = ShmPublisherEndpoint("/pool", queue_size=4, max_message_size=size)
    await ep.start()
    try:
        assert ep.ring is not None and ep.rings_made == 1  # before any subscriber or message
        pool = ep.pool()
        assert pool["populated"] and pool["slot_bytes"] >= size and pool["bytes"] == ep.ring.size
        assert pool["lease_slots"] == shm_publisher.DEFAULT_LEASE_SLOTS and pool["leases_granted"] == 0
        assert ep.ring.layout.capacity >= size and ep.ring.layout.flags & POPULATED
        got: list[bytes] = []
        arrived = asyncio.Event()

        def on_frame(body: bytes) -> None:
            got.append(bytes(body))
            arrived.set()

        answer = parse_answer(ep.answer())
        assert answer is not None
        conn = await ShmSubscriberConnection.attach(answer, HEADER, on_frame=on_frame)
        try:
            # the subscriber's read-only mapping is resident as a whole before any message (ours and the
            # publisher's mappings of the same pages are both in this process: at least twice the ring)
            assert resident_kib("mrosd-shm-pool") >= 2 * (size >> 10)
            body = os.urandom(size)
            ep.publish(body)
            await backports.wait_for(arrived.wait(), 5)
            assert got == [body] and ep.rings_made == 1
        finally:
            await conn.aclose()
    finally:
        await ep.aclose()


async def test_loans_given_back_or_published_without_subscribers_never_use_up_the_pool() -> None:
    ep = ShmPublisherEndpoint("/pool", queue_size=2, max_message_size=4096)
    await ep.start()
    try:
        assert ep.ring is not None
        for _ in range(3 * ep.ring.layout.slots):  # lent and given back unpublished
            lent = ep.loan_slot(100)
            assert lent is not None
            ep.end_loan(*lent)
        for _ in range(3 * ep.ring.layout.slots):  # lent and published with nobody listening
            lent = ep.loan_slot(100)
            assert lent is not None and ep.publish_loaned(*lent, 0, 10)
        assert ep.can_lend(100) and not ep._loaned
    finally:
        await ep.aclose()
