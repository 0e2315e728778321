"""Two (or more) masters in one process, each with its FleetBridge, linked over Zenoh on loopback."""

from __future__ import annotations

import asyncio
import json
import textwrap
from collections.abc import AsyncIterator
from contextlib import AsyncExitStack, asynccontextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

import mrosd
from mrosd.fleet.bridge import FleetBridge
from mrosd.fleet.keys import NameFilter
from mrosd.fleet.options import FleetOptions
from mrosd.master import Master
from tests.netns.nsutil import ZENOH_PORT, lab_daemon_config
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


async def publish_forever(pub: Any, msg: Any, period: float = 0.05) -> None:
    """Publish ``msg`` every ``period`` seconds until cancelled (a link's first samples may come before it is up)."""
    while True:
        pub.publish_nowait(msg)
        await asyncio.sleep(period)


async def first_across(robot: Robot, topic: str, cls: Any, pub: Any, msg: Any, listener: mrosd.Node) -> Any:
    """The first ``msg`` that reaches ``listener`` on ``topic`` of ``robot``: once ``robot``'s bridge has heard of
    the topic, ``listener`` subscribes and ``pub`` publishes ``msg`` every 50 ms until one arrives (bounded)."""
    await robot.bridge.wait_until(lambda: topic in robot.bridge.received, 15)
    sub = await listener.subscribe(topic, cls)
    sender = asyncio.create_task(publish_forever(pub, msg))
    try:
        return await sub.next(timeout=10)
    finally:
        sender.cancel()


def bare_peer(endpoint: str) -> Any:
    """A bare Zenoh session linked to ``endpoint``: it can put and ask anything (a bridge, or a hostile peer)."""
    cfg = zenoh.Config()
    cfg.insert_json5("mode", '"peer"')
    cfg.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{free_port()}"]))
    cfg.insert_json5("connect/endpoints", json.dumps([endpoint]))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(cfg)


def daemon_config(tmp: Path, robot: str, listen: str, connect: str, extra: str) -> Path:
    """An mrosd.toml for one robot of the netns lab and the benchmark: [fleet] plus ``extra``."""
    connect_list = f'"tcp/{connect}:{ZENOH_PORT}"' if connect else ""
    fleet_section = f"""
    [fleet]
    enabled = true
    robot = "{robot}"
    listen = ["tcp/{listen}:{ZENOH_PORT}"]
    connect = [{connect_list}]
    """
    return lab_daemon_config(tmp / f"{robot}.toml", textwrap.dedent(fleet_section) + extra)
