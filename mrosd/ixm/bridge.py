"""Bridges between IXM keys and ROS topics, configured in ``[ixm.rules.bridges]``.

This module owns the glue only: one ``mrosd.Node`` and one ``AsyncIxmClient``; each bridge is a task that
moves values one way. ``to_topic``: the bridge reads the key (woken by each write) and publishes each new
value on the topic, so that TCPROS subscribers (rospy, roscpp, mrosd) see the writes of shared-memory
clients. ``from_topic``: the bridge subscribes to the topic and writes each message into the key. A key
bridged both ways would echo its own messages, so a key takes one direction; use two keys for both.

Configuration (the key's type is the topic's message type; variable-size types need ``max_size``)::

    [ixm.rules.bridges."/arm/joints"]
    topic = "/joint_states"        # default: the key's name
    type = "sensor_msgs/JointState"
    max_size = 4096
    direction = "to_topic"         # or "from_topic"

Latest-value semantics hold across the bridge: a publisher slower than the writer skips values, and a
topic faster than the key's readers overwrites the key; neither side ever blocks the other.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Mapping
from typing import Any, Literal

import msgspec

from mrosd.errors import ConfigError, MrosError
from mrosd.ixm.client import AsyncIxmClient, AsyncIxmKey
from mrosd.lograte import RateLimitedLog

__all__ = ["Bridge", "IxmBridge", "parse_bridges"]

log = logging.getLogger("mrosd.ixm.bridge")
#: a writer of the key or a subscriber can make every message fail: one line per kind and 10 s, with a count
_ratelog = RateLimitedLog(log)


class Bridge(msgspec.Struct, frozen=True, kw_only=True):
    """One key bound to one topic, in one direction."""

    key: str
    topic: str
    type: str
    direction: Literal["to_topic", "from_topic"]
    max_size: int | None = None


def parse_bridges(raw: Mapping[str, Any] | None, source: str = "ixm.rules") -> list[Bridge]:
    """The ``bridges`` table of ``[ixm.rules]``.

    Raises:
        ConfigError: a bridge lacks a message type, has an unknown field or direction.
    """
    table = (raw or {}).get("bridges", {})
    if not isinstance(table, Mapping):
        raise ConfigError(f"{source}.bridges must be a table of key -> bridge")
    out: list[Bridge] = []
    for key, spec in table.items():
        where = f'{source}.bridges."{key}"'
        if not isinstance(spec, Mapping):
            raise ConfigError(f"{where} must be a table")
        unknown = set(spec) - {"topic", "type", "direction", "max_size"}
        if unknown:
            raise ConfigError(f"{where}: unknown field(s) {', '.join(sorted(unknown))}")
        if not isinstance(spec.get("type"), str) or "/" not in spec["type"]:
            raise ConfigError(f"{where}.type must be a ROS message type such as std_msgs/Float64")
        direction = spec.get("direction", "to_topic")
        if direction not in ("to_topic", "from_topic"):
            raise ConfigError(f"{where}.direction must be 'to_topic' or 'from_topic', got {direction!r}")
        max_size = spec.get("max_size")
        if max_size is not None and (not isinstance(max_size, int) or isinstance(max_size, bool) or max_size <= 0):
            raise ConfigError(f"{where}.max_size must be a positive integer")
        topic = spec.get("topic", key)
        if not isinstance(topic, str) or not topic:
            raise ConfigError(f"{where}.topic must be a topic name")
        out.append(Bridge(key=key, topic=topic, type=spec["type"], direction=direction, max_size=max_size))
    return out


class IxmBridge:
    """Runs every configured bridge; ``start()``/``aclose()``, an async context manager."""

    def __init__(
        self,
        socket_path: str,
        master_uri: str,
        bridges: list[Bridge],
        node_name: str = "/mrosd_ixm_bridge",
        admission: Any = None,
    ) -> None:
        self.socket_path = socket_path
        #: the node's ``AdmissionLimits`` (inbound TCPROS caps: the daemon's budget), or None for the defaults
        self.admission = admission
        self.master_uri = master_uri
        self.bridges = bridges
        self.node_name = node_name
        self._node: Any = None
        self._ixm: AsyncIxmClient | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._keys: list[AsyncIxmKey] = []

    async def start(self) -> None:
        """Open every key and topic.

        Raises:
            MrosError: a key cannot be opened (rules, type) or the master cannot be reached.
        """
        if not self.bridges:
            return
        from mrosd import Node
        from mrosd.msg import get_message_class

        try:
            self._ixm = await AsyncIxmClient(self.socket_path, name="ixm-bridge").connect()
            self._node = Node(self.node_name, master_uri=self.master_uri, admission=self.admission)
            await self._node.start()
            for bridge in self.bridges:
                cls = get_message_class(bridge.type)
                if bridge.direction == "to_topic":
                    key = await self._ixm.open(bridge.key, bridge.type, max_size=bridge.max_size, mode="r")
                    pub = await self._node.advertise(bridge.topic, cls)
                    self._tasks.append(asyncio.create_task(self._to_topic(bridge, key, pub)))
                else:
                    key = await self._ixm.open(bridge.key, bridge.type, max_size=bridge.max_size, mode="w")
                    await self._node.subscribe(bridge.topic, cls, callback=self._writer(bridge, key))
                self._keys.append(key)
                log.info(
                    "IXM bridge %s %s %s (%s)",
                    bridge.key,
                    "->" if bridge.direction == "to_topic" else "<-",
                    bridge.topic,
                    bridge.type,
                )
        except BaseException:
            await self.aclose()
            raise

    @staticmethod
    async def _to_topic(bridge: Bridge, key: AsyncIxmKey, pub: Any) -> None:
        async for msg in key:
            try:
                await pub.publish(msg)
            except MrosError as exc:
                _ratelog.warning(
                    f"pub-{bridge.key}", "IXM bridge %s -> %s: publish failed: %s", bridge.key, bridge.topic, exc
                )

    @staticmethod
    def _writer(bridge: Bridge, key: AsyncIxmKey) -> Any:
        def write(msg: Any) -> None:
            try:
                key.write(msg)
            except MrosError as exc:  # larger than max_size, another writer holding the lock: drop this message
                _ratelog.warning(
                    f"drop-{bridge.key}", "IXM bridge %s <- %s: message dropped: %s", bridge.key, bridge.topic, exc
                )

        return write

    async def aclose(self) -> None:
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, MrosError):
                await task
        self._tasks.clear()
        if self._node is not None:
            with contextlib.suppress(MrosError):
                await self._node.aclose()
            self._node = None
        if self._ixm is not None:
            await self._ixm.aclose()
            self._ixm = None
        self._keys.clear()

    async def __aenter__(self) -> IxmBridge:
        await self.start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()
