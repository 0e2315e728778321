"""The ros2 part's services against hostile ROS 2 peers and slow ROS 1 servers: garbage request bodies, CDR
lengths that lie, missing or short attachments, a ROS 1 server that never answers, a flood of calls, a ROS 2
server that never replies or replies garbage, and one that vanishes. Each is a clear error to the caller, in
bounded time, and nothing stays in flight."""

from __future__ import annotations

import asyncio
import logging
import struct
import time
from pathlib import Path
from typing import Any

import pytest

import mrosd
from mrosd.errors import MrosError
from mrosd.msg import get_service_class
from mrosd.ros2.attachment import decode_attachment, encode_attachment
from mrosd.ros2.bridge import Ros2Bridge, Ros2Options
from tests.ros2.conftest import router
from tests.rosenv import Processes, needs_ros, ros_env

zenoh = pytest.importorskip("zenoh")
pytestmark = [needs_ros]
__all__ = ["router"]  # the in-process Zenoh router of tests/ros2

SETBOOL_HASH = "RIHS01_abe9e4bb6b41b40e6789712c00ec8871923e089af3f667a79992a428cff2da0a"
SetBool = get_service_class("std_srvs/SetBool")
GID = bytes(range(16))

SLOW = """
import time, rospy
from std_srvs.srv import SetBool
rospy.init_node("sleeper")
def never(req):
    time.sleep(60)
rospy.Service("/slow", SetBool, never)
rospy.spin()
"""


def _peer(router: int) -> Any:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", f'["tcp/127.0.0.1:{router}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


def _query(peer: Any, key: str, payload: bytes, attachment: bytes | None) -> list[tuple[str, bytes, bytes]]:
    """All replies to one query: ("ok" | "err", payload, attachment)."""
    kw: dict[str, Any] = {"payload": payload, "timeout": 20.0, "target": zenoh.QueryTarget.ALL_COMPLETE}
    if attachment is not None:
        kw["attachment"] = attachment
    out = []
    for reply in peer.get(key, **kw):
        if reply.ok is not None:
            att = reply.ok.attachment
            out.append(("ok", reply.ok.payload.to_bytes(), att.to_bytes() if att is not None else b""))
        else:
            out.append(("err", reply.err.payload.to_bytes(), b""))
    return out


def _cdr_strings(*texts: str) -> bytes:
    body = b"\x00\x01\x00\x00"
    for text in texts:
        raw = text.encode() + b"\x00"
        body += b"\x00" * (-len(body) % 4) if len(body) > 4 else b""
        body += struct.pack("<I", len(raw)) + raw
    return body


async def test_hostile_queries_and_a_ros1_server_that_never_answers_get_error_replies(
    procs: Processes, rosmaster: str, tmp_path: Path, router: int
) -> None:
    options = Ros2Options(
        domain_id=0,
        connect=(f"tcp/127.0.0.1:{router}",),
        to_ros2=("/slow", "/sleeper/set_logger_level"),
        service_timeout=1.0,
    )
    peer = await asyncio.to_thread(_peer, router)
    try:
        async with Ros2Bridge(options, rosmaster) as bridge:
            procs.python(SLOW, ros_env(rosmaster, tmp_path))
            services = bridge.services
            assert services is not None

            def offered() -> bool:
                return all(
                    (o := services.offered.get(n)) is not None and o.token is not None
                    for n in ("/slow", "/sleeper/set_logger_level")
                )

            await bridge.wait_until(offered, 30)
            logger_key = services.offered["/sleeper/set_logger_level"].key
            slow_key = services.offered["/slow"].key
            good = encode_attachment(7, time.time_ns(), GID)

            async def ask(key: str, payload: bytes, attachment: bytes | None) -> list[tuple[str, bytes, bytes]]:
                return await asyncio.to_thread(_query, peer, key, payload, attachment)

            # a well-formed call crosses, and the reply carries the request's sequence number and GID
            [(kind, body, att)] = await ask(logger_key, _cdr_strings("rospy", "info"), good)
            assert kind == "ok", body
            back = decode_attachment(att)
            assert (back.sequence_number, back.gid) == (7, GID)

            hostile = {
                "garbage body": (b"\x07\x07\x07", good),
                "lying length": (b"\x00\x01\x00\x00" + struct.pack("<I", 0x7FFFFFF0) + b"abc", good),
                "no attachment": (_cdr_strings("rospy", "info"), None),
                "short attachment": (_cdr_strings("rospy", "info"), good[:20]),
                "empty body": (b"", good),
            }
            for what, (payload, attachment) in hostile.items():
                replies = await ask(logger_key, payload, attachment)
                assert [k for k, _, _ in replies] == ["err"], (what, replies)
                assert replies[0][1].startswith(b"mrosd: /sleeper/set_logger_level"), (what, replies)

            # a ROS 1 server that never answers: an error reply once the call times out
            request = b"\x00\x01\x00\x00\x01"
            started = time.monotonic()
            [(kind, body, _)] = await ask(slow_key, request, good)
            assert kind == "err" and b"/slow" in body, body
            assert time.monotonic() - started < 5.0

            # a flood beyond the calls in flight: the excess is refused at once
            services.max_calls = 2
            replies = await asyncio.gather(*(ask(slow_key, request, good) for _ in range(5)))
            texts = [r[0][1] for r in replies]
            assert sum(b"too many calls in flight" in t for t in texts) >= 3, texts
            await bridge.wait_until(lambda: services.inflight_in == 0, 10)
            # still serving
            [(kind, body, _)] = await ask(logger_key, _cdr_strings("rospy", "info"), good)
            assert kind == "ok", body
    finally:
        await asyncio.to_thread(peer.close)


