"""The calls tcpros makes (mrosd.shm.topic): answer requestTopic, attach, publish, statistics; fallbacks."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field
from typing import Any

import pytest

from mrosd import backports
from mrosd.errors import HandshakeError
from mrosd.shm import topic as shm_topic
from mrosd.shm.negotiate import HostIdentity, subscriber_offer

MD5 = "992ce8a1687cec8c8bd883ec73ca41d1"


@dataclass
class FakeNode:
    name: str


@dataclass
class FakePublisher:
    topic: str = "/chatter"
    type: str = "std_msgs/String"
    md5sum: str = MD5
    message_definition: str = "string data"
    latch: bool = True
    queue_size: int = 10
    max_message_size: int | None = None
    latched: bytes | None = b"\x03\x00\x00\x00old"
    node: Any = field(default_factory=lambda: FakeNode("/talker"))


@dataclass
class FakeSubscriber:
    topic: str = "/chatter"
    type: str = "std_msgs/String"
    md5sum: str = MD5
    message_definition: str = "string data"
    node: Any = field(default_factory=lambda: FakeNode("/listener"))


async def test_a_same_host_subscriber_is_answered_with_shared_memory_and_gets_every_message() -> None:
    changes = asyncio.Event()
    side = shm_topic.ShmTopicPublisher(FakePublisher(), on_change=changes.set)
    protocols = shm_topic.request_protocols()
    assert [p[0] for p in protocols] == ["MROSSHM", "TCPROS"]
    params = await side.answer(protocols)
    assert params is not None and params[0] == "MROSSHM"
    got: list[bytes] = []
    three = asyncio.Event()

    def on_frame(body: bytes) -> None:
        got.append(body)
        if len(got) == 3:
            three.set()

    attached = await shm_topic.attach_subscriber(FakeSubscriber(), "http://x:1/", params, on_frame, timeout=5)
    assert attached is not None
    conn, header = attached
    try:
        assert header.callerid == "/talker" and header.latching == "1"
        await backports.wait_for(changes.wait(), 5)
        side.publish(b"new")
        side.publish_parts([b"a", b"b"], 2)
        await backports.wait_for(three.wait(), 5)
        assert got == [b"old", b"new", b"ab"]
        assert side.count() == 1
        assert side.stats_rows()[0][1:] == [8, 3, True, 0]  # the latched message counts
        assert side.bus_info_rows()[0][2:5] == ["o", "SHMROS", "/chatter"]
    finally:
        await conn.aclose()
        await side.aclose()


async def test_a_subscriber_of_another_type_is_refused_as_over_tcpros() -> None:
    side = shm_topic.ShmTopicPublisher(FakePublisher())
    params = await side.answer(shm_topic.request_protocols())
    with pytest.raises(HandshakeError, match=r"publisher \[http://x:1/\] refused \[/chatter\]: md5sums do not match"):
        await shm_topic.attach_subscriber(
            FakeSubscriber(type="std_msgs/Int32", md5sum="0" * 32), "http://x:1/", params, lambda b: None, timeout=5
        )
    await side.aclose()


async def test_tcpros_answers_and_other_hosts_are_left_to_tcpros(monkeypatch: pytest.MonkeyPatch) -> None:
    side = shm_topic.ShmTopicPublisher(FakePublisher())
    assert await side.answer([["TCPROS"]]) is None
    elsewhere = HostIdentity(boot_id="another-kernel", netns="1", uid=0)
    assert await side.answer([subscriber_offer(elsewhere), ["TCPROS"]]) is None
    assert side.endpoint is None
    assert await shm_topic.attach_subscriber(FakeSubscriber(), "u", ["TCPROS", "h", 1], lambda b: None, 1) is None
    monkeypatch.setenv("MROSD_SHM", "0")
    assert shm_topic.request_protocols() == [["TCPROS"]]
    assert await side.answer([subscriber_offer(HostIdentity("b", "n", 0)), ["TCPROS"]]) is None


async def test_a_declared_message_size_makes_the_pool_before_any_subscriber() -> None:
    side = shm_topic.ShmTopicPublisher(FakePublisher(latch=False, latched=None, max_message_size=1 << 20))
    try:
        await side.prepare()
        assert side.endpoint is not None and side.endpoint.ring is not None
        assert side.endpoint.ring.layout.capacity >= 1 << 20
        params = await side.answer(shm_topic.request_protocols())
        assert params is not None and side.endpoint.rings_made == 1
    finally:
        await side.aclose()
