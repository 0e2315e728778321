"""The master's HTTP/1.1 server: an accept loop and the connections it holds, no framework.

Why hand-written: the master answers thousands of tiny calls per second and a generic server's per-request
machinery costs more than the XML-RPC work itself; ``python -m bench master`` runs this server against the same
master behind aiohttp's low-level server (llhttp) in one run (A/B). What a request may look like and the bytes
of every answer are ``mrosd.master.httpframing`` (sans IO); turning a body into a reply is
``mrosd.master.dispatch``; one connection's protocol is ``mrosd.master.httpconn``; this module accepts,
admits and sweeps connections and guards resources.

Pipelined requests are answered in order. Backpressure: a client that does not read its responses (transport
write buffer full) is not read from until it does. Refused with a status and a closed connection: what
``httpframing.parse_head`` refuses, header blocks over ``MAX_HEADER_SIZE`` (431), peers outside the
allow-list (403), and connections beyond the global cap or the cap per who (503: a remote address, or a local
uid told apart by ``mrosd.master.peers``; the policy is ``mrosd.master.admission``). Big replies
(``dispatch.LargeReply``) are written a slice at a time as the client reads.

Resources: idle keep-alive connections are closed after ``idle_timeout`` (to 1.5x that); a started request
must complete within ``REQUEST_TIMEOUT``; the accept loop backs off (50 ms doubling to 2 s) when the process
is out of file descriptors instead of retrying at once, and repeated errors are logged at a bounded rate.
Bodies over ``INCREMENTAL_DECODE_SIZE`` are decoded in slices with the loop running in between; closing the
server cancels such work at once.
"""

from __future__ import annotations

import asyncio
import errno
import ipaddress
import logging
import resource
import socket
from typing import Any

from mrosd.lograte import RateLimitedLog
from mrosd.master.admission import Admission
from mrosd.master.httpconn import BodyHandler, HttpProtocol
from mrosd.master.httpframing import status_response
from mrosd.master.peers import Endpoint, PeerUids, is_local, peer_address

log = logging.getLogger(__name__)
_ratelog = RateLimitedLog(log)

#: Defaults of ``HttpServer``/``Master``: open connections in all, from one peer address, and the idle time
#: after which a kept-alive connection with nothing pending is closed (rospy and roscpp reconnect).
MAX_CONNECTIONS = 4096
MAX_CONNECTIONS_PER_HOST = 2048
IDLE_TIMEOUT = 60.0

#: File descriptors left to the rest of the process when the connection cap is clamped to RLIMIT_NOFILE.
FD_RESERVE = 64

#: Accept back-off while the process is out of file descriptors: first delay, ceiling.
ACCEPT_BACKOFF = (0.05, 2.0)
_ACCEPT_BATCH = 64
_OUT_OF_RESOURCES = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})

Network = ipaddress.IPv4Network | ipaddress.IPv6Network


def allowed(networks: list[Network] | None, host: str | None) -> bool:
    """Whether a peer address is inside one of ``networks`` (None allows everyone)."""
    if networks is None:
        return True
    addr = peer_address(host) if host else None
    if addr is None:
        return False
    return any(addr in net for net in networks)


def _nofile_limit() -> int:
    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    return soft if soft != resource.RLIM_INFINITY else 1 << 20


