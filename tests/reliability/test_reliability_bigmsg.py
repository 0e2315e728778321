"""Big messages against a real daemon: what they cost must follow the bytes in use, not a multiple of them.

Publishers latch big messages on one topic and web clients subscribe to it, one after the other (the later
ones get the hub's latched replay). What the daemon must hold while the clients stay: the hub's latched store
(at most ``MAX_LATCHED_BYTES``, here one message) and nothing that outlives a send. Before: every TCPROS link
kept its newest large receive buffer as a spare for the next frame, and each shared-memory link kept its last
four copies, so each publisher's message stayed resident once delivered and dropped (6 x 40 MiB with 4
clients: +267 MiB over TCPROS; over shared memory +244 MiB of copies, and +240 MiB of the publishers' rings
mapped, which RSS counts as well).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import sys
import xmlrpc.client
from pathlib import Path

import aiohttp
import pytest

from mrosd import backports
from tests.reliability.test_reliability_web_doors import FOXGLOVE, LATCHERS, _until_advertised
from tests.rosenv import Processes
from tests.web.webdaemon import MiB, Watch, WebDaemon

#: Over glibc's largest dynamic mmap threshold (32 MiB): a freed buffer of this size goes back to the kernel
#: at once, so the daemon's RSS shows what is still referenced. Two do not fit the latched store's 64 MiB.
MESSAGE_MIB = 33
PUBLISHERS = 4
CLIENTS = 3


@pytest.mark.parametrize(
    ("transport", "protocol"), [("tcpros", "foxglove"), ("shm", "foxglove"), ("tcpros", "rosbridge")]
)
def test_big_latched_messages_cost_what_is_held_not_a_buffer_per_link(
    tmp_path: Path, transport: str, protocol: str
) -> None:
    """4 publishers each latch 33 MiB, over TCPROS (their shared memory off) or shared memory; 3 clients
    (Foxglove, or rosbridge with ``cbor-raw``) subscribe one after the other. Once every message was delivered,
    the daemon's own memory holds about one of them (the latched store's), not one per link or per client,
    and the peak stays within issue 31's bar.

    The daemon's anonymous memory is what it allocated; over shared memory its RSS also counts the
    publishers' ring pages it has mapped (their memory, not a copy), so the peak is judged over TCPROS."""
    procs = Processes(tmp_path)
    daemon = WebDaemon(procs, tmp_path)
    try:
        env = dict(os.environ, MROSD_SHM="0") if transport == "tcpros" else None
        argv = [sys.executable, "-c", LATCHERS, daemon.uri, str(PUBLISHERS), str(MESSAGE_MIB)]
        latchers = procs.start(argv, env)
        assert latchers.stdout is not None and latchers.stdout.readline().strip() == b"ready"
        anon0 = daemon.rss("RssAnon")

        async def main() -> tuple[list[int], int]:
            counts = []
            async with aiohttp.ClientSession() as http:
                sockets = []
                for k in range(CLIENTS):
                    if protocol == "foxglove":
                        ws = await http.ws_connect(daemon.foxglove_url, protocols=FOXGLOVE, max_msg_size=0)
                        channel = await _until_advertised(ws, "/big")
                        op = {"op": "subscribe", "subscriptions": [{"id": 1, "channelId": channel}]}
                    else:  # each client gets its own op of every message: cbor-raw is the body as it came
                        ws = await http.ws_connect(daemon.rosbridge_url, max_msg_size=0)
                        op = {"op": "subscribe", "topic": "/big", "compression": "cbor-raw"}
                    sockets.append(ws)
                    await ws.send_str(json.dumps(op))
                    got = [0]
                    reader = asyncio.create_task(_count_messages(ws, got))
                    async with backports.timeout(20):
                        if k == 0:  # the hub's subscription opens: every publisher's latched message arrives
                            while await asyncio.to_thread(_links_delivered, daemon.uri) < PUBLISHERS:  # noqa: ASYNC110
                                await asyncio.sleep(0.1)
                        while got[0] < 1:  # noqa: ASYNC110 - counted by the reader
                            await asyncio.sleep(0.05)
                    # the first client takes what its budget holds of them (over TCPROS the hub reads at its
                    # pace: all), the later ones the replay of what the store kept; then nothing is in flight
                    with contextlib.suppress(TimeoutError):
                        async with backports.timeout(1.5):
                            while got[0] < (PUBLISHERS if k == 0 else 1):  # noqa: ASYNC110
                                await asyncio.sleep(0.05)
                    reader.cancel()
                    counts.append(got[0])
                held = daemon.rss("RssAnon") - anon0  # every client still subscribed, everything delivered
                for ws in sockets:
                    await ws.close()
            return counts, held

        with Watch(daemon) as watch:
            counts, held = asyncio.run(main())
        print(watch, f"held +{held / MiB:.0f} MiB", "messages per client", counts)
        assert counts[0] >= 1 and counts[1:] == [1] * (CLIENTS - 1), counts
        if transport == "tcpros":
            assert counts[0] == PUBLISHERS, counts
        assert held < 2 * MESSAGE_MIB * MiB, f"+{held / MiB:.0f} MiB held for {MESSAGE_MIB} MiB in use"
        if transport == "tcpros":
            assert watch.growth < 256 * MiB, watch
        assert watch.worst < 1.0 and watch.failed == 0, watch
    finally:
        daemon.close()
        procs.close()


async def _count_messages(ws: aiohttp.ClientWebSocketResponse, got: list[int]) -> None:
    while True:
        msg = await ws.receive()
        assert msg.type in (aiohttp.WSMsgType.BINARY, aiohttp.WSMsgType.TEXT), msg
        got[0] += msg.type == aiohttp.WSMsgType.BINARY


def _links_delivered(master_uri: str) -> int:
    """How many of the web node's links on /big have delivered a message (its getBusStats)."""
    with xmlrpc.client.ServerProxy(master_uri) as master:
        code, _, uri = master.lookupNode("/bigmsg_test", "/mrosd_web")
    assert code == 1, uri
    with xmlrpc.client.ServerProxy(uri) as node:
        _, _, (_, subs, _) = node.getBusStats("/bigmsg_test")
    for topic, links in subs:
        if topic == "/big":
            return sum(1 for link in links if link[2] >= 1)
    return 0
