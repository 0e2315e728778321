"""A peer that behaves as zenoh-bridge-ros1 does on the wire (facts from its source), over a real Zenoh link.

The peer is a bare Zenoh session that puts and subscribes exactly the keys and payloads the bridge's
``discovery.rs``, ``topic_utilities.rs``, ``abstract_bridge.rs`` and ``aloha_declaration.rs`` produce with
``BRIDGE_NAMESPACE`` unset (``*``): announcements with no payload, data as the body without its length, services
as queryables answered with the response body.
"""

from __future__ import annotations

import asyncio
import threading

import pytest

from mrosd import backports
from mrosd.fleet.keys import RenameRule
from mrosd.msg import get_message_class, get_service_class
from tests.fleet.fleetenv import bare_peer, fleet

zenoh = pytest.importorskip("zenoh", reason="the fleet tests need eclipse-zenoh (pip install 'mrosd[fleet]')")

String = get_message_class("std_msgs/String")
SetBool = get_service_class("std_srvs/SetBool")
STRING_KEY = "7374645f6d7367732f537472696e67/992ce8a1687cec8c8bd883ec73ca41d1"
SETBOOL_KEY = f"{b'std_srvs/SetBool'.hex()}/{SetBool._md5sum}"
HELLO = b"\x05\x00\x00\x00hello"


class Beacons:
    """The bridge's ALOHA declaration: the same empty put every period until stopped (a thread)."""

    def __init__(self, session: object, keys: list[str], period: float = 0.5) -> None:
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(session, keys, period), daemon=True)
        self._thread.start()

    def _run(self, session: object, keys: list[str], period: float) -> None:
        while not self._stop.wait(period):
            for key in keys:
                session.put(key, b"")  # type: ignore[attr-defined]

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)


async def test_a_bridge_robots_topic_and_service_reach_mrosd() -> None:
    async with fleet("robot2", rename=RenameRule(wildcard_robot="legacy")) as (r2,), r2.node("listener") as b:
        peer = await asyncio.to_thread(bare_peer, r2.endpoint)
        loop = asyncio.get_running_loop()
        asked = asyncio.Event()
        wanted = f"ros1_discovery_info/*/sub/{STRING_KEY}/*/chatter"

        def on_announcement(sample: object) -> None:
            if str(sample.key_expr) == wanted:  # type: ignore[attr-defined]
                loop.call_soon_threadsafe(asked.set)

        listener = peer.declare_subscriber("ros1_discovery_info/*/*/*/*/*/*/**", on_announcement)  # type: ignore[attr-defined]

        def answer(query: object) -> None:
            with query:  # type: ignore[attr-defined]
                req = SetBool._request_class.deserialize(query.payload.to_bytes())  # type: ignore[attr-defined]
                resp = SetBool._response_class(success=req.data, message="from a bridge robot")
                query.reply(query.key_expr, resp.serialize())  # type: ignore[attr-defined]

        queryable = peer.declare_queryable(f"{SETBOOL_KEY}/*/set", answer)  # type: ignore[attr-defined]
        beacons = Beacons(
            peer,
            [f"ros1_discovery_info/*/pub/{STRING_KEY}/*/chatter", f"ros1_discovery_info/*/srv/{SETBOOL_KEY}/*/set"],
        )
        stop = threading.Event()

        def publish() -> None:
            while not stop.wait(0.05):
                peer.put(f"{STRING_KEY}/*/chatter", HELLO)  # type: ignore[attr-defined]

        pusher = threading.Thread(target=publish, daemon=True)
        pusher.start()
        try:
            await r2.bridge.wait_until(lambda: "/legacy/chatter" in r2.bridge.received, 15)
            sub = await b.subscribe("/legacy/chatter", String)
            assert (await sub.next(timeout=10)).data == "hello"
            # it asks for the topic the way a bridge would hear it: under the bridge's namespace '*'
            await backports.wait_for(asked.wait(), 5)
            proxy = b.service_proxy("/legacy/set", SetBool)
            await proxy.wait_for_service(timeout=15)
            resp = await proxy.call(SetBool._request_class(data=True))
            assert resp.success and resp.message == "from a bridge robot"
        finally:
            stop.set()
            pusher.join(5)
            beacons.stop()
            queryable.undeclare()
            listener.undeclare()
            await asyncio.to_thread(peer.close)  # type: ignore[attr-defined]


async def test_mrosd_topic_and_service_reach_a_bridge_robot() -> None:
    async with fleet("robot1") as (r1,), r1.node("talker") as a:

        def handle(req: object) -> object:
            return SetBool._response_class(success=True, message="from mrosd")

        await a.advertise_service("/set", SetBool, handle)
        pub = await a.advertise("/chatter", String)
        peer = await asyncio.to_thread(bare_peer, r1.endpoint)
        heard: list[str] = []
        bodies: list[bytes] = []
        listener = peer.declare_subscriber(  # type: ignore[attr-defined]
            "ros1_discovery_info/*/*/*/*/*/*/**", lambda s: heard.append(str(s.key_expr))
        )
        # the bridge's ZenohToRos1 subscribes under its own namespace '*', which matches every robot's
        data = peer.declare_subscriber(f"{STRING_KEY}/*/chatter", lambda s: bodies.append(s.payload.to_bytes()))  # type: ignore[attr-defined]
        try:
            async with backports.timeout(15):
                while f"ros1_discovery_info/*/pub/{STRING_KEY}/robot1/chatter" not in heard or not bodies:
                    pub.publish_nowait(String(data="hello"))
                    await asyncio.sleep(0.05)
            assert bodies[0] == HELLO
            assert f"ros1_discovery_info/*/srv/{SETBOOL_KEY}/robot1/set" in heard
            # the bridge's Ros1ToZenohClient: a get on the service key with the request body
            request = SetBool._request_class(data=True).serialize()
            replies = await asyncio.to_thread(
                lambda: list(peer.get(f"{SETBOOL_KEY}/*/set", payload=request, timeout=10))  # type: ignore[attr-defined]
            )
            assert replies and replies[0].ok is not None
            resp = SetBool._response_class.deserialize(replies[0].ok.payload.to_bytes())
            assert resp.success and resp.message == "from mrosd"
        finally:
            data.undeclare()
            listener.undeclare()
            await asyncio.to_thread(peer.close)  # type: ignore[attr-defined]
