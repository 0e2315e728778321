"""A node cancelled in the middle of a registration call (Ctrl-C under ``mrosd.run`` while it starts) leaves
no registration behind.

The master may have registered the topic or service before the call was cut short; the node cannot know,
so it unregisters what it asked for. Before the fix, it forgot the endpoint and the master kept it until
the dead-node sweep (5 s, or never with ``cleanup_interval = 0``), listing a node that was gone.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable
from typing import Any

import pytest

import mrosd
from mrosd.master import Master
from mrosd.msg import get_message_class, get_service_class

String = get_message_class("std_msgs/String")
SetBool = get_service_class("std_srvs/SetBool")


def _registered(master: Master, name: str) -> bool:
    _, _, (pubs, subs, srvs) = master.api.get_system_state("/test")
    return any(entry == name for entry, _ in [*pubs, *subs, *srvs])


async def _cancel_once_registered(master: Master, name: str, call: Awaitable[Any]) -> bool:
    """Run ``call``; cancel it as soon as the master holds ``name`` (its answer still in flight).

    Returns whether the cancellation cut the call short (False: the answer came first; try again)."""
    task = asyncio.ensure_future(call)
    while not _registered(master, name) and not task.done():  # noqa: ASYNC110 (a race, not an event: every turn)
        await asyncio.sleep(0)
    task.cancel()
    try:
        await task
    except asyncio.CancelledError:
        return True
    return False


@pytest.mark.parametrize("kind", ["publisher", "subscriber", "service"])
async def test_a_registration_cancelled_in_flight_is_undone(kind: str) -> None:
    async with Master(host="127.0.0.1", port=0, cleanup_interval=0) as master:
        cut_short = 0
        for attempt in range(20):
            name = f"/{kind}_{attempt}"
            async with mrosd.Node(f"n{attempt}", master_uri=master.uri, argv=[], host="127.0.0.1") as node:
                call: Awaitable[Any] = (
                    node.advertise(name, String)
                    if kind == "publisher"
                    else node.subscribe(name, String)
                    if kind == "subscriber"
                    else node.advertise_service(name, SetBool, lambda r: None)
                )
                if await _cancel_once_registered(master, name, call):
                    cut_short += 1
                    assert not _registered(master, name), f"{name} left registered by a cancelled call"
        assert cut_short > 0  # the race was actually exercised
