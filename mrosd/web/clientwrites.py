"""What browser clients change in the ROS graph through the hub: the topics they publish (one publisher per
topic, shared by every client that advertises it, closed with its last owner) and the parameters they watch
(one master subscription per name, shared by every client callback on it).

It must not know the protocols: sessions call it through ``WebHub``.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from mrosd.errors import MrosError
from mrosd.msg import load_type, load_type_async
from mrosd.tcpros import Node
from mrosd.web.access import AccessPolicy

log = logging.getLogger(__name__)

__all__ = ["ClientWrites"]


@dataclass(slots=True)
class _SharedPublisher:
    publisher: Any
    msg_class: Any
    owners: int = 0


class ClientWrites:
    """The hub's publishers and parameter watches on behalf of its clients."""

    def __init__(self, node: Node, policy: AccessPolicy) -> None:
        self.node = node
        self.policy = policy
        self.publishers: dict[str, _SharedPublisher] = {}
        self._lock = asyncio.Lock()
        self._params: dict[str, set[Callable[[str, Any], None]]] = {}

    # --- client publishers -----------------------------------------------------------------------

    def message_class(self, msg_type: str) -> Any:
        """The class of a type a client names, from the type search path.

        Raises:
            MsgError: unknown type (the message names where it was looked for).
        """
        return load_type(msg_type, "")

    async def client_class(self, msg_type: str, definition: str | None = None) -> Any:
        """The class of a type a client names with its own definition (built off the event loop), else
        from the type search path.

        Raises:
            MsgError: unknown type (the message names where it was looked for) or a malformed definition.
        """
        return await load_type_async(msg_type, definition or "")

    async def acquire_publisher(self, topic: str, msg_class: Any) -> Any:
        """The shared publisher of ``topic`` (advertised at the first owner).

        Raises:
            MrosError: not allowed, another type already published here, or the master refused.
        """
        if not self.policy.allows_topic(topic):
            raise MrosError(f"topic {topic} is not allowed by the [web] topics allow-list")
        async with self._lock:
            entry = self.publishers.get(topic)
            if entry is None:
                pub = await self.node.advertise(topic, msg_class, queue_size=100)
                entry = _SharedPublisher(pub, msg_class)
                self.publishers[topic] = entry
            elif entry.msg_class._md5sum != msg_class._md5sum:
                raise MrosError(f"{topic} is already published by a web client as {entry.msg_class._type}")
            entry.owners += 1
            return entry.publisher

    async def release_publisher(self, topic: str) -> None:
        async with self._lock:
            entry = self.publishers.get(topic)
            if entry is None:
                return
            entry.owners -= 1
            if entry.owners <= 0:
                del self.publishers[topic]
                await entry.publisher.aclose()

    # --- parameters ------------------------------------------------------------------------------

    async def watch_param(self, name: str, callback: Callable[[str, Any], None], *, check: bool = True) -> Any:
        """Call ``callback(key, value)`` on every update of ``name`` (one master subscription per name).

        ``check=False`` is the hub's own watch (``/use_sim_time``), not a client's: the allow-list does not
        apply. Returns the value the master answered the subscription with (``{}``: unset), or None when the
        name was already watched.

        Raises:
            MrosError: not allowed, or the master refused the subscription.
        """
        if check and not self.policy.allows_param(name):
            raise MrosError(f"parameter {name} is not allowed by the [web] params allow-list")
        callbacks = self._params.get(name)
        value = None
        if callbacks is None:
            callbacks = self._params[name] = set()
            try:
                value = await self.node.subscribe_param(name, lambda key, value: self._param_update(name, key, value))
            except BaseException:
                del self._params[name]
                raise
        callbacks.add(callback)
        return value

    def _param_update(self, name: str, key: str, value: Any) -> None:
        for cb in list(self._params.get(name, ())):
            try:
                cb(key, value)
            except Exception:
                log.exception("web: a parameter listener failed")

    async def unwatch_param(self, name: str, callback: Callable[[str, Any], None]) -> None:
        callbacks = self._params.get(name)
        if callbacks is None:
            return
        callbacks.discard(callback)
        if not callbacks:
            del self._params[name]
            await self.node.unsubscribe_param(name)
