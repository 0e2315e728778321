"""Hostile rosbridge clients sending ``fragment`` ops: what they can make the bridge hold, and that it still serves.

rosbridge's defragmentation capability keeps every fragment it is sent, by message id, for 600 s, with no
bound on bytes, ids or the ``total`` a client claims. Here a client's unfinished fragmented messages cost at
most the bytes it sent, within a per-client and a server-wide budget, a number of ids, and a timeout. Real
sockets and a real master; the server runs in the test's loop so that its state can be inspected.
"""

from __future__ import annotations

import json
import tracemalloc
from typing import Any

import aiohttp

import mrosd
from mrosd import backports
from mrosd.master import Master
from mrosd.msg import get_message_class
from mrosd.web.foxglove_server import SessionLimits
from mrosd.web.server import WebServer
from tests.web.inloop import node, rosbridge_and_node, until

String = get_message_class("std_msgs/String")
KiB = 1024
MiB = 1024 * KiB


def fragment(message_id: Any, num: int, total: Any, data: str) -> str:
    return json.dumps({"op": "fragment", "id": message_id, "num": num, "total": total, "data": data})


async def statuses(ws: aiohttp.ClientWebSocketResponse, count: int, timeout: float = 10.0) -> list[dict[str, Any]]:
    found: list[dict[str, Any]] = []
    async with backports.timeout(timeout):
        while len(found) < count:
            msg = json.loads((await ws.receive()).data)
            if msg["op"] == "status":
                found.append(msg)
    return found


async def barrier(ws: aiohttp.ClientWebSocketResponse, timeout: float = 10.0) -> list[dict[str, Any]]:
    """Wait until the server has handled every op sent before (ops are handled in order; a rosapi call is
    answered after them); the statuses that came meanwhile."""
    await ws.send_str(json.dumps({"op": "call_service", "service": "/rosapi/get_time", "id": "barrier"}))
    found: list[dict[str, Any]] = []
    async with backports.timeout(timeout):
        while True:
            msg = json.loads((await ws.receive()).data)
            if msg["op"] == "status":
                found.append(msg)
            elif msg["op"] == "service_response" and msg.get("id") == "barrier":
                return found


async def publish_in_fragments(
    ws: aiohttp.ClientWebSocketResponse, listener: Any, text: str, message_id: str, size: int = 7
) -> None:
    """The honest client: a publish op cut into fragments reaches the ROS subscriber."""
    op = json.dumps({"op": "publish", "topic": "/chatter", "msg": {"data": text}})
    parts = [op[i : i + size] for i in range(0, len(op), size)]
    for num, part in enumerate(parts):
        await ws.send_str(fragment(message_id, num, len(parts), part))
    got = await listener.next(timeout=10)
    assert got.data == text


async def honest_setup(server: WebServer, robot: mrosd.Node, http: aiohttp.ClientSession) -> tuple[Any, Any]:
    listener = await robot.subscribe("/chatter", String)
    ws = await http.ws_connect(server.rosbridge_url)
    await ws.send_str(json.dumps({"op": "advertise", "topic": "/chatter", "type": "std_msgs/String"}))
    await listener.wait_for_publishers(1, timeout=10)
    return ws, listener


def held(server: WebServer) -> int:
    return sum(s.fragments.size for s in server.rosbridge_sessions)


async def test_fragments_claiming_a_billion_parts_hold_only_the_bytes_sent(master: Master) -> None:
    """``total: 1000000000`` is a claim: the bridge keeps what arrived (a dict by part number), never a table
    of the claimed size; ``total: 1e9`` (not an integer) is refused and holds nothing."""
    async with rosbridge_and_node(master.uri, "robot") as (server, robot, http):
        ws, listener = await honest_setup(server, robot, http)
        await publish_in_fragments(ws, listener, "before", "honest-1")
        await ws.send_str(fragment("float", 0, 1e9, "x" * 100))
        assert "total" in (await statuses(ws, 1))[0]["msg"]

        sent = 0
        tracemalloc.start()
        try:
            before = tracemalloc.get_traced_memory()[0]
            for num in range(2000):  # 2000 parts of 1 KiB of a message that claims a billion
                text = fragment("huge", num * 499_999, 1_000_000_000, "y" * KiB)
                sent += len(text)
                await ws.send_str(text)
            await publish_in_fragments(ws, listener, "after", "honest-2")  # served in order: all 2000 are in
            grown = tracemalloc.get_traced_memory()[0] - before
        finally:
            tracemalloc.stop()
        (session,) = server.rosbridge_sessions
        assert len(session.fragments) == 1
        assert 2000 * KiB < session.fragments.size <= sent * 1.5
        assert grown < sent * 1.5, (grown, sent)  # what Python really holds follows the bytes that came
        await ws.close()
        await until(lambda: not server.rosbridge_sessions)
        assert server.rosbridge_fragments.size == 0


