"""Hostile requests to the daemon's tf2_web_republisher (``/republish_tfs`` and its action), over real sockets.

tf2_web_republisher itself takes rate 0 (a timer of infinite period), NaN thresholds (never an update), any number
of frames and subscriptions, and a timeout of 0 (the topic gone before the client subscribes). Here each is
refused with a status saying why, or clamped, and the node keeps serving the next client.
"""

from __future__ import annotations

import asyncio
import math
import struct
from collections.abc import AsyncIterator, Callable
from typing import Any

import pytest

import mrosd
from mrosd import backports
from mrosd.actions import ActionClient, Status
from mrosd.errors import ServiceError
from mrosd.master import Master
from mrosd.msg import Duration, get_message_class, get_service_class
from mrosd.tf import TransformBroadcaster, transform_stamped
from mrosd.tf.republish import MAX_RATE, Limits
from mrosd.tf.republish_node import SERVICE_NAME, TFRepublisherNode
from mrosd.wire.header import encode_header

RepublishTFs = get_service_class("tf2_web_republisher/RepublishTFs")
Request = RepublishTFs._request_class
TFArray = get_message_class("tf2_web_republisher/TFArray")
Goal = get_message_class("tf2_web_republisher/TFSubscriptionGoal")


@pytest.fixture
async def robot() -> AsyncIterator[tuple[Master, TFRepublisherNode, mrosd.Node]]:
    async with Master(host="127.0.0.1", port=0) as master:
        repub = TFRepublisherNode(master.uri, host="127.0.0.1", limits=Limits(max_subscriptions=4), goal_idle_timeout=1)
        async with repub, mrosd.Node("client", master_uri=master.uri, argv=[], host="127.0.0.1") as node:
            assert repub.serving
            yield master, repub, node


async def until(repub: TFRepublisherNode, done: Callable[[], bool], timeout: float = 5.0) -> None:
    """Wait for ``done()``, woken by each subscription the republisher adds or removes."""
    async with backports.timeout(timeout):
        while not done():
            repub.changed.clear()
            if not done():
                await repub.changed.wait()


def request(**kw: Any) -> Any:
    fields: dict[str, Any] = {
        "source_frames": ["arm"],
        "target_frame": "world",
        "angular_thres": 0.0,
        "trans_thres": 0.0,
        "rate": 10.0,
        "timeout": Duration(2, 0),
    }
    fields.update(kw)
    return Request(**fields)


async def refused(node: mrosd.Node, req: Any) -> str:
    with pytest.raises(ServiceError) as info:
        await node.service_proxy(SERVICE_NAME, RepublishTFs).call(req)
    return str(info.value)


@pytest.mark.parametrize(
    ("fields", "why"),
    [
        ({"rate": 0.0}, "rate must be above 0 Hz"),
        ({"rate": -5.0}, "rate must be above 0 Hz"),
        ({"rate": math.nan}, "rate must be a finite number"),
        ({"rate": math.inf}, "rate must be a finite number"),
        ({"angular_thres": math.nan}, "angular_thres must be a finite number"),
        ({"trans_thres": -1.0}, "thresholds must not be negative"),
        ({"source_frames": [f"f{i}" for i in range(5000)]}, "5000 source frames asked; at most 1000"),
        ({"source_frames": ["x" * 1_000_000]}, "a frame id of 1000000 characters"),
        ({"target_frame": "/"}, "empty frame id"),
    ],
)
async def test_hostile_requests_are_refused_with_the_reason(robot: Any, fields: dict[str, Any], why: str) -> None:
    _, repub, node = robot
    assert why in await refused(node, request(**fields))
    assert repub.core.subscriptions == {}
    ok = await node.service_proxy(SERVICE_NAME, RepublishTFs).call(request())  # the next client is served
    assert ok.topic_name == "/tf2_web_republisher/tf_repub_0"


