"""Master API and Parameter Server handlers: validate, resolve, call the pure registry, queue notifications.

Each handler takes the XML-RPC arguments exactly as received and returns rosmaster's
``(code, statusMessage, value)`` triple: 1 success, 0 failure, -1 error (bad arguments). Wrong
arity or argument types answer -1 with a message, never a fault and never a crash, as rosmaster's
``apivalidate`` does. Handlers never await a node: notifications are handed to the ``Notifier``.
``METHODS`` is the explicit camelCase -> handler table served by ``Master``. Callers' names are
resolved by ``mrosd.names.lenient_resolve`` (rosgraph's rules, as rosmaster applies them).
"""

from __future__ import annotations

import asyncio
import logging
import os
from collections.abc import Awaitable, Callable
from typing import Any

from mrosd import backports
from mrosd.errors import InvalidArgument
from mrosd.master.cleanup import DEFAULT_CLEANUP_INTERVAL, GraphCleaner
from mrosd.master.notifier import Notifier
from mrosd.master.params import ParamTree, param_updates, subscription_key
from mrosd.master.registry import ANYTYPE, Notification, Registry
from mrosd.names import SEP, lenient_resolve

log = logging.getLogger(__name__)

Reply = tuple[int, str, Any]
Validator = Callable[[Any, str], Any]


#: An argument failed validation; the message is returned to the caller with code -1.
Invalid = InvalidArgument


# --- validators ---------------------------------------------------------------------------------


def non_empty_str(what: str) -> Validator:
    def check(value: Any, caller_id: str) -> Any:
        if not value:
            raise Invalid(f"ERROR: parameter [{what}] must be specified and non-empty")
        if not isinstance(value, str):
            raise Invalid(f"ERROR: parameter [{what}] must be a string")
        return value

    return check


def not_none(what: str) -> Validator:
    def check(value: Any, caller_id: str) -> Any:
        if value is None:
            raise Invalid(f"ERROR: parameter [{what}] must be specified")
        return value

    return check


def is_api(what: str) -> Validator:
    def check(value: Any, caller_id: str) -> Any:
        if not value or not isinstance(value, str):
            raise Invalid(f"ERROR: parameter [{what}] is not an XMLRPC URI")
        if not value.startswith(("http://", "https://", "rosrpc://")):
            raise Invalid(f"ERROR: parameter [{what}] is not an RPC URI")
        return value

    return check


def valid_name(what: str) -> Validator:
    def check(value: Any, caller_id: str) -> Any:
        if not value or not isinstance(value, str):
            raise Invalid(f"ERROR: parameter [{what}] must be a non-empty string")
        if ":" in value or " " in value:
            raise Invalid(f"ERROR: parameter [{what}] contains illegal chars")
        return lenient_resolve(value, caller_id)

    return check


def graph_name(what: str) -> Validator:
    """A topic or service name: a valid name that is not the root namespace."""
    base = valid_name(what)

    def check(value: Any, caller_id: str) -> Any:
        resolved = base(value, caller_id)
        if value == SEP:
            raise Invalid(f"ERROR: parameter [{what}] cannot be the global namespace")
        return resolved

    return check


def empty_or_valid_name(what: str) -> Validator:
    def check(value: Any, caller_id: str) -> Any:
        if not isinstance(value, str):
            raise Invalid(f"ERROR: parameter [{what}] must be a string")
        return lenient_resolve(value, caller_id) if value else ""

    return check


def type_name(what: str) -> Validator:
    def check(value: Any, caller_id: str) -> Any:
        if value == ANYTYPE:
            return value
        if not value or not isinstance(value, str):
            raise Invalid(f"ERROR: parameter [{what}] must be a non-empty string")
        if len(value.split(SEP)) != 2:
            raise Invalid(f"ERROR: parameter [{what}] is not a valid package resource name")
        return value

    return check


Impl = Callable[..., Reply]
Handler = Callable[..., Awaitable[Reply]]


