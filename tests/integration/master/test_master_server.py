"""Our Master over real sockets: client calls, notifications to real node servers, bad input, allow-list."""

from __future__ import annotations

import asyncio
import io
from collections.abc import AsyncIterator
from typing import Any

import aiohttp
import pytest

from mrosd import backports
from mrosd.errors import MasterError
from mrosd.master import Master, MasterClient
from mrosd.xmlrpc import MAX_BODY_SIZE, Fault, XmlRpcClient, XmlRpcServer, encode_call
from tests.rosenv import free_port


class FakeNode:
    """A real slave-API XML-RPC server that records the master's callbacks."""

    def __init__(self, delay: float = 0.0, param_reply: int = 1) -> None:
        self.calls: list[tuple[str, tuple[Any, ...]]] = []
        self.delay = delay
        self.param_reply = param_reply
        self.changed = asyncio.Event()
        self.server = XmlRpcServer(
            {"publisherUpdate": self._pub, "paramUpdate": self._param, "shutdown": self._shutdown},
            "127.0.0.1",
            0,
        )

    @property
    def api(self) -> str:
        return f"http://127.0.0.1:{self.server.port}/"

    async def _record(self, method: str, args: tuple[Any, ...]) -> None:
        if self.delay:
            await asyncio.sleep(self.delay)
        self.calls.append((method, args))
        self.changed.set()

    async def _pub(self, *args: Any) -> list[Any]:
        await self._record("publisherUpdate", args)
        return [1, "", 0]

    async def _param(self, *args: Any) -> list[Any]:
        await self._record("paramUpdate", args)
        return [self.param_reply, "", 0]

    async def _shutdown(self, *args: Any) -> list[Any]:
        await self._record("shutdown", args)
        return [1, "", 0]

    async def wait_for(self, count: int, timeout: float = 5.0) -> None:
        async with backports.timeout(timeout):
            while len(self.calls) < count:
                self.changed.clear()
                await self.changed.wait()


@pytest.fixture
async def master() -> AsyncIterator[Master]:
    async with Master("127.0.0.1", 0, advertise="127.0.0.1", notify_timeout=1.0) as m:
        yield m


@pytest.fixture
async def node_factory() -> AsyncIterator[Any]:
    nodes: list[FakeNode] = []

    async def make(**kw: Any) -> FakeNode:
        node = FakeNode(**kw)
        await node.server.start()
        nodes.append(node)
        return node

    yield make
    for n in nodes:
        await n.server.aclose()


async def test_master_reports_its_uri_and_port(master: Master) -> None:
    assert master.uri == f"http://127.0.0.1:{master.port}/"
    async with MasterClient(master.uri, "/c") as c:
        assert await c.get_uri() == master.uri


async def test_subscribers_receive_publisher_updates_in_order(master: Master, node_factory: Any) -> None:
    listener = await node_factory()
    async with MasterClient(master.uri, "/listener") as lc, MasterClient(master.uri, "/talker") as tc:
        assert await lc.register_subscriber("/chatter", "std_msgs/String", listener.api) == []
        assert await tc.register_publisher("/chatter", "std_msgs/String", "http://127.0.0.1:1/") == [listener.api]
        await listener.wait_for(1)
        assert listener.calls[0] == ("publisherUpdate", ("/master", "/chatter", ["http://127.0.0.1:1/"]))
        await tc.unregister_publisher("/chatter", "http://127.0.0.1:1/")
        await listener.wait_for(2)
        assert listener.calls[-1] == ("publisherUpdate", ("/master", "/chatter", []))


async def test_a_dead_or_slow_node_never_delays_calls_or_other_nodes(master: Master, node_factory: Any) -> None:
    slow = await node_factory(delay=1.5)  # beyond the master's 1 s notify timeout
    fast = await node_factory()
    dead = f"http://127.0.0.1:{free_port()}/"
    async with MasterClient(master.uri, "/c") as c:
        for i, api in enumerate([slow.api, dead, fast.api]):
            async with MasterClient(master.uri, f"/sub{i}") as sub:
                await sub.register_subscriber("/t", "a/B", api)
        loop = asyncio.get_running_loop()
        start = loop.time()
        for i in range(20):
            await c.register_publisher(f"/t{i}", "a/B", "http://127.0.0.1:2/")
            async with MasterClient(master.uri, f"/pub{i}") as pub:
                await pub.register_publisher("/t", "a/B", f"http://127.0.0.1:{i + 2}/")
        await c.get_system_state()
        assert loop.time() - start < 2.0
        await fast.wait_for(1)
        # coalesced: the fast node sees the latest list, not necessarily all 20
        await asyncio.sleep(0)
        assert len(fast.calls) <= 20


