"""The ros2 part against hostile ROS 1 graphs: names Zenoh cannot carry, types ROS 2 cannot express, bad
bodies, and a ROS 2 side that stops reading."""

from __future__ import annotations

import asyncio
import logging
import time
import xmlrpc.client
from typing import Any

import pytest

import mrosd
from mrosd.msg import get_message_class, load_type
from mrosd.ros2.bridge import Ros2Bridge, Ros2Options
from tests.ros2.conftest import router

zenoh = pytest.importorskip("zenoh")
String = get_message_class("std_msgs/String")
__all__ = ["router"]  # the in-process Zenoh router of tests/ros2


def _options(router: int, *globs: str, queue_size: int = 16) -> Ros2Options:
    return Ros2Options(domain_id=0, connect=(f"tcp/127.0.0.1:{router}",), to_ros2=globs, queue_size=queue_size)


async def test_topic_names_zenoh_cannot_carry_are_skipped_with_one_line(
    rosmaster: str, router: int, caplog: pytest.LogCaptureFixture
) -> None:
    """A stranger registers publishers under names that are not ROS names (a Zenoh wildcard, the mangling
    character); rosmaster takes them. The bridge must not put them on Zenoh keys."""
    bad = ["/bad/**", "/chat%ter", "/x/$*"]
    with caplog.at_level(logging.WARNING, logger="mrosd.ros2.bridge"):
        async with Ros2Bridge(_options(router, "/**"), rosmaster) as bridge:
            with xmlrpc.client.ServerProxy(rosmaster) as api:
                for topic in bad:
                    await asyncio.to_thread(
                        api.registerPublisher, "/stranger", topic, "std_msgs/String", "http://127.0.0.1:9/"
                    )
            reads = bridge.graph_reads
            await bridge.wait_until(lambda: bridge.graph_reads >= reads + 2, 10)
        assert not set(bad) & set(bridge.topics)
        lines = [r.getMessage() for r in caplog.records if "not a ROS name" in r.getMessage()]
        assert len(lines) == len(bad), lines


CUSTOM_BAD = "float64 X\n"
CUSTOM_OK = "float64 x\n"


async def test_an_unmappable_type_is_one_line_and_the_other_topics_still_cross(
    rosmaster: str, router: int, caplog: pytest.LogCaptureFixture
) -> None:
    bad_cls = load_type("my_pkg/Bad", CUSTOM_BAD)
    ok_cls = load_type("my_pkg/Good", CUSTOM_OK)
    with caplog.at_level(logging.WARNING, logger="mrosd.ros2.bridge"):
        async with (
            Ros2Bridge(_options(router, "/bad", "/good"), rosmaster) as bridge,
            mrosd.Node("talker", master_uri=rosmaster, argv=[], host="127.0.0.1") as node,
        ):
            pub_bad = await node.advertise("/bad", bad_cls)
            pub_ok = await node.advertise("/good", ok_cls)

            async def publish_until() -> None:
                while True:
                    await pub_bad.publish(bad_cls())
                    await pub_ok.publish(ok_cls())
                    await asyncio.sleep(0.05)

            task = asyncio.create_task(publish_until())
            try:
                await bridge.wait_until(
                    lambda: (
                        "/bad" in bridge.topics
                        and bool(bridge.topics["/bad"].problem)
                        and "/good" in bridge.topics
                        and bridge.topics["/good"].rmw is not None
                        and bridge.topics["/good"].rmw.sent > 0
                    ),
                    30,
                )
            finally:
                task.cancel()
    lines = [r.getMessage() for r in caplog.records if "my_pkg/Bad" in r.getMessage()]
    assert len(lines) == 1 and "'X'" in lines[0] and "\n" not in lines[0]


