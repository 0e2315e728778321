"""Helpers of the web tests that run the master, the ``WebServer`` and the ROS nodes in the test's own event loop
(tests/web and the web's hostile tests in tests/reliability): a node on loopback, a rosbridge server with a node
and an HTTP client session, a bounded wait on the server's state, and a sink on the hub that records what it is
given.

It knows nothing of daemons in subprocesses (tests/web/webdaemon.py) nor of browsers.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager

import aiohttp

import mrosd
from mrosd import backports
from mrosd.web.server import WebServer


def node(name: str, master: str) -> mrosd.Node:
    """A node on 127.0.0.1 with no command-line remappings, registered with ``master``."""
    return mrosd.Node(name, master_uri=master, argv=[], host="127.0.0.1")


@asynccontextmanager
async def rosbridge_and_node(
    master: str, name: str
) -> AsyncIterator[tuple[WebServer, mrosd.Node, aiohttp.ClientSession]]:
    """A ``WebServer`` with its rosbridge port, a node ``name`` and an HTTP session for WebSocket clients, all on
    ``master``; closed in the reverse order."""
    async with (
        WebServer(master, port=0, rosbridge_port=0, node_host="127.0.0.1") as server,
        node(name, master) as robot,
        aiohttp.ClientSession() as http,
    ):
        yield server, robot, http


async def until(cond: Callable[[], object], timeout: float = 10.0, step: float = 0.005) -> None:
    """Re-check ``cond`` every ``step`` seconds (the server runs in this loop too, and its state lives in its
    callbacks, so there is no event to await), at most ``timeout`` seconds."""
    async with backports.timeout(timeout):
        while not cond():  # noqa: ASYNC110 - the state lives in the server's callbacks
            await asyncio.sleep(step)


class Collect:
    """A sink on the hub as a client's (queues nothing): every body it is given."""

    def __init__(self) -> None:
        self.bodies: asyncio.Queue[bytes] = asyncio.Queue()

    def deliver(self, topic: str, body: bytes | bytearray, receipt_ns: int) -> None:
        self.bodies.put_nowait(bytes(body))

    def backlog(self, topic: str) -> int:
        return 0

    def queued(self) -> int:
        return 0

    def shed_oldest(self) -> None:
        pass


__all__ = ["Collect", "node", "rosbridge_and_node", "until"]