def _wrap(name: str, error_value: Any, validators: tuple[Validator, ...], impl: Impl) -> Impl:
    """rosmaster's apivalidate: arity, caller_id type, per-argument checks, error value on failure."""
    arity = len(validators) + 1

    def handler(*args: Any) -> Reply:
        if not args:
            return -1, "missing required caller_id parameter", error_value
        if len(args) != arity:
            return -1, "Error: bad call arity", error_value
        caller_id = args[0]
        if not isinstance(caller_id, str):
            return -1, "caller_id must be a string", error_value
        values = []
        try:
            for i, check in enumerate(validators, 1):  # a plain loop: no comprehension frame per call
                values.append(check(args[i], caller_id))
        except Invalid as exc:
            return -1, str(exc), error_value
        try:
            return impl(caller_id, *values)
        except Exception as exc:
            log.exception("master: %s%r failed", name, args)
            return 0, f"Internal failure: {exc}", error_value

    handler.__name__ = name
    return handler


def _as_async(handler: Impl) -> Handler:
    async def call(*args: Any) -> Reply:
        return handler(*args)

    call.__name__ = handler.__name__
    return call


#: Longest wait of one ``waitSystemStateChange`` call (seconds).
WATCH_MAX_TIMEOUT = 60.0
#: Most ``waitSystemStateChange`` calls waiting at once for one caller id, and in total.
WATCH_MAX_PER_CALLER = 4
WATCH_MAX_TOTAL = 1024

#: Methods whose reply depends only on their arguments and the registry/parameter state (``state_version``),
#: so the HTTP layer may cache their replies. Not getUri: ``uri`` is only set once the socket is bound.
READ_ONLY_METHODS = frozenset(
    {
        "lookupNode",
        "getPublishedTopics",
        "getTopicTypes",
        "getSystemState",
        "getPid",
        "lookupService",
        "getParam",
        "searchParam",
        "hasParam",
        "getParamNames",
    }
)


