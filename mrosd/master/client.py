"""Typed async client of the ROS 1 Master API and Parameter Server.

``MasterClient`` owns nothing but a caller id and a reference to an ``XmlRpcClient``; every method
is one XML-RPC call that unwraps rosmaster's ``[code, statusMessage, value]`` triple: the value on
code 1, ``MasterError`` on code 0/-1 (or a fault), ``MasterUnreachableError`` when no answer came.
Used by ``mrosd.tcpros`` nodes and by the CLI; it works against any ROS master, ours or rosmaster.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from typing import Any, Literal

from mrosd.errors import MasterError, MasterUnreachableError, XmlRpcError
from mrosd.xmlrpc import Fault, XmlRpcClient

#: One topic as getPublishedTopics/getTopicTypes report it: ``[name, type]``.
TopicType = tuple[str, str]
#: ``[[name, [node, ...]], ...]`` for publishers, subscribers or services.
GraphList = list[tuple[str, list[str]]]


def unwrap_reply(method: str, reply: Any) -> Any:
    """The value of a ROS API ``(code, statusMessage, value)`` reply to ``method`` (master or slave API).

    Raises:
        MasterError: the code is not 1 (success), or the reply is not such a triple.
    """
    if not isinstance(reply, list | tuple) or len(reply) != 3 or not isinstance(reply[0], int):
        raise MasterError(method, -1, f"malformed reply {reply!r:.200}")
    code, status, value = reply
    if code != 1:
        raise MasterError(method, code, str(status))
    return value


class MasterClient:
    """One caller id talking to one master URI.

    Args:
        master_uri: ``http://host:port/`` of the master.
        caller_id: the fully resolved name of the calling node (e.g. ``/talker``).
        xmlrpc: a shared client; when omitted one is created and closed by ``aclose()``.
        timeout: per-call timeout in seconds (``None`` uses the XML-RPC client's default).
    """

    def __init__(
        self,
        master_uri: str,
        caller_id: str,
        xmlrpc: XmlRpcClient | None = None,
        *,
        timeout: float | None = None,
    ) -> None:
        self.master_uri = master_uri
        self.caller_id = caller_id
        self._owns_xmlrpc = xmlrpc is None
        self._xmlrpc = xmlrpc if xmlrpc is not None else XmlRpcClient()
        self._timeout = timeout

    async def aclose(self) -> None:
        """Close the XML-RPC client if this instance created it."""
        if self._owns_xmlrpc:
            await self._xmlrpc.aclose()

    async def __aenter__(self) -> MasterClient:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()

    async def call(self, method: str, *args: Any, timeout: float | None = None) -> Any:
        """Call ``method(caller_id, *args)`` and return the value of a code-1 answer.

        ``timeout`` overrides the client's per-call timeout for this call (long polls).

        Raises:
            MasterError: the master answered with code 0 or -1, a fault, or a malformed triple.
            MasterUnreachableError: no answer (refused connection, timeout, HTTP error).
        """
        limit = self._timeout if timeout is None else timeout
        try:
            reply = await self._xmlrpc.call(self.master_uri, method, self.caller_id, *args, timeout=limit)
        except Fault as exc:
            raise MasterError(method, exc.code, exc.message) from exc
        except XmlRpcError as exc:
            raise MasterUnreachableError(self.master_uri, str(exc)) from exc
        return unwrap_reply(method, reply)

    # --- Master API: registration ------------------------------------------------------------

    async def register_service(self, service: str, service_api: str, caller_api: str) -> None:
        """Register ``service`` (rosrpc URI ``service_api``) provided by the node at ``caller_api``."""
        await self.call("registerService", service, service_api, caller_api)

    async def unregister_service(self, service: str, service_api: str) -> int:
        """Unregister a service; returns the number unregistered (0 if it was not ours)."""
        return int(await self.call("unregisterService", service, service_api))

    async def register_subscriber(self, topic: str, topic_type: str, caller_api: str) -> list[str]:
        """Subscribe; returns the XML-RPC URIs of the current publishers."""
        return [str(u) for u in await self.call("registerSubscriber", topic, topic_type, caller_api)]

    async def unregister_subscriber(self, topic: str, caller_api: str) -> int:
        """Unsubscribe; returns the number unregistered."""
        return int(await self.call("unregisterSubscriber", topic, caller_api))

    async def register_publisher(self, topic: str, topic_type: str, caller_api: str) -> list[str]:
        """Advertise; returns the XML-RPC URIs of the current subscribers."""
        return [str(u) for u in await self.call("registerPublisher", topic, topic_type, caller_api)]

    async def unregister_publisher(self, topic: str, caller_api: str) -> int:
        """Unadvertise; returns the number unregistered."""
        return int(await self.call("unregisterPublisher", topic, caller_api))

    # --- Master API: name service and state --------------------------------------------------

    async def lookup_node(self, node_name: str) -> str:
        """XML-RPC URI of the node called ``node_name``."""
        return str(await self.call("lookupNode", node_name))

    async def get_published_topics(self, subgraph: str = "") -> list[TopicType]:
        """``[(topic, type), ...]`` of topics with publishers, restricted to namespace ``subgraph``."""
        return [(str(t), str(ty)) for t, ty in await self.call("getPublishedTopics", subgraph)]

    async def get_topic_types(self) -> list[TopicType]:
        """``[(topic, type), ...]`` of every known topic (published or subscribed)."""
        return [(str(t), str(ty)) for t, ty in await self.call("getTopicTypes")]

    async def get_system_state(self) -> tuple[GraphList, GraphList, GraphList]:
        """``(publishers, subscribers, services)``, each ``[(name, [node, ...]), ...]``."""
        pubs, subs, srvs = await self.call("getSystemState")

        def conv(entries: Any) -> GraphList:
            return [(str(name), [str(n) for n in nodes]) for name, nodes in entries]

        return conv(pubs), conv(subs), conv(srvs)

    async def get_graph(self) -> GraphSnapshot:
        """The graph as ``getSystemState`` and ``getTopicTypes`` report it (two calls, any master)."""
        state = await self.call("getSystemState")
        types = await self.call("getTopicTypes")
        return GraphSnapshot.from_master(state, types)

    async def wait_system_state_change(self, since: int, timeout: float) -> tuple[int, GraphSnapshot]:
        """mrosd's ``waitSystemStateChange`` long poll: ``(version, graph)`` once the graph's version
        differs from ``since`` or after ``timeout`` seconds.

        Raises:
            MasterError: the master does not offer it (rosmaster: a fault) or refused the wait.
        """
        limit = timeout + (self._timeout if self._timeout is not None else 5.0)
        reply = await self.call("waitSystemStateChange", since, timeout, timeout=limit)
        if not isinstance(reply, list | tuple) or len(reply) != 3 or type(reply[0]) is not int:
            raise MasterError("waitSystemStateChange", -1, f"malformed value {reply!r:.200}")
        return reply[0], GraphSnapshot.from_master(reply[1], reply[2])

    async def get_uri(self) -> str:
        """The master's own URI."""
        return str(await self.call("getUri"))

    async def lookup_service(self, service: str) -> str:
        """The ``rosrpc://`` URI of ``service``."""
        return str(await self.call("lookupService", service))

    # --- Parameter Server --------------------------------------------------------------------

    async def delete_param(self, key: str) -> None:
        """Delete ``key`` (and its subtree)."""
        await self.call("deleteParam", key)

    async def set_param(self, key: str, value: Any) -> None:
        """Set ``key``; a dict value replaces the whole subtree."""
        await self.call("setParam", key, value)

    async def get_param(self, key: str) -> Any:
        """Value of ``key`` (a dict for a namespace). Raises ``MasterError`` if unset."""
        return await self.call("getParam", key)

    async def search_param(self, key: str) -> str | None:
        """Closest ``key`` up the caller's namespace, or ``None`` when not found."""
        try:
            found = await self.call("searchParam", key)
        except MasterUnreachableError:
            raise
        except MasterError as exc:
            if exc.code == -1 and "cannot find" in exc.status.lower():
                return None
            raise
        return str(found) if found else None

    async def subscribe_param(self, caller_api: str, key: str) -> Any:
        """Subscribe the node at ``caller_api`` to ``key``; returns its current value (``{}`` if unset)."""
        return await self.call("subscribeParam", caller_api, key)

    async def unsubscribe_param(self, caller_api: str, key: str) -> int:
        """Unsubscribe; returns the number unsubscribed."""
        return int(await self.call("unsubscribeParam", caller_api, key))

    async def has_param(self, key: str) -> bool:
        """Whether ``key`` is set."""
        return bool(await self.call("hasParam", key))

    async def get_param_names(self) -> list[str]:
        """Every parameter name (leaves only)."""
        return [str(n) for n in await self.call("getParamNames")]


# --- watching the graph -------------------------------------------------------------------------

GraphKind = Literal["node", "topic", "service"]


@dataclass(frozen=True, slots=True)
class GraphChange:
    """One node, topic or service that appeared or vanished; ``detail`` is a topic's type."""

    appeared: bool
    kind: GraphKind
    name: str
    detail: str = ""


@dataclass(frozen=True, slots=True)
class GraphSnapshot:
    """Nodes, topics (with types) and services (with their provider) of one moment of the graph."""

    nodes: frozenset[str] = frozenset()
    topics: dict[str, str] = field(default_factory=dict)
    services: dict[str, str] = field(default_factory=dict)
    #: the publishing nodes of each topic that has any, in registration order
    publishers: dict[str, tuple[str, ...]] = field(default_factory=dict)

    @classmethod
    def from_master(cls, state: Any, topic_types: Any) -> GraphSnapshot:
        """From getSystemState's ``[pubs, subs, srvs]`` and getTopicTypes' ``[[topic, type], ...]``.

        Raises:
            MasterError: the values do not have those shapes.
        """
        try:
            pubs, subs, srvs = state
            types = {str(t): str(ty) for t, ty in topic_types}
            nodes: set[str] = set()
            topics: dict[str, str] = {}
            publishers: dict[str, tuple[str, ...]] = {}
            for name, members in pubs:
                publishers[str(name)] = tuple(str(n) for n in members)
            for name, members in [*pubs, *subs]:
                topics[str(name)] = types.get(str(name), "*")
                nodes.update(str(n) for n in members)
            services: dict[str, str] = {}
            for name, members in srvs:
                services[str(name)] = str(members[0]) if members else ""
                nodes.update(str(n) for n in members)
        except (TypeError, ValueError) as exc:
            raise MasterError("getSystemState", -1, f"malformed graph: {exc}") from exc
        return cls(frozenset(nodes), topics, services, publishers)


@dataclass(slots=True)
class GraphDelta:
    """What changed in the graph, name by name: a topic's type (None: gone) and publishers, a service's
    provider (None: gone), a node's presence. Names not listed did not change."""

    topics: dict[str, str | None] = field(default_factory=dict)
    publishers: dict[str, tuple[str, ...]] = field(default_factory=dict)
    services: dict[str, str | None] = field(default_factory=dict)
    nodes: dict[str, bool] = field(default_factory=dict)

    def __bool__(self) -> bool:
        return bool(self.topics or self.publishers or self.services or self.nodes)


def graph_delta(old: GraphSnapshot, new: GraphSnapshot) -> GraphDelta:
    """The names that differ between two snapshots (for a graph that is polled rather than pushed)."""
    delta = GraphDelta()
    for name, msg_type in new.topics.items():
        if old.topics.get(name) != msg_type:
            delta.topics[name] = msg_type
    for name in old.topics.keys() - new.topics.keys():
        delta.topics[name] = None
    for name in old.publishers.keys() | new.publishers.keys():
        pubs = new.publishers.get(name, ())
        if old.publishers.get(name, ()) != pubs:
            delta.publishers[name] = pubs
    for name, provider in new.services.items():
        if old.services.get(name) != provider:
            delta.services[name] = provider
    for name in old.services.keys() - new.services.keys():
        delta.services[name] = None
    delta.nodes.update(dict.fromkeys(new.nodes - old.nodes, True))
    delta.nodes.update(dict.fromkeys(old.nodes - new.nodes, False))
    return delta


def graph_changes(old: GraphSnapshot, new: GraphSnapshot) -> list[GraphChange]:
    """What appeared (nodes, then topics, then services) and vanished (the reverse order), sorted by name."""
    out = [GraphChange(True, "node", n) for n in sorted(new.nodes - old.nodes)]
    out += [GraphChange(True, "topic", t, ty) for t, ty in sorted(new.topics.items()) if t not in old.topics]
    out += [GraphChange(True, "service", s, p) for s, p in sorted(new.services.items()) if s not in old.services]
    out += [GraphChange(False, "service", s, p) for s, p in sorted(old.services.items()) if s not in new.services]
    out += [GraphChange(False, "topic", t, ty) for t, ty in sorted(old.topics.items()) if t not in new.topics]
    out += [GraphChange(False, "node", n) for n in sorted(old.nodes - new.nodes)]
    return out


async def watch_graph(
    client: MasterClient, *, poll_interval: float = 0.5, wait_timeout: float = 30.0
) -> AsyncIterator[GraphSnapshot]:
    """Yield the graph now, then every time it changes, for as long as the caller iterates.

    Against mrosd the master pushes changes (``waitSystemStateChange`` long polls, one in flight);
    against any other master (rosmaster answers the unknown method with a fault) it polls
    ``getSystemState``/``getTopicTypes`` every ``poll_interval`` seconds. If the master becomes
    unreachable after the first answer, it retries at the polling pace until it answers again.

    Raises:
        MasterUnreachableError: the master does not answer the first call.
    """
    current = await client.get_graph()
    yield current
    push = True
    version = -1
    while True:
        try:
            if push:
                try:
                    version, graph = await client.wait_system_state_change(version, wait_timeout)
                except MasterError:
                    push = False  # not an mrosd master (or too many watches): poll instead
                    continue
            else:
                await asyncio.sleep(poll_interval)
                graph = await client.get_graph()
        except MasterUnreachableError:
            await asyncio.sleep(poll_interval)
            push = True
            version = -1
            continue
        if graph != current:
            current = graph
            yield graph
