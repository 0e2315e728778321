"""Big messages against a real daemon: what they cost must follow the bytes in use, not a multiple of them.

Publishers latch big messages on one topic and web clients subscribe to it, one after the other (the later
ones get the hub's latched replay). What the daemon must hold while the clients stay: the hub's latched store
(at most ``MAX_LATCHED_BYTES``, here one message) and nothing that outlives a send. Before: every TCPROS link
kept its newest large receive buffer as a spare for the next frame, so each publisher's message stayed
resident once delivered and dropped (6 x 40 MiB with 4 clients: +267 MiB over TCPROS).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import sys
from pathlib import Path

import aiohttp

from mrosd import backports
from tests.reliability.test_reliability_web_doors import FOXGLOVE, LATCHERS, _until_advertised
from tests.rosenv import Processes
from tests.web.webdaemon import MiB, Watch, WebDaemon

#: Over glibc's largest dynamic mmap threshold (32 MiB): a freed buffer of this size goes back to the kernel
#: at once, so the daemon's RSS shows what is still referenced. Two do not fit the latched store's 64 MiB.
MESSAGE_MIB = 33
PUBLISHERS = 4
CLIENTS = 3


def test_big_latched_messages_cost_what_is_held_not_a_buffer_per_link(tmp_path: Path) -> None:
    """4 publishers (TCPROS: shared memory off) each latch 33 MiB; 3 Foxglove clients subscribe one after the
    other. Once every message was delivered, the daemon holds about one of them (the latched store's), not
    one per link, and the peak stays within issue 31's bar."""
    procs = Processes(tmp_path)
    daemon = WebDaemon(procs, tmp_path)
    try:
        env = dict(os.environ, MROSD_SHM="0")
        argv = [sys.executable, "-c", LATCHERS, daemon.uri, str(PUBLISHERS), str(MESSAGE_MIB)]
        latchers = procs.start(argv, env)
        assert latchers.stdout is not None and latchers.stdout.readline().strip() == b"ready"
        rss0 = daemon.rss()

        async def main() -> tuple[list[int], int]:
            counts = []
            async with aiohttp.ClientSession() as http:
                sockets = []
                for k in range(CLIENTS):
                    ws = await http.ws_connect(daemon.foxglove_url, protocols=FOXGLOVE, max_msg_size=0)
                    sockets.append(ws)
                    channel = await _until_advertised(ws, "/big")
                    await ws.send_str(
                        json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": channel}]})
                    )
                    # the first client gets every publisher's message (the hub reads at its pace); the later
                    # ones the replay of what the store kept
                    want = PUBLISHERS if k == 0 else 1
                    got = 0
                    with contextlib.suppress(TimeoutError):
                        async with backports.timeout(20):
                            while got < want:
                                msg = await ws.receive()
                                assert msg.type in (aiohttp.WSMsgType.BINARY, aiohttp.WSMsgType.TEXT), msg
                                got += msg.type == aiohttp.WSMsgType.BINARY
                    counts.append(got)
                held = daemon.rss() - rss0  # every client still subscribed, everything delivered
                for ws in sockets:
                    await ws.close()
            return counts, held

        with Watch(daemon) as watch:
            counts, held = asyncio.run(main())
        print(watch, f"held +{held / MiB:.0f} MiB", "messages per client", counts)
        assert counts == [PUBLISHERS] + [1] * (CLIENTS - 1), counts
        assert held < 2 * MESSAGE_MIB * MiB, f"+{held / MiB:.0f} MiB held for {MESSAGE_MIB} MiB in use"
        assert watch.growth < 256 * MiB, watch
        assert watch.worst < 1.0 and watch.failed == 0, watch
    finally:
        daemon.close()
        procs.close()
