"""``XmlRpcServer``: a node's slave API, a ``MethodTable`` served over the project's one HTTP/1.1 server.

The HTTP side is the master's (``mrosd.master.httpserver``, framing by ``mrosd.master.httpframing``): POST with
one Content-Length only, bodies bound by ``MAX_BODY_SIZE`` (413), header blocks by ``MAX_HEADER_SIZE`` (431),
a started request completed within ``REQUEST_TIMEOUT`` (408), idle keep-alive connections closed, caps on
connections in all and per peer (503), pipelined requests answered in order, a client that does not read not
read from, a request followed by the peer's EOF (``shutdown(SHUT_WR)``) still answered, one rate-limited line
per refused request. Dispatch (multicall, faults) is ``mrosd.xmlrpc.methods``. No aiohttp: a node's start-up
does not pay for it.
"""

from __future__ import annotations

from collections.abc import Coroutine, Mapping
from typing import Any

from mrosd.master.httpserver import HttpServer
from mrosd.xmlrpc.methods import Handler, MethodTable

__all__ = ["MAX_CONNECTIONS", "MAX_CONNECTIONS_PER_HOST", "Handler", "XmlRpcServer"]

#: Connections a slave API holds open at once, in all and per peer (a remote address, or a local uid): callers
#: are the master and the other nodes, each with a call or two at a time.
MAX_CONNECTIONS = 1024
MAX_CONNECTIONS_PER_HOST = 512
#: Seconds a kept-alive connection with nothing pending stays open (closed after 1x to 1.5x that).
IDLE_TIMEOUT = 60.0


class XmlRpcServer(MethodTable):
    """An XML-RPC server dispatching to a table of async handlers (see ``MethodTable``).

    ``port`` holds the bound port once ``start()`` returned. ``reuse_address`` is kept for callers: the
    listening socket always sets ``SO_REUSEADDR``.
    """

    def __init__(
        self,
        methods: Mapping[str, Handler],
        host: str = "0.0.0.0",
        port: int = 0,
        *,
        name: str = "xmlrpc",
        backlog: int = 1024,
        reuse_address: bool = True,
        max_connections: int = MAX_CONNECTIONS,
        max_connections_per_host: int = MAX_CONNECTIONS_PER_HOST,
        idle_timeout: float = IDLE_TIMEOUT,
    ) -> None:
        super().__init__(methods, name=name)
        del reuse_address
        self._host = host
        self._port = port
        self._backlog = backlog
        self._limits = (max_connections, max_connections_per_host, idle_timeout)
        self._http: HttpServer | None = None
        self.port = 0

    def handle(self, body: bytes) -> Coroutine[Any, Any, bytes]:
        """The HTTP server's hook: one request body to a coroutine answering it."""
        return self.dispatch_body(body)

    async def start(self) -> None:
        """Bind and start serving; ``self.port`` holds the bound port afterwards."""
        conns, per_host, idle = self._limits
        http = HttpServer(
            self, None, max_connections=conns, max_connections_per_host=per_host, idle_timeout=idle, name=self._name
        )
        await http.start(self._host, self._port, backlog=self._backlog)
        self._http = http
        self.port = http.port

    @property
    def connections(self) -> int:
        """Connections open right now."""
        return self._http.connections if self._http is not None else 0

    async def aclose(self) -> None:
        """Stop serving and close every connection (calls still running are cancelled)."""
        http, self._http = self._http, None
        if http is not None:
            await http.aclose()

    async def __aenter__(self) -> XmlRpcServer:
        await self.start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()
