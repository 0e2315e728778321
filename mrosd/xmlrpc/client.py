"""``XmlRpcClient``: every outgoing XML-RPC call of a process part, over kept-alive connections (asyncio streams).

Owns the call's transport: the per-call timeout (connect included), connections kept alive per server and
reused (at most ``limit`` in use at once, idle ones closed after ``KEEPALIVE_TIMEOUT``), replies read to their
end but never past ``MAX_REPLY_SIZE``, and every transport failure as one ``XmlRpcError`` naming the method and
the URI. The HTTP framing is the project's one (``mrosd.master.httpframing``); the bytes of the call are
``mrosd.xmlrpc.codec``'s. Must not know what is called. No aiohttp: a node's start-up does not pay for it.
"""

from __future__ import annotations

import asyncio
import collections
import select
from typing import Any
from urllib.parse import urlsplit

from mrosd import backports
from mrosd.errors import RemoteProtocolError, XmlRpcError
from mrosd.master.httpframing import MAX_HEADER_SIZE, REQUEST_HEAD, parse_response_head
from mrosd.xmlrpc.codec import MAX_REPLY_SIZE, decode_response, encode_call

#: Default timeout for one outgoing call, connect included.
DEFAULT_TIMEOUT = 10.0

#: Seconds an idle kept-alive connection stays in the pool (servers close theirs later: the master after 60 s).
KEEPALIVE_TIMEOUT = 15.0

#: Longest line of a chunked body's framing (a size and its extensions).
_MAX_CHUNK_LINE = 1024

#: Request bodies from this size on are written after their head, not joined to it.
_SEPARATE_BODY = 64 * 1024

_Key = tuple[str, int]

#: The peer shut its sending side (Linux); POLLIN reports the same end of stream elsewhere.
_POLLRDHUP = getattr(select, "POLLRDHUP", 0)


class _Conn:
    __slots__ = ("idle_since", "reader", "writer")

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader = reader
        self.writer = writer
        self.idle_since = 0.0

    def close(self) -> None:
        self.writer.close()


class _TooBig(Exception):
    """A reply over ``MAX_REPLY_SIZE``."""


class XmlRpcClient:
    """Kept-alive connections for all outgoing XML-RPC calls of a process part.

    Create it inside a running event loop (or let the first call do so) and ``aclose()`` it.
    ``limit``: connections in use at once (further calls wait their turn, within their timeout).
    """

    def __init__(self, timeout: float = DEFAULT_TIMEOUT, limit: int = 256) -> None:
        self._timeout = timeout
        self._limit = limit
        self._slots: asyncio.Semaphore | None = None
        self._idle: dict[_Key, collections.deque[_Conn]] = {}
        self._idle_count = 0
        self._busy: set[_Conn] = set()

    async def call(self, uri: str, method: str, *params: Any, timeout: float | None = None) -> Any:
        """Call ``method`` on the server at ``uri`` and return its single result value.

        Raises:
            Fault: the server answered with a fault.
            XmlRpcError: the server is unreachable, timed out, or answered with garbage.
        """
        body = encode_call(method, params)
        limit = self._timeout if timeout is None else timeout
        try:
            async with backports.timeout(limit):
                data = await self._post(uri, body)
        except TimeoutError as exc:
            raise XmlRpcError(f"{method} at {uri}: no answer within {limit:g} s") from exc
        except _TooBig as exc:
            raise XmlRpcError(f"{method} at {uri}: {exc}") from exc
        except (
            OSError,
            ValueError,
            RemoteProtocolError,
            asyncio.IncompleteReadError,
            asyncio.LimitOverrunError,
        ) as exc:
            raise XmlRpcError(f"{method} at {uri}: {exc or type(exc).__name__}") from exc
        try:
            return decode_response(data)
        except RemoteProtocolError as exc:
            raise XmlRpcError(f"{method} at {uri}: {exc}") from exc

    async def _post(self, uri: str, body: bytes) -> bytes:
        parts = urlsplit(uri)
        if parts.scheme != "http" or not parts.hostname:
            raise ValueError(f"not an http:// URI: {uri!r}")
        host, port = parts.hostname, parts.port or 80
        authority = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
        head = REQUEST_HEAD % ((parts.path or "/").encode(), authority.encode("ascii"), len(body))
        if self._slots is None:
            self._slots = asyncio.Semaphore(self._limit)
        async with self._slots:
            key = (host, port)
            conn = self._pooled(key)  # checked just now, and nothing awaited until the request is written
            if conn is None:
                reader, writer = await asyncio.open_connection(host, port, limit=MAX_HEADER_SIZE)
                conn = _Conn(reader, writer)
            self._busy.add(conn)
            keep = False
            try:
                # Sent once, never again: once a byte is written the server may have executed the call
                # (registerPublisher, setParam), so a connection lost from here on is the call's error.
                conn.writer.write(head + body if len(body) < _SEPARATE_BODY else head)
                if len(body) >= _SEPARATE_BODY:
                    conn.writer.write(body)  # not copied into one more big bytes object
                await conn.writer.drain()
                status, length, keep_alive, chunked = await self._read_head(conn.reader)
                data = await _read_body(conn.reader, length, chunked)
                if status != 200:
                    raise ValueError(f"HTTP status {status}")
                keep = keep_alive
                return data
            finally:
                self._busy.discard(conn)
                if keep:
                    self._release(key, conn)
                else:
                    conn.close()

    @staticmethod
    async def _read_head(reader: asyncio.StreamReader) -> tuple[int, int | None, bool, bool]:
        while True:
            try:
                head = await reader.readuntil(b"\r\n\r\n")
            except asyncio.LimitOverrunError as exc:
                raise ValueError(f"HTTP response head over {MAX_HEADER_SIZE} bytes") from exc
            status, length, keep_alive, chunked = parse_response_head(head[:-4])
            if status != 100:  # an interim "100 Continue" precedes the real answer
                return status, length, keep_alive, chunked

    def _pooled(self, key: _Key) -> _Conn | None:
        idle = self._idle.get(key)
        now = asyncio.get_running_loop().time()
        while idle:
            conn = idle.pop()
            self._idle_count -= 1
            if now - conn.idle_since < KEEPALIVE_TIMEOUT and _reusable(conn):
                return conn
            conn.close()
        return None

    def _release(self, key: _Key, conn: _Conn) -> None:
        if not _reusable(conn):
            conn.close()  # closed by the server, or bytes nobody asked for: not reusable
            return
        conn.idle_since = asyncio.get_running_loop().time()
        self._idle.setdefault(key, collections.deque()).append(conn)
        self._idle_count += 1
        if self._idle_count > self._limit:  # bounded: the oldest idle connection of the fullest server goes
            fullest = max(self._idle.values(), key=len)
            fullest.popleft().close()
            self._idle_count -= 1

    async def aclose(self) -> None:
        """Close every pooled connection (and those of calls still running)."""
        conns = [conn for idle in self._idle.values() for conn in idle] + list(self._busy)
        self._idle.clear()
        self._idle_count = 0
        for conn in conns:
            conn.close()
        for conn in conns:
            try:
                await conn.writer.wait_closed()
            except (OSError, asyncio.CancelledError):
                pass

    async def __aenter__(self) -> XmlRpcClient:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()


