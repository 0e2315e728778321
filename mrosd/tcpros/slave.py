"""The ROS slave API of a node: the XML-RPC handlers, one explicit camelCase -> method table.

Handlers translate between XML-RPC arguments and the owning node's state and return ROS's
``[code, statusMessage, value]`` triples; they never raise for a caller's bad input. Arguments are checked
as rospy checks them, with the same codes: a wrong number of arguments, a caller id that is not a string,
an empty or relative topic or parameter name, or a publisher list that is not a list of URIs answers
``-1`` with the method's empty value; so does a ``requestTopic`` protocol list that is not a list (rospy
answers 0 there, ros_comm's test_slave_api wants -1). ``publisherUpdate`` for a topic the node does not subscribe to
succeeds (rospy's answer; ros_comm's test_slave_api checks it) and ``paramUpdate`` for a key the node does
not subscribe to answers ``-1`` (the master then drops that subscription).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any
from urllib.parse import urlsplit

from mrosd.errors import InvalidArgument, InvalidNameError
from mrosd.names import SEP, canonicalize, is_valid_name, join, namespace_of

if TYPE_CHECKING:
    from mrosd.tcpros.owner import SlaveOwner
    from mrosd.xmlrpc import Handler

log = logging.getLogger(__name__)

SUCCESS = 1
FAILURE = 0
ERROR = -1


def _global_name(what: str, value: Any, caller_id: str) -> str:
    if not isinstance(value, str) or not value:
        raise InvalidArgument(f"ERROR: parameter [{what}] must be a non-empty string")
    if not value.startswith(SEP):
        raise InvalidArgument(f"ERROR: parameter [{what}] must be a globally referenced name")
    return canonicalize(value)


def _topic(what: str, value: Any, caller_id: str) -> str:
    """A legal topic name, resolved in the caller's namespace when relative (rospy's is_topic)."""
    if not isinstance(value, str) or not value:
        raise InvalidArgument(f"ERROR: parameter [{what}] must be a non-empty string")
    if not is_valid_name(value) or value.startswith("~"):
        raise InvalidArgument(f"ERROR: parameter [{what}] contains illegal chars")
    if value == SEP:
        raise InvalidArgument(f"ERROR: parameter [{what}] cannot be the global namespace")
    try:
        return join(namespace_of(caller_id) if caller_id.startswith(SEP) else SEP, value)
    except InvalidNameError as exc:
        raise InvalidArgument(f"ERROR: parameter [{what}] is not a legal name: {exc}") from None


def _uri_list(what: str, value: Any, caller_id: str) -> list[str]:
    if not isinstance(value, list):
        raise InvalidArgument(f"ERROR: param [{what}] must be a list")
    for uri in value:
        if not isinstance(uri, str):
            raise InvalidArgument(f"ERROR: param [{what}] must be a list of strings")
        parts = urlsplit(uri)
        if not parts.scheme or not parts.netloc:
            raise InvalidArgument(f"ERROR: param [{what}] does not contain valid URLs [{uri}]")
    return value


def _protocols(what: str, value: Any, caller_id: str) -> list[Any]:
    # rospy checks only non-emptiness and answers 0 for a string; ros_comm's test_slave_api wants -1 for it.
    if not value:
        raise InvalidArgument(f"ERROR: parameter [{what}] must be specified and non-empty")
    if not isinstance(value, list):
        raise InvalidArgument(f"ERROR: parameter [{what}] must be a list of protocols")
    return value


Validator = Callable[[str, Any, str], Any]


def _api(
    empty: Any, *validators: tuple[str, Validator | None], optional: int = 0
) -> Callable[[Callable[..., Awaitable[list[Any]]]], Handler]:
    """Arity, caller id and argument checks in front of a handler, answering ``[-1, why, empty]``."""

    def wrap(fn: Callable[..., Awaitable[list[Any]]]) -> Handler:
        name = fn.__name__
        most = 1 + len(validators)

        async def handler(*args: Any) -> list[Any]:
            if not args:
                return [ERROR, "missing required caller_id parameter", empty]
            if not most - optional <= len(args) <= most:
                return [ERROR, "Error: bad call arity", empty]
            if not isinstance(args[0], str):
                return [ERROR, "caller_id must be a string", empty]
            checked: list[Any] = [args[0]]
            for (what, check), value in zip(validators, args[1:], strict=False):
                try:
                    checked.append(value if check is None else check(what, value, args[0]))
                except InvalidArgument as exc:
                    log.debug("slave API %s: %s", name, exc)
                    return [ERROR, str(exc), empty]
            return await fn(*checked)

        handler.__name__ = name
        return handler

    return wrap


class SlaveApi:
    """Answers the slave API calls that masters, rosnode and peers make on a node."""

    def __init__(self, owner: SlaveOwner) -> None:
        self.owner = owner

    def methods(self) -> dict[str, Handler]:
        owner = self.owner

        @_api([])
        async def get_bus_stats(caller_id: str) -> list[Any]:
            pubs = [p.stats() for p in owner.publishers.values()]
            subs = [s.stats() for s in owner.subscribers.values()]
            srvs = [[s.name, s.calls] for s in owner.services.values()]
            return [SUCCESS, "bus stats", [pubs, subs, srvs]]

        @_api([])
        async def get_bus_info(caller_id: str) -> list[Any]:
            info: list[Any] = []
            for p in owner.publishers.values():
                info.extend(p.bus_info())
            for s in owner.subscribers.values():
                info.extend(s.bus_info())
            return [SUCCESS, "bus info", info]

        @_api("")
        async def get_master_uri(caller_id: str) -> list[Any]:
            return [SUCCESS, owner.master_uri, owner.master_uri]

        @_api("")
        async def get_uri(caller_id: str) -> list[Any]:
            return [SUCCESS, owner.uri, owner.uri]

        @_api("")
        async def get_name(caller_id: str) -> list[Any]:
            return [SUCCESS, owner.name, owner.name]

        @_api(0, ("msg", None), optional=1)
        async def shutdown(caller_id: str, msg: Any = "") -> list[Any]:
            log.warning("node %s: shutdown requested by %s: %s", owner.name, caller_id, msg)
            owner.shutdown_requested(f"{caller_id}: {msg}")
            return [SUCCESS, "shutdown", 0]

        @_api(-1)
        async def get_pid(caller_id: str) -> list[Any]:
            return [SUCCESS, "", os.getpid()]

        @_api([])
        async def get_subscriptions(caller_id: str) -> list[Any]:
            return [SUCCESS, "subscriptions", [[s.topic, s.type] for s in owner.subscribers.values()]]

        @_api([])
        async def get_publications(caller_id: str) -> list[Any]:
            return [SUCCESS, "publications", [[p.topic, p.type] for p in owner.publishers.values()]]

        @_api(-1, ("parameter_key", _global_name), ("parameter_value", None))
        async def param_update(caller_id: str, key: str, value: Any) -> list[Any]:
            if owner.param_update(key, value):
                return [SUCCESS, "", 0]
            return [ERROR, "not subscribed", 0]

        @_api(-1, ("topic", _topic), ("publishers", _uri_list))
        async def publisher_update(caller_id: str, topic: str, publishers: list[str]) -> list[Any]:
            sub = owner.subscribers.get(topic)
            if sub is not None:
                sub.update_publishers(publishers)
            return [SUCCESS, "", 0]

        @_api([], ("topic", _topic), ("protocols", _protocols))
        async def request_topic(caller_id: str, topic: str, protocols: list[Any]) -> list[Any]:
            pub = owner.publishers.get(topic)
            if pub is None:
                return [ERROR, f"Not a publisher of [{topic}]", []]
            params = await pub.shm_answer(protocols)
            if params is not None:
                return [SUCCESS, f"ready on shared memory {params[2]}", params]
            for proto in protocols:
                if isinstance(proto, list) and proto and proto[0] == "TCPROS":
                    return [
                        SUCCESS,
                        f"ready on {owner.host}:{owner.tcpros_port}",
                        ["TCPROS", owner.host, owner.tcpros_port],
                    ]
            return [FAILURE, "no supported protocol implementations", []]

        return {
            "getBusStats": get_bus_stats,
            "getBusInfo": get_bus_info,
            "getMasterUri": get_master_uri,
            "getUri": get_uri,
            "getName": get_name,
            "shutdown": shutdown,
            "getPid": get_pid,
            "getSubscriptions": get_subscriptions,
            "getPublications": get_publications,
            "paramUpdate": param_update,
            "publisherUpdate": publisher_update,
            "requestTopic": request_topic,
        }