class MasterApi:
    """The state of one master (registry + parameter tree) and its handlers.

    Args:
        notifier: where notifications go; may be None for a pure, in-memory master (tests).
        uri: the master's own advertised URI (getUri).
        cleanup_interval: seconds between sweeps removing nodes whose slave API refuses connections
            (``cleanup.GraphCleaner``); 0 or None turns it off (strict rosmaster behaviour). The
            sweeping task starts with the first registration, once a notifier is attached.
    """

    def __init__(
        self, notifier: Notifier | None, uri: str = "", *, cleanup_interval: float | None = DEFAULT_CLEANUP_INTERVAL
    ) -> None:
        self.registry = Registry()
        self.params = ParamTree()
        self.notifier = notifier
        self.uri = uri
        self.outbox: list[Notification] = []  # only used when there is no notifier
        self.cleanup_interval = cleanup_interval
        self.cleaner: GraphCleaner | None = None
        v_key = non_empty_str("key")
        v_api = is_api("caller_api")
        self.sync_methods: dict[str, Impl] = {
            "registerService": _wrap(
                "registerService",
                0,
                (graph_name("service"), is_api("service_api"), v_api),
                self.register_service,
            ),
            "unregisterService": _wrap(
                "unregisterService", 0, (graph_name("service"), is_api("service_api")), self.unregister_service
            ),
            "registerSubscriber": _wrap(
                "registerSubscriber",
                [],
                (graph_name("topic"), type_name("topic_type"), v_api),
                self.register_subscriber,
            ),
            "unregisterSubscriber": _wrap(
                "unregisterSubscriber", 0, (graph_name("topic"), v_api), self.unregister_subscriber
            ),
            "registerPublisher": _wrap(
                "registerPublisher",
                [],
                (graph_name("topic"), type_name("topic_type"), v_api),
                self.register_publisher,
            ),
            "unregisterPublisher": _wrap(
                "unregisterPublisher", 0, (graph_name("topic"), v_api), self.unregister_publisher
            ),
            "lookupNode": _wrap("lookupNode", "", (valid_name("node"),), self.lookup_node),
            "getPublishedTopics": _wrap(
                "getPublishedTopics", 0, (empty_or_valid_name("subgraph"),), self.get_published_topics
            ),
            "getTopicTypes": _wrap("getTopicTypes", [], (), self.get_topic_types),
            "getSystemState": _wrap("getSystemState", [[], [], []], (), self.get_system_state),
            "getUri": _wrap("getUri", "", (), self.get_uri),
            "getPid": _wrap("getPid", -1, (), self.get_pid),
            "lookupService": _wrap("lookupService", "", (graph_name("service"),), self.lookup_service),
            "deleteParam": _wrap("deleteParam", 0, (v_key,), self.delete_param),
            "setParam": _wrap("setParam", 0, (v_key, not_none("value")), self.set_param),
            "getParam": _wrap("getParam", 0, (v_key,), self.get_param),
            "searchParam": _wrap("searchParam", "", (v_key,), self.search_param),
            "subscribeParam": _wrap("subscribeParam", 0, (v_api, v_key), self.subscribe_param),
            "unsubscribeParam": _wrap("unsubscribeParam", 0, (v_api, v_key), self.unsubscribe_param),
            "hasParam": _wrap("hasParam", False, (v_key,), self.has_param),
            "getParamNames": _wrap("getParamNames", [], (), self.get_param_names),
        }
        #: The same handlers as coroutines, for ``XmlRpcServer`` (multicall and the in-memory tests).
        self.methods: dict[str, Handler] = {name: _as_async(h) for name, h in self.sync_methods.items()}
        # The mrosd extension: a long poll for graph changes (async, so served by the fallback dispatch).
        self.methods["waitSystemStateChange"] = self.wait_system_state_change
        self._graph_changed: asyncio.Future[None] | None = None
        self._watchers: dict[str, int] = {}
        self._snapshot: tuple[int, list[Any]] | None = None

    def state_version(self) -> tuple[int, int]:
        """Changes whenever the registry or the parameter tree may have changed."""
        return self.registry.version, self.params.version

    def _graph_touched(self) -> None:
        """Wake every ``waitSystemStateChange`` waiter (the registry may have changed)."""
        changed = self._graph_changed
        if changed is not None:
            self._graph_changed = None
            if not changed.done():
                changed.set_result(None)

    def _start_background(self) -> None:
        """Start the graph cleaner on the running loop (once), owned by the notifier for shutdown."""
        if self.cleaner is not None or self.notifier is None or self.notifier.closed or not self.cleanup_interval:
            return
        self.cleaner = GraphCleaner(self.registry, self._cleaned, self.cleanup_interval)
        self.notifier.adopt(asyncio.get_running_loop().create_task(self.cleaner.run()))

    def _cleaned(self, notes: list[Notification]) -> None:
        self._send(notes)
        self._graph_touched()

    def _send(self, notes: list[Notification]) -> None:
        if not notes:
            return
        if self.notifier is not None:
            self.notifier.submit(notes)
        else:
            self.outbox.extend(notes)

    def on_notification_result(self, note: Notification, reply: Any) -> None:
        """A node answering paramUpdate with -1 no longer wants the key (rosmaster drops it)."""
        if note.method != "paramUpdate" or not isinstance(reply, list | tuple) or not reply or reply[0] != -1:
            return
        key = subscription_key(str(note.args[0]))
        for node in self.registry.nodes_at(note.api):
            self.registry.unsubscribe_param(node, key, note.api)

    # --- services ----------------------------------------------------------------------------

    def register_service(self, caller_id: str, service: str, service_api: str, caller_api: str) -> Reply:
        self._start_background()
        self._send(self.registry.register_service(caller_id, service, service_api, caller_api))
        self._graph_touched()
        return 1, f"Registered [{caller_id}] as provider of [{service}]", 1

    def unregister_service(self, caller_id: str, service: str, service_api: str) -> Reply:
        n = self.registry.unregister_service(caller_id, service, service_api)
        self._graph_touched()
        if n:
            return 1, f"Unregistered [{caller_id}] as provider of [{service}]", 1
        return 1, f"[{caller_id}] is not a provider of [{service}]", 0

    def lookup_service(self, caller_id: str, service: str) -> Reply:
        uri = self.registry.lookup_service(service)
        if uri:
            return 1, f"rosrpc URI: [{uri}]", uri
        return -1, "no provider", ""

    # --- topics ------------------------------------------------------------------------------

    def register_subscriber(self, caller_id: str, topic: str, topic_type: str, caller_api: str) -> Reply:
        self._start_background()
        pubs, notes = self.registry.register_subscriber(caller_id, topic, topic_type, caller_api)
        self._send(notes)
        self._graph_touched()
        return 1, f"Subscribed to [{topic}]", pubs

    def unregister_subscriber(self, caller_id: str, topic: str, caller_api: str) -> Reply:
        n = self.registry.unregister_subscriber(caller_id, topic, caller_api)
        self._graph_touched()
        if n:
            return 1, f"Unregistered [{caller_id}] as provider of [{topic}]", 1
        return 1, f"[{caller_id}] is not a known provider of [{topic}]", 0

    def register_publisher(self, caller_id: str, topic: str, topic_type: str, caller_api: str) -> Reply:
        self._start_background()
        subs, notes = self.registry.register_publisher(caller_id, topic, topic_type, caller_api)
        self._send(notes)
        self._graph_touched()
        return 1, f"Registered [{caller_id}] as publisher of [{topic}]", subs

    def unregister_publisher(self, caller_id: str, topic: str, caller_api: str) -> Reply:
        n, notes = self.registry.unregister_publisher(caller_id, topic, caller_api)
        self._send(notes)
        self._graph_touched()
        if n:
            return 1, f"Unregistered [{caller_id}] as provider of [{topic}]", 1
        return 1, f"[{caller_id}] is not a known provider of [{topic}]", 0

    # --- graph state -------------------------------------------------------------------------

    def lookup_node(self, caller_id: str, node: str) -> Reply:
        api = self.registry.lookup_node(node)
        if api is None:
            return -1, f"unknown node [{node}]", ""
        return 1, "node api", api

    def get_published_topics(self, caller_id: str, subgraph: str) -> Reply:
        return 1, "current topics", self.registry.published_topics(subgraph)

    def get_topic_types(self, caller_id: str) -> Reply:
        return 1, "current system state", [[t, ty] for t, ty in self.registry.topic_types.items()]

    def get_system_state(self, caller_id: str) -> Reply:
        return 1, "current system state", self.registry.system_state()

    def graph_snapshot(self) -> list[Any]:
        """``[version, getSystemState value, getTopicTypes value]`` (the version fits an XML-RPC int).

        The same object until the registry changes (callers must not edit it), so a big one is encoded
        once for every waiter (``mrosd.master.dispatch``).
        """
        memo = self._snapshot
        if memo is not None and memo[0] == self.registry.version:
            return memo[1]
        snapshot = [
            self.registry.version & 0x7FFFFFFF,
            self.registry.system_state(),
            [[t, ty] for t, ty in self.registry.topic_types.items()],
        ]
        self._snapshot = (self.registry.version, snapshot)
        return snapshot

    async def wait_system_state_change(self, *args: Any) -> Reply:
        """mrosd extension ``waitSystemStateChange(caller_id, since_version, timeout)``: a long poll.

        Answers ``[version, system state, topic types]`` as soon as the graph's version differs from
        ``since_version`` (at once if it already does, e.g. after a master restart), or after
        ``timeout`` seconds (at most ``WATCH_MAX_TIMEOUT``) with the unchanged state. Waiters are
        bounded per caller id and in total; beyond that the call fails with -1 and the client polls.
        """
        if len(args) != 3:
            return -1, "Error: bad call arity", []
        caller_id, since, timeout = args
        if not isinstance(caller_id, str) or not caller_id:
            return -1, "caller_id must be a non-empty string", []
        if type(since) is not int:
            return -1, "ERROR: parameter [since_version] must be an int", []
        if type(timeout) not in (int, float) or not timeout >= 0:
            return -1, "ERROR: parameter [timeout] must be a non-negative number", []
        if self.registry.version & 0x7FFFFFFF == since and timeout > 0:
            if self._watchers.get(caller_id, 0) >= WATCH_MAX_PER_CALLER or (
                sum(self._watchers.values()) >= WATCH_MAX_TOTAL
            ):
                return -1, "too many waitSystemStateChange calls in progress: poll getSystemState", []
            self._watchers[caller_id] = self._watchers.get(caller_id, 0) + 1
            try:
                async with backports.timeout(min(float(timeout), WATCH_MAX_TIMEOUT)):
                    while self.registry.version & 0x7FFFFFFF == since:
                        if self._graph_changed is None:
                            self._graph_changed = asyncio.get_running_loop().create_future()
                        await asyncio.shield(self._graph_changed)
            except TimeoutError:
                pass
            finally:
                left = self._watchers[caller_id] - 1
                if left:
                    self._watchers[caller_id] = left
                else:
                    del self._watchers[caller_id]
        return 1, "current system state", self.graph_snapshot()

    def get_uri(self, caller_id: str) -> Reply:
        return 1, "", self.uri

    def get_pid(self, caller_id: str) -> Reply:
        return 1, "", os.getpid()

    # --- parameters --------------------------------------------------------------------------

    def _param_subscribers(self) -> dict[str, dict[str, str]]:
        return self.registry.param_subscribers

    def delete_param(self, caller_id: str, key: str) -> Reply:
        key = lenient_resolve(key, caller_id)
        try:
            self.params.delete(key)
        except KeyError:
            return -1, f"parameter [{key}] is not set", 0
        self._send(param_updates(self._param_subscribers(), key, {}))
        return 1, f"parameter {key} deleted", 0

    def set_param(self, caller_id: str, key: str, value: Any) -> Reply:
        key = lenient_resolve(key, caller_id)
        subs = self._param_subscribers()
        had_subtree = False
        if subs and not isinstance(value, dict):
            try:
                old = self.params.get(key)
            except KeyError:
                old = None
            had_subtree = isinstance(old, dict) and bool(old)
        try:
            self.params.set(key, value)
        except TypeError as exc:
            return -1, str(exc), 0
        self._send(param_updates(subs, key, value, had_subtree=had_subtree, ignore_node=caller_id))
        return 1, f"parameter {key} set", 0

    def get_param(self, caller_id: str, key: str) -> Reply:
        key = lenient_resolve(key, caller_id)
        try:
            return 1, f"Parameter [{key}]", self.params.get(key)
        except KeyError:
            return -1, f"Parameter [{key}] is not set", 0

    def search_param(self, caller_id: str, key: str) -> Reply:
        try:
            found = self.params.search(caller_id, key)
        except ValueError as exc:
            return -1, f"cannot search for [{key}]: {exc}", ""
        if found:
            return 1, f"Found [{found}]", found
        return -1, f"Cannot find parameter [{key}] in an upwards search", ""

    def subscribe_param(self, caller_id: str, caller_api: str, key: str) -> Reply:
        self._start_background()
        key = lenient_resolve(key, caller_id)
        try:
            value = self.params.get(key)
        except KeyError:
            value = {}
        self._send(self.registry.subscribe_param(caller_id, subscription_key(key), caller_api))
        return 1, f"Subscribed to parameter [{key}]", value

    def unsubscribe_param(self, caller_id: str, caller_api: str, key: str) -> Reply:
        key = lenient_resolve(key, caller_id)
        self.registry.unsubscribe_param(caller_id, subscription_key(key), caller_api)
        return 1, f"Unsubscribe to parameter [{key}]", 1

    def has_param(self, caller_id: str, key: str) -> Reply:
        key = lenient_resolve(key, caller_id)
        return 1, key, self.params.has(key)

    def get_param_names(self, caller_id: str) -> Reply:
        return 1, "Parameter names", self.params.names()
