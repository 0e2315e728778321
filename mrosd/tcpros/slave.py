"""The ROS slave API of a node: the XML-RPC handlers, one explicit camelCase -> method table.

Handlers translate between XML-RPC arguments and the ``Node``'s state and return ROS's
``[code, statusMessage, value]`` triples; they never raise for a caller's bad input.
"""

from __future__ import annotations

import logging
import os
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mrosd.tcpros.node import Node
    from mrosd.xmlrpc import Handler

log = logging.getLogger(__name__)

SUCCESS = 1
FAILURE = 0
ERROR = -1


class SlaveApi:
    """Answers the slave API calls that masters, rosnode and peers make on a node."""

    def __init__(self, node: Node) -> None:
        self.node = node

    def methods(self) -> dict[str, Handler]:
        return {
            "getBusStats": self.get_bus_stats,
            "getBusInfo": self.get_bus_info,
            "getMasterUri": self.get_master_uri,
            "shutdown": self.shutdown,
            "getPid": self.get_pid,
            "getSubscriptions": self.get_subscriptions,
            "getPublications": self.get_publications,
            "paramUpdate": self.param_update,
            "publisherUpdate": self.publisher_update,
            "requestTopic": self.request_topic,
        }

    async def get_bus_stats(self, caller_id: str) -> list[Any]:
        node = self.node
        pubs = [p.stats() for p in node.publishers.values()]
        subs = [s.stats() for s in node.subscribers.values()]
        srvs = [[s.name, s.calls] for s in node.services.values()]
        return [SUCCESS, "bus stats", [pubs, subs, srvs]]

    async def get_bus_info(self, caller_id: str) -> list[Any]:
        info: list[Any] = []
        for p in self.node.publishers.values():
            info.extend(p.bus_info())
        for s in self.node.subscribers.values():
            info.extend(s.bus_info())
        return [SUCCESS, "bus info", info]

    async def get_master_uri(self, caller_id: str) -> list[Any]:
        return [SUCCESS, self.node.master_uri, self.node.master_uri]

    async def shutdown(self, caller_id: str, msg: str = "") -> list[Any]:
        log.warning("node %s: shutdown requested by %s: %s", self.node.name, caller_id, msg)
        self.node._shutdown_requested(f"{caller_id}: {msg}")
        return [SUCCESS, "shutdown", 0]

    async def get_pid(self, caller_id: str) -> list[Any]:
        return [SUCCESS, "", os.getpid()]

    async def get_subscriptions(self, caller_id: str) -> list[Any]:
        return [SUCCESS, "subscriptions", [[s.topic, s.type] for s in self.node.subscribers.values()]]

    async def get_publications(self, caller_id: str) -> list[Any]:
        return [SUCCESS, "publications", [[p.topic, p.type] for p in self.node.publishers.values()]]

    async def param_update(self, caller_id: str, key: str, value: Any) -> list[Any]:
        self.node._param_update(key, value)
        return [SUCCESS, "", 0]

    async def publisher_update(self, caller_id: str, topic: str, publishers: list[str]) -> list[Any]:
        sub = self.node.subscribers.get(topic)
        if sub is None:
            return [FAILURE, f"not subscribed to {topic}", 0]
        if not isinstance(publishers, list):
            return [ERROR, "publishers must be a list of URIs", 0]
        sub.update_publishers([u for u in publishers if isinstance(u, str)])
        return [SUCCESS, "", 0]

    async def request_topic(self, caller_id: str, topic: str, protocols: list[Any]) -> list[Any]:
        if topic not in self.node.publishers:
            return [ERROR, f"Not a publisher of [{topic}]", []]
        if not isinstance(protocols, list):
            return [ERROR, "protocols must be a list", []]
        for proto in protocols:
            if isinstance(proto, list) and proto and proto[0] == "TCPROS":
                return [
                    SUCCESS,
                    f"ready on {self.node.host}:{self.node.tcpros_port}",
                    ["TCPROS", self.node.host, self.node.tcpros_port],
                ]
        return [FAILURE, "no supported protocol implementations (only TCPROS)", []]
