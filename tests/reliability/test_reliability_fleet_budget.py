"""The fleet's in-daemon node takes its share of the descriptor budget (issue 33, item 9).

Before, the fleet part had no cap of its own: its node admitted inbound TCPROS connections up to the node
default (4096) and its Zenoh session accepted up to Zenoh's 1000 sessions, whatever the daemon's
RLIMIT_NOFILE. Now ``mrosd.fdbudget`` gives it a share, and the bridge derives its caps from it.
"""

from __future__ import annotations

import asyncio
import contextlib
from typing import Any

import pytest

from mrosd.fdbudget import fd_budgets
from mrosd.fleet.bridge import FleetBridge, fleet_admission, fleet_sessions
from mrosd.master import Master
from tests.fleet.fleetenv import bare_peer, options
from tests.rosenv import free_port

zenoh = pytest.importorskip("zenoh", reason="the fleet tests need eclipse-zenoh (pip install 'mrosd[fleet]')")


def test_the_fleet_has_a_share_and_its_caps_come_from_it() -> None:
    for limit in (512, 1024, 65536):
        budgets = fd_budgets(limit)
        assert budgets.fleet >= 1
        assert sum(budgets.parts().values()) + budgets.reserve <= limit
    share = fd_budgets(1024).fleet
    assert fleet_admission(share).max_connections == share // 2
    assert fleet_sessions(share) == share // 4


async def test_zenoh_sessions_beyond_the_budget_are_refused() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    async with Master(host="127.0.0.1", port=0) as master:
        bridge = FleetBridge(options("robot1", endpoint), master.uri, host="127.0.0.1", fd_budget=8)
        async with bridge:
            assert bridge.node.admission_limits.max_connections == 4
            assert bridge.services.max_calls == 2
            peers: list[Any] = []
            try:
                for _ in range(4):
                    peers.append(await asyncio.to_thread(bare_peer, endpoint))
                linked = await asyncio.to_thread(lambda: list(bridge.session.info.peers_zid()))
                assert len(linked) <= fleet_sessions(8) == 2
            finally:
                for peer in peers:
                    with contextlib.suppress(Exception):
                        peer.close()
