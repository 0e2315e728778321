"""Our nodes talking to each other over real sockets, registered with Debian's real rosmaster."""

from __future__ import annotations

import asyncio
import logging
import os
import socket
import struct
from collections.abc import Iterator

import pytest

import mrosd
from mrosd import backports
from mrosd.errors import HandshakeError, LocalProtocolError, ServiceError
from mrosd.msg import get_message_class, get_service_class
from mrosd.wire.header import ConnectionHeader, decode_connection_header, encode_header
from mrosd.xmlrpc import XmlRpcClient
from tests.rosenv import Processes, free_port, needs_ros, start_rosmaster, start_rosmaster_on

pytestmark = needs_ros

String = get_message_class("std_msgs/String")
Int32 = get_message_class("std_msgs/Int32")
SetBool = get_service_class("std_srvs/SetBool")


@pytest.fixture(scope="module")
def rosmaster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """One Debian ``rosmaster --core`` for the module (starting one costs a second of CPU): each test's nodes
    unregister when they close, and no test here reads the whole graph. The restart test starts its own."""
    procs = Processes(tmp_path_factory.mktemp("rosmaster"))
    try:
        yield start_rosmaster(procs)
    finally:
        procs.close()


def node(name: str, master: str, **kw: object) -> mrosd.Node:
    return mrosd.Node(name, master_uri=master, argv=[], host="127.0.0.1", **kw)  # type: ignore[arg-type]


async def test_a_message_published_by_one_node_reaches_a_subscriber_of_another(rosmaster: str) -> None:
    async with node("talker", rosmaster) as a, node("listener", rosmaster) as b:
        pub = await a.advertise("/chatter", String)
        sub = await b.subscribe("/chatter", String)
        await sub.wait_for_publishers(1, timeout=10)
        await pub.wait_for_subscribers(1, timeout=10)
        for i in range(5):
            await pub.publish(String(data=f"hello {i}"))
        got = [(await sub.next(timeout=5)).data for _ in range(5)]
        assert got == [f"hello {i}" for i in range(5)]


async def test_a_subscriber_started_first_connects_when_the_publisher_appears(rosmaster: str) -> None:
    got: asyncio.Queue[str] = asyncio.Queue()
    async with node("listener", rosmaster) as b:
        await b.subscribe("/late", String, callback=lambda m: got.put_nowait(m.data))
        async with node("talker", rosmaster) as a:
            pub = await a.advertise("/late", String)
            await pub.wait_for_subscribers(1, timeout=10)
            await pub.publish(String(data="x"))
            assert await backports.wait_for(got.get(), 5) == "x"


async def test_an_async_callback_receives_messages_in_order(rosmaster: str) -> None:
    got: list[int] = []
    done = asyncio.Event()

    async def on_msg(m: object) -> None:
        got.append(m.data)  # type: ignore[attr-defined]
        if len(got) == 20:
            done.set()

    async with node("talker", rosmaster) as a, node("listener", rosmaster) as b:
        pub = await a.advertise("/n", Int32)
        await b.subscribe("/n", Int32, callback=on_msg)
        await pub.wait_for_subscribers(1, timeout=10)
        for i in range(20):
            await pub.publish(Int32(data=i))
        await backports.wait_for(done.wait(), 5)
        assert got == list(range(20))


async def test_a_latched_message_reaches_a_late_subscriber_as_it_was_published(rosmaster: str) -> None:
    async with node("talker", rosmaster) as a, node("listener", rosmaster) as b:
        pub = await a.advertise("/latched", String, latch=True)
        msg = String(data="first")
        await pub.publish(msg)
        msg.data = "edited after publish"
        sub = await b.subscribe("/latched", String)
        assert (await sub.next(timeout=5)).data == "first"


async def test_raw_mode_yields_bytes_and_the_publishers_header(rosmaster: str) -> None:
    async with node("talker", rosmaster) as a, node("echo", rosmaster) as b:
        pub = await a.advertise("/raw", String, latch=True)
        await pub.publish(String(data="hi"))
        sub = await b.subscribe("/raw", mrosd.AnyMsg)
        raw = await sub.next(timeout=5)
        assert isinstance(raw, mrosd.RawMessage)
        assert raw.data == b"\x02\x00\x00\x00hi"
        assert raw.header.type == "std_msgs/String"
        assert raw.header.md5sum == String._md5sum
        from mrosd.msg import load_type

        cls = load_type(raw.header.type, raw.header.message_definition or "")
        assert cls.deserialize(raw.data).data == "hi"


