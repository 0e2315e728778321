"""dynamic_reconfigure's client and server on a Node: ``NS/set_parameters`` (Reconfigure), with
``NS/parameter_descriptions`` and ``NS/parameter_updates`` latched."""

from __future__ import annotations

import asyncio
import inspect
import logging
from collections.abc import Awaitable, Callable, Mapping
from typing import TYPE_CHECKING, Any

from mrosd import backports
from mrosd.errors import MrosError
from mrosd.lograte import RateLimitedLog
from mrosd.msg import get_service_class
from mrosd.reconfigure.description import (
    Config,
    ConfigDescription,
    Description,
    ReconfigureError,
    config_values,
    encode_config,
)

if TYPE_CHECKING:
    from mrosd.tcpros import Node, Publisher, Service, Subscriber

log = logging.getLogger(__name__)
_peer_log = RateLimitedLog(log)

Reconfigure = get_service_class("dynamic_reconfigure/Reconfigure")

#: ``callback(config, level)`` returns the config to keep (it may adjust values), sync or async.
Callback = Callable[[dict[str, Any], int], "dict[str, Any] | Awaitable[dict[str, Any]]"]
#: Level passed to the first callback (dynamic_reconfigure passes ~0).
ALL_LEVELS = 0xFFFFFFFF


class ReconfigureServer:
    """Serve ``description``'s parameters under ``namespace`` (default: the node's name, as rospy's Server).

    Initial values are the defaults, overridden by parameters already on the parameter server under the
    namespace; every accepted config is written back there, as dynamic_reconfigure does.
    """

    def __init__(self, node: Node, description: Description, callback: Callback, namespace: str | None = None) -> None:
        self.node = node
        self.description = description
        self.callback = callback
        self.ns = (node.resolve_name(namespace) if namespace is not None else node.name).rstrip("/")
        self.config: dict[str, Any] = description.defaults()
        self._descr_pub: Publisher | None = None
        self._update_pub: Publisher | None = None
        self._service: Service | None = None
        self._lock = asyncio.Lock()

    async def start(self) -> ReconfigureServer:
        for p in self.description.params():
            try:
                value = await self.node.get_param(f"{self.ns}/{p.name}")
            except MrosError:
                continue
            try:
                self.config[p.name] = self.description.check(p.name, value)
            except ReconfigureError as exc:
                log.warning("%s: ignoring parameter %s/%s: %s", self.ns, self.ns, p.name, exc)
        self.description.clamp(self.config)
        self._descr_pub = await self.node.advertise(f"{self.ns}/parameter_descriptions", ConfigDescription, latch=True)
        self._update_pub = await self.node.advertise(f"{self.ns}/parameter_updates", Config, latch=True)
        await self._descr_pub.publish(self.description.to_msg())
        await self._apply(dict(self.config), ALL_LEVELS)
        self._service = await self.node.advertise_service(f"{self.ns}/set_parameters", Reconfigure, self._on_set)
        return self

    async def aclose(self) -> None:
        for endpoint in (self._service, self._descr_pub, self._update_pub):
            if endpoint is not None:
                await endpoint.aclose()

    async def __aenter__(self) -> ReconfigureServer:
        return await self.start()

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()

    async def update(self, changes: Mapping[str, Any]) -> dict[str, Any]:
        """Change values from this side (checked, clamped, through the callback, published)."""
        checked = {k: self.description.check(k, v) for k, v in changes.items()}
        async with self._lock:
            new = {**self.config, **checked}
            self.description.clamp(new)
            return await self._apply(new, self.description.level(new, self.config))

    async def _apply(self, new: dict[str, Any], level: int) -> dict[str, Any]:
        result = self.callback(dict(new), level)
        if inspect.isawaitable(result):
            result = await result
        if not isinstance(result, dict):
            raise ReconfigureError(f"{self.ns}: the reconfigure callback returned {type(result).__name__}, not a dict")
        # the callback may adjust values; keep only described parameters, in their types
        kept = dict(self.config)
        for name, value in result.items():
            if self.description.param(name) is not None:
                kept[name] = value
        self.config = kept
        for name, value in kept.items():
            await self.node.set_param(f"{self.ns}/{name}", value)
        assert self._update_pub is not None
        await self._update_pub.publish(encode_config(self.config, self.description.groups))
        return self.config

    async def _on_set(self, request: Any) -> Any:
        changes: dict[str, Any] = {}
        for name, value in config_values(request.config).items():
            try:
                changes[name] = self.description.check(name, value, ranges=False)
            except ReconfigureError as exc:  # a peer's bad value: left out, one log line
                _peer_log.warning(f"reconfigure {self.ns}", "%s: set_parameters: %s", self.ns, exc)
        async with self._lock:
            new = {**self.config, **changes}
            self.description.clamp(new)
            await self._apply(new, self.description.level(new, self.config))
        return Reconfigure._response_class(config=encode_config(self.config, self.description.groups))


