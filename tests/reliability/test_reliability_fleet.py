"""The fleet part facing a hostile Zenoh peer: announcement floods, garbage keys, sample and query floods.

The peer is a bare Zenoh session in the test (no bridge): it can put any key and any payload, as anything
that reaches the robot's Zenoh port can.
"""

from __future__ import annotations

import asyncio
import time

import pytest

from mrosd.fleet.keys import ItemKind, discovery_key
from mrosd.msg import get_message_class, get_service_class
from tests.fleet.fleetenv import bare_peer, first_across, fleet

zenoh = pytest.importorskip("zenoh", reason="the fleet tests need eclipse-zenoh (pip install 'mrosd[fleet]')")

String = get_message_class("std_msgs/String")
SetBool = get_service_class("std_srvs/SetBool")
MD5 = String._md5sum


async def _master_answers_fast(robot: object) -> float:
    """Seconds a getSystemState from another node takes while the attack runs."""
    async with robot.node("observer") as n:  # type: ignore[attr-defined]
        t0 = time.monotonic()
        await n.master_call("getSystemState")
        return time.monotonic() - t0


async def test_announcement_flood_does_not_make_the_master_hold_a_publisher_per_name() -> None:
    async with fleet("robot1") as (r1,):
        peer = await asyncio.to_thread(bare_peer, r1.endpoint)
        try:
            for i in range(1000):
                key = discovery_key(ItemKind.PUBLISHER, "std_msgs/String", MD5, "evil", f"/t{i}")
                peer.put(key, b"")  # type: ignore[attr-defined]
            await asyncio.sleep(3)
            state = await r1.bridge.node.master_call("getSystemState")
            ours = [t for t, nodes in state[0] if r1.bridge.node.name in nodes]
            assert len(r1.bridge.received) <= r1.bridge.options.max_received
            assert len(ours) <= r1.bridge.options.max_received
            assert r1.bridge.status()["refused_items"] > 0
            assert await _master_answers_fast(r1) < 1.0
        finally:
            peer.close()  # type: ignore[attr-defined]


async def test_garbage_announcements_are_counted_and_ignored() -> None:
    async with fleet("robot1", "robot2") as (r1, r2), r1.node("talker") as a, r2.node("listener") as b:
        peer = await asyncio.to_thread(bare_peer, r2.endpoint)
        try:
            for key in [
                "ros1_discovery_info/*/pub/zz/abc/evil/t",
                f"ros1_discovery_info/*/bogus/{b'a/B'.hex()}/{MD5}/evil/t",
                f"ros1_discovery_info/*/pub/{b'not a type'.hex()}/{MD5}/evil/t",
                f"ros1_discovery_info/*/pub/{b'a/B'.hex()}/{MD5}/evil/9t",
            ]:
                for _ in range(50):
                    peer.put(key, b"")  # type: ignore[attr-defined]
            # the honest robot still gets through
            pub = await a.advertise("/chatter", String)
            pub.publish_nowait(String(data="x"))
            assert (await first_across(r2, "/robot1/chatter", String, pub, String(data="x"), b)).data == "x"
            assert r2.bridge.status()["bad_announcements"] >= 4
            assert not [t for t in r2.bridge.received if "evil" in t]
        finally:
            peer.close()  # type: ignore[attr-defined]


async def test_sample_flood_to_a_subscriber_that_does_not_read_is_bounded() -> None:
    async with fleet("robot2") as (r2,), r2.node("stalled") as b:
        peer = await asyncio.to_thread(bare_peer, r2.endpoint)
        try:
            peer.put(discovery_key(ItemKind.PUBLISHER, "std_msgs/String", MD5, "evil", "/flood"), b"")  # type: ignore[attr-defined]
            await r2.bridge.wait_until(lambda: "/evil/flood" in r2.bridge.received, 15)
            sub = await b.subscribe("/evil/flood", String, queue_size=1)  # never read
            await r2.bridge.wait_until(lambda: r2.bridge.received["/evil/flood"].subscriber is not None, 15)
            body = String(data="y" * 65_000).serialize()
            key = r2.bridge.received["/evil/flood"].item.data_key

            def flood() -> None:
                for _ in range(5_000):
                    peer.put(key, body)  # type: ignore[attr-defined]

            flooding = asyncio.create_task(asyncio.to_thread(flood))
            slowest = 0.0
            while not flooding.done():
                peer.put(discovery_key(ItemKind.PUBLISHER, "std_msgs/String", MD5, "evil", "/flood"), b"")  # type: ignore[attr-defined]
                slowest = max(slowest, await _master_answers_fast(r2))
            await flooding
            st = r2.bridge.status()["received"]["/evil/flood"]
            assert slowest < 1.0, f"a master call took {slowest:.2f} s during the flood"
            assert st["messages"] + st["dropped"] > 0
            assert len(sub._queue) <= 1 if hasattr(sub, "_queue") else True
        finally:
            peer.close()  # type: ignore[attr-defined]


async def test_query_flood_on_a_slow_service_is_capped() -> None:
    async with fleet("robot1") as (r1,), r1.node("server") as a:
        running = 0
        most = 0

        async def slow(req: object) -> object:
            nonlocal running, most
            running += 1
            most = max(most, running)
            await asyncio.sleep(1.0)
            running -= 1
            return SetBool._response_class(success=True)

        await a.advertise_service("/set", SetBool, slow)
        await r1.bridge.wait_until(
            lambda: r1.bridge.sent_services.get("/set") is not None and r1.bridge.sent_services["/set"].key != "", 15
        )
        key = r1.bridge.sent_services["/set"].key
        peer = await asyncio.to_thread(bare_peer, r1.endpoint)
        try:
            replies: list[object] = []
            for _ in range(300):
                peer.get(key, replies.append, payload=SetBool._request_class(data=True).serialize(), timeout=5)  # type: ignore[attr-defined]
            await asyncio.sleep(3)
            assert most <= 64
            assert r1.bridge.status()["refused_calls"] > 0
            assert await _master_answers_fast(r1) < 1.0
        finally:
            peer.close()  # type: ignore[attr-defined]