def _reusable(conn: _Conn) -> bool:
    """True when an idle connection can carry a request: the server has neither closed it nor sent anything.

    Asks the socket too, not only the stream: a close the server made a moment ago is in the socket before the
    event loop has read it, and a request written then would be lost (or, had the server read it, executed
    without an answer). ``poll`` with no wait: any event (bytes, end of stream, error) means not reusable.
    """
    if conn.writer.is_closing() or conn.reader.at_eof() or conn.reader._buffer:  # type: ignore[attr-defined]
        return False
    sock = conn.writer.get_extra_info("socket")
    if sock is None:
        return False
    try:
        poller = select.poll()
        poller.register(sock.fileno(), select.POLLIN | select.POLLPRI | _POLLRDHUP)
        return not poller.poll(0)
    except (OSError, ValueError):
        return False


def _too_big() -> _TooBig:
    return _TooBig(f"response exceeds the {MAX_REPLY_SIZE >> 20} MiB any mrosd master sends (MAX_REPLY_SIZE)")


async def _read_body(reader: asyncio.StreamReader, length: int | None, chunked: bool) -> bytes:
    """The whole response body, never past ``MAX_REPLY_SIZE``: framed by its length, its chunks, or the EOF."""
    if length is not None:
        if length > MAX_REPLY_SIZE:
            raise _TooBig(
                f"response of {length} bytes exceeds the {MAX_REPLY_SIZE >> 20} MiB any mrosd master sends"
                " (MAX_REPLY_SIZE)"
            )
        return await reader.readexactly(length)
    if not chunked:
        data = await reader.read(MAX_REPLY_SIZE + 1)
        chunks = [data]
        size = len(data)
        while data and size <= MAX_REPLY_SIZE:
            data = await reader.read(MAX_REPLY_SIZE + 1 - size)
            chunks.append(data)
            size += len(data)
        if size > MAX_REPLY_SIZE:
            raise _too_big()
        return b"".join(chunks)
    pieces: list[bytes] = []
    size = 0
    while True:
        line = await reader.readuntil(b"\r\n")
        if len(line) > _MAX_CHUNK_LINE:
            raise ValueError("malformed chunked body")
        try:
            chunk_size = int(line.split(b";", 1)[0].strip(), 16)
        except ValueError as exc:
            raise ValueError("malformed chunked body") from exc
        if chunk_size < 0:
            raise ValueError("malformed chunked body")
        if chunk_size == 0:
            break
        size += chunk_size
        if size > MAX_REPLY_SIZE:
            raise _too_big()
        pieces.append(await reader.readexactly(chunk_size))
        if await reader.readexactly(2) != b"\r\n":
            raise ValueError("malformed chunked body")
    for _ in range(64):  # trailer fields, then the blank line
        if await reader.readuntil(b"\r\n") == b"\r\n":
            return b"".join(pieces)
    raise ValueError("malformed chunked body")
