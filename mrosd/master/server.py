"""``Master``: the ROS 1 master process part, composing the handlers, the notifier and the XML-RPC server.

Owns the listening socket, the outgoing XML-RPC client used for callbacks, and the optional
allow-list of client networks (requests from other addresses get HTTP 403 before any parsing).
"""

from __future__ import annotations

import ipaddress
import logging
import os
import socket
from collections.abc import Iterable
from typing import Any
from urllib.parse import urlsplit

from aiohttp import web

from mrosd.master.api import MasterApi
from mrosd.master.notifier import Notifier
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


class _GuardedServer(XmlRpcServer):
    """XmlRpcServer that refuses clients outside the allowed networks with HTTP 403."""

    def __init__(self, *args: Any, allow: list[Network] | None = None, **kw: Any) -> None:
        super().__init__(*args, **kw)
        self._allow = allow

    def _allowed(self, remote: str | None) -> bool:
        if self._allow is None:
            return True
        if not remote:
            return False
        try:
            addr = ipaddress.ip_address(remote.split("%", 1)[0])
        except ValueError:
            return False
        if isinstance(addr, ipaddress.IPv6Address) and addr.ipv4_mapped is not None:
            addr = addr.ipv4_mapped
        return any(addr in net for net in self._allow)

    async def _handle_http(self, request: web.Request) -> web.Response:
        if not self._allowed(request.remote):
            log.warning("master: refused request from %s (not in the allow-list)", request.remote)
            return web.Response(status=403, text="client address not allowed\n")
        return await super()._handle_http(request)


class Master:
    """A ROS 1 master (Master API + Parameter Server) on one event loop.

    Args:
        host: address to bind.
        port: TCP port (0 picks a free one; see ``.port`` after ``start()``).
        allow: client networks allowed to call (e.g. ``["127.0.0.0/8", "10.0.0.0/8"]``); None allows all.
        advertise: host name for ``.uri``; default from ROS_HOSTNAME/ROS_IP/bind address.
        notify_timeout: seconds allowed for one callback to a node.
        notify_queue: most callbacks queued per node (oldest dropped beyond).
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
    ) -> None:
        self.host = host
        self._requested_port = port
        self._advertise = advertise
        self._allow = parse_networks(allow) if allow is not None else None
        self._client = XmlRpcClient(timeout=notify_timeout)
        self.api = MasterApi(None)
        self.notifier = Notifier(
            self._client,
            timeout=notify_timeout,
            max_queue=notify_queue,
            on_result=self.api.on_notification_result,
        )
        self.api.notifier = self.notifier
        self._server = _GuardedServer(self.api.methods, host, port, name="master", allow=self._allow)
        self.port = 0
        self.uri = ""

    async def start(self) -> None:
        """Bind and serve; ``.port`` and ``.uri`` are set afterwards."""
        await self._server.start()
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
        await self.notifier.aclose()
        await self._client.aclose()

    async def __aenter__(self) -> Master:
        await self.start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()
