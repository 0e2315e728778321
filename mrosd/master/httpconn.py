"""One client connection of the master's HTTP/1.1 server: requests parsed and answered in order.

Owns a connection's life: header blocks parsed by ``mrosd.master.httpframing``, bodies handed to the
dispatcher (``mrosd.master.dispatch``) and answered in order, pipelined requests held while a slow call runs,
backpressure both ways (a client that does not read is not read from), the request deadline
(``REQUEST_TIMEOUT``), a refused client's bounded read before its 403, and a big reply written a slice at a
time as its reader takes it. Must not know the accept loop, the caps or the other connections: its server is
seen only as a ``ConnectionOwner`` (``mrosd.master.httpserver``).
"""

from __future__ import annotations

import asyncio
import functools
import logging
import socket
from collections.abc import Coroutine
from typing import Any, Protocol, cast

from mrosd.errors import HttpRefused
from mrosd.lograte import RateLimitedLog
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
from mrosd.master.peers import Endpoint
from mrosd.xmlrpc.codec import FAULT_INTERNAL_ERROR, encode_fault

__all__ = ["MAX_REFUSED_BYTES", "REQUEST_TIMEOUT", "WRITE_SLICE", "BodyHandler", "ConnectionOwner", "HttpProtocol"]

log = logging.getLogger(__name__)
_ratelog = RateLimitedLog(log)

#: Largest body a client outside the allow-list may send before its 403 (it is read, never handled).
MAX_REFUSED_BYTES = 64 * 1024

#: Time a client has to complete a request once its first byte arrived (slowloris defence), and the longest a
#: big reply may wait for its reader to take more (a reader that stops holds the reply's share of the budget).
REQUEST_TIMEOUT = 30.0

#: A big reply (``LargeReply``) is handed to the transport this many bytes at a time, as the client reads.
WRITE_SLICE = 256 * 1024


class BodyHandler(Protocol):
    """Turns one request body into a response body, or a coroutine producing one (``dispatch``'s handler, a
    slave API's ``XmlRpcServer``)."""

    def handle(self, body: bytes) -> bytes | Coroutine[Any, Any, Reply]: ...


class ConnectionOwner(Protocol):
    """The server that accepted a connection: told once it is gone, so that its slot is free again."""

    def forget(self, proto: HttpProtocol) -> None: ...


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
        handler: BodyHandler,
        server: ConnectionOwner,
        host: str,
        refused: bool,
        *,
        peer: Endpoint = ("", 0),
        ours: Endpoint = ("", 0),
        name: str = "master",
    ) -> None:
        self._handler = handler
        #: Who serves, for the log lines ("master", "slave /talker").
        self.name = name
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
            _ratelog.warning("allow", "%s: refusing connection from %s (not in the allow-list)", self.name, self.host)
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
            logging.INFO,
            "timeout",
            "%s: closing %s: request incomplete after %g s",
            self.name,
            self.host,
            REQUEST_TIMEOUT,
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
                logging.INFO,
                "refused",
                "%s: HTTP %d to %s: %s",
                self.name,
                exc.status,
                self.host,
                exc.text.strip().decode(),
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
