"""ShmPublisherEndpoint and ShmSubscriberConnection in one event loop: iteration, views, growth, refusals, ends,
and the publisher's queue beside the ring (bursts, stalled subscribers)."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

import pytest

from mrosd import backports
from mrosd.errors import HandshakeError, LocalProtocolError, RemoteProtocolError
from mrosd.shm import ShmPublisherEndpoint, ShmSubscriberConnection, ShmView, parse_answer
from mrosd.shm import publisher as shm_publisher
from mrosd.shm.negotiate import VERSION, ShmAnswer
from mrosd.wire.handshake import publisher_reply
from mrosd.wire.header import ConnectionHeader

HEADER = ConnectionHeader(callerid="/listener", topic="/chatter", md5sum="*", type="*")


async def endpoint(**kw: object) -> ShmPublisherEndpoint:
    ep = ShmPublisherEndpoint("/chatter", **kw)  # type: ignore[arg-type]
    await ep.start()
    return ep


def answer(ep: ShmPublisherEndpoint) -> ShmAnswer:
    got = parse_answer(ep.answer())
    assert got is not None
    return got


async def until(cond: Callable[[], object], timeout: float = 5.0) -> None:
    """Re-check ``cond`` at each turn of the loop (the other side runs in this loop too), bounded."""
    async with backports.timeout(timeout):
        while not cond():  # noqa: ASYNC110 - the state lives in another object's callbacks
            await asyncio.sleep(0.005)


async def test_iterating_subscriber_reads_copies_in_order_through_a_growing_ring() -> None:
    ep = await endpoint(queue_size=10, initial_capacity=64)
    conn = await ShmSubscriberConnection.attach(answer(ep), HEADER)
    try:
        await until(lambda: ep.links)
        sent = [b"a" * 10, b"b" * 1000, b"c" * 5, b"d" * 100_000]
        for body in sent:
            ep.publish(body)
        await asyncio.sleep(0.05)  # the replacement rings are announced before anything is read
        got = [await anext(conn) for _ in sent]
        assert got == sent and conn.dropped == 0
        assert ep.rings_made == 3
        assert ep.bus_info()[0][3] == "SHMROS"
        assert ep.stats()[0]["messages"] == 4
    finally:
        await conn.aclose()
        await ep.aclose()


async def test_a_handshake_checks_md5_as_tcpros_does() -> None:
    def handshake(h: ConnectionHeader) -> ConnectionHeader:
        return publisher_reply(
            h,
            topic="/chatter",
            msg_type="std_msgs/String",
            md5sum="992ce8a1687cec8c8bd883ec73ca41d1",
            message_definition="string data",
            callerid="/talker",
            latching=False,
        )

    ep = await endpoint(handshake=handshake)
    try:
        good = ConnectionHeader(
            callerid="/l", topic="/chatter", md5sum="992ce8a1687cec8c8bd883ec73ca41d1", type="std_msgs/String"
        )
        conn = await ShmSubscriberConnection.attach(answer(ep), good)
        assert conn.reply_header is not None and conn.reply_header.callerid == "/talker"
        await conn.aclose()
        bad = ConnectionHeader(callerid="/l", topic="/chatter", md5sum="0" * 32, type="std_msgs/Int32")
        with pytest.raises(HandshakeError, match="md5sums do not match"):
            await ShmSubscriberConnection.attach(answer(ep), bad)
        assert not ep.links
    finally:
        await ep.aclose()


async def test_a_wrong_token_is_refused() -> None:
    ep = await endpoint()
    try:
        wrong = ShmAnswer(version=VERSION, address=ep.address, token="0" * 32)
        with pytest.raises(HandshakeError, match="wrong token"):
            await ShmSubscriberConnection.attach(wrong, HEADER)
    finally:
        await ep.aclose()


async def test_uids_are_checked_on_both_sides() -> None:
    ep = await endpoint(trusted=frozenset())
    try:
        with pytest.raises(RemoteProtocolError, match="closed the connection"):
            await ShmSubscriberConnection.attach(answer(ep), HEADER)
    finally:
        await ep.aclose()
    ep = await endpoint()
    try:
        with pytest.raises(RemoteProtocolError, match="untrusted uid"):
            await ShmSubscriberConnection.attach(answer(ep), HEADER, trusted=frozenset())
    finally:
        await ep.aclose()


async def test_a_zero_copy_view_is_leased_past_its_callback_until_released_or_dropped() -> None:
    ep = await endpoint(queue_size=2, lease_slots=2)
    kept: list[ShmView] = []

    conn = await ShmSubscriberConnection.attach(answer(ep), HEADER, on_frame=kept.append, zero_copy=True)
    try:
        await until(lambda: ep.links)
        assert conn.max_leased == 2 and ep.links[0].grant == 2
        ep.publish(b"hello")
        await until(lambda: kept)
        first = kept[0]
        assert first.leased and bytes(first.data) == b"hello"
        assert ep.ring is not None
        for i in range(3 * ep.ring.layout.slots):  # laps the ring many times: never the leased slot
            ep.publish(bytes([i]) * 10)
            await asyncio.sleep(0)
        await until(lambda: len(kept) + conn.lease_drops == 1 + 3 * ep.ring.layout.slots)  # type: ignore[union-attr]
        assert first.intact() and bytes(first.data) == b"hello" and ep.links[0].leases()
        assert conn.lease_drops > 0  # the second lease was taken, then every later message was dropped
        with first:
            pass
        with pytest.raises(ValueError):
            bytes(first.data)  # released: reading it is an error, not a read of whatever the slot holds now
        kept.clear()  # the other lease goes with its view (garbage)
        await until(lambda: not ep.links[0].leases())
        with pytest.raises(LocalProtocolError):
            await anext(conn)
    finally:
        await conn.aclose()
        await ep.aclose()


async def test_the_end_of_either_side_is_seen_by_the_other() -> None:
    ep = await endpoint()
    changes: list[int] = []
    ep.on_change = lambda: changes.append(len(ep.links))
    conn = await ShmSubscriberConnection.attach(answer(ep), HEADER)
    await until(lambda: changes == [1])
    await conn.aclose()
    await until(lambda: changes == [1, 0])
    conn = await ShmSubscriberConnection.attach(answer(ep), HEADER)
    await ep.aclose()
    await backports.wait_for(asyncio.shield(conn.closed), 5)
    assert conn.error == ""
    with pytest.raises(StopAsyncIteration):
        await anext(conn)


async def test_nothing_is_allocated_for_a_topic_nobody_reads() -> None:
    ep = await endpoint()
    ep.publish(b"x" * 100_000)
    assert ep.ring is None
    await ep.aclose()
    with pytest.raises(LocalProtocolError):
        ep.publish(b"x")


async def test_cancelling_a_waiter_of_closed_still_releases_everything_at_aclose() -> None:
    ep = await endpoint()
    conn = await ShmSubscriberConnection.attach(answer(ep), HEADER)

    async def waiter() -> None:
        await conn.closed  # awaited directly: cancelling this task cancels the future itself

    task = asyncio.ensure_future(waiter())
    await asyncio.sleep(0)
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    await conn.aclose()
    assert conn._channel is None and conn._ring is None and not conn.connected
    await ep.aclose()


# the publisher's queue beside the ring -------------------------------------------------------------------


async def test_a_burst_longer_than_the_ring_waits_in_the_publishers_queue_and_arrives_whole() -> None:
    ep = await endpoint(queue_size=100)
    conn = await ShmSubscriberConnection.attach(answer(ep), HEADER)
    try:
        await until(lambda: ep.links)
        sent = [bytes([i]) * 300_000 for i in range(40)]
        for body in sent:  # no turn of the loop in between: the subscriber reads nothing meanwhile
            ep.publish(body)
        assert ep.ring is not None and ep.ring.layout.slots < 40
        assert len(ep.backlog) == 40 - ep.ring.layout.slots and ep.ring.layout.waiting
        got = [bytes(await backports.wait_for(anext(conn), 5)) for _ in sent]
        assert got == sent and conn.dropped == 0
        await until(lambda: not ep.backlog)
        assert not ep.ring.layout.waiting and ep.stats()[0]["messages"] == 40
    finally:
        await conn.aclose()
        await ep.aclose()


async def test_a_stalled_subscriber_holds_back_one_that_keeps_up_for_at_most_stall(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(shm_publisher, "STALL", 0.1)
    ep = await endpoint(queue_size=1000)
    stalled = await ShmSubscriberConnection.attach(answer(ep), HEADER)  # never iterated until the end
    got: list[tuple[float, bytes]] = []
    live = await ShmSubscriberConnection.attach(
        answer(ep), HEADER, on_frame=lambda b: got.append((time.monotonic(), bytes(b)))
    )
    try:
        await until(lambda: len(ep.links) == 2)
        sent = [i.to_bytes(4, "little") * 1000 for i in range(200)]
        published: list[float] = []
        for body in sent:
            ep.publish(body)
            published.append(time.monotonic())
            await asyncio.sleep(0.001)
        await until(lambda: len(got) == len(sent))
        assert [b for _, b in got] == sent and live.dropped == 0
        delays = [t - p for (t, _), p in zip(got, published, strict=True)]
        assert max(delays) < 0.1 + 0.5  # STALL, and a loaded machine's slack
        assert [lk.lagging for lk in ep.links] == [True, False]
        # the stalled one finds the newest messages that are still in the ring, and counts the rest as lost
        first = await backports.wait_for(anext(stalled), 5)
        assert bytes(first) != sent[0] and stalled.dropped > 0
    finally:
        await stalled.aclose()
        await live.aclose()
        await ep.aclose()


async def test_a_lone_stalled_subscriber_is_queued_for_at_most_queue_size_then_loses_the_oldest() -> None:
    ep = await endpoint(queue_size=3)
    conn = await ShmSubscriberConnection.attach(answer(ep), HEADER)
    try:
        await until(lambda: ep.links)
        for i in range(50):
            ep.publish(bytes([i]) * 100)  # never waits, whatever the subscriber does
            assert len(ep.backlog) <= 3 + 1
        assert ep.links[0].lagging
        got = []
        while len(got) + conn.dropped < 50:
            got.append(bytes(await backports.wait_for(anext(conn), 5)))
        assert got[-1] == bytes([49]) * 100 and conn.dropped > 0
        assert got == sorted(got)  # in order, the oldest ones gone
    finally:
        await conn.aclose()
        await ep.aclose()


async def test_a_held_zero_copy_view_is_not_overwritten_until_it_is_released() -> None:
    ep = await endpoint(queue_size=100, lease_slots=2)
    conn = await ShmSubscriberConnection.attach(answer(ep), HEADER, zero_copy=True)
    try:
        await until(lambda: ep.links)
        ep.publish(b"first" * 1000)
        view = await backports.wait_for(anext(conn), 5)
        assert isinstance(view, ShmView)
        assert ep.ring is not None
        for i in range(ep.ring.layout.slots + 3):  # laps the ring: these wait while the view is held
            ep.publish(bytes([i]) * 5000)
        assert view.intact() and bytes(view.data) == b"first" * 1000 and ep.backlog
        rest = [bytes((await backports.wait_for(anext(conn), 5)).data) for _ in range(ep.ring.layout.slots + 3)]
        assert rest == [bytes([i]) * 5000 for i in range(ep.ring.layout.slots + 3)] and conn.dropped == 0
    finally:
        await conn.aclose()
        await ep.aclose()


async def test_a_callback_that_keeps_nothing_has_every_copy_made_into_one_reused_buffer() -> None:
    ep = await endpoint(queue_size=100)
    sizes: list[int] = []
    conn = await ShmSubscriberConnection.attach(answer(ep), HEADER, on_frame=lambda b: sizes.append(len(b)))
    conn._pool.clear()  # the process's pool: nothing kept by earlier tests
    try:
        await until(lambda: ep.links)
        for i in range(10):  # one burst: drained in one batch, one frame after the other
            ep.publish(bytes([i]) * 200_000)
        await until(lambda: len(sizes) == 10)
        assert len(conn._pool) == 1  # the previous frame was let go before the next copy
    finally:
        await conn.aclose()
        await ep.aclose()
