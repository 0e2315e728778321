"""``WebServer``: the daemon's web part (and ``mros bridge``): one ``WebHub``, the Foxglove and rosbridge listeners.

An embeddable server with ``start()``/``aclose()`` like the daemon's other parts. It refuses to listen off
loopback without a token (``AccessPolicy.check_bind``); the token is accepted as ``?token=`` in the URL
(browsers cannot set headers on a WebSocket) or as ``Authorization: Bearer <token>``. WebSocket frames are
capped at ``max_frame`` bytes by aiohttp before anything is buffered beyond them.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
from collections.abc import Awaitable, Callable, Sequence
from typing import Any

from aiohttp import web

from mrosd import backports
from mrosd.errors import ConfigError
from mrosd.msg.typestore import TypeStore
from mrosd.web import foxglove as fg
from mrosd.web.access import AccessPolicy
from mrosd.web.admission import Admission, OriginGate
from mrosd.web.assets import MAX_ASSET_BYTES, AssetReader
from mrosd.web.fairsend import IN_FLIGHT_BYTES
from mrosd.web.foxglove_server import FoxgloveSession
from mrosd.web.handshake import AuthFirstResponse, PeerErrorLog, gate_middleware, read_auth, refuse_later
from mrosd.web.hub import WebHub
from mrosd.web.limits import SessionLimits
from mrosd.web.page import index, page_routes
from mrosd.web.queue import Ledger

log = logging.getLogger(__name__)

__all__ = ["WebServer"]

#: Largest WebSocket message a client may send (a client-published image fits; more is refused by aiohttp).
MAX_CLIENT_FRAME = 64 * 1024 * 1024
#: Seconds a closing server waits for its clients to take their close frame.
CLOSE_TIMEOUT = 1.0
#: Most WebSocket clients at once (authenticated; see ``mrosd.web.admission``).
MAX_CLIENTS = 64
#: rosbridge connections waiting for their ``auth`` op: in all, and from one remote address. Beyond either the
#: oldest is closed for the new one (``Admission.pend``), so a stranger never keeps the operator out.
MAX_PENDING = 256
MAX_PENDING_PER_ADDRESS = 32
#: Bytes of unfinished fragmented messages (rosbridge ``fragment`` ops) held for all clients together.
MAX_FRAGMENT_BYTES = 256 * 1024 * 1024
#: Seconds a first rosbridge client waits for the web part's services to join the graph before its ops are read.
GRAPH_SERVICES_WAIT = 10.0


#: Times a port chosen by the first address (port 0) is tried on the others before giving up: another
#: process may hold that number on another address.
BIND_ATTEMPTS = 5
#: Seconds between two looks at the clients' drop counts for the status file (rewritten only when they changed).
DROPS_PERIOD = 5.0
#: Clients and topics per client whose drops the status file names (the most dropping ones): 16 x 16 rows
#: stay far below the status file's read bound (``mrosd.runstatus.MAX_STATUS_BYTES``).
STATUS_CLIENTS = 16
STATUS_TOPICS = 16


class WebServer:
    """Serves Foxglove WebSocket on ``host:port`` (port 0: any free port, read ``port`` after start).

    ``host`` may be several addresses (``["127.0.0.1", "::1"]``): each port is served on every one of them, with
    the same number (port 0: the one the first address got); ``url`` and the log name the first.
    """

    def __init__(
        self,
        master_uri: str,
        *,
        host: str | Sequence[str] = "127.0.0.1",
        port: int = 8765,
        policy: AccessPolicy | None = None,
        limits: SessionLimits | None = None,
        node_name: str = "mrosd_web",
        max_clients: int = MAX_CLIENTS,
        max_frame: int = MAX_CLIENT_FRAME,
        node_host: str | None = None,
        rosbridge_port: int | None = None,
        max_queued_bytes: int | None = None,
        asset_store: TypeStore | None = None,
        asset_bytes: int | None = None,
        max_fragment_bytes: int = MAX_FRAGMENT_BYTES,
    ) -> None:
        self.policy = policy or AccessPolicy()
        self.hosts = [host] if isinstance(host, str) else list(dict.fromkeys(host))
        if not self.hosts:
            raise ConfigError("web: no address to bind (host is an empty list)")
        self.policy.check_bind(self.hosts)
        #: the address URLs name (the first)
        self.host = self.hosts[0]
        self.port = port
        self.limits = limits or SessionLimits()
        self.admission = Admission(
            max_clients=max_clients, max_pending=MAX_PENDING, pending_per_address=MAX_PENDING_PER_ADDRESS
        )
        self.gate = OriginGate(self.policy.hostnames, self.policy.allowed_origins)
        self.max_frame = max_frame
        #: fetchAsset: package:// URIs found where the type search finds packages (``asset_store``, default the
        #: process's own), none at all when the policy's asset allow-list is empty
        assets = (
            AssetReader(asset_store, allows=self.policy.allows_asset, max_bytes=asset_bytes or MAX_ASSET_BYTES)
            if self.policy.assets
            else None
        )
        self.hub = WebHub(master_uri, name=node_name, policy=self.policy, host=node_host, assets=assets)
        if max_queued_bytes is not None:
            self.hub.max_queued_bytes = max_queued_bytes
        self.sessions: set[FoxgloveSession] = set()
        #: rosbridge v2 port (None: not served); read after start when 0 was asked
        self.rosbridge_port = rosbridge_port
        self.rosbridge_sessions: set[Any] = set()
        #: bytes every rosbridge client holds in unfinished fragmented messages, bounded by max_fragment_bytes
        self.rosbridge_fragments = Ledger()
        self.max_fragment_bytes = max_fragment_bytes
        self._runner: web.AppRunner | None = None
        self._rosbridge_runner: web.AppRunner | None = None
        #: called (at most every ``DROPS_PERIOD`` s) when clients' drop counts changed: the daemon rewrites its
        #: status file (``mros daemon status`` shows them)
        self.on_drops: Callable[[], None] | None = None
        self._drops_task: asyncio.Task[None] | None = None
        #: run once, when the first client is admitted, after rosapi's services joined the graph (the daemon
        #: starts its tf2_web_republisher node this way); each failure is logged and the others go on
        self.first_client_hooks: list[Callable[[], Awaitable[Any]]] = []
        self._graph_task: asyncio.Task[None] | None = None

    @property
    def max_clients(self) -> int:
        return self.admission.max_clients

    @max_clients.setter
    def max_clients(self, value: int) -> None:
        self.admission.max_clients = value

    @property
    def url(self) -> str:
        return self.urls[0]

    @property
    def urls(self) -> list[str]:
        """The Foxglove WebSocket URL on each bound address."""
        return [f"ws://{_url_host(h)}:{self.port}/" for h in self.hosts]

    @property
    def page_url(self) -> str:
        """The page to open in a browser (served on the Foxglove port; ``?token=`` added when one is set)."""
        query = "?token=..." if self.policy.token else ""
        return f"http://{_url_host(self.host)}:{self.port}/{query}"

    @property
    def rosbridge_url(self) -> str:
        return self.rosbridge_urls[0]

    @property
    def rosbridge_urls(self) -> list[str]:
        """The rosbridge URL on each bound address."""
        return [f"ws://{_url_host(h)}:{self.rosbridge_port}/" for h in self.hosts]

    async def start(self) -> None:
        """Start the hub (graph watch) and listen.

        Raises:
            OSError: the port is in use.
            MrosError: the master does not answer.
        """
        await self.hub.start()
        try:
            self._runner, self.port = await self._listen(self._foxglove, self.port, page=True)
            if self.rosbridge_port is not None:
                self._rosbridge_runner, self.rosbridge_port = await self._listen(self._rosbridge, self.rosbridge_port)
        except BaseException:
            await self.aclose()
            raise
        self._drops_task = asyncio.get_running_loop().create_task(self._watch_drops(), name="web drops")
        urls = " ".join(self.urls)
        log.info("web: Foxglove WebSocket on %s, page %s (master %s)", urls, self.page_url, self.hub.master_uri)
        if self.rosbridge_port is not None:
            log.info("web: rosbridge v2 on %s", " ".join(self.rosbridge_urls))

    async def _listen(self, handler: Any, port: int, *, page: bool = False) -> tuple[web.AppRunner, int]:
        app = web.Application(middlewares=[gate_middleware(self.gate, lambda: self.port)])
        app.router.add_get("/", handler)
        if page:
            page_routes(app)
        runner = web.AppRunner(
            app, handle_signals=False, access_log=None, shutdown_timeout=CLOSE_TIMEOUT, logger=PeerErrorLog()
        )
        await runner.setup()
        attempts = BIND_ATTEMPTS
        while True:
            try:
                return runner, await self._bind_every_host(runner, port)
            except OSError as exc:
                attempts -= 1
                # port 0: the number the first address got may be taken on another one; choose again
                if port == 0 and exc.errno == errno.EADDRINUSE and attempts > 0:
                    continue
                await runner.cleanup()
                raise
            except BaseException:
                await runner.cleanup()
                raise

    async def _bind_every_host(self, runner: web.AppRunner, port: int) -> int:
        """Listen on ``port`` on every address (0: the first address's free port on the others too); on a
        failure none stays listening."""
        sites: list[web.TCPSite] = []
        try:
            for host in self.hosts:
                site = web.TCPSite(runner, host, port, reuse_address=True)
                await site.start()
                sites.append(site)
                server: Any = site._server
                if port == 0 and server is not None and server.sockets:
                    port = int(server.sockets[0].getsockname()[1])
        except BaseException:
            for site in sites:
                await site.stop()
            raise
        return port

    async def _rosbridge(self, request: web.Request) -> web.StreamResponse:
        """A rosbridge client: with the token in its URL (or none configured) it takes a slot at once; else it is
        pending, with a small frame limit and a deadline, until its first op authenticates it."""
        from mrosd.web.rosbridge_server import RosbridgeSession

        address = str(request.remote)
        writer = None
        if self.policy.token_ok(self._token(request)):
            ws = web.WebSocketResponse(
                compress=True, max_msg_size=self.max_frame, heartbeat=30.0, writer_limit=IN_FLIGHT_BYTES
            )
            why = self.admission.admit(address)
            if why is not None:
                raise web.HTTPServiceUnavailable(text=why + "\n")
        else:
            pending = AuthFirstResponse(
                max_frame=self.max_frame,
                token_ok=self.policy.token_ok,
                compress=True,
                heartbeat=30.0,
                writer_limit=IN_FLIGHT_BYTES,
            )
            writer = await pending.prepare(request)
            for old in self.admission.pend(pending, address):
                refuse_later(old, "too many connections waiting to authenticate")  # type: ignore[arg-type]
            try:
                authed = await read_auth(pending, self.policy.token_ok)
            finally:
                self.admission.settle(pending)
            if not authed:
                return pending
            why = self.admission.admit(address)
            if why is not None:
                await pending.close(code=1013, message=why.encode())
                return pending
            pending.check_lifted()
            ws = pending
        try:
            await self._join_graph(wait=True)
            if not ws.prepared:
                writer = await ws.prepare(request)
            session = RosbridgeSession(
                self.hub,
                ws,
                self.limits,
                peer=address,
                fragments=(self.rosbridge_fragments, self.max_fragment_bytes),
                writer=writer,
            )
            self.rosbridge_sessions.add(session)
            try:
                await session.run()
            finally:
                self.rosbridge_sessions.discard(session)
                if not ws.closed:
                    await ws.close()
        finally:
            self.admission.release(address)
        return ws

    async def _join_graph(self, *, wait: bool) -> None:
        """The web part's own services (rosapi's, and the hooks': tf2_web_republisher) join the graph when the
        first client is admitted, not when the daemon starts: until someone uses the web part, the graph is what
        roscore's would be (ros_comm's test_rosmaster counts every service in it). A rosbridge client ``wait``s
        for them (bounded), so its first ``call_service`` finds them; a Foxglove client sees them advertised."""
        if self._graph_task is None:
            self._graph_task = asyncio.get_running_loop().create_task(self._graph_services(), name="web graph")
        if wait and not self._graph_task.done():
            await asyncio.wait({self._graph_task}, timeout=GRAPH_SERVICES_WAIT)

    async def _graph_services(self) -> None:
        """Never raises (``aclose`` awaits it): a failure is one line, and the web part goes on without."""
        if self.rosbridge_port is not None:
            from mrosd.web import rosapi  # rosapi's services in the graph, as its node registers them

            try:
                await rosapi.register(self.hub)  # each service's failure is logged there
            except Exception as exc:
                log.error("web: rosapi's services did not join the graph: %s", exc)
        for hook in self.first_client_hooks:
            try:
                await hook()
            except Exception as exc:
                log.error("web: starting a service for the first client failed: %s", exc)

    def _token(self, request: web.Request) -> str | None:
        token = request.query.get("token")
        if token is not None:
            return token
        auth = request.headers.get("Authorization", "")
        return auth[7:] if auth.startswith("Bearer ") else None

    async def _foxglove(self, request: web.Request) -> web.StreamResponse:
        if request.headers.get("Upgrade", "").lower() != "websocket":
            return index()  # a browser opening the port: the page (it then connects back with the token)
        if not self.policy.token_ok(self._token(request)):
            raise web.HTTPUnauthorized(text="token required: add ?token=... to the URL\n")
        offered = [p.strip() for p in request.headers.get("Sec-WebSocket-Protocol", "").split(",") if p.strip()]
        if fg.choose_subprotocol(offered) is None:
            raise web.HTTPBadRequest(text=f"offer one of the subprotocols {', '.join(fg.SUBPROTOCOLS)}\n")
        address = str(request.remote)
        why = self.admission.admit(address)
        if why is not None:
            raise web.HTTPServiceUnavailable(text=why + "\n")
        try:
            await self._join_graph(wait=False)
            ws = web.WebSocketResponse(
                protocols=fg.SUBPROTOCOLS,
                compress=True,
                max_msg_size=self.max_frame,
                heartbeat=30.0,
                writer_limit=IN_FLIGHT_BYTES,
            )
            writer = await ws.prepare(request)
            session = FoxgloveSession(self.hub, ws, writer, self.limits, peer=address)
            self.sessions.add(session)
            try:
                await session.run()
            finally:
                self.sessions.discard(session)
                if not ws.closed:
                    await ws.close()
        finally:
            self.admission.release(address)
        return ws

    def drops(self) -> list[tuple[str, dict[str, int]]]:
        """Per client that had messages dropped: (protocol and address, topic -> dropped), the clients and
        topics with the most drops first, at most ``STATUS_CLIENTS`` x ``STATUS_TOPICS`` (the status file
        is read bounded)."""
        rows = []
        for session in (*self.sessions, *self.rosbridge_sessions):
            per_topic: dict[str, int] = {}
            for sub in list(session.subs.values()):
                if sub.queue.dropped:
                    topic = sub.topic if isinstance(sub.topic, str) else sub.topic.name
                    per_topic[topic] = per_topic.get(topic, 0) + sub.queue.dropped
            if per_topic:
                top = sorted(per_topic.items(), key=lambda kv: -kv[1])[:STATUS_TOPICS]
                rows.append((f"{session.KIND} {session.peer}", dict(top)))
        rows.sort(key=lambda row: -sum(row[1].values()))
        return rows[:STATUS_CLIENTS]

    def encoders(self) -> list[tuple[str, dict[str, Any]]]:
        """Per ``T/compressed`` topic encoded here: (topic, its counters), the most encoding first, at most
        ``STATUS_TOPICS``."""
        rows = [(name, st.as_dict()) for name, st in self.hub.compressed.stats.items() if st.encoded or st.refused]
        rows.sort(key=lambda row: -row[1]["encoded"])
        return rows[:STATUS_TOPICS]

    async def _watch_drops(self) -> None:
        last: tuple[int, int] = (0, 0)
        while True:
            await asyncio.sleep(DROPS_PERIOD)
            encoded = sum(row["encoded"] + row["refused"] for _, row in self.encoders())
            total = (sum(sum(d.values()) for _, d in self.drops()), encoded)
            if total != last and self.on_drops is not None:
                last = total
                try:
                    self.on_drops()
                except Exception:  # the status file is a convenience; the daemon goes on without it
                    log.exception("web: the drop counts could not be written to the status")

    async def aclose(self) -> None:
        """Close every client, stop listening, then close the hub (its subscriptions and node)."""
        for task in (self._drops_task, self._graph_task):
            if task is not None:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
        self._drops_task = self._graph_task = None
        runners = [r for r in (self._runner, self._rosbridge_runner) if r is not None]
        self._runner = self._rosbridge_runner = None
        # Clients first (aiohttp's cleanup would otherwise wait for each open WebSocket handler to end).
        sockets: list[Any] = [s.ws for s in (*self.sessions, *self.rosbridge_sessions)]
        sockets += self.admission.pending_keys()  # connections still to authenticate
        closing = [ws.close(code=1001, message=b"server shutdown") for ws in sockets]
        if closing:
            with contextlib.suppress(TimeoutError):
                async with backports.timeout(CLOSE_TIMEOUT):
                    await asyncio.gather(*closing, return_exceptions=True)
        for runner in runners:
            await runner.cleanup()
        await self.hub.aclose()

    async def __aenter__(self) -> WebServer:
        await self.start()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()


def _url_host(host: str) -> str:
    return f"[{host}]" if ":" in host else host
