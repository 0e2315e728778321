"""A stranger's Zenoh peer against the ros2 part, as issue 31 attacked the fleet part (cases 3 and 4).

With ``router = true`` the bridge listens on every address, and any rmw_zenoh node, or a bare Zenoh session that
fakes rmw_zenoh's keys and liveliness tokens, can reach it. The stranger here is such a bare session: it
announces publishers and servers under any name and type, puts any body on a data key, and sends any request
to an exported service. It may publish only into the names ``from_ros2`` imports and call only the services
``to_ros2`` exports; nothing malformed reaches a rospy node; garbage and slow calls never block an honest
one; thousands of announcements hold bounded memory and a few log lines.
"""

from __future__ import annotations

import asyncio
import logging
import struct
import time
from collections.abc import AsyncIterator
from contextlib import AsyncExitStack, asynccontextmanager
from pathlib import Path
from typing import Any

import pytest

import mrosd
from mrosd.fleet.raw import raw_message_class
from mrosd.master import Master
from mrosd.msg import get_message_class
from mrosd.ros2 import inbound as inbound_mod
from mrosd.ros2 import services as services_mod
from mrosd.ros2.attachment import encode_attachment
from mrosd.ros2.bridge import Ros2Bridge, Ros2Options
from mrosd.ros2.keys import data_key, dds_type_name, mangle_name
from mrosd.ros2.types import TypeMapper
from tests.rosenv import ROS_PYTHON, Processes, free_port, iter_lines_until, needs_ros, ros_env

zenoh = pytest.importorskip("zenoh")
pytestmark = [needs_ros]

String = get_message_class("std_msgs/String")
Twist = get_message_class("geometry_msgs/Twist")
_MAPPER = TypeMapper()
STRING_HASH = _MAPPER.mapping("std_msgs/String").type_hash
TWIST_HASH = _MAPPER.mapping("geometry_msgs/Twist").type_hash
SETBOOL_HASH = "RIHS01_abe9e4bb6b41b40e6789712c00ec8871923e089af3f667a79992a428cff2da0a"
CDR_HEADER = b"\x00\x01\x00\x00"

BASE_CONTROLLER = """
import sys, rospy
from geometry_msgs.msg import Twist
from std_msgs.msg import String
rospy.init_node("base_controller")
rospy.Subscriber("/cmd_vel", Twist, lambda m: (print("twist", m.linear.x), sys.stdout.flush()))
rospy.Subscriber("/imported", String, lambda m: (print(m.data), sys.stdout.flush()))
print("ready"); sys.stdout.flush()
rospy.spin()
"""

SLOW = """
import sys, time, rospy
from std_srvs.srv import SetBool, SetBoolResponse
rospy.init_node("sleeper")
def never(req):
    time.sleep(60)
rospy.Service("/slow", SetBool, never)
rospy.Service("/fast", SetBool, lambda req: SetBoolResponse(success=req.data, message="rospy answered"))
print("ready"); sys.stdout.flush()
rospy.spin()
"""

CALLER = """
import sys, rospy
from std_srvs.srv import SetBool
rospy.init_node("caller")
for name in sys.argv[1:]:
    rospy.wait_for_service(name, 20)
    try:
        rospy.ServiceProxy(name, SetBool)(True)
        print(name, "answered")
    except rospy.ServiceException as exc:
        print(name, "error", str(exc).replace("\\n", " "))
    sys.stdout.flush()
"""


def _token(zid: str, n: int, kind: str, name: str, ros2_type: str, type_hash: str, qos: str = "::,:,:,:,,") -> str:
    return f"@ros2_lv/0/{zid}/0/{n}/{kind}/%/%/evil/{mangle_name(name)}/{dds_type_name(ros2_type)}/{type_hash}/{qos}"


def _peer(endpoint: str) -> Any:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", f'["{endpoint}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


