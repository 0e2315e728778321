"""``Master``: the ROS 1 master process part, composing the handlers, the notifier and the XML-RPC server.

Owns the listening socket, the outgoing XML-RPC client used for callbacks, and the optional
allow-list of client networks (connections from other addresses get HTTP 403 once their bounded request is
in; it is never decoded or handled).
HTTP framing is ``httpframing`` (sans IO), connections and their limits ``httpserver``, body-to-reply
dispatch ``dispatch``; the XML-RPC codec is ``mrosd.xmlrpc``.
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
import os
import socket
from collections.abc import Iterable
from urllib.parse import urlsplit

from mrosd.master.api import READ_ONLY_METHODS, MasterApi
from mrosd.master.cleanup import DEFAULT_CLEANUP_INTERVAL
from mrosd.master.client import GraphDelta, GraphSnapshot
from mrosd.master.dispatch import XmlRpcHttpHandler
from mrosd.master.httpserver import IDLE_TIMEOUT, MAX_CONNECTIONS, MAX_CONNECTIONS_PER_HOST, HttpServer
from mrosd.master.notifier import Notifier
from mrosd.master.registry import ANYTYPE, GraphJournal, Registry
from mrosd.xmlrpc import XmlRpcClient, XmlRpcServer

log = logging.getLogger(__name__)

DEFAULT_PORT = 11311

Network = ipaddress.IPv4Network | ipaddress.IPv6Network


def parse_networks(allow: Iterable[str]) -> list[Network]:
    """``["127.0.0.0/8", "::1"]`` -> networks; a bare address is a single-host network.

    Raises:
        ValueError: an entry is not an address or network.
    """
    return [ipaddress.ip_network(entry.strip(), strict=False) for entry in allow]


def advertised_host(bind_host: str, environ: dict[str, str] | None = None) -> str:
    """The host name put in the master's URI: ROS_HOSTNAME, ROS_IP, the bind address, or the host name."""
    env = os.environ if environ is None else environ
    for var in ("ROS_HOSTNAME", "ROS_IP"):
        value = env.get(var, "").strip()
        if value:
            return value
    if bind_host and bind_host not in ("0.0.0.0", "::"):
        return bind_host
    return socket.gethostname() or "localhost"


def port_from_master_uri(uri: str | None, default: int = DEFAULT_PORT) -> int:
    """The port of ``ROS_MASTER_URI`` (``http://host:port/``), or ``default``."""
    if not uri:
        return default
    try:
        return urlsplit(uri).port or default
    except ValueError:
        return default


class GraphFeed(GraphJournal):
    """The graph's changes for an observer in the master's own process (the daemon's web hub), with no
    XML-RPC in between: the registry records the names each change touches, and ``next_delta`` reads just
    those names back, so a registration costs the observer O(1), not a new snapshot of the whole graph.

    Use it on the master's event loop; ``close()`` detaches it.
    """

    __slots__ = ("_changed", "_registry")

    def __init__(self, registry: Registry) -> None:
        super().__init__()
        self._registry = registry
        self._changed = asyncio.Event()
        registry.journals.append(self)

    def touched(self) -> None:
        self._changed.set()

    def close(self) -> None:
        if self in self._registry.journals:
            self._registry.journals.remove(self)

    def snapshot(self) -> GraphSnapshot:
        """The whole graph now (once, at the start; later changes come from ``next_delta``)."""
        reg = self._registry
        topics = {t: reg.topic_types.get(t, ANYTYPE) for t in (*reg.publishers, *reg.subscribers)}
        services = {s: e.node for s, e in reg.services.items()}
        publishers = {t: tuple(nodes) for t, nodes in reg.publishers.items()}
        return GraphSnapshot(frozenset(reg.nodes), topics, services, publishers)

    async def next_delta(self) -> GraphDelta:
        """Wait for the next change; returns every name changed since the last call (coalesced)."""
        await self._changed.wait()
        self._changed.clear()
        reg = self._registry
        delta = GraphDelta()
        topics, self.topics = self.topics, set()
        services, self.services = self.services, set()
        nodes, self.nodes = self.nodes, set()
        for t in topics:
            present = t in reg.publishers or t in reg.subscribers
            delta.topics[t] = reg.topic_types.get(t, ANYTYPE) if present else None
            delta.publishers[t] = tuple(reg.publishers.get(t, ()))
        for s in services:
            entry = reg.services.get(s)
            delta.services[s] = entry.node if entry is not None else None
        for n in nodes:
            delta.nodes[n] = n in reg.nodes
        return delta