async def test_a_type_mismatch_is_reported_clearly_on_the_subscriber(
    rosmaster: str, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.ERROR)
    async with node("talker", rosmaster) as a, node("listener", rosmaster) as b:
        await a.advertise("/mixed", String)
        sub = await b.subscribe("/mixed", Int32)
        async with backports.timeout(10):
            while not sub.errors:
                sub._changed.clear()
                await sub._changed.wait()
        assert "md5sums do not match" in sub.errors[0]
        assert "refused [/mixed]" in sub.errors[0]
        assert any("md5sums do not match" in r.getMessage() for r in caplog.records)


async def test_a_subscriber_reconnects_after_the_publisher_restarts(rosmaster: str) -> None:
    async with node("listener", rosmaster) as b:
        sub = await b.subscribe("/restart", String)
        for round_ in range(2):
            async with node("talker", rosmaster) as a:
                pub = await a.advertise("/restart", String)
                await pub.wait_for_subscribers(1, timeout=10)
                await pub.publish(String(data=f"round {round_}"))
                assert (await sub.next(timeout=5)).data == f"round {round_}"


@pytest.mark.parametrize("bound", ["count", "bytes"])
async def test_a_slow_subscriber_drops_oldest_and_never_slows_a_fast_one(rosmaster: str, bound: str) -> None:
    """Bounded by ``queue_size`` (5), or by ``max_queued_bytes`` (50 kB: two and a half messages of 20 kB)."""
    async with node("talker", rosmaster) as a, node("fast", rosmaster) as b:
        if bound == "count":
            pub = await a.advertise("/flood", String, queue_size=5)
        else:
            pub = await a.advertise("/flood", String, queue_size=1000, max_queued_bytes=50_000)
        fast = await b.subscribe("/flood", String, queue_size=100000)
        await pub.wait_for_subscribers(1, timeout=10)
        # The slow subscriber: a raw socket that handshakes and then never reads.
        host, port = "127.0.0.1", a.tcpros_port
        slow = socket.create_connection((host, port))
        slow.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        hdr = ConnectionHeader(callerid="/slow", topic="/flood", md5sum="*", type="*", tcp_nodelay="1")
        slow.sendall(encode_header(hdr))
        await pub.wait_for_subscribers(2, timeout=10)
        try:
            payload = "x" * 20000
            async with backports.timeout(30):
                for i in range(300):
                    await pub.publish(String(data=f"{i} {payload}"))
                    # The fast subscriber keeps up: every message arrives, in order.
                    assert (await fast.next()).data.startswith(f"{i} ")
            slow_link = next(lk for lk in pub.links if lk.callerid == "/slow")
            assert slow_link.dropped > 0
            if bound == "count":
                assert len(slow_link.queue) <= 5
            else:
                assert 0 < slow_link.queued_bytes <= 50_000 and len(slow_link.queue) == 2
            client = XmlRpcClient()
            stats = await client.call(a.uri, "getBusStats", "/test")
            await client.aclose()
            flood = next(p for p in stats[2][0] if p[0] == "/flood")
            assert max(c[4] for c in flood[2]) == slow_link.dropped
        finally:
            slow.close()


async def test_a_garbage_header_closes_only_that_connection(rosmaster: str) -> None:
    async with node("talker", rosmaster) as a, node("listener", rosmaster) as b:
        pub = await a.advertise("/g", String)
        sub = await b.subscribe("/g", String)
        await pub.wait_for_subscribers(1, timeout=10)
        reader, writer = await asyncio.open_connection("127.0.0.1", a.tcpros_port)
        writer.write(b"\xff\xff\xff\xff" + os.urandom(64))
        assert await backports.wait_for(reader.read(), 5) == b""
        writer.close()
        await pub.publish(String(data="still here"))
        assert (await sub.next(timeout=5)).data == "still here"


async def test_a_wrong_topic_gets_an_error_header(rosmaster: str) -> None:
    async with node("talker", rosmaster) as a:
        reader, writer = await asyncio.open_connection("127.0.0.1", a.tcpros_port)
        writer.write(encode_header(ConnectionHeader(callerid="/x", topic="/nothing", md5sum="*", type="*")))
        (n,) = struct.unpack("<I", await backports.wait_for(reader.readexactly(4), 5))
        reply = decode_connection_header(await reader.readexactly(n))
        assert reply.error is not None and "/nothing" in reply.error
        writer.close()