@asynccontextmanager
async def robot(**keys: Any) -> AsyncIterator[tuple[str, Ros2Bridge, str]]:
    """An mrosd master and a bridge with ``router = true`` (it listens; the stranger dials it)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    async with AsyncExitStack() as stack:
        master = await stack.enter_async_context(Master(host="127.0.0.1", port=0))
        options = Ros2Options(domain_id=0, connect=(), listen=(endpoint,), router=True, **keys)
        bridge = await stack.enter_async_context(Ros2Bridge(options, master.uri, host="127.0.0.1"))
        yield master.uri, bridge, endpoint


async def _lines(proc: Any, count: int, timeout: float) -> list[str]:
    return await asyncio.to_thread(lambda: list(iter_lines_until(proc, count, timeout)))


async def _lines_within(proc: Any, timeout: float) -> list[str]:
    """Every line ``proc`` prints within ``timeout`` seconds."""

    def read() -> list[str]:
        got: list[str] = []
        try:
            got.extend(iter_lines_until(proc, 1_000_000, timeout))
        except TimeoutError:
            pass
        return got

    return await asyncio.to_thread(read)


def _lookup(master_uri: str, name: str) -> bool:
    import xmlrpc.client

    with xmlrpc.client.ServerProxy(master_uri) as api:
        code, _msg, _uri = api.lookupService("/probe", name)
    return bool(code == 1)


# --- case 1: names not imported ----------------------------------------------------------------------------


@pytest.mark.parametrize(("mode", "from_ros2"), [("listed", ("/imported",)), ("demand", ()), ("all", ("/imported",))])
async def test_a_stranger_publishes_only_into_names_from_ros2_imports(
    procs: Processes, tmp_path: Path, mode: str, from_ros2: tuple[str, ...]
) -> None:
    """Modes "all" and "demand" widen what goes to ROS 2; what comes from it is only what ``from_ros2`` lists."""
    async with robot(mode=mode, from_ros2=from_ros2) as (master_uri, bridge, endpoint):
        base = procs.python(BASE_CONTROLLER, ros_env(master_uri, tmp_path))
        assert await _lines(base, 1, 30) == ["ready"]
        peer = await asyncio.to_thread(_peer, endpoint)
        try:
            zid = str(peer.zid())
            liveliness = peer.liveliness()
            tokens = [
                liveliness.declare_token(_token(zid, 1, "MP", "/cmd_vel", "geometry_msgs/msg/Twist", TWIST_HASH)),
                liveliness.declare_token(_token(zid, 2, "MP", "/other", "std_msgs/msg/String", STRING_HASH)),
                liveliness.declare_token(_token(zid, 3, "SS", "/reset", "std_srvs/srv/SetBool", SETBOOL_HASH)),
                liveliness.declare_token(_token(zid, 4, "MP", "/imported", "std_msgs/msg/String", STRING_HASH)),
            ]
            cmd_vel = peer.declare_publisher(data_key(0, "/cmd_vel", "geometry_msgs/msg/Twist", TWIST_HASH))
            imported = peer.declare_publisher(data_key(0, "/imported", "std_msgs/msg/String", STRING_HASH))
            inbound = bridge.inbound
            if from_ros2:
                assert inbound is not None
                # the tokens are handled in order: once /imported is taken, the others were looked at
                await bridge.wait_until(lambda: "/imported" in inbound.topics, 20)
            else:
                reads = bridge.graph_reads
                await bridge.wait_until(lambda: bridge.graph_reads >= reads + 2, 10)
            body = CDR_HEADER + struct.pack("<6d", 1.0, 0, 0, 0, 0, 0)
            deadline = time.monotonic() + 1.5
            while time.monotonic() < deadline:  # 75 Twists, and as many Strings on the imported name
                cmd_vel.put(body)
                imported.put(CDR_HEADER + struct.pack("<I", 3) + b"ok\x00")
                await asyncio.sleep(0.02)
            if from_ros2:
                assert await _lines(base, 1, 10) == ["ok"]  # the imported name crosses (and shows the data path works)
            assert "/cmd_vel" not in bridge.node.publishers and "/other" not in bridge.node.publishers
            assert inbound is None or not {"/cmd_vel", "/other"} & set(inbound.topics)
            assert bridge.services is not None and "/reset" not in bridge.services.provided
            assert not await asyncio.to_thread(_lookup, master_uri, "/reset")
            rest = await _lines_within(base, 0.5)
            assert not any(line.startswith("twist") for line in rest), rest
            # a ROS 1 service outside ``to_ros2`` has no queryable: a query on it gets no reply at all
            if mode == "listed":
                replies = list(peer.get("0/base_controller/**", timeout=1.0))
                assert [r for r in replies if r.ok is not None] == []
            for tok in tokens:
                tok.undeclare()
        finally:
            await asyncio.to_thread(peer.close)


# --- case 2: malformed bodies ------------------------------------------------------------------------------

LISTENER = """
import sys, rospy
from std_msgs.msg import String
rospy.init_node("listener")
rospy.Subscriber("/chatter", String, lambda m: (print(m.data), sys.stdout.flush()))
print("ready"); sys.stdout.flush()
rospy.spin()
"""


def _cdr_string(text: str) -> bytes:
    raw = text.encode() + b"\x00"
    return CDR_HEADER + struct.pack("<I", len(raw)) + raw


async def test_malformed_bodies_either_way_never_reach_a_subscriber_and_are_counted(
    procs: Processes, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """ROS 2 -> ROS 1: garbage CDR, a string length of 2^31, trailing bytes, a body shorter than its header, on
    an imported topic with a rospy subscriber: none arrives, each is counted ``bad``, the log has no traceback
    and a few lines at most, and the valid messages after them arrive in order (rospy drops a connection on a
    bad frame for good, so one forwarded lie would end the subscription). ROS 1 -> ROS 2 (row ros2-5): a rogue
    ROS 1 publisher's bodies that do not match their type are counted and never put on Zenoh."""
    bad_cdr = [
        b"\x07" * 9,  # not even an encapsulation header
        CDR_HEADER + struct.pack("<I", 1 << 31) + b"lies",  # a string length of 2^31
        _cdr_string("trailing") + b"\x00" * 8,  # bytes after the message
        b"\x00\x01",  # shorter than the encapsulation header
    ]
    with caplog.at_level(logging.WARNING, logger="mrosd"):
        async with robot(from_ros2=("/chatter",), to_ros2=("/upstream",), queue_size=64) as (uri, bridge, endpoint):
            listener = procs.python(LISTENER, ros_env(uri, tmp_path))
            assert await _lines(listener, 1, 30) == ["ready"]
            peer = await asyncio.to_thread(_peer, endpoint)
            try:
                zid = str(peer.zid())
                token = peer.liveliness().declare_token(
                    _token(zid, 1, "MP", "/chatter", "std_msgs/msg/String", STRING_HASH)
                )
                inbound = bridge.inbound
                assert inbound is not None

                def connected() -> bool:
                    rt = inbound.topics.get("/chatter")
                    return rt is not None and rt.publisher is not None and rt.publisher.get_num_connections() > 0

                await bridge.wait_until(connected, 30)
                publisher = peer.declare_publisher(data_key(0, "/chatter", "std_msgs/msg/String", STRING_HASH))
                for body in bad_cdr:
                    publisher.put(body)
                for i in range(20):
                    publisher.put(_cdr_string(f"valid {i}"))
                    await asyncio.sleep(0.01)
                assert await _lines(listener, 20, 15) == [f"valid {i}" for i in range(20)]
                rt = inbound.topics["/chatter"]
                assert (rt.bad, rt.received) == (len(bad_cdr), 20)

                # ROS 1 -> ROS 2: a rogue ROS 1 publisher's raw bodies on /upstream
                heard: list[bytes] = []
                sub = peer.declare_subscriber(
                    data_key(0, "/upstream", "std_msgs/msg/String", STRING_HASH),
                    lambda sample: heard.append(sample.payload.to_bytes()),
                )
                raw = raw_message_class("std_msgs/String", String._md5sum, String._full_text)
                async with mrosd.Node("rogue", master_uri=uri, argv=[], host="127.0.0.1") as node:
                    rogue = await node.advertise("/upstream", raw)
                    bad_ros1 = [struct.pack("<I", 1 << 31) + b"lies", struct.pack("<I", 2) + b"ok" + b"tail", b"\x01"]

                    async def first_good() -> None:  # until the bridge has subscribed and mapped the type
                        while not heard:
                            rogue.publish_serialized(struct.pack("<I", 5) + b"first")
                            await asyncio.sleep(0.05)

                    await asyncio.wait_for(first_good(), 20)
                    bt = bridge.topics["/upstream"]
                    assert bt.rmw is not None
                    for body in bad_ros1:
                        rogue.publish_serialized(body)
                    rogue.publish_serialized(struct.pack("<I", 4) + b"last")
                    await bridge.wait_until(lambda: heard[-1:] == [_cdr_string("last")], 10)
                    assert bt.rmw.bad == len(bad_ros1)
                    assert set(heard) == {_cdr_string("first"), _cdr_string("last")}
                sub.undeclare()
                token.undeclare()
            finally:
                await asyncio.to_thread(peer.close)
    assert not [r for r in caplog.records if r.exc_info], "a traceback was logged"
    lines = [r.getMessage() for r in caplog.records if "does not convert" in r.getMessage()]
    assert 1 <= len(lines) <= 6, lines