class ReconfigureClient:
    """A client of the dynamic_reconfigure server at ``server`` (a node name or namespace)."""

    def __init__(self, node: Node, server: str) -> None:
        self.node = node
        self.ns = node.resolve_name(server).rstrip("/")
        self.description: Description | None = None
        self.config: dict[str, Any] | None = None
        self._subs: list[Subscriber] = []
        self._described = asyncio.Event()
        self._updated = asyncio.Event()

    async def start(self) -> ReconfigureClient:
        self._subs.append(
            await self.node.subscribe(f"{self.ns}/parameter_descriptions", ConfigDescription, self._on_description)
        )
        self._subs.append(await self.node.subscribe(f"{self.ns}/parameter_updates", Config, self._on_update))
        return self

    async def aclose(self) -> None:
        for sub in self._subs:
            await sub.aclose()

    async def __aenter__(self) -> ReconfigureClient:
        return await self.start()

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()

    def _on_description(self, msg: Any) -> None:
        self.description = Description.from_msg(msg)
        self._described.set()

    def _on_update(self, msg: Any) -> None:
        self.config = config_values(msg)
        self._updated.set()

    async def get_description(self, timeout: float = 5.0) -> Description:
        """The server's description (latched on ``parameter_descriptions``).

        Raises:
            ReconfigureError: none within ``timeout`` seconds.
        """
        try:
            async with backports.timeout(timeout):
                await self._described.wait()
        except TimeoutError:
            raise ReconfigureError(
                f"no description from {self.ns}/parameter_descriptions within {timeout:g} s"
            ) from None
        assert self.description is not None
        return self.description

    async def get_configuration(self, timeout: float = 5.0) -> dict[str, Any]:
        """The server's current values (latched on ``parameter_updates``).

        Raises:
            ReconfigureError: none within ``timeout`` seconds.
        """
        try:
            async with backports.timeout(timeout):
                await self._updated.wait()
        except TimeoutError:
            raise ReconfigureError(f"no config from {self.ns}/parameter_updates within {timeout:g} s") from None
        assert self.config is not None
        return dict(self.config)

    async def update_configuration(self, changes: Mapping[str, Any], timeout: float = 5.0) -> dict[str, Any]:
        """Set values (converted and checked against the description) and return the server's config after.

        Raises:
            ReconfigureError: a value does not fit, or the server's service failed.
        """
        description = await self.get_description(timeout)
        checked = {name: description.check(name, value) for name, value in changes.items()}
        proxy = self.node.service_proxy(f"{self.ns}/set_parameters", Reconfigure)
        try:
            async with backports.timeout(timeout):
                response = await proxy.call(Reconfigure._request_class(config=encode_config(checked)))
        except (MrosError, TimeoutError) as exc:
            raise ReconfigureError(f"{self.ns}/set_parameters failed: {exc}") from exc
        finally:
            closer = getattr(proxy, "aclose", None)
            if closer is not None:
                await closer()
        self.config = {**(self.config or {}), **config_values(response.config)}
        return dict(self.config)