async def test_services_answer_and_report_handler_errors(rosmaster: str) -> None:
    async def handler(req: object) -> object:
        if not req.data:  # type: ignore[attr-defined]
            raise ValueError("refused on purpose")
        return SetBool._response_class(success=True, message="ok")

    async with node("server", rosmaster) as a, node("client", rosmaster) as b:
        await a.advertise_service("/set", SetBool, handler)
        proxy = b.service_proxy("/set", SetBool)
        resp = await proxy.call(SetBool._request_class(data=True))
        assert (resp.success, resp.message) == (True, "ok")
        with pytest.raises(ServiceError, match="refused on purpose"):
            await proxy.call(SetBool._request_class(data=False))
        async with b.service_proxy("/set", SetBool, persistent=True) as persistent:
            for _ in range(3):
                assert (await persistent(SetBool._request_class(data=True))).success
        with pytest.raises(ServiceError):
            await b.service_proxy("/missing", SetBool).call(SetBool._request_class(data=True), timeout=5)


async def test_a_service_md5_mismatch_is_a_handshake_error(rosmaster: str) -> None:
    Trigger = get_service_class("std_srvs/Trigger")
    async with node("server", rosmaster) as a, node("client", rosmaster) as b:
        await a.advertise_service("/svc", SetBool, lambda r: SetBool._response_class())
        with pytest.raises(HandshakeError, match="md5sums do not match"):
            await b.service_proxy("/svc", Trigger).call(Trigger._request_class())


async def test_the_slave_api_describes_the_node(rosmaster: str) -> None:
    async with node("talker", rosmaster) as a:
        await a.advertise("/chatter", String)
        await a.subscribe("/other", Int32)
        c = XmlRpcClient()
        try:
            assert (await c.call(a.uri, "getPid", "/t"))[2] == os.getpid()
            assert (await c.call(a.uri, "getMasterUri", "/t"))[2] == rosmaster
            assert sorted((await c.call(a.uri, "getPublications", "/t"))[2]) == [
                ["/chatter", "std_msgs/String"],
                ["/rosout", "rosgraph_msgs/Log"],
            ]
            assert (await c.call(a.uri, "getSubscriptions", "/t"))[2] == [["/other", "std_msgs/Int32"]]
            code, _, proto = await c.call(a.uri, "requestTopic", "/t", "/chatter", [["TCPROS"]])
            assert (code, proto) == (1, ["TCPROS", "127.0.0.1", a.tcpros_port])
            assert (await c.call(a.uri, "requestTopic", "/t", "/nope", [["TCPROS"]]))[0] == -1
            assert (await c.call(a.uri, "getBusInfo", "/t"))[0] == 1
            await c.call(a.uri, "shutdown", "/t", "test")
            assert a.shutdown_event.is_set()
        finally:
            await c.aclose()


async def test_using_a_node_before_start_is_a_clear_error() -> None:
    n = mrosd.Node("x", master_uri="http://127.0.0.1:1/", argv=[])
    with pytest.raises(LocalProtocolError, match="not started"):
        await n.advertise("/a", String)


async def test_ipv6_hosts_are_advertised_as_bracketed_literals(rosmaster: str) -> None:
    n = mrosd.Node("v6", master_uri=rosmaster, argv=[], host="::1", watchdog_interval=0)
    async with n:
        assert n.uri.startswith("http://[::1]:")
        assert n.service_uri.startswith("rosrpc://[::1]:")


def test_topics_and_services_work_under_uvloop(rosmaster: str) -> None:
    uvloop = pytest.importorskip("uvloop")

    async def main() -> None:
        async with node("talker", rosmaster) as a, node("listener", rosmaster) as b:
            pub = await a.advertise("/uv", String, latch=True)
            await pub.publish(String(data="uv"))
            sub = await b.subscribe("/uv", String)
            assert (await sub.next(timeout=5)).data == "uv"
            await a.advertise_service("/uvs", SetBool, lambda r: SetBool._response_class(success=r.data))
            assert (await b.service_proxy("/uvs", SetBool).call(SetBool._request_class(data=True))).success

    with backports.Runner(loop_factory=uvloop.new_event_loop) as runner:
        runner.run(main())