async def test_publisher_updates_coalesce_to_the_latest_list(master: Master, node_factory: Any) -> None:
    node = await node_factory(delay=0.2)
    async with MasterClient(master.uri, "/l") as lc:
        await lc.register_subscriber("/t", "a/B", node.api)
        for i in range(10):
            async with MasterClient(master.uri, f"/pub{i}") as tc:
                await tc.register_publisher("/t", "a/B", f"http://127.0.0.1:{i + 2}/")
        await master.notifier.drain()
        assert len(node.calls) < 10
        assert node.calls[-1][1][2] == [f"http://127.0.0.1:{i + 2}/" for i in range(10)]


async def test_param_updates_reach_subscribers_of_parents_and_children(master: Master, node_factory: Any) -> None:
    parent, child = await node_factory(), await node_factory()
    async with (
        MasterClient(master.uri, "/p") as pc,
        MasterClient(master.uri, "/ch") as cc,
        MasterClient(master.uri, "/setter") as setter,
    ):
        await pc.subscribe_param(parent.api, "/robot")
        await cc.subscribe_param(child.api, "/robot/arm/gain")
        await setter.set_param("/robot/arm", {"gain": 3})
        await parent.wait_for(1)
        await child.wait_for(1)
        assert parent.calls[0][1] == ("/master", "/robot/arm/", {"gain": 3})
        assert child.calls[0][1] == ("/master", "/robot/arm/gain/", 3)
        await setter.delete_param("/robot")
        await child.wait_for(2)
        assert child.calls[1][1] == ("/master", "/robot/arm/gain/", {})


async def test_reregistering_a_node_sends_shutdown_to_the_old_api(master: Master, node_factory: Any) -> None:
    old = await node_factory()
    async with MasterClient(master.uri, "/dup") as c:
        await c.register_publisher("/t", "a/B", old.api)
        await c.register_publisher("/t", "a/B", "http://127.0.0.1:5/")
        await old.wait_for(1)
        assert old.calls[0][0] == "shutdown"
        assert await c.lookup_node("/dup") == "http://127.0.0.1:5/"


async def test_malformed_and_oversized_requests_get_faults_and_the_master_keeps_serving(master: Master) -> None:
    async with aiohttp.ClientSession() as s:
        async with s.post(master.uri, data=b"<methodCall><not-xml") as r:
            assert r.status == 200 and b"fault" in await r.read()
        try:
            async with s.post(master.uri, data=io.BytesIO(b"x" * (MAX_BODY_SIZE + 10))) as r:
                assert b"fault" in await r.read() or r.status == 413
        except aiohttp.ClientError:
            pass  # the server may close the connection while the client is still sending
        async with s.post(master.uri, data=encode_call("noSuchMethod", ("/c",))) as r:
            assert b"fault" in await r.read()
    client = XmlRpcClient()
    try:
        with pytest.raises(Fault):
            await client.call(master.uri, "noSuchMethod", "/c")
        code, _, _ = await client.call(master.uri, "registerPublisher", "/c", 1, 2)
        assert code == -1
    finally:
        await client.aclose()
    async with MasterClient(master.uri, "/c") as c:
        with pytest.raises(MasterError):
            await c.lookup_node("/nobody")
        assert await c.get_uri() == master.uri


async def test_clients_outside_the_allow_list_get_http_403() -> None:
    async with (
        Master("127.0.0.1", 0, advertise="127.0.0.1", allow=["10.0.0.0/8"]) as m,
        aiohttp.ClientSession() as s,
        s.post(m.uri, data=encode_call("getUri", ("/c",))) as r,
    ):
        assert r.status == 403
    async with (
        Master("127.0.0.1", 0, advertise="127.0.0.1", allow=["127.0.0.0/8"]) as m,
        MasterClient(m.uri, "/c") as c,
    ):
        assert await c.get_uri() == m.uri
