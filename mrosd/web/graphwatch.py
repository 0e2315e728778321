"""The hub's view of the ROS graph, kept up to date name by name (O(change), never O(graph) per change),
and what its clients are told of it (``TopicInfo``, ``ServiceInfo``, ``GraphListener``).

Two sources, one shape (``GraphDelta``: only the names that changed):

- in the daemon, the master runs in the same process: its ``GraphFeed`` records the names each registration
  touches and the hub reads just those back (no XML-RPC, no snapshot);
- against any other master (``mros bridge``), ``mrosd.master.client.watch_graph`` long-polls an mrosd master or
  polls rosmaster, and each new snapshot is diffed against the previous one into a delta.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from typing import Protocol

from mrosd.master.client import GraphDelta, GraphSnapshot, MasterClient, graph_delta, watch_graph

__all__ = [
    "ClientSet",
    "GraphListener",
    "GraphSource",
    "LiveGraph",
    "ServiceInfo",
    "TopicInfo",
    "graph_deltas",
]


class GraphListener(Protocol):
    """A connected client, told about topics and services that became available or went away."""

    def topics_changed(self, added: list[TopicInfo], removed: list[TopicInfo]) -> None: ...

    def services_changed(self, added: list[ServiceInfo], removed: list[ServiceInfo]) -> None: ...


class ClientSet(set[GraphListener]):
    """The hub's connected clients: the first to arrive starts the probes that waited for someone to ask."""

    def __init__(self, arrived: Callable[[], None]) -> None:
        super().__init__()
        self._arrived = arrived

    def add(self, listener: GraphListener) -> None:
        first = not self
        super().add(listener)
        if first:
            self._arrived()


@dataclass(frozen=True, slots=True)
class TopicInfo:
    """A topic a client can subscribe to: ``id`` is stable for as long as its type stays the same."""

    id: int
    name: str
    type: str
    definition: str


@dataclass(frozen=True, slots=True)
class ServiceInfo:
    """A service a client can call: its type as the server told a probe, and both halves' definitions."""

    id: int
    name: str
    type: str
    request_definition: str
    response_definition: str


class LocalFeed(Protocol):
    """What ``mrosd.master.server.GraphFeed`` offers."""

    def snapshot(self) -> GraphSnapshot: ...

    async def next_delta(self) -> GraphDelta: ...

    def close(self) -> None: ...


class GraphSource(Protocol):
    """A master in this process (``mrosd.master.Master``)."""

    def graph_feed(self) -> LocalFeed: ...


class LiveGraph:
    """Nodes, topics (with their type and publishing nodes) and services (with their provider), mutable."""

    __slots__ = ("nodes", "publishers", "services", "topics")

    def __init__(self) -> None:
        self.nodes: set[str] = set()
        self.topics: dict[str, str] = {}
        self.services: dict[str, str] = {}
        self.publishers: dict[str, tuple[str, ...]] = {}

    def apply(self, delta: GraphDelta) -> None:
        for name, msg_type in delta.topics.items():
            if msg_type is None:
                self.topics.pop(name, None)
            else:
                self.topics[name] = msg_type
        for name, pubs in delta.publishers.items():
            if pubs:
                self.publishers[name] = pubs
            else:
                self.publishers.pop(name, None)
        for name, provider in delta.services.items():
            if provider is None:
                self.services.pop(name, None)
            else:
                self.services[name] = provider
        for name, present in delta.nodes.items():
            if present:
                self.nodes.add(name)
            else:
                self.nodes.discard(name)


async def graph_deltas(
    client: MasterClient, *, local: GraphSource | None = None, poll_interval: float = 0.5
) -> AsyncIterator[GraphDelta]:
    """The whole graph as a first delta (from nothing), then each change, for as long as the caller iterates.

    Raises:
        MasterUnreachableError: (remote) the master does not answer the first call.
    """
    empty = GraphSnapshot()
    if local is not None:
        feed = local.graph_feed()
        try:
            yield graph_delta(empty, feed.snapshot())
            while True:
                delta = await feed.next_delta()
                if delta:
                    yield delta
        finally:
            feed.close()
        return
    previous: GraphSnapshot | None = None
    async for graph in watch_graph(client, poll_interval=poll_interval):
        delta = graph_delta(previous or empty, graph)
        if delta or previous is None:
            yield delta
        previous = graph
