"""Two mrosd masters linked over Zenoh, with mrosd nodes on each (real sockets, one process)."""

from __future__ import annotations

import asyncio

from mrosd.msg import get_message_class, get_service_class
from tests.fleet.fleetenv import first_across, fleet, publish_forever

String = get_message_class("std_msgs/String")
SetBool = get_service_class("std_srvs/SetBool")


async def test_topic_crosses_under_the_robots_name() -> None:
    async with fleet("robot1", "robot2") as (r1, r2), r1.node("talker") as a, r2.node("listener") as b:
        pub = await a.advertise("/chatter", String)

        task = asyncio.create_task(publish_forever(pub, String(data="hello")))
        try:
            await r2.bridge.wait_until(lambda: "/robot1/chatter" in r2.bridge.received, 15)
            await asyncio.sleep(0.5)
            # nobody on robot2 asked yet: robot1 sends nothing over the link
            assert r1.bridge.sent["/chatter"].sent == 0
            sub = await b.subscribe("/robot1/chatter", String)
            msg = await sub.next(timeout=10)
            assert msg.data == "hello"
            st = r2.bridge.status()
            assert st["received"]["/robot1/chatter"]["messages"] >= 1
            assert r1.bridge.status()["sent"]["/chatter"]["matched"]
        finally:
            task.cancel()


async def test_service_call_across_and_its_error() -> None:
    async with fleet("robot1", "robot2") as (r1, r2), r1.node("server") as a, r2.node("client") as b:

        def handle(req: object) -> object:
            if not req.data:  # type: ignore[attr-defined]
                raise ValueError("refused on purpose")
            return SetBool._response_class(success=True, message="done on robot1")

        await a.advertise_service("/set", SetBool, handle)
        proxy = b.service_proxy("/robot1/set", SetBool)
        await proxy.wait_for_service(timeout=15)
        resp = await proxy.call(SetBool._request_class(data=True))
        assert resp.success and resp.message == "done on robot1"
        try:
            await proxy.call(SetBool._request_class(data=False))
        except Exception as exc:
            assert "refused on purpose" in str(exc)
        else:
            raise AssertionError("the remote error did not reach the caller")
        assert r1.bridge.status()["services_sent"]["/set"]["calls"] == 2
        assert r2.bridge.status()["services_received"]["/robot1/set"]["errors"] == 1


async def test_latched_topic_reaches_a_late_subscriber() -> None:
    async with fleet("robot1", "robot2") as (r1, r2), r1.node("mapper") as a, r2.node("late") as b:
        pub = await a.advertise("/map", String, latch=True)
        await pub.publish(String(data="the map"))
        await r2.bridge.wait_until(lambda: "/robot1/map" in r2.bridge.received, 15)
        await asyncio.sleep(1.0)  # published long before anyone on robot2 asked for it
        sub = await b.subscribe("/robot1/map", String)
        msg = await sub.next(timeout=10)
        assert msg.data == "the map"
        assert r2.bridge.status()["received"]["/robot1/map"]["latched"]


async def test_tf_frames_get_the_robot_name() -> None:
    tf_message = get_message_class("tf2_msgs/TFMessage")
    stamped = get_message_class("geometry_msgs/TransformStamped")
    async with fleet("robot1", "robot2", prefix_tf=True) as (r1, r2), r1.node("tf") as a, r2.node("viewer") as b:
        pub = await a.advertise("/tf", tf_message)
        t = stamped(child_frame_id="base_link")
        t.header.frame_id = "odom"
        msg = await first_across(r2, "/robot1/tf", tf_message, pub, tf_message(transforms=[t]), b)
        assert (msg.transforms[0].header.frame_id, msg.transforms[0].child_frame_id) == (
            "robot1/odom",
            "robot1/base_link",
        )


async def test_a_latched_message_that_crossed_live_is_latched_for_later_subscribers() -> None:
    async with (
        fleet("robot1", "robot2") as (r1, r2),
        r1.node("mapper") as a,
        r2.node("early") as b,
        r2.node("late") as c,
    ):
        pub = await a.advertise("/map", String, latch=True)
        await r2.bridge.wait_until(lambda: "/robot1/map" in r2.bridge.received, 15)
        early = await b.subscribe("/robot1/map", String)
        await r1.bridge.wait_until(lambda: r1.bridge.sent["/map"].matched, 15)
        await pub.publish(String(data="the map"))  # crosses live: someone on robot2 already listens
        assert (await early.next(timeout=10)).data == "the map"
        late = await c.subscribe("/robot1/map", String)
        assert (await late.next(timeout=10)).data == "the map"