class Master:
    """A ROS 1 master (Master API + Parameter Server) on one event loop.

    Args:
        host: address to bind.
        port: TCP port (0 picks a free one; see ``.port`` after ``start()``).
        allow: client networks allowed to call (e.g. ``["127.0.0.0/8", "10.0.0.0/8"]``); None allows all.
        advertise: host name for ``.uri``; default from ROS_HOSTNAME/ROS_IP/bind address.
        notify_timeout: seconds allowed for one callback to a node.
        notify_queue: most callbacks queued per node (oldest dropped beyond).
        max_connections: open client connections in all (beyond: HTTP 503 and close); clamped at start to
            RLIMIT_NOFILE minus a reserve.
        max_connections_per_host: open client connections of one remote address or one local uid.
        idle_timeout: seconds after which an idle kept-alive client connection is closed (1x to 1.5x).
        cleanup_interval: seconds between sweeps removing nodes whose slave API refuses connections
            (confirmed by getPid); 0 turns the sweep off, as rosmaster keeps dead nodes.
    """

    def __init__(
        self,
        host: str = "0.0.0.0",
        port: int = DEFAULT_PORT,
        *,
        allow: Iterable[str] | None = None,
        advertise: str | None = None,
        notify_timeout: float = 5.0,
        notify_queue: int = 10_000,
        max_connections: int = MAX_CONNECTIONS,
        max_connections_per_host: int = MAX_CONNECTIONS_PER_HOST,
        idle_timeout: float = IDLE_TIMEOUT,
        cleanup_interval: float = DEFAULT_CLEANUP_INTERVAL,
    ) -> None:
        self.host = host
        self._requested_port = port
        self._advertise = advertise
        self._allow = parse_networks(allow) if allow is not None else None
        self._client = XmlRpcClient(timeout=notify_timeout)
        self.api = MasterApi(None, cleanup_interval=cleanup_interval)
        self.notifier = Notifier(
            self._client,
            timeout=notify_timeout,
            max_queue=notify_queue,
            on_result=self.api.on_notification_result,
        )
        self.api.notifier = self.notifier
        self._dispatch = XmlRpcServer(self.api.methods, name="master")  # codec + multicall; never bound
        self._handler = XmlRpcHttpHandler(
            self.api.sync_methods, self._dispatch, cacheable=READ_ONLY_METHODS, state_version=self.api.state_version
        )
        self._server = HttpServer(
            self._handler,
            self._allow,
            max_connections=max_connections,
            max_connections_per_host=max_connections_per_host,
            idle_timeout=idle_timeout,
        )
        self.port = 0
        self.uri = ""

    def graph_feed(self) -> GraphFeed:
        """Follow the graph's changes in this process (``GraphFeed``; close it when done)."""
        return GraphFeed(self.api.registry)

    async def start(self) -> None:
        """Bind and serve; ``.port`` and ``.uri`` are set afterwards."""
        await self._server.start(self.host, self._requested_port)
        self.port = self._server.port
        host = self._advertise or advertised_host(self.host)
        if ":" in host and not host.startswith("["):
            host = f"[{host}]"
        self.uri = f"http://{host}:{self.port}/"
        self.api.uri = self.uri
        log.info("ROS master listening on %s:%d, advertised as %s", self.host, self.port, self.uri)

    async def aclose(self) -> None:
        """Stop serving, drop queued callbacks, close connections."""
        await self._server.aclose()
        self._handler.close()
        await self.notifier.aclose()
        await self._client.aclose()

    async def __aenter__(self) -> Master:
        await self.start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()