# --- case 3: service requests ------------------------------------------------------------------------------


class _Replies:
    """Replies to queries sent without waiting (Zenoh's thread appends; the loop polls the count)."""

    def __init__(self) -> None:
        self.texts: list[str] = []

    def handler(self) -> Any:
        def on_reply(reply: Any) -> None:
            self.texts.append("ok" if reply.ok is not None else reply.err.payload.to_bytes().decode())

        return zenoh.handlers.Callback(on_reply, lambda: None)


def _ask(peer: Any, key: str, body: bytes, attachment: bytes | None) -> list[str]:
    kw: dict[str, Any] = {"payload": body, "timeout": 20.0}
    if attachment is not None:
        kw["attachment"] = attachment
    return ["ok" if r.ok is not None else r.err.payload.to_bytes().decode() for r in peer.get(key, **kw)]


async def test_slow_and_garbage_calls_from_one_peer_never_block_another_peers_honest_call(
    procs: Processes, tmp_path: Path
) -> None:
    """One peer (one client GID) floods a slow ROS 1 service with honest-looking calls, then with calls under
    80 made-up GIDs; garbage requests come in between. The garbage is refused at once, before any slot (its
    reply names the malformation even while the slots are full); another peer's honest call is answered
    throughout; and nothing stays in flight."""
    async with robot(to_ros2=("/slow", "/fast"), service_timeout=4.0) as (uri, bridge, endpoint):
        server = procs.python(SLOW, ros_env(uri, tmp_path))
        assert await _lines(server, 1, 30) == ["ready"]
        services = bridge.services
        assert services is not None
        await bridge.wait_until(
            lambda: all((o := services.offered.get(n)) is not None and o.token is not None for n in ("/slow", "/fast")),
            30,
        )
        slow, fast = services.offered["/slow"].key, services.offered["/fast"].key
        hostile, honest = await asyncio.gather(asyncio.to_thread(_peer, endpoint), asyncio.to_thread(_peer, endpoint))
        try:
            request = CDR_HEADER + b"\x01"
            flood = _Replies()
            one_gid = encode_attachment(1, time.time_ns(), b"\xee" * 16)
            for _ in range(80):
                hostile.get(slow, flood.handler(), payload=request, attachment=one_gid, timeout=20.0)
            # refusals come back at once; the admitted calls stay in flight
            await bridge.wait_until(lambda: len(flood.texts) + services.inflight_in >= 80, 10)
            in_flight = services.inflight_in
            garbage = await asyncio.to_thread(_ask, hostile, slow, b"\x07\x07\x07", one_gid)
            assert len(garbage) == 1 and "does not convert" in garbage[0], garbage
            mine = encode_attachment(1, time.time_ns(), b"\x11" * 16)
            assert await asyncio.to_thread(_ask, honest, fast, request, mine) == ["ok"], f"{in_flight} in flight"

            forged = _Replies()
            for n in range(80):
                gid = encode_attachment(n, time.time_ns(), n.to_bytes(16, "little"))
                hostile.get(slow, forged.handler(), payload=request, attachment=gid, timeout=20.0)
            await bridge.wait_until(lambda: len(forged.texts) + services.inflight_in >= 80 + in_flight, 10)
            in_flight = services.inflight_in
            assert await asyncio.to_thread(_ask, honest, fast, request, mine) == ["ok"], f"{in_flight} in flight"
            await bridge.wait_until(lambda: services.inflight_in == 0, 15)
            assert await asyncio.to_thread(_ask, honest, fast, request, mine) == ["ok"]
        finally:
            await asyncio.gather(asyncio.to_thread(hostile.close), asyncio.to_thread(honest.close))


