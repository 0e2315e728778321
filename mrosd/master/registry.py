"""The master's graph registry as pure data: nodes, publishers, subscribers, services, parameter subscribers.

Every mutating method returns the notifications the caller must send (``Notification`` values); nothing
here awaits, sleeps or touches a socket, so the whole rosmaster semantics is testable in memory.
Names arrive already resolved (the handlers in ``api.py`` resolve them against the caller id).

Semantics follow rosmaster (ros_comm 1.15): a node is known while it has at least one registration;
a node name re-registering with a different XML-RPC URI replaces the old node entirely (its
registrations are dropped and the old URI is told to shut down); the type recorded for a topic is the
last publisher's (a subscriber only sets it when none is known, and ``*`` never overwrites a type).
One deliberate improvement, from DESIGN.md: the old URI is never told to shut down when another
node name now owns it (a dead node's port reused by someone else). As in rosmaster, subscribers of
topics the replaced node published are not sent a ``publisherUpdate`` for the removal.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

ANYTYPE = "*"


@dataclass(slots=True)
class Notification:
    """One XML-RPC call the master owes a node: ``method('/master', *args)`` at ``api``.

    ``coalesce`` is set for calls where only the latest matters (publisherUpdate per topic).
    """

    api: str
    method: str
    args: tuple[Any, ...]
    coalesce: str | None = None


def publisher_update(api: str, topic: str, pub_uris: list[str]) -> Notification:
    """A ``publisherUpdate(topic, pub_uris)`` for the subscriber at ``api``."""
    return Notification(api, "publisherUpdate", (topic, pub_uris), coalesce=topic)


def param_update(api: str, key: str, value: Any) -> Notification:
    """A ``paramUpdate(key, value)`` for the parameter subscriber at ``api``."""
    return Notification(api, "paramUpdate", (key, value))


def shutdown(api: str, reason: str) -> Notification:
    """A ``shutdown(reason)`` for the node at ``api``."""
    return Notification(api, "shutdown", (reason,))


class GraphJournal:
    """The names whose registrations changed since its owner last drained it (one per in-process observer).

    The registry adds a name to ``topics``, ``services`` or ``nodes`` whenever a registration of it may have
    changed, then calls ``touched()`` (a no-op here: an owner on an event loop wakes itself there). The owner
    reads the current state of just those names, so following the graph costs O(change), not O(graph).
    """

    __slots__ = ("nodes", "services", "topics")

    def __init__(self) -> None:
        self.topics: set[str] = set()
        self.services: set[str] = set()
        self.nodes: set[str] = set()

    def touched(self) -> None:
        """Called after names were added (once per registry call that changed something)."""


@dataclass(slots=True)
class NodeEntry:
    """One node: its XML-RPC URI and what it registered (as insertion-ordered sets)."""

    name: str
    api: str
    publications: dict[str, None] = field(default_factory=dict)
    subscriptions: dict[str, None] = field(default_factory=dict)
    services: dict[str, None] = field(default_factory=dict)
    param_subscriptions: dict[str, None] = field(default_factory=dict)
    #: Bumped by every registration call of this node (a live node re-registering shows up here).
    generation: int = 0

    def is_empty(self) -> bool:
        return not (self.publications or self.subscriptions or self.services or self.param_subscriptions)


@dataclass(slots=True)
class ServiceEntry:
    """The one provider of a service."""

    node: str
    caller_api: str
    service_api: str


class Registry:
    """Nodes and their topic, service and parameter registrations.

    Topic maps are ``topic -> {node name: caller_api}`` in registration order, which is the order
    rosmaster reports them in.
    """

    def __init__(self) -> None:
        self.nodes: dict[str, NodeEntry] = {}
        self.publishers: dict[str, dict[str, str]] = {}
        self.subscribers: dict[str, dict[str, str]] = {}
        self.services: dict[str, ServiceEntry] = {}
        self.param_subscribers: dict[str, dict[str, str]] = {}
        self.topic_types: dict[str, str] = {}
        #: How many nodes currently use each XML-RPC URI (a reused port may briefly be shared).
        self._api_users: dict[str, int] = {}
        #: Bumped by every method that may change the registry (a repeated identical registration
        #: does not); replies computed from the registry stay valid while it is unchanged.
        self.version = 0
        self._system_state: tuple[int, list[list[list[Any]]]] | None = None
        #: told the names each change touches (``GraphJournal``); usually empty
        self.journals: list[GraphJournal] = []

    def _touch(self, topics: tuple[str, ...] = (), services: tuple[str, ...] = (), nodes: tuple[str, ...] = ()) -> None:
        for journal in self.journals:
            journal.topics.update(topics)
            journal.services.update(services)
            journal.nodes.update(nodes)
            journal.touched()

    # --- nodes -------------------------------------------------------------------------------

    def _node(self, name: str, api: str, out: list[Notification]) -> NodeEntry:
        """The entry for ``name`` at ``api``, replacing an entry with another URI."""
        node = self.nodes.get(name)
        if node is not None and node.api == api:
            node.generation += 1
            return node
        if node is not None:
            self._drop_node(node)
            if self._api_users.get(node.api, 0) == 0:
                out.append(shutdown(node.api, f"[{name}] Reason: new node registered with same name"))
        node = NodeEntry(name, api)
        self.nodes[name] = node
        if self.journals:
            self._touch(nodes=(name,))
        self._api_users[api] = self._api_users.get(api, 0) + 1
        return node

    def _forget_if_empty(self, node: NodeEntry) -> None:
        if node.is_empty() and self.nodes.get(node.name) is node:
            del self.nodes[node.name]
            self._release_api(node.api)
            if self.journals:
                self._touch(nodes=(node.name,))

    def _release_api(self, api: str) -> None:
        users = self._api_users.get(api, 0) - 1
        if users > 0:
            self._api_users[api] = users
        else:
            self._api_users.pop(api, None)

    def _drop_node(self, node: NodeEntry) -> None:
        """Remove every registration of ``node`` (being replaced).

        Like rosmaster, subscribers of the topics it published are not told: they learn the new
        publisher list when the replacing node registers each topic again.
        """
        for topic in node.publications:
            _remove(self.publishers, topic, node.name)
        for topic in node.subscriptions:
            _remove(self.subscribers, topic, node.name)
        for key in node.param_subscriptions:
            _remove(self.param_subscribers, key, node.name)
        for service in node.services:
            entry = self.services.get(service)
            if entry is not None and entry.node == node.name:
                del self.services[service]
        del self.nodes[node.name]
        self._release_api(node.api)
        if self.journals:
            self._touch((*node.publications, *node.subscriptions), tuple(node.services), (node.name,))

    def remove_node(self, name: str) -> list[Notification]:
        """Unregister everything node ``name`` registered, as ``rosnode cleanup`` does call by call.

        Returns the publisherUpdates owed to subscribers of the topics it published; no shutdown.
        """
        node = self.nodes.get(name)
        if node is None:
            return []
        self.version += 1
        topics = list(node.publications)
        self._drop_node(node)
        out: list[Notification] = []
        for topic in topics:
            out.extend(self._publisher_updates(topic))
        return out

    def apis(self) -> dict[str, list[str]]:
        """``{XML-RPC URI: [node names]}`` of every registered node."""
        out: dict[str, list[str]] = {}
        for node in self.nodes.values():
            out.setdefault(node.api, []).append(node.name)
        return out

    def lookup_node(self, name: str) -> str | None:
        """XML-RPC URI of node ``name``, or None when unknown."""
        node = self.nodes.get(name)
        return node.api if node is not None else None

    def nodes_at(self, api: str) -> list[str]:
        """Names of the nodes registered with XML-RPC URI ``api``."""
        return [n.name for n in self.nodes.values() if n.api == api]

    # --- topics ------------------------------------------------------------------------------

    def _registered(self, entry: NodeEntry | None, api: str, topic: str, topic_type: str, *, publisher: bool) -> bool:
        """Whether registering this publisher/subscriber again would change nothing (same URI, same type)."""
        if entry is None or entry.api != api:
            return False
        if publisher:
            return topic in entry.publications and (
                (topic_type == ANYTYPE and topic in self.topic_types) or self.topic_types.get(topic) == topic_type
            )
        return topic in entry.subscriptions and (topic_type == ANYTYPE or topic in self.topic_types)

    def _publisher_updates(self, topic: str) -> list[Notification]:
        pubs = list(self.publishers.get(topic, {}).values())
        return [publisher_update(api, topic, pubs) for api in self.subscribers.get(topic, {}).values()]

    def register_publisher(
        self, node: str, topic: str, topic_type: str, api: str
    ) -> tuple[list[str], list[Notification]]:
        """Add a publisher; returns the subscribers' URIs and the publisherUpdates to send."""
        if not self._registered(self.nodes.get(node), api, topic, topic_type, publisher=True):
            self.version += 1
        out: list[Notification] = []
        entry = self._node(node, api, out)
        entry.publications[topic] = None
        self.publishers.setdefault(topic, {})[node] = api
        if topic_type != ANYTYPE or topic not in self.topic_types:
            self.topic_types[topic] = topic_type
        out.extend(self._publisher_updates(topic))
        if self.journals:
            self._touch((topic,))
        return list(self.subscribers.get(topic, {}).values()), out

    def unregister_publisher(self, node: str, topic: str, api: str) -> tuple[int, list[Notification]]:
        """Remove a publisher if ``api`` matches; returns 0/1 and the publisherUpdates to send."""
        self.version += 1
        entry = self.nodes.get(node)
        pubs = self.publishers.get(topic, {})
        if entry is None or pubs.get(node) != api:
            return 0, []
        _remove(self.publishers, topic, node)
        entry.publications.pop(topic, None)
        self._forget_if_empty(entry)
        if self.journals:
            self._touch((topic,))
        return 1, self._publisher_updates(topic)

    def register_subscriber(
        self, node: str, topic: str, topic_type: str, api: str
    ) -> tuple[list[str], list[Notification]]:
        """Add a subscriber; returns the current publishers' URIs (and any replacement notifications)."""
        if not self._registered(self.nodes.get(node), api, topic, topic_type, publisher=False):
            self.version += 1
        out: list[Notification] = []
        entry = self._node(node, api, out)
        entry.subscriptions[topic] = None
        self.subscribers.setdefault(topic, {})[node] = api
        if topic not in self.topic_types and topic_type != ANYTYPE:
            self.topic_types[topic] = topic_type
        if self.journals:
            self._touch((topic,))
        return list(self.publishers.get(topic, {}).values()), out

    def unregister_subscriber(self, node: str, topic: str, api: str) -> int:
        """Remove a subscriber if ``api`` matches; returns 0/1."""
        self.version += 1
        entry = self.nodes.get(node)
        if entry is None or self.subscribers.get(topic, {}).get(node) != api:
            return 0
        _remove(self.subscribers, topic, node)
        entry.subscriptions.pop(topic, None)
        self._forget_if_empty(entry)
        if self.journals:
            self._touch((topic,))
        return 1

    # --- services ----------------------------------------------------------------------------

    def register_service(self, node: str, service: str, service_api: str, api: str) -> list[Notification]:
        """Make ``node`` the (only) provider of ``service``; the previous provider is replaced."""
        self.version += 1
        out: list[Notification] = []
        entry = self._node(node, api, out)
        previous = self.services.get(service)
        if previous is not None and previous.node != node:
            old = self.nodes.get(previous.node)
            if old is not None:
                old.services.pop(service, None)
                self._forget_if_empty(old)
        entry.services[service] = None
        self.services[service] = ServiceEntry(node, api, service_api)
        if self.journals:
            self._touch(services=(service,))
        return out

    def unregister_service(self, node: str, service: str, service_api: str) -> int:
        """Remove ``service`` if ``node`` still provides it at ``service_api``; returns 0/1."""
        self.version += 1
        current = self.services.get(service)
        if current is None or current.node != node or current.service_api != service_api:
            return 0
        del self.services[service]
        entry = self.nodes.get(node)
        if entry is not None:
            entry.services.pop(service, None)
            self._forget_if_empty(entry)
        if self.journals:
            self._touch(services=(service,))
        return 1

    def lookup_service(self, service: str) -> str | None:
        """The ``rosrpc://`` URI of ``service``, or None."""
        entry = self.services.get(service)
        return entry.service_api if entry is not None else None

    # --- parameter subscriptions -------------------------------------------------------------

    def subscribe_param(self, node: str, key: str, api: str) -> list[Notification]:
        """Record that ``node`` caches parameter ``key`` (a canonical key ending in ``/``)."""
        self.version += 1
        out: list[Notification] = []
        entry = self._node(node, api, out)
        entry.param_subscriptions[key] = None
        self.param_subscribers.setdefault(key, {})[node] = api
        return out

    def unsubscribe_param(self, node: str, key: str, api: str) -> int:
        """Forget a parameter subscription if ``api`` matches; returns 0/1."""
        self.version += 1
        entry = self.nodes.get(node)
        if entry is None or self.param_subscribers.get(key, {}).get(node) != api:
            return 0
        _remove(self.param_subscribers, key, node)
        entry.param_subscriptions.pop(key, None)
        self._forget_if_empty(entry)
        return 1

    # --- state -------------------------------------------------------------------------------

    def published_topics(self, subgraph: str) -> list[list[str]]:
        """``[[topic, type], ...]`` for topics with publishers under namespace ``subgraph`` ('' = all)."""
        if subgraph and not subgraph.endswith("/"):
            subgraph += "/"
        return [[t, self.topic_types.get(t, ANYTYPE)] for t in self.publishers if t.startswith(subgraph)]

    def system_state(self) -> list[list[list[Any]]]:
        """``[publishers, subscribers, services]`` as rosmaster's getSystemState lists them.

        The same object until ``version`` changes (callers must not edit it): a big state is then encoded
        once and shared by every caller (``mrosd.master.dispatch`` keys shared replies on the value).
        """
        memo = self._system_state
        if memo is not None and memo[0] == self.version:
            return memo[1]
        state = [
            [[t, list(nodes)] for t, nodes in self.publishers.items()],
            [[t, list(nodes)] for t, nodes in self.subscribers.items()],
            [[s, [e.node]] for s, e in self.services.items()],
        ]
        self._system_state = (self.version, state)
        return state


def _remove(table: dict[str, dict[str, str]], key: str, node: str) -> None:
    members = table.get(key)
    if members is None:
        return
    members.pop(node, None)
    if not members:
        del table[key]