class HttpServer:
    """The listening socket, its accept loop, and every open connection (so closing really closes them all).

    Args:
        handler: turns request bodies into response bodies.
        networks: allowed client networks (None: everyone).
        max_connections: open connections in all; clamped to RLIMIT_NOFILE minus ``FD_RESERVE`` at start.
        max_connections_per_host: open connections of one who: a remote address, or a local uid (the name is
            kept for the callers and the config key ``[master] max_connections_per_host``).
        idle_timeout: seconds a kept-alive connection may stay idle (closed after 1x to 1.5x that).
        name: who serves, for the log lines ("master", or a node's "slave /talker").
    """

    def __init__(
        self,
        handler: BodyHandler,
        networks: list[Network] | None,
        *,
        max_connections: int = MAX_CONNECTIONS,
        max_connections_per_host: int = MAX_CONNECTIONS_PER_HOST,
        idle_timeout: float = IDLE_TIMEOUT,
        name: str = "master",
    ) -> None:
        if max_connections < 1 or max_connections_per_host < 1 or idle_timeout <= 0:
            raise ValueError("connection caps must be at least 1 and the idle timeout positive")
        self._handler = handler
        self._networks = networks
        self.name = name
        self.max_connections = max_connections
        self.max_connections_per_host = max_connections_per_host
        self.idle_timeout = idle_timeout
        self._live: set[HttpProtocol] = set()
        self._admission: Admission[HttpProtocol] = Admission(max_connections, max_connections_per_host)
        self._peers = PeerUids()
        #: Accepted sockets on their way to their protocol (a task each), closed with the server if still there.
        self._pending: dict[asyncio.Task[Any], socket.socket] = {}
        self._socks: list[socket.socket] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self._backoff = 0.0
        self._resume: asyncio.TimerHandle | None = None
        self._sweeper: asyncio.TimerHandle | None = None
        self._cap = max_connections
        #: Connections refused for a cap, closed to make room for another client's, and accept back-offs for
        #: lack of file descriptors (for tests and stats).
        self.refused_connections = 0
        self.shed_connections = 0
        self.accept_backoffs = 0
        self.port = 0

    @property
    def connections(self) -> int:
        return len(self._live)

    async def start(self, host: str, port: int, backlog: int = 1024) -> None:
        """Bind every address ``host`` resolves to (one port for all) and listen; ``.port`` is that port."""
        loop = asyncio.get_running_loop()
        infos = await loop.getaddrinfo(host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
        socks: list[socket.socket] = []
        try:
            for family, kind, proto, _, resolved in dict.fromkeys(infos):
                sock = socket.socket(family, kind, proto)
                socks.append(sock)
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                if family == socket.AF_INET6:
                    sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
                addr = resolved
                if socks[1:]:  # the port picked for the first address (port 0) serves the others too
                    addr = (resolved[0], socks[0].getsockname()[1], *resolved[2:])
                sock.bind(addr)
                sock.listen(backlog)
                sock.setblocking(False)
        except BaseException:
            for sock in socks:
                sock.close()
            raise
        self._socks = socks
        self._loop = loop
        self._cap = max(1, min(self.max_connections, _nofile_limit() - FD_RESERVE))
        self._admission = Admission(self._cap, self.max_connections_per_host)
        if self._cap < self.max_connections:
            log.warning(
                "%s: at most %d connections (RLIMIT_NOFILE %d); raise the limit for %d",
                self.name,
                self._cap,
                _nofile_limit(),
                self.max_connections,
            )
        self.port = int(socks[0].getsockname()[1])
        self._listen(True)
        self._sweeper = loop.call_later(self.idle_timeout / 2, self._sweep)

    def _listen(self, on: bool) -> None:
        assert self._loop is not None
        for sock in self._socks:
            if on:
                self._loop.add_reader(sock.fileno(), self._accept, sock)
            else:
                self._loop.remove_reader(sock.fileno())

    def _accept(self, sock: socket.socket) -> None:
        if self._loop is None:
            return
        for _ in range(_ACCEPT_BATCH):
            try:
                conn, addr = sock.accept()
            except (BlockingIOError, InterruptedError):
                return
            except ConnectionAbortedError:
                continue
            except OSError as exc:
                if exc.errno in _OUT_OF_RESOURCES:
                    self._pause_accepting(exc)
                else:
                    _ratelog.error("accept", "%s: accept failed: %s", self.name, exc)
                return
            self._backoff = 0.0
            self._adopt(conn, addr)

    def _pause_accepting(self, exc: OSError) -> None:
        """Out of file descriptors (or memory): stop accepting for a while instead of spinning on the error."""
        assert self._loop is not None
        low, high = ACCEPT_BACKOFF
        self._backoff = min(high, self._backoff * 2) if self._backoff else low
        self.accept_backoffs += 1
        _ratelog.error(
            "emfile",
            "%s: cannot accept (%s) with %d connections open; pausing accepts for %g s",
            self.name,
            exc.strerror or exc,
            len(self._live),
            self._backoff,
        )
        self._listen(False)
        self._resume = self._loop.call_later(self._backoff, self._resume_accepting)

    def _resume_accepting(self) -> None:
        self._resume = None
        if self._loop is not None:
            self._listen(True)
            for sock in self._socks:
                self._accept(sock)

    def _adopt(self, conn: socket.socket, addr: Any) -> None:
        host = str(addr[0]) if isinstance(addr, tuple) and addr else ""
        peer: Endpoint = (host, int(addr[1])) if isinstance(addr, tuple) and len(addr) > 1 else (host, 0)
        try:
            name = conn.getsockname()
            ours: Endpoint = (str(name[0]), int(name[1]))
        except OSError:
            ours = ("", 0)
        local = is_local(host, ours[0])
        refused = not allowed(self._networks, host)
        proto = HttpProtocol(self._handler, self, host, refused, peer=peer, ours=ours, name=self.name)
        admission = self._admission
        uid = None
        if admission.needs_identity(local):
            # Only now is it worth asking the kernel who is who: first the local connections admitted
            # without a uid (each once), then the newcomer.
            for other in admission.unidentified():
                admission.identify(other, self._peers.uid(other.peer, other.ours))
            if local:
                uid = self._peers.uid(peer, ours)
        decision = admission.admit(proto, host, local, uid)
        if not decision.admitted:
            self.refused_connections += 1
            who = f"{host} (uid {uid})" if uid is not None else host
            _ratelog.warning("cap", "%s: refusing a connection from %s: %s", self.name, who, decision.reason)
            try:
                conn.setblocking(False)
                conn.send(status_response(503, b"too many connections\n"))
            except OSError:
                pass
            conn.close()
            return
        shed = decision.shed
        if shed is not None:
            self.shed_connections += 1
            self._live.discard(shed)
            _ratelog.warning(
                "shed",
                "%s: all %d connection slots taken; closing the oldest idle connection of %s to admit %s",
                self.name,
                self._cap,
                decision.shed_from,
                host if uid is None else f"{host} (uid {uid})",
            )
            shed.close()
        conn.setblocking(False)
        self._live.add(proto)
        assert self._loop is not None
        task = self._loop.create_task(self._connect(conn, proto))
        self._pending[task] = conn
        task.add_done_callback(self._connected)

    async def _connect(self, conn: socket.socket, proto: HttpProtocol) -> None:
        assert self._loop is not None
        try:
            await self._loop.connect_accepted_socket(lambda: proto, conn)
        except Exception as exc:
            _ratelog.warning("connect", "%s: dropping a new connection from %s: %s", self.name, proto.host, exc)
            conn.close()
            self.forget(proto)

    def _connected(self, task: asyncio.Task[Any]) -> None:
        self._pending.pop(task, None)

    def forget(self, proto: HttpProtocol) -> None:
        """Called once a connection is gone: its slot is free again."""
        self._live.discard(proto)
        self._admission.forget(proto)

    def _sweep(self) -> None:
        """Close connections idle since the sweep before last (sweeps run every ``idle_timeout / 2``)."""
        if self._loop is None:
            return
        now = self._loop.time()
        for proto in list(self._live):
            if proto.stalled(now):
                _ratelog.log(
                    logging.INFO, "stalled", "%s: closing %s: it stopped reading a big reply", self.name, proto.host
                )
                proto.abort()
                continue
            if proto.activity != proto.seen_activity or not proto.idle:
                proto.seen_activity = proto.activity
                proto.idle_sweeps = 0
                continue
            proto.idle_sweeps += 1
            if proto.idle_sweeps >= 2:
                proto.close()
        self._sweeper = self._loop.call_later(self.idle_timeout / 2, self._sweep)

    async def aclose(self) -> None:
        """Stop listening, abort every open connection and cancel the work of its pending calls."""
        for handle in (self._resume, self._sweeper):
            if handle is not None:
                handle.cancel()
        if self._loop is not None:
            if self._resume is None:
                self._listen(False)
            for sock in self._socks:
                sock.close()
        self._loop, self._socks, self._resume, self._sweeper = None, [], None, None
        for task, conn in list(self._pending.items()):
            task.cancel()
            conn.close()  # a task cancelled before it ran never closes its socket
        for proto in list(self._live):
            proto.abort()
        self._live.clear()
        self._admission = Admission(self._cap, self.max_connections_per_host)
        self._peers.close()
        await asyncio.sleep(0)  # let the aborted transports report connection_lost