async def test_a_ros2_side_that_stops_reading_never_stalls_the_loop_and_drops_oldest(
    rosmaster: str, router: int
) -> None:
    """1080p images into a Zenoh subscriber whose callback blocks: the link fills, the sender thread waits, the
    per-topic queue drops its oldest, and the loop keeps ticking."""
    release = __import__("threading").Event()
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", f'["tcp/127.0.0.1:{router}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    stuck = zenoh.open(conf)
    sub = stuck.declare_subscriber("0/camera/**", lambda sample: release.wait(30))
    Image = get_message_class("sensor_msgs/Image")
    img = Image()
    img.height, img.width, img.encoding, img.step = 1080, 1920, "rgb8", 5760
    img.data = bytes(1920 * 1080 * 3)
    worst = 0.0
    try:
        async with (
            Ros2Bridge(_options(router, "/camera/image", queue_size=4), rosmaster) as bridge,
            mrosd.Node("camera", master_uri=rosmaster, argv=[], host="127.0.0.1") as node,
        ):
            pub = await node.advertise("/camera/image", Image)
            await bridge.wait_until(lambda: "/camera/image" in bridge.topics, 20)
            key: list[str] = []
            end = time.monotonic() + 20
            while time.monotonic() < end:
                before = time.monotonic()
                await pub.publish(img)
                await asyncio.sleep(1 / 30)
                worst = max(worst, time.monotonic() - before - 1 / 30)
                bt: Any = bridge.topics.get("/camera/image")
                if bt is not None and bt.key:
                    key[:] = [bt.key]
                    if bridge.status()[0]["dropped"] >= 20:
                        break
            assert key, "the image topic was never mapped"
            status = bridge.status()[0]
            assert status["dropped"] >= 20, status
            assert worst < 0.5, f"the loop stalled {worst:.3f} s"
            release.set()
    finally:
        release.set()
        sub.undeclare()
        stuck.close()


STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"


def _peer(router: int) -> Any:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", f'["tcp/127.0.0.1:{router}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


def _mp_token(zid: str, n: int, mangled_topic: str) -> str:
    return f"@ros2_lv/0/{zid}/0/{n}/MP/%/%/evil/{mangled_topic}/std_msgs::msg::dds_::String_/{STRING_HASH}/::,:,:,:,,"


async def test_a_ros2_peer_announcing_names_that_are_not_ros_names_or_too_many_topics_is_bounded(
    rosmaster: str, router: int, caplog: pytest.LogCaptureFixture
) -> None:
    """A hostile ROS 2 peer announces publishers on non-canonical names (``/a//b``, ``/a b``, ``/c/``) and on
    more topics than the bridge takes from ROS 2: none of the first get a ROS 1 publisher or a Zenoh
    subscription, and the rest stop at the cap, one line."""
    from mrosd.ros2 import inbound

    peer = _peer(router)
    zid = str(peer.zid())
    tokens = [peer.liveliness().declare_token(_mp_token(zid, i, t)) for i, t in enumerate(["%a%%b", "%a b", "%c%"])]
    many = inbound.MAX_RECEIVED_TOPICS + 5
    tokens += [peer.liveliness().declare_token(_mp_token(zid, 100 + i, f"%many%t{i}")) for i in range(many)]
    try:
        with caplog.at_level(logging.WARNING, logger="mrosd.ros2.inbound"):
            async with Ros2Bridge(
                Ros2Options(domain_id=0, connect=(f"tcp/127.0.0.1:{router}",), from_ros2=("/**",)), rosmaster
            ) as bridge:
                await bridge.wait_until(
                    lambda: bridge.inbound is not None and len(bridge.inbound.topics) >= inbound.MAX_RECEIVED_TOPICS,
                    60,
                )
                await asyncio.sleep(0.5)
                assert bridge.inbound is not None
                names = set(bridge.inbound.topics)
        assert not names & {"/a//b", "/a b", "/c/", "/a/b", "/c"}
        assert len(names) == inbound.MAX_RECEIVED_TOPICS
        messages = [r.getMessage() for r in caplog.records]
        assert sum("not a ROS name" in m for m in messages) == 3
        assert sum("more than" in m for m in messages) == 1
    finally:
        for tok in tokens:
            tok.undeclare()
        peer.close()