def _ss_token(zid: str, n: int, mangled: str) -> str:
    return f"@ros2_lv/0/{zid}/0/{n}/SS/%/%/evil/{mangled}/std_srvs::srv::dds_::SetBool_/{SETBOOL_HASH}/::,10:,:,:,,"


async def test_a_ros2_server_that_never_replies_replies_garbage_or_vanishes_is_a_clear_ros1_error(
    rosmaster: str, router: int, caplog: pytest.LogCaptureFixture
) -> None:
    """...and one announced under the name of a ROS 1 node's service never takes that name over (rosmaster
    would let a second registration replace the first)."""
    peer = await asyncio.to_thread(_peer, router)
    held: list[Any] = []  # queries kept unanswered
    entities: list[Any] = []

    def garble(query: Any) -> None:
        query.reply(query.key_expr, b"\x00\x01\x00\x00\x01\x00\x00\x00\xff\xff\xff\x7f", attachment=b"x" * 33)
        query.drop()

    try:
        zid = str(peer.zid())
        entities.append(
            peer.declare_queryable(f"0/silent/std_srvs::srv::dds_::SetBool_/{SETBOOL_HASH}", held.append, complete=True)
        )
        entities.append(
            peer.declare_queryable(f"0/garbled/std_srvs::srv::dds_::SetBool_/{SETBOOL_HASH}", garble, complete=True)
        )
        silent = peer.liveliness().declare_token(_ss_token(zid, 1, "%silent"))
        entities.append(peer.liveliness().declare_token(_ss_token(zid, 2, "%garbled")))
        entities.append(peer.liveliness().declare_token(_ss_token(zid, 3, "%taken")))
        # a publisher of a node named "SS": its token holds "/SS/" but is no service's
        string = "std_msgs::msg::dds_::String_/RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
        entities.append(peer.liveliness().declare_token(f"@ros2_lv/0/{zid}/0/4/MP/%/%/SS/%by_ss/{string}/::,:,:,:,,"))
        options = Ros2Options(
            domain_id=0,
            connect=(f"tcp/127.0.0.1:{router}",),
            from_ros2=("/silent", "/garbled", "/taken", "/by_ss"),
            service_timeout=1.0,
        )
        async with mrosd.Node("caller", master_uri=rosmaster, argv=[], host="127.0.0.1") as node:
            await node.advertise_service("/taken", SetBool, lambda req: SetBool._response_class(message="ROS 1's"))
            async with Ros2Bridge(options, rosmaster) as bridge:
                services = bridge.services
                assert services is not None
                with caplog.at_level(logging.WARNING, logger="mrosd.ros2.services"):
                    await bridge.wait_until(
                        lambda: (
                            all(
                                (p := services.provided.get(n)) is not None and p.service is not None
                                for n in ("/silent", "/garbled")
                            )
                            and any("/taken is a ROS 1 service already" in r.getMessage() for r in caplog.records)
                            and bridge.inbound is not None
                            and "/by_ss" in bridge.inbound.topics
                        ),
                        30,
                    )
                assert "/taken" not in services.provided
                request = SetBool._request_class(data=True)
                assert (await node.service_proxy("/taken", SetBool).call(request, timeout=5)).message == "ROS 1's"
                started = time.monotonic()
                with pytest.raises(MrosError, match="no answer"):
                    await node.service_proxy("/silent", SetBool).call(request, timeout=10)
                assert time.monotonic() - started < 5.0
                with pytest.raises(MrosError, match="does not convert"):
                    await node.service_proxy("/garbled", SetBool).call(request, timeout=10)
                assert services.inflight_out == 0

                silent.undeclare()  # the ROS 2 server vanishes: its ROS 1 service goes with it
                await bridge.wait_until(lambda: "/silent" not in services.provided, 10)
                with pytest.raises(MrosError):
                    await node.service_proxy("/silent", SetBool).call(request, timeout=5)

                # a server that flaps: at most one ROS 1 service, none once it is gone for good
                for n in range(20):
                    peer.liveliness().declare_token(_ss_token(zid, 100 + n, "%silent")).undeclare()
                last = peer.liveliness().declare_token(_ss_token(zid, 200, "%silent"))
                await bridge.wait_until(
                    lambda: (p := services.provided.get("/silent")) is not None and p.service is not None, 10
                )
                last.undeclare()
                await bridge.wait_until(lambda: "/silent" not in services.provided and not services._providing, 10)
                assert "/silent" not in bridge.node.services
    finally:
        for entity in entities:
            entity.undeclare()
        for query in held:
            query.drop()
        await asyncio.to_thread(peer.close)
