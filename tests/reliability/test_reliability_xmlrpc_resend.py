"""The XML-RPC client never sends one call twice: it retries only a request that provably never left.

A kept-alive connection can be closed by its server at any moment. When the close is already known before
the request is written (the server's FIN is waiting in the socket), the client takes another connection and
the call goes out once. Once a byte of the request is written, the server may have read and executed it
(``registerPublisher``, ``setParam``), whatever happens to the connection afterwards: the call then fails
with one ``XmlRpcError`` and is never sent again. The server here is a real socket in a thread, so that its
close lands while the client's event loop has not looked at the connection yet.
"""

from __future__ import annotations

import socket
import threading
from collections.abc import Iterator

import pytest

from mrosd.errors import XmlRpcError
from mrosd.xmlrpc import XmlRpcClient, encode_response

WAIT = 10.0


class CountingServer:
    """A blocking HTTP/1.1 XML-RPC server in a thread: counts every request it reads (as executed) and then
    answers it kept-alive, or, from the ``drop_after``-th request on, closes the connection without an answer.
    ``close_idle()`` closes the connections waiting for their next request, as an idle timeout does."""

    def __init__(self, drop_after: int | None = None) -> None:
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.uri = f"http://127.0.0.1:{self.port}/"
        self.executed = 0
        self.connections = 0
        self.drop_after = drop_after
        self._idle: list[socket.socket] = []
        self._lock = threading.Lock()
        self._threads = [threading.Thread(target=self._accept, daemon=True)]
        self._threads[0].start()

    def _accept(self) -> None:
        while True:
            try:
                conn, _ = self.listener.accept()
            except OSError:
                return
            self.connections += 1
            t = threading.Thread(target=self._serve, args=(conn,), daemon=True)
            self._threads.append(t)
            t.start()

    def _serve(self, conn: socket.socket) -> None:
        with conn:
            f = conn.makefile("rb")
            self._waiting(conn)
            while True:
                try:
                    head = f.readline()
                except OSError:
                    return
                with self._lock:
                    if conn in self._idle:
                        self._idle.remove(conn)
                if not head:
                    return
                length = 0
                while (line := f.readline()) not in (b"\r\n", b""):
                    if line.lower().startswith(b"content-length:"):
                        length = int(line.split(b":", 1)[1])
                f.read(length)
                self.executed += 1  # the request was read whole: as far as the caller knows, it took effect
                if self.drop_after is not None and self.executed >= self.drop_after:
                    conn.shutdown(socket.SHUT_RDWR)
                    return
                body = encode_response(self.executed)
                self._waiting(conn)  # idle from before its answer is sent, so that close_idle() finds it
                conn.sendall(b"HTTP/1.1 200 OK\r\nContent-Length: %d\r\n\r\n%s" % (len(body), body))

    def _waiting(self, conn: socket.socket) -> None:
        with self._lock:
            self._idle.append(conn)

    def close_idle(self) -> None:
        """Close every connection that waits for its next request, and return once they are closed."""
        with self._lock:
            idle, self._idle = self._idle, []
        for conn in idle:
            conn.shutdown(socket.SHUT_RDWR)

    def close(self) -> None:
        self.listener.shutdown(socket.SHUT_RDWR)  # wakes the blocked accept() (close alone does not)
        self.listener.close()
        self.close_idle()
        for t in self._threads:
            t.join(WAIT)


@pytest.fixture
def server() -> Iterator[CountingServer]:
    s = CountingServer()
    yield s
    s.close()


@pytest.fixture
def dropping_server() -> Iterator[CountingServer]:
    s = CountingServer(drop_after=2)
    yield s
    s.close()


async def test_a_call_the_server_read_and_then_dropped_is_not_sent_again(dropping_server: CountingServer) -> None:
    async with XmlRpcClient(timeout=WAIT) as client:
        assert await client.call(dropping_server.uri, "registerPublisher", "/n", "/t", "T", "http://x:1/") == 1
        with pytest.raises(XmlRpcError, match="registerPublisher"):
            await client.call(dropping_server.uri, "registerPublisher", "/n", "/t", "T", "http://x:1/")
    assert dropping_server.executed == 2  # the second call once, not twice
    assert dropping_server.connections == 1


async def test_an_idle_connection_closed_at_the_moment_of_reuse_is_replaced_before_the_call_is_sent(
    server: CountingServer,
) -> None:
    async with XmlRpcClient(timeout=WAIT) as client:
        assert await client.call(server.uri, "setParam", "/n", "/p", 1) == 1
        for _ in range(3):
            # the server closes the idle connection; the client's loop does not run before the next call
            # writes, so the close is only in the socket, not yet seen by the stream
            server.close_idle()
            assert await client.call(server.uri, "setParam", "/n", "/p", 1) == server.executed
    assert server.executed == 4  # each call executed once
    assert server.connections == 4  # each on a new connection
