"""A rosbridge client that advertises thousands of topics (issue 31, case 7).

Each ``advertise`` of a new topic registers a publisher with the master, and every registration changes the
graph the hub watches: without a cap, one client's 10,000 advertises kept a core busy for minutes. ``advertise``
is capped per client like ``subscribe`` (``max_subscriptions``); the ops beyond are refused with a status, and
the master stays responsive throughout. Real sockets, a real master, the server in the test's loop.
"""

from __future__ import annotations

import json
import time

import aiohttp

from mrosd import backports
from mrosd.master import Master
from mrosd.web.foxglove_server import SessionLimits
from mrosd.web.server import WebServer
from tests.reliability.test_reliability_rosbridge_fragments import barrier
from tests.web.inloop import node

CAP = 50
ADVERTISES = 2000


async def test_one_clients_advertise_flood_is_capped_and_the_master_answers(master: Master) -> None:
    limits = SessionLimits(max_subscriptions=CAP)
    async with (
        WebServer(master.uri, port=0, rosbridge_port=0, node_host="127.0.0.1", limits=limits) as server,
        node("probe", master.uri) as probe,
        aiohttp.ClientSession() as http,
    ):
        ws = await http.ws_connect(server.rosbridge_url)
        slowest = 0.0
        start = time.monotonic()
        for i in range(ADVERTISES):
            await ws.send_str(json.dumps({"op": "advertise", "topic": f"/flood/t{i}", "type": "std_msgs/String"}))
            if i % 200 == 0:  # the master answers while the ops are handled
                t0 = time.monotonic()
                async with backports.timeout(1.0):
                    await probe.master.call("getPid")
                slowest = max(slowest, time.monotonic() - t0)
        refused = await barrier(ws, timeout=20)
        elapsed = time.monotonic() - start
        assert len(refused) == ADVERTISES - CAP, (len(refused), elapsed)
        assert all(f"at most {CAP} advertised topics" in s["msg"] for s in refused)
        pubs, _, _ = await probe.master.get_system_state()
        flood = [t for t, _ in pubs if t.startswith("/flood/")]
        assert len(flood) == CAP
        assert slowest < 1.0
        assert elapsed < 20
        await ws.close()
