"""The master's HTTP/1.1 server: an accept loop and an ``asyncio.Protocol``, no framework.

Why hand-written: the master answers thousands of tiny calls per second and a generic server's per-request
machinery costs more than the XML-RPC work itself; ``python -m bench master`` runs this server against the same
master behind aiohttp's low-level server (llhttp) in one run (A/B). What a request may look like and the bytes
of every answer are ``mrosd.master.httpframing`` (sans IO); turning a body into a reply is
``mrosd.master.dispatch``; this module moves bytes between them and the sockets and guards resources.

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
import functools
import ipaddress
import logging
import resource
import socket
from collections.abc import Coroutine
from typing import TYPE_CHECKING, Any, cast

from mrosd.errors import HttpRefused
from mrosd.lograte import RateLimitedLog
from mrosd.master.admission import Admission
from mrosd.master.dispatch import LargeReply, Reply
from mrosd.master.httpframing import (
    CACHED_HEAD_SIZE,
    CONTINUE_RESPONSE,
    MAX_HEADER_SIZE,
    OK_HEAD,
    OK_RESPONSE,
    parse_head,
    parse_short_head,
    status_response,
)
from mrosd.master.peers import Endpoint, PeerUids, is_local, peer_address
from mrosd.xmlrpc import FAULT_INTERNAL_ERROR, encode_fault

if TYPE_CHECKING:
    from mrosd.master.dispatch import XmlRpcHttpHandler

log = logging.getLogger(__name__)
_ratelog = RateLimitedLog(log)

#: Largest body a client outside the allow-list may send before its 403 (it is read, never handled).
MAX_REFUSED_BYTES = 64 * 1024

#: Time a client has to complete a request once its first byte arrived (slowloris defence), and the longest a
#: big reply may wait for its reader to take more (a reader that stops holds the reply's share of the budget).
REQUEST_TIMEOUT = 30.0

#: A big reply (``LargeReply``) is handed to the transport this many bytes at a time, as the client reads.
WRITE_SLICE = 256 * 1024

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


class _Request:
    """A parsed header block; ``body_start`` counts from the first byte of the request."""

    __slots__ = ("body_start", "keep_alive", "length")

    def __init__(self, body_start: int, length: int, keep_alive: bool) -> None:
        self.body_start = body_start
        self.length = length
        self.keep_alive = keep_alive


class HttpProtocol(asyncio.Protocol):
    """One client connection: parse requests, answer them in order."""

    def __init__(
        self,
        handler: XmlRpcHttpHandler,
        server: HttpServer,
        host: str,
        refused: bool,
        *,
        peer: Endpoint = ("", 0),
        ours: Endpoint = ("", 0),
    ) -> None:
        self._handler = handler
        self._server = server
        self.host = host
        #: The two ends as ``(host, port)``: the key to the peer's socket in the kernel's tables.
        self.peer = peer
        self.ours = ours
        self._refused = refused
        self._buf = bytearray()
        self._transport: asyncio.Transport | None = None
        self._request: _Request | None = None
        self._busy = False
        self._closed = False
        self._eof = False
        self._reading_paused = False
        self._timer: asyncio.TimerHandle | None = None
        self._task: asyncio.Task[Reply] | None = None
        #: A big reply being written, where it stands, and when its reader last took some of it.
        self._out: LargeReply | None = None
        self._out_chunk = 0
        self._out_pos = 0
        self._out_keep_alive = False
        self._out_progress = 0.0
        self._write_paused = False
        #: Bumped on every read; the server's idle sweep compares it between sweeps.
        self.activity = 0
        self.idle_sweeps = 0
        self.seen_activity = -1

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._transport = cast(asyncio.Transport, transport)  # uvloop's transports are not subclasses
        if self._closed:  # shed before its transport existed
            transport.close()
            return
        if self._refused:
            # Answered once its request is in (closing at once races the client's send into a broken pipe
            # instead of a readable 403); MAX_REFUSED_BYTES bounds what such a client may send first.
            _ratelog.warning("allow", "master: refusing connection from %s (not in the allow-list)", self.host)
            return
        sock = transport.get_extra_info("socket")
        if sock is not None:
            try:
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            except OSError:
                pass

    def connection_lost(self, exc: Exception | None) -> None:
        self._closed = True
        self._end_stream()
        self._buf.clear()
        self._disarm()
        if self._task is not None:
            self._task.cancel()
        self._server.forget(self)

    def eof_received(self) -> bool | None:
        """The peer shut its write side: a call still running is answered, then the connection closes.

        Clients may send a request and ``shutdown(SHUT_WR)`` before reading (rosmaster answers them). Calls
        answered within the read that brought them are done already; a slow one (a big body decoded in
        slices) is still running: keep the write side open for it. Bytes left over after it can only be a
        request cut short. Nothing running: close now (returning None lets the transport close).
        """
        if not self._busy or self._closed:
            return None
        self._eof = True
        return True

    @property
    def idle(self) -> bool:
        """Nothing pending: no partial request, no call running."""
        return not self._buf and not self._busy and self._request is None

    @property
    def sheddable(self) -> bool:
        """No call running: closing it loses no answer (it is idle, or its request is still arriving)."""
        return not self._busy and not self._closed

    def close(self) -> None:
        """Close quietly (an idle connection: any response now would be mistaken for the next call's)."""
        if not self._closed:
            self._closed = True
            if self._transport is not None:
                self._transport.close()

    def abort(self) -> None:
        if self._task is not None:
            self._task.cancel()
        if self._transport is not None:
            self._transport.abort()
        self._closed = True

    def data_received(self, data: bytes) -> None:
        if self._closed:
            return
        self.activity += 1
        if self._buf or self._busy:
            self._buf += data
            self._process()
        else:  # the usual case: whole requests in one read, answered straight from ``data``
            pos = self._consume(data)
            if pos < len(data) and not self._closed:
                self._buf += memoryview(data)[pos:]
        if self._buf and self._timer is None and not self._closed:
            # Armed once per pending request, not per byte: trickling bytes cannot extend it.
            self._timer = asyncio.get_running_loop().call_later(REQUEST_TIMEOUT, self._timed_out)
        if self._busy and len(self._buf) > MAX_HEADER_SIZE and self._transport is not None:
            self._transport.pause_reading()  # a pipelining client waits while a slow call runs
            self._reading_paused = True

    def _disarm(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _timed_out(self) -> None:
        self._timer = None
        if self._closed or not self._buf:
            return
        if self._busy:  # the pending bytes wait on our own slow call, not on the client
            self._timer = asyncio.get_running_loop().call_later(REQUEST_TIMEOUT, self._timed_out)
            return
        _ratelog.log(
            logging.INFO, "timeout", "master: closing %s: request incomplete after %g s", self.host, REQUEST_TIMEOUT
        )
        self._fail(408, b"request not completed in time\n")

    def pause_writing(self) -> None:
        # The client does not read its responses: stop reading its requests (and writing a big reply) until it does.
        self._write_paused = True
        if self._transport is not None and not self._closed:
            self._transport.pause_reading()

    def resume_writing(self) -> None:
        self._write_paused = False
        if self._transport is not None and not self._closed and not self._reading_paused:
            self._transport.resume_reading()
        if self._out is not None:
            self._pump()

    def stalled(self, now: float) -> bool:
        """A big reply whose reader took nothing for ``REQUEST_TIMEOUT`` seconds."""
        return self._out is not None and now - self._out_progress > REQUEST_TIMEOUT

    def _fail(self, status: int, text: bytes) -> None:
        if self._transport is None or self._closed:
            return
        self._transport.write(status_response(status, text))
        self._transport.close()
        self._closed = True
        self._buf.clear()

    def _parse_head(self, buf: bytes | bytearray, pos: int) -> _Request | None:
        """Parse the header block starting at ``buf[pos]``; None while incomplete (or after failing)."""
        end = buf.find(b"\r\n\r\n", pos, pos + MAX_HEADER_SIZE + 4)
        if end < 0:
            if len(buf) - pos > MAX_HEADER_SIZE:
                self._fail(431, b"header block too large\n")
            return None
        try:
            head = bytes(buf[pos:end])
            parse = parse_short_head if len(head) <= CACHED_HEAD_SIZE else parse_head
            length, keep_alive, expect_continue = parse(head)
        except HttpRefused as exc:
            _ratelog.log(
                logging.INFO, "refused", "master: HTTP %d to %s: %s", exc.status, self.host, exc.text.strip().decode()
            )
            self._fail(exc.status, exc.text)
            return None
        if expect_continue and self._transport is not None:
            self._transport.write(CONTINUE_RESPONSE)
        return _Request(end + 4 - pos, length, keep_alive)

    def _process(self) -> None:
        """Answer the complete requests in the buffer (after a slow call, or with a partial request)."""
        if self._busy or self._closed or not self._buf:
            return
        pos = self._consume(self._buf)
        if pos and not self._closed:
            del self._buf[:pos]

    def _consume(self, buf: bytes | bytearray) -> int:
        """Answer every complete request at the start of ``buf``, in order; returns the bytes used.

        Stops at an incomplete request (kept in ``self._request`` once its head is parsed), at a
        call that needs the event loop (``self._busy``), or when the connection fails.
        """
        pos = 0
        size = len(buf)
        handle = self._handler.handle
        while pos < size and not self._busy and not self._closed:
            req = self._request
            if req is None:
                req = self._parse_head(buf, pos)
                if req is None:
                    return pos
                self._request = req
            start = pos + req.body_start
            stop = start + req.length
            if self._refused and (size >= stop or req.length > MAX_REFUSED_BYTES):
                self._fail(403, b"client address not allowed\n")
                return pos
            if size < stop:
                return pos
            if type(buf) is bytes:
                body = buf[start:stop]
            else:
                with memoryview(buf) as view:  # one copy of a big body, not two
                    body = bytes(view[start:stop])
            pos = stop
            self._request = None
            if self._timer is not None:
                self._disarm()
            result = handle(body)
            if type(result) is bytes:
                self._respond(result, req.keep_alive)
            else:
                self._busy = True
                task = asyncio.get_running_loop().create_task(cast(Coroutine[Any, Any, bytes], result))
                task.add_done_callback(functools.partial(self._finished, keep_alive=req.keep_alive))
                self._task = task
        return pos

    def _finished(self, task: asyncio.Task[Reply], *, keep_alive: bool) -> None:
        self._task = None
        if task.cancelled():
            self._next()
            return
        exc = task.exception()
        out = encode_fault(FAULT_INTERNAL_ERROR, f"internal error: {exc!r}") if exc else task.result()
        if type(out) is LargeReply:
            self._start_stream(out, keep_alive)
            return
        self._respond(cast(bytes, out), keep_alive)
        self._next()

    def _next(self) -> None:
        """The call in progress is answered: go on with what the client sent meanwhile."""
        self._busy = False
        if self._reading_paused and self._transport is not None and not self._closed:
            self._reading_paused = False
            self._transport.resume_reading()
        self._process()
        if self._eof and not self._busy:
            self.close()

    def _start_stream(self, reply: LargeReply, keep_alive: bool) -> None:
        """Write a big reply a slice at a time as the client reads (the shared value is never copied whole)."""
        if self._transport is None or self._closed:
            reply.release()
            self._busy = False
            return
        self._out = reply
        self._out_chunk = 0
        self._out_pos = 0
        self._out_keep_alive = keep_alive
        self._out_progress = asyncio.get_running_loop().time()
        conn = b"keep-alive" if keep_alive else b"close"
        self._transport.write(OK_HEAD % (len(reply), conn) + reply.prefix)
        self._pump()

    def _pump(self) -> None:
        reply, transport = self._out, self._transport
        if reply is None or transport is None:
            return
        self._out_progress = asyncio.get_running_loop().time()
        chunks = reply.body.chunks
        while not self._write_paused:
            if self._closed:
                self._end_stream()
                return
            if self._out_chunk >= len(chunks):
                transport.write(reply.suffix)
                self._end_stream()
                if not self._out_keep_alive:
                    transport.close()
                    self._closed = True
                    return
                self._next()
                return
            chunk = chunks[self._out_chunk]
            pos = self._out_pos
            if pos == 0 and len(chunk) <= WRITE_SLICE:
                piece: bytes | memoryview = chunk
                self._out_chunk += 1
            else:
                piece = memoryview(chunk)[pos : pos + WRITE_SLICE]
                self._out_pos = pos + len(piece)
                if self._out_pos >= len(chunk):
                    self._out_chunk += 1
                    self._out_pos = 0
            transport.write(piece)  # may call pause_writing() at once, ending this loop

    def _end_stream(self) -> None:
        if self._out is not None:
            self._out.release()
            self._out = None

    def _respond(self, body: bytes, keep_alive: bool) -> None:
        if self._transport is None or self._closed:
            return
        conn = b"keep-alive" if keep_alive else b"close"
        self._transport.write(OK_RESPONSE % (len(body), conn, body))
        if not keep_alive:
            self._transport.close()
            self._closed = True


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
    """

    def __init__(
        self,
        handler: XmlRpcHttpHandler,
        networks: list[Network] | None,
        *,
        max_connections: int = MAX_CONNECTIONS,
        max_connections_per_host: int = MAX_CONNECTIONS_PER_HOST,
        idle_timeout: float = IDLE_TIMEOUT,
    ) -> None:
        if max_connections < 1 or max_connections_per_host < 1 or idle_timeout <= 0:
            raise ValueError("connection caps must be at least 1 and the idle timeout positive")
        self._handler = handler
        self._networks = networks
        self.max_connections = max_connections
        self.max_connections_per_host = max_connections_per_host
        self.idle_timeout = idle_timeout
        self._live: set[HttpProtocol] = set()
        self._admission: Admission[HttpProtocol] = Admission(max_connections, max_connections_per_host)
        self._peers = PeerUids()
        self._pending: set[asyncio.Task[Any]] = set()
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
                "master: at most %d connections (RLIMIT_NOFILE %d); raise the limit for %d",
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
                    _ratelog.error("accept", "master: accept failed: %s", exc)
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
            "master: cannot accept (%s) with %d connections open; pausing accepts for %g s",
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
        proto = HttpProtocol(self._handler, self, host, refused, peer=peer, ours=ours)
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
            _ratelog.warning("cap", "master: refusing a connection from %s: %s", who, decision.reason)
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
                "master: all %d connection slots taken; closing the oldest idle connection of %s to admit %s",
                self._cap,
                decision.shed_from,
                host if uid is None else f"{host} (uid {uid})",
            )
            shed.close()
        conn.setblocking(False)
        self._live.add(proto)
        assert self._loop is not None
        task = self._loop.create_task(self._connect(conn, proto))
        self._pending.add(task)
        task.add_done_callback(self._pending.discard)

    async def _connect(self, conn: socket.socket, proto: HttpProtocol) -> None:
        assert self._loop is not None
        try:
            await self._loop.connect_accepted_socket(lambda: proto, conn)
        except Exception as exc:
            _ratelog.warning("connect", "master: dropping a new connection from %s: %s", proto.host, exc)
            conn.close()
            self.forget(proto)

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
                _ratelog.log(logging.INFO, "stalled", "master: closing %s: it stopped reading a big reply", proto.host)
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
        for task in list(self._pending):
            task.cancel()
        for proto in list(self._live):
            proto.abort()
        self._live.clear()
        self._admission = Admission(self._cap, self.max_connections_per_host)
        self._peers.close()
        await asyncio.sleep(0)  # let the aborted transports report connection_lost
