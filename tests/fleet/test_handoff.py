"""The crossings between Zenoh's threads and the loop: real threads, a real loop, a real Zenoh session."""

from __future__ import annotations

import asyncio
import threading

import pytest

from mrosd import backports
from mrosd.fleet.handoff import Inbox, Outbox


async def test_inbox_from_many_threads_is_bounded_and_counts_what_it_drops() -> None:
    loop = asyncio.get_running_loop()
    delivered: dict[str, int] = {}
    biggest = 0

    def deliver(name: str, items: list[int]) -> None:
        nonlocal biggest
        biggest = max(biggest, len(items))
        delivered[name] = delivered.get(name, 0) + len(items)

    inbox = Inbox(loop, deliver, maxlen=8, maxlen_of={"@big": 1000})

    def producer(name: str) -> None:
        for i in range(5000):
            inbox.put(name, i)

    threads = [threading.Thread(target=producer, args=(n,)) for n in ("a", "b", "@big", "a")]
    for t in threads:
        t.start()
    # joined on a worker thread: the loop keeps draining meanwhile, and the producers never wait for it
    await asyncio.to_thread(lambda: [t.join(10) for t in threads])
    await asyncio.sleep(0.05)
    assert biggest <= 1000
    for name, sent in (("a", 10_000), ("b", 5000), ("@big", 5000)):
        assert delivered.get(name, 0) + inbox.dropped(name) == sent
    assert inbox.dropped("a") > 0


async def test_outbox_sends_round_robin_and_announces() -> None:
    zenoh = pytest.importorskip("zenoh", reason="needs eclipse-zenoh")
    cfg = zenoh.Config()
    cfg.insert_json5("scouting/multicast/enabled", "false")
    session = await asyncio.to_thread(zenoh.open, cfg)
    got: list[str] = []
    loop = asyncio.get_running_loop()
    seen_both = asyncio.Event()

    def on_sample(sample: object) -> None:
        got.append(str(sample.key_expr))  # type: ignore[attr-defined]
        if "t/b" in got and "t/announce" in got:
            loop.call_soon_threadsafe(seen_both.set)

    try:
        sub = session.declare_subscriber("t/**", on_sample)
        pubs = {k: session.declare_publisher(k) for k in ("t/a", "t/b")}
        outbox = Outbox(session, maxlen=4, announce_options={}, period=0.05)
        outbox.announcements = frozenset({"t/announce"})
        outbox.start()
        for i in range(100):
            outbox.put("t/a", pubs["t/a"], b"%d" % i)
        outbox.put("t/b", pubs["t/b"], b"b")
        await backports.wait_for(seen_both.wait(), 5)
        await asyncio.sleep(0.2)  # what is still queued for t/a goes out (at most maxlen bodies)
        await asyncio.to_thread(outbox.close)
        assert got.count("t/a") + outbox.dropped("t/a") == 100
        sub.undeclare()
    finally:
        await asyncio.to_thread(session.close)