def _ss(zid: str, n: int, name: str) -> str:
    return _token(zid, n, "SS", name, "std_srvs/srv/SetBool", SETBOOL_HASH, "::,10:,:,:,,")


async def test_a_ros2_server_replying_malformed_bodies_gives_a_rospy_caller_a_clear_error(
    procs: Processes, tmp_path: Path
) -> None:
    """A ROS 2 server (a bare queryable with an ``SS`` token) answers a lying length, trailing bytes, an empty
    body: rospy's ServiceProxy raises a ServiceException naming the service, never hangs or decodes garbage."""
    replies = {
        "/lying": CDR_HEADER + b"\x01\x00\x00\x00" + struct.pack("<I", 1 << 31),
        "/trailing": CDR_HEADER + b"\x01\x00\x00\x00" + struct.pack("<I", 1) + b"\x00" + b"\x00" * 16,
        "/empty": b"",
    }
    async with robot(from_ros2=tuple(replies), service_timeout=2.0) as (uri, bridge, endpoint):
        peer = await asyncio.to_thread(_peer, endpoint)
        entities: list[Any] = []
        try:
            zid = str(peer.zid())
            for n, (name, body) in enumerate(replies.items()):

                def answer(query: Any, body: bytes = body) -> None:
                    query.reply(query.key_expr, body, attachment=query.attachment)
                    query.drop()

                key = data_key(0, name, "std_srvs/srv/SetBool", SETBOOL_HASH)
                entities.append(peer.declare_queryable(key, answer, complete=True))
                entities.append(peer.liveliness().declare_token(_ss(zid, n + 1, name)))
            services = bridge.services
            assert services is not None
            await bridge.wait_until(
                lambda: all((p := services.provided.get(n)) is not None and p.service is not None for n in replies),
                30,
            )
            caller = procs.start([ROS_PYTHON, "-c", CALLER, *replies], ros_env(uri, tmp_path))
            lines = await _lines(caller, len(replies), 30)
            for line, name in zip(lines, replies, strict=True):
                assert line.startswith(f"{name} error"), lines
                assert "does not convert" in line or "answer" in line, lines
            assert services.inflight_out == 0
        finally:
            for entity in entities:
                entity.undeclare()
            await asyncio.to_thread(peer.close)