async def test_a_request_claiming_a_billion_frames_is_refused_before_anything_is_allocated(robot: Any) -> None:
    _, repub, node = robot
    uri = await node.master.lookup_service(SERVICE_NAME)
    host, port = uri.removeprefix("rosrpc://").rstrip("/").rsplit(":", 1)
    reader, writer = await asyncio.open_connection(host, int(port))
    try:
        header = {"callerid": "/evil", "service": SERVICE_NAME, "md5sum": RepublishTFs._md5sum}
        writer.write(encode_header(header))
        body = struct.pack("<I", 1_000_000_000)  # source_frames: a count of 10^9 and nothing behind it
        writer.write(struct.pack("<I", len(body)) + body)
        await writer.drain()
        async with backports.timeout(5):
            (hlen,) = struct.unpack("<I", await reader.readexactly(4))
            await reader.readexactly(hlen)
            ok = (await reader.readexactly(1))[0]
            (n,) = struct.unpack("<I", await reader.readexactly(4))
            text = (await reader.readexactly(n)).decode()
    finally:
        writer.close()
        await writer.wait_closed()
    assert ok == 0 and "cannot decode" in text
    assert repub.core.subscriptions == {}


async def test_subscriptions_are_capped_and_an_unused_topic_frees_its_slot(robot: Any) -> None:
    _, repub, node = robot
    proxy = node.service_proxy(SERVICE_NAME, RepublishTFs)
    for _ in range(4):
        await proxy.call(request(timeout=Duration(0, 0)))  # 0: clamped to MIN_TOPIC_TIMEOUT (1 s), not gone at once
    assert "4 subscriptions are held" in await refused(node, request())
    # nobody subscribed: each topic goes after its timeout, and with the last one /tf is not followed any more
    await until(repub, lambda: not repub.core.subscriptions and repub.buffer is None)
    assert (await proxy.call(request())).topic_name == "/tf2_web_republisher/tf_repub_4"


async def test_a_huge_rate_is_clamped_and_an_unknown_frame_is_never_sent(robot: Any) -> None:
    _, _repub, node = robot
    reply = await node.service_proxy(SERVICE_NAME, RepublishTFs).call(request(source_frames=["arm", "ghost"], rate=1e9))
    got: list[Any] = []
    sub = await node.subscribe(reply.topic_name, TFArray, got.append)
    tf = TransformBroadcaster(node)
    loop = asyncio.get_running_loop()
    start = loop.time()
    while loop.time() - start < 1.0:
        await tf.send_transform(transform_stamped("world", "arm", mrosd.Time.now().to_nsec(), (1, 0, 0, 0, 0, 0, 1)))
        await asyncio.sleep(0.01)
    await sub.aclose()
    assert 20 <= len(got) <= MAX_RATE * 1.2  # thresholds 0: one message a tick, at most MAX_RATE ticks a second
    assert {t.child_frame_id for m in got for t in m.transforms} == {"arm"}  # "ghost" never sent


async def test_a_hostile_goal_ends_aborted_with_the_reason_and_an_abandoned_one_ends(robot: Any) -> None:
    _, repub, node = robot
    async with ActionClient(node, "/tf2_web_republisher", "tf2_web_republisher/TFSubscriptionAction") as client:
        await client.wait_for_server(timeout=10)
        bad = await client.send_goal(Goal(source_frames=["arm"], target_frame="world", rate=math.nan))
        await backports.wait_for(bad, 5)
        assert bad.status is Status.ABORTED and "rate must be a finite number" in bad.text
        good = await client.send_goal(Goal(source_frames=["arm"], target_frame="world", rate=10.0))
        await until(repub, lambda: bool(repub.core.subscriptions))
    # the client is gone (no subscriber to the feedback): the goal ends after goal_idle_timeout (1 s here)
    await until(repub, lambda: not repub.core.subscriptions)
    assert good.status is not Status.SUCCEEDED


async def test_a_running_tf2_web_republisher_keeps_the_names_and_a_later_one_takes_them_over(robot: Any) -> None:
    master, repub, _ = robot
    second = TFRepublisherNode(master.uri, host="127.0.0.1")
    async with second:
        assert not second.serving  # the first one holds the node name and /republish_tfs
    assert repub.serving
    # a real tf2_web_republisher starting later registers the same node name: the master shuts ours down
    async with mrosd.Node("/tf2_web_republisher", master_uri=master.uri, argv=[], host="127.0.0.1") as real:
        await real.advertise_service("/republish_tfs", RepublishTFs, lambda _req: None)
        async with backports.timeout(5):
            await repub.node.shutdown_event.wait()
        await until(repub, lambda: not repub.serving)
        assert await real.master.lookup_service("/republish_tfs") == real.service_uri