async def test_nodes_register_again_after_the_master_restarts(procs: Processes) -> None:
    port = free_port()
    uri = f"http://127.0.0.1:{port}/"

    master = start_rosmaster_on(procs, port)
    async with node("talker", uri, watchdog_interval=0.1) as a, node("listener", uri, watchdog_interval=0.1) as b:
        pub = await a.advertise("/survivor", String)
        sub = await b.subscribe("/survivor", String)
        await pub.wait_for_subscribers(1, timeout=10)
        await asyncio.to_thread(procs.stop, master)
        # Connections between nodes do not need the master: traffic continues while it is down.
        await pub.publish(String(data="during"))
        assert (await sub.next(timeout=5)).data == "during"
        await asyncio.to_thread(start_rosmaster_on, procs, port)
        client = XmlRpcClient()
        try:
            async with backports.timeout(20):
                while True:
                    state = (await client.call(uri, "getSystemState", "/test"))[2]
                    pubs = {t: n for t, n in state[0]}
                    subs = {t: n for t, n in state[1]}
                    if pubs.get("/survivor") == ["/talker"] and subs.get("/survivor") == ["/listener"]:
                        break
                    await asyncio.sleep(0.05)
        finally:
            await client.aclose()
        # A publisher that appears after the restart is found through the new master.
        async with node("talker2", uri) as c:
            pub2 = await c.advertise("/survivor", String)
            await pub2.wait_for_subscribers(1, timeout=10)


async def test_large_messages_arrive_intact_in_both_framing_paths(rosmaster: str) -> None:
    Image = get_message_class("sensor_msgs/Image")
    async with node("talker", rosmaster) as a, node("listener", rosmaster) as b:
        pub = await a.advertise("/big", Image)
        sub = await b.subscribe("/big", Image, queue_size=10)
        await pub.wait_for_subscribers(1, timeout=10)
        sizes = [300_000, 5, 2_000_000, 70_000]
        for i, size in enumerate(sizes):
            data = bytes([i + 1]) * size
            await pub.publish(Image(height=1, width=size, encoding="mono8", step=size, data=data))
        for i, size in enumerate(sizes):
            msg = await sub.next(timeout=10)
            assert bytes(msg.data) == bytes([i + 1]) * size


def test_large_messages_queued_behind_a_full_socket_arrive_whole_and_in_order_under_uvloop(
    rosmaster: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("MROSD_SHM", "0")  # the TCPROS write path is under test, not the same-host shared memory
    uvloop = pytest.importorskip("uvloop")
    Image = get_message_class("sensor_msgs/Image")

    async def main() -> None:
        async with node("talker", rosmaster) as a, node("listener", rosmaster) as b:
            pub = await a.advertise("/big_uv", Image, queue_size=50)
            sub = await b.subscribe("/big_uv", Image, queue_size=50)
            await pub.wait_for_subscribers(1, timeout=10)
            await sub.wait_for_publishers(1, timeout=10)
            # 20 x 1.5 MB in one go: the transport pauses after the first, the rest wait as (prefix, body).
            size = 1_500_000
            for i in range(20):
                pub.publish_nowait(Image(height=1, width=size, encoding="mono8", step=size, data=bytes([i]) * size))
            for i in range(20):
                msg = await sub.next(timeout=10)
                assert len(msg.data) == size and msg.data[0] == i and msg.data[-1] == i
            assert pub.links[0].dropped == 0

    with backports.Runner(loop_factory=uvloop.new_event_loop) as runner:
        runner.run(main())


async def test_a_subscribed_parameter_reports_changes_and_other_keys_are_refused(rosmaster: str) -> None:
    changes: asyncio.Queue[tuple[str, object]] = asyncio.Queue()
    async with node("tuner", rosmaster) as a:
        assert await a.subscribe_param("gain", lambda k, v: changes.put_nowait((k, v))) == {}
        c = XmlRpcClient()
        try:
            await c.call(rosmaster, "setParam", "/someone_else", "/gain", 2.5)  # the master skips the setter
            assert await backports.wait_for(changes.get(), 10) == ("/gain", 2.5)
            assert (await c.call(a.uri, "paramUpdate", "/t", "/other", 1))[0] == -1
            await a.unsubscribe_param("gain")
            assert (await c.call(a.uri, "paramUpdate", "/t", "/gain", 1))[0] == -1
        finally:
            await c.aclose()