# --- case 4: resource claims -------------------------------------------------------------------------------


async def test_thousands_of_announcements_hold_bounded_state_and_a_few_lines(
    caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A peer announces, with distinct names: services beyond the cap, services and publishers of types nobody
    knows, thousands of publishers and subscribers of one topic, nodes, and tokens too long to be rmw_zenoh's.
    What the bridge holds stays under its caps (services capped here at 16 to keep the test short: each costs
    a master registration, as a topic does, and ros2-7 checks the 256 topics), and each kind of refusal is a
    few lines, not one per name."""
    monkeypatch.setattr(services_mod, "MAX_SERVICES", 16)
    many = 1000
    with caplog.at_level(logging.INFO, logger="mrosd.ros2"):
        async with robot(from_ros2=("/**",)) as (_uri, bridge, endpoint):
            peer = await asyncio.to_thread(_peer, endpoint)
            tokens: list[Any] = []
            try:
                zid = str(peer.zid())
                declare = peer.liveliness().declare_token
                n = 0

                def next_id() -> int:
                    nonlocal n
                    n += 1
                    return n

                for i in range(many):
                    tokens.append(declare(_ss(zid, next_id(), f"/srv{i}")))
                    tokens.append(declare(_token(zid, next_id(), "SS", f"/nosrv{i}", f"nopkg{i}/srv/X", SETBOOL_HASH)))
                    tokens.append(declare(_token(zid, next_id(), "MP", f"/notype{i}", f"nopkg{i}/msg/X", STRING_HASH)))
                    tokens.append(declare(_token(zid, next_id(), "MP", "/crowd", "std_msgs/msg/String", STRING_HASH)))
                    tokens.append(declare(_token(zid, next_id(), "MS", "/watched", "std_msgs/msg/String", STRING_HASH)))
                    tokens.append(declare(f"@ros2_lv/0/{zid}/0/{next_id()}/NN/%/%/node{i}"))
                for i in range(20):
                    tokens.append(declare(f"@ros2_lv/0/{zid}/0/{next_id()}/MP/%/%/n/%long{'x' * 8000}{i}/a/b/c"))
                last = declare(_token(zid, next_id(), "MP", "/sentinel", "std_msgs/msg/String", STRING_HASH))
                inbound, services = bridge.inbound, bridge.services
                assert inbound is not None and services is not None
                await bridge.wait_until(lambda: "/sentinel" in inbound.topics, 60)
                assert len(services.provided) <= 16
                assert len(inbound.topics) <= inbound_mod.MAX_RECEIVED_TOPICS
                crowd = inbound.topics["/crowd"].sources
                assert len(crowd) <= inbound_mod.MAX_SOURCES
                assert sum(len(keys) for keys in inbound.remote_subscribers.values()) <= inbound_mod.MAX_SOURCES
                assert len(bridge.mapper._ros1_known) <= 1024
                assert sum(len(p.servers) for p in services.provided.values()) <= 16 * inbound_mod.MAX_SOURCES
                last.undeclare()
                await bridge.wait_until(lambda: "/sentinel" not in inbound.topics, 20)
            finally:
                for tok in tokens:
                    tok.undeclare()
                await asyncio.to_thread(peer.close)
    refusals = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(refusals) <= 20, f"{len(refusals)} lines: {refusals[:5]}"


# --- mutual TLS ---------------------------------------------------------------------------------------------


def _tls_session(endpoint: str, tls: dict[str, str]) -> Any:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", f'["{endpoint}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    for key, value in tls.items():
        conf.insert_json5(f"transport/link/tls/{key}", f'"{value}"')
    if "connect_certificate" in tls:
        conf.insert_json5("transport/link/tls/enable_mtls", "true")
    return zenoh.open(conf)


async def test_with_client_certificates_a_stranger_cannot_link_and_a_laptop_with_one_can(tmp_path: Path) -> None:
    """``router = true`` on a ``tls/`` endpoint with the CA, certificate and key: a ROS 2 machine whose session
    shows a certificate of that CA links and its publisher is imported; one that knows the (public) CA but has
    no certificate cannot open a session at all."""
    from tests.fleet.test_fleet_tls import make_ca_and_cert

    tls = make_ca_and_cert(tmp_path / "pki", "robots")
    endpoint = f"tls/127.0.0.1:{free_port()}"
    async with AsyncExitStack() as stack:
        master = await stack.enter_async_context(Master(host="127.0.0.1", port=0))
        options = Ros2Options(domain_id=0, connect=(), listen=(endpoint,), router=True, from_ros2=("/chatter",), **tls)
        bridge = await stack.enter_async_context(Ros2Bridge(options, master.uri, host="127.0.0.1"))
        with pytest.raises(zenoh.ZError):  # no link to any endpoint
            await asyncio.to_thread(_tls_session, endpoint, {"root_ca_certificate": tls["tls_root_ca"]})
        laptop = await asyncio.to_thread(
            _tls_session,
            endpoint,
            {
                "root_ca_certificate": tls["tls_root_ca"],
                "connect_certificate": tls["tls_certificate"],
                "connect_private_key": tls["tls_private_key"],
            },
        )
        try:
            token = laptop.liveliness().declare_token(
                _token(str(laptop.zid()), 1, "MP", "/chatter", "std_msgs/msg/String", STRING_HASH)
            )
            inbound = bridge.inbound
            assert inbound is not None
            await bridge.wait_until(lambda: "/chatter" in inbound.topics, 20)
            token.undeclare()
        finally:
            await asyncio.to_thread(laptop.close)
