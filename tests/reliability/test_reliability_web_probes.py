"""The web hub's type probes against hostile and unwanted peers (issue 31, cases 8 and 10).

Case 8: a rogue node registers hundreds of services at an address that accepts and never answers. Honest
services must still reach the clients at once, a rosbridge ``call_service`` without ``type`` must answer (or
fail with a clear status) within a few seconds, and the master keeps answering.

Case 10: with no browser client connected the hub subscribes to nothing: a publisher whose type the hub cannot
look up sees no subscriber (the hub learns the type only once a client is there to ask for channels).

Real sockets, a real master and real mrosd nodes; the web server runs in the test's loop.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import AsyncIterator
from typing import Any

import aiohttp
import pytest

from mrosd import backports
from mrosd.master import Master
from mrosd.master.client import MasterClient
from mrosd.msg import get_service_class, load_type
from mrosd.web.probes import PROBE_TIMEOUT
from mrosd.web.server import WebServer
from tests.web.inloop import node, until

Trigger = get_service_class("std_srvs/Trigger")
ROGUE_SERVICES = 400


@pytest.fixture
async def master() -> AsyncIterator[Master]:
    # no graph sweep: the rogue's slave API is a closed port, and it must stay registered
    async with Master(host="127.0.0.1", port=0, cleanup_interval=0) as m:
        yield m


class Inbox:
    """Every JSON message a WebSocket client receives, read in the background."""

    def __init__(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        self.ws = ws
        self.messages: list[dict[str, Any]] = []
        self._task = asyncio.get_running_loop().create_task(self._read())

    async def _read(self) -> None:
        async for msg in self.ws:
            if msg.type == aiohttp.WSMsgType.TEXT:
                self.messages.append(json.loads(msg.data))

    def advertised_services(self) -> set[str]:
        return {s["name"] for m in self.messages if m["op"] == "advertiseServices" for s in m["services"]}

    def advertised_topics(self) -> set[str]:
        return {c["topic"] for m in self.messages if m["op"] == "advertise" for c in m["channels"]}

    def find(self, op: str, **match: Any) -> dict[str, Any] | None:
        return next((m for m in self.messages if m["op"] == op and all(m.get(k) == v for k, v in match.items())), None)

    async def close(self) -> None:
        await self.ws.close()
        self._task.cancel()
        await asyncio.gather(self._task, return_exceptions=True)


async def silent_server() -> tuple[asyncio.Server, int, list[asyncio.StreamWriter]]:
    """A TCP server that accepts every connection and never sends a byte (the rogue's service address)."""
    held: list[asyncio.StreamWriter] = []

    async def hold(_reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        held.append(writer)

    server = await asyncio.start_server(hold, "127.0.0.1", 0)
    return server, server.sockets[0].getsockname()[1], held


async def register_rogue_services(master: Master, port: int, count: int, *, many_names: bool) -> None:
    """``count`` services at the silent address, under one node name or each under its own."""
    clients = [MasterClient(master.uri, f"/rogue{i if many_names else ''}") for i in range(count if many_names else 1)]
    try:
        await asyncio.gather(
            *(
                clients[i % len(clients)].register_service(
                    f"/rogue/srv{i}", f"rosrpc://127.0.0.1:{port}", "http://127.0.0.1:9/"
                )
                for i in range(count)
            )
        )
    finally:
        for client in clients:
            await client.aclose()


async def get_pid_worst(master_uri: str, stop: asyncio.Event) -> float:
    """The slowest getPid answer while ``stop`` is not set."""
    worst = 0.0
    async with MasterClient(master_uri, "/watchdog", timeout=5.0) as client:
        while not stop.is_set():
            t0 = time.monotonic()
            await client.call("getPid")
            worst = max(worst, time.monotonic() - t0)
            try:
                await backports.wait_for(stop.wait(), 0.05)
            except TimeoutError:
                pass
    return worst


@pytest.mark.parametrize("many_names", [False, True], ids=["one node", "a node name per service"])
async def test_a_rogue_with_hundreds_of_silent_services_cannot_hold_back_honest_ones(
    master: Master, many_names: bool
) -> None:
    server, port, held = await silent_server()
    stop = asyncio.Event()
    watchdog = asyncio.get_running_loop().create_task(get_pid_worst(master.uri, stop))
    try:
        async with (
            WebServer(master.uri, port=0, rosbridge_port=0, node_host="127.0.0.1") as web,
            node("honest", master.uri) as honest,
            aiohttp.ClientSession() as http,
        ):
            fox = Inbox(await http.ws_connect(web.url, protocols=["foxglove.websocket.v1"]))
            bridge = Inbox(await http.ws_connect(web.rosbridge_url))
            await register_rogue_services(master, port, ROGUE_SERVICES, many_names=many_names)
            await until(lambda: len(held) > 0)  # the hub is probing the rogue now
            await honest.advertise_service("/honest/a", Trigger, lambda r: Trigger._response_class(True, "a"))
            t0 = time.monotonic()
            await until(lambda: "/honest/a" in fox.advertised_services(), timeout=10)
            advertised_after = time.monotonic() - t0
            # A service registered just now, called at once without a type: the call looks its type up itself.
            await honest.advertise_service("/honest/b", Trigger, lambda r: Trigger._response_class(True, "b"))
            t0 = time.monotonic()
            await bridge.ws.send_str(json.dumps({"op": "call_service", "service": "/honest/b", "id": "b"}))
            await until(lambda: bridge.find("service_response", id="b"), timeout=15)
            honest_call = time.monotonic() - t0
            reply = bridge.find("service_response", id="b")
            assert reply is not None and reply["result"] is True and reply["values"]["message"] == "b", reply
            # A call to one of the rogue's services fails fast with a status saying why.
            t0 = time.monotonic()
            await bridge.ws.send_str(json.dumps({"op": "call_service", "service": "/rogue/srv399", "id": "r"}))
            await until(lambda: bridge.find("service_response", id="r"), timeout=15)
            rogue_call = time.monotonic() - t0
            reply = bridge.find("service_response", id="r")
            assert reply is not None and reply["result"] is False and "/rogue/srv399" in reply["values"], reply
            # Under a name per service the rogue can hold every probe slot until the first times out (and
            # quarantines its address for every name): the honest service waits at most that one timeout.
            limit = PROBE_TIMEOUT + 1.5 if many_names else 1.5
            assert advertised_after < limit, f"the honest service was advertised after {advertised_after:.1f} s"
            assert honest_call < 3.0, f"call_service without type took {honest_call:.1f} s"
            assert rogue_call < 3.0, f"call_service to a silent server took {rogue_call:.1f} s to fail"
            # The hub holds few connections to the rogue at any time, however many services it registered.
            assert len(web.hub.probes.in_flight()) <= 8
            await fox.close()
            await bridge.close()
    finally:
        stop.set()
        worst = await watchdog
        server.close()
        for writer in held:
            writer.close()
    assert worst < 1.0, f"getPid took {worst:.2f} s during the attack"


SECRET = load_type("hubtest/Secret", "int32 x\nstring note\n")


async def web_subscriptions(master: Master, topic: str) -> list[str]:
    _pubs, subs, _srvs = master.api.registry.system_state()
    return [n for t, nodes in subs if t == topic for n in nodes]


@pytest.mark.parametrize("in_process", [False, True], ids=["over XML-RPC", "the master in-process"])
async def test_no_subscription_to_a_publisher_while_no_browser_client_asks(master: Master, in_process: bool) -> None:
    web = WebServer(master.uri, port=0, node_host="127.0.0.1")
    if in_process:  # as the daemon runs it: the hub follows the master's own change notes
        web.hub.use_master(master)
    async with (
        web,
        node("camera", master.uri) as camera,
        aiohttp.ClientSession() as http,
    ):
        pub = await camera.advertise("/secret", SECRET)
        await until(lambda: "/secret" in web.hub.graph.topics)
        # The hub knows the topic but not its type's definition; nobody asked for it: it must not subscribe.
        with pytest.raises(TimeoutError):
            await pub.wait_for_subscribers(1, timeout=1.0)
        assert await web_subscriptions(master, "/secret") == []
        assert "/secret" not in web.hub.topics
        # A Foxglove client connects: it wants the channel list, so the hub learns the type from the publisher.
        fox = Inbox(await http.ws_connect(web.url, protocols=["foxglove.websocket.v1"]))
        await until(lambda: "/secret" in fox.advertised_topics())
        assert web.hub.topics["/secret"].definition.startswith("int32 x")
        await fox.close()
        await until(lambda: web.hub.sink_count("/secret") == 0)


async def test_an_unreachable_publisher_is_probed_once_not_forever(master: Master) -> None:
    """A publisher whose slave API refuses connections: one probe while a client is connected, then none until
    the topic's publishers change."""
    web = WebServer(master.uri, port=0, node_host="127.0.0.1")
    web.hub.probes.timeout = 0.5
    async with (
        web,
        MasterClient(master.uri, "/ghost") as ghost,
        aiohttp.ClientSession() as http,
    ):
        fox = Inbox(await http.ws_connect(web.url, protocols=["foxglove.websocket.v1"]))
        await ghost.register_publisher("/ghost", "hubtest/Ghost", "http://127.0.0.1:9/")
        await until(lambda: "/ghost" in web.hub._topic_failed)
        await until(lambda: not web.hub.probes.in_flight())
        subscribed = 0
        for _ in range(20):  # 1 s: the hub's node never subscribes to /ghost again
            subscribed += len(await web_subscriptions(master, "/ghost"))
            await asyncio.sleep(0.05)
        assert subscribed == 0
        assert "/ghost" not in fox.advertised_topics()
        # Another publisher appears: that one is worth a probe.
        async with node("alive", master.uri) as alive:
            await alive.advertise("/ghost", load_type("hubtest/Ghost", "int8 boo\n"))
            await until(lambda: "/ghost" in fox.advertised_topics())
        await fox.close()