async def test_a_fragmented_message_that_never_finishes_is_dropped_after_the_timeout(master: Master) -> None:
    limits = SessionLimits(fragment_timeout=0.5)
    async with (
        WebServer(master.uri, port=0, rosbridge_port=0, node_host="127.0.0.1", limits=limits) as server,
        node("robot", master.uri) as robot,
        aiohttp.ClientSession() as http,
    ):
        ws, listener = await honest_setup(server, robot, http)
        for num in range(3):  # 3 of 4, then silence
            await ws.send_str(fragment("stuck", num, 4, "z" * 100 * KiB))
        await until(lambda: held(server) > 300 * KiB)
        (status,) = await statuses(ws, 1, timeout=5)
        assert status["level"] == "error"
        assert "stuck" in status["msg"]
        assert "3 of 4" in status["msg"]
        assert held(server) == 0
        assert server.rosbridge_fragments.size == 0
        await publish_in_fragments(ws, listener, "still served", "honest")
        await ws.close()


async def test_a_client_streaming_fragments_past_its_budget_holds_at_most_the_budget(master: Master) -> None:
    limits = SessionLimits(fragment_bytes=2 * MiB)
    async with (
        WebServer(master.uri, port=0, rosbridge_port=0, node_host="127.0.0.1", limits=limits) as server,
        node("robot", master.uri) as robot,
        aiohttp.ClientSession() as http,
    ):
        ws, listener = await honest_setup(server, robot, http)
        peak = 0
        for num in range(100):  # 10 MiB of one message that never ends
            await ws.send_str(fragment("endless", num, 1000, "w" * 100 * KiB))
            if num % 10 == 0:
                await publish_in_fragments(ws, listener, f"between {num}", f"honest-{num}")
                peak = max(peak, held(server))
        found = await statuses(ws, 1)
        assert "endless" in found[0]["msg"]
        assert str(2 * MiB) in found[0]["msg"]
        assert 0 < peak <= 2 * MiB
        await ws.close()


async def test_a_client_opening_thousands_of_ids_holds_at_most_max_fragmented(master: Master) -> None:
    async with rosbridge_and_node(master.uri, "robot") as (server, robot, http):
        hostile, listener = await honest_setup(server, robot, http)
        for i in range(3000):
            await hostile.send_str(fragment(f"id{i}", 0, 2, "v" * 10))
        honest = await http.ws_connect(server.rosbridge_url)
        await honest.send_str(json.dumps({"op": "advertise", "topic": "/chatter", "type": "std_msgs/String"}))
        await publish_in_fragments(honest, listener, "served", "honest")
        await until(lambda: sum(len(s.fragments) for s in server.rosbridge_sessions) >= server.limits.max_fragmented)
        (session,) = [s for s in server.rosbridge_sessions if len(s.fragments)]
        assert len(session.fragments) == server.limits.max_fragmented
        found = await statuses(hostile, 1)
        assert f"at most {server.limits.max_fragmented}" in found[0]["msg"]
        await hostile.close()
        await honest.close()


async def test_many_clients_together_hold_at_most_the_server_budget(master: Master) -> None:
    limits = SessionLimits(fragment_bytes=2 * MiB)
    async with (
        WebServer(
            master.uri, port=0, rosbridge_port=0, node_host="127.0.0.1", limits=limits, max_fragment_bytes=5 * MiB
        ) as server,
        aiohttp.ClientSession() as http,
    ):
        clients = [await http.ws_connect(server.rosbridge_url) for _ in range(4)]
        peak = 0
        for i, ws in enumerate(clients):  # 1.9 MiB each: within each client's budget, 7.6 MiB together
            for num in range(19):
                await ws.send_str(fragment(f"c{i}", num, 100, "u" * 100 * KiB))
            found = await barrier(ws)
            peak = max(peak, server.rosbridge_fragments.size)
            if i < 2:
                assert not found
            else:  # crossed the server's budget: refused, naming it
                assert str(5 * MiB) in found[0]["msg"], found
        assert peak <= 5 * MiB
        assert held(server) == server.rosbridge_fragments.size
        for ws in clients:
            await ws.close()
        await until(lambda: not server.rosbridge_sessions)
        assert server.rosbridge_fragments.size == 0
