"""Two (or more) masters in one process, each with its FleetBridge, linked over Zenoh on loopback."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import AsyncExitStack, asynccontextmanager
from dataclasses import dataclass

import pytest

import mrosd
from mrosd.fleet.bridge import FleetBridge
from mrosd.fleet.keys import NameFilter
from mrosd.fleet.options import FleetOptions
from mrosd.master import Master
from tests.rosenv import free_port

zenoh = pytest.importorskip("zenoh", reason="the fleet tests need eclipse-zenoh (pip install 'mrosd[fleet]')")

EVERYTHING = NameFilter(include=("/**",))


@dataclass
class Robot:
    name: str
    master: Master
    bridge: FleetBridge
    endpoint: str

    def node(self, name: str) -> mrosd.Node:
        return mrosd.Node(name, master_uri=self.master.uri, argv=[], host="127.0.0.1")


def options(robot: str, listen: str, connect: tuple[str, ...] = (), **kw: object) -> FleetOptions:
    base: dict[str, object] = {
        "listen": (listen,),
        "connect": connect,
        "send_topics": EVERYTHING,
        "receive_topics": EVERYTHING,
        "send_services": NameFilter(include=("/set", "/fail", "/add_two_ints")),
        "receive_services": EVERYTHING,
    }
    base.update(kw)
    return FleetOptions(robot, **base)  # type: ignore[arg-type]


@asynccontextmanager
async def fleet(*names: str, transport: str = "tcp", connect_to: str = "", **kw: object) -> AsyncIterator[list[Robot]]:
    """Robots in a line: each one connects to the one before it (the first to ``connect_to`` if given);
    ``transport`` tcp, or tls on localhost."""
    host = "localhost" if transport == "tls" else "127.0.0.1"
    async with AsyncExitStack() as stack:
        robots: list[Robot] = []
        for name in names:
            master = await stack.enter_async_context(Master(host="127.0.0.1", port=0))
            endpoint = f"{transport}/{host}:{free_port()}"
            connect = (robots[-1].endpoint,) if robots else ((connect_to,) if connect_to else ())
            bridge = FleetBridge(options(name, endpoint, connect, **kw), master.uri, host="127.0.0.1")
            await stack.enter_async_context(bridge)
            robots.append(Robot(name, master, bridge, endpoint))
        yield robots
