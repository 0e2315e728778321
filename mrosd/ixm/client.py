"""The IXM client API, sync (``IxmClient``) and asyncio (``AsyncIxmClient``): the paper's IxmInit/Write/Read/Free.

Both are thin shells around the sans-IO ``ClientConnection`` (framing, descriptors, WakeList pushes) that
only move bytes and descriptors over the Unix socket and wait; keys (``mrosd.ixm.keys``) read and write
shared memory without the daemon, which is only involved at open and close.

Wake-ups without polling (the paper's open point): each reader creates a pipe and gives its write end to
the daemon at open; the daemon hands every writer of the key the current readers' write ends (SCM_RIGHTS)
and counts those pushes in a page the writer maps read-only. A write is: take the writers' ``flock``,
seqlock-copy the value, release, then one 1-byte ``RWF_NOWAIT`` write into each reader's pipe, which no
holder of the pipe can make blocking (``mrosd.ixm.channel``). A reader blocks in ``poll`` (or the event
loop) on its own read end. Readers never block the writer: a reader that does not
keep up simply sees the latest value (IXM keys hold the latest value, not a queue).

Before anything else a client checks who serves the socket (SO_PEERCRED): root, its own uid, or a uid in
``trusted_uids`` / ``$MROSD_IXM_TRUSTED_UIDS``; anyone else could hand it memory of their choosing.

Example::

    with IxmClient() as ixm:
        joints = ixm.open("/arm/joints", "float64", count=6, mode="w")
        joints.write([0.0] * 6)

    async with AsyncIxmClient() as ixm:
        joints = await ixm.open("/arm/joints", "float64", count=6)
        async for value in joints:
            ...
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import os
import select
import socket
import sys
import time
from collections.abc import AsyncIterator, Iterable, Iterator
from typing import Any, Literal

from mrosd import backports
from mrosd.errors import IxmError, RemoteProtocolError
from mrosd.ixm.channel import recv_with_fds, send_frame
from mrosd.ixm.connection import ClientConnection, check_daemon, close_all, error_from, open_request, trusted_uids
from mrosd.ixm.keys import ASYNC_LOCK_WAIT, KeyBase, KeyState
from mrosd.ixm.protocol import Close, Error, Hello, List, Listing, Reply, Request
from mrosd.ixm.rundir import find_ixm_socket
from mrosd.spin import AdaptiveSpin, default_max_ns, loop_spinner

_now_ns = time.monotonic_ns
_yield = os.sched_yield

__all__ = ["DEFAULT_TIMEOUT", "AsyncIxmClient", "AsyncIxmKey", "IxmClient", "IxmKey"]

#: Bound on one request/reply exchange with the daemon.
DEFAULT_TIMEOUT = 5.0
#: How often a reader no one can wake any more (its daemon is gone) looks at the key's counter, in ms.
_ORPHAN_POLL_MS = 10
_GONE = (errno.EPIPE, errno.ECONNRESET)

Mode = Literal["r", "w", "rw"]


def _default_name() -> str:
    return os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else f"pid{os.getpid()}"


def type_name(obj: object) -> str:
    return obj.__class__.__name__


def _listing(reply: Reply) -> Listing:
    if isinstance(reply, Error):
        raise error_from(reply)
    if not isinstance(reply, Listing):
        raise RemoteProtocolError(f"unexpected {type_name(reply)} in answer to list")
    return reply


class IxmKey(KeyBase):
    """A key opened by ``IxmClient.open``: ``read``/``write``/``wait``/iteration/``close``."""

    def __init__(self, client: IxmClient, state: KeyState) -> None:
        self._client = client
        self._state = state
        self._poll: select.poll | None = None
        #: every write end of our wake-up pipe is closed (the daemon is gone): poll the counter instead
        self._orphaned = False
        #: spin-then-block (mrosd.spin): how long ``wait`` watches the sequence counter before sleeping
        self._spin = AdaptiveSpin(default_max_ns())
        if state.wake_fd is not None:
            self._poll = select.poll()
            self._poll.register(state.wake_fd, select.POLLIN)

    def wait(self, timeout: float | None = None) -> Any:
        """Block until a value newer than the last one read here is written, and return it.

        Raises:
            TimeoutError: nothing new within ``timeout`` seconds.
            IxmError: the key was not opened for reading.
        """
        self.wait_written(timeout)
        return self._state.read()

    def wait_written(self, timeout: float | None = None) -> None:
        """Block until a value newer than the last one read here is written, without reading it.

        For large values: follow with ``read_into`` (one copy) or ``view``.

        Raises:
            TimeoutError: nothing new within ``timeout`` seconds.
        """
        st = self._state
        if self._poll is None:
            raise IxmError(f"{st.key} is open for writing only; open it with mode 'r' or 'rw' to wait")
        fresh = st.fresh
        if fresh():
            return
        spin = self._spin
        if spin.window_ns:
            # Watch the shared sequence counter for the window, yielding the CPU at each step: when the
            # writer is runnable on this same CPU it runs at once instead of after our window. The writer's
            # wake-up that comes with a write caught here is drained by the next blocking wait.
            end = _now_ns() + spin.window_ns
            while _now_ns() < end:
                if fresh():
                    return
                _yield()
        blocked = _now_ns()
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            if fresh():
                spin.blocked(_now_ns() - blocked)
                return
            remaining = -1 if deadline is None else max(0, int((deadline - time.monotonic()) * 1000))
            if self._orphaned:  # no one can wake us: look at the counter every few milliseconds instead
                remaining = _ORPHAN_POLL_MS if remaining < 0 else min(remaining, _ORPHAN_POLL_MS)
                time.sleep(remaining / 1000)
                ready = False
            else:
                ready = bool(self._poll.poll(remaining))
            if not ready and deadline is not None and time.monotonic() >= deadline:
                if fresh():
                    return
                raise TimeoutError(f"no write to {st.key} within {timeout} s")
            if ready and not st.drain_wake():
                self._orphaned = True

    def __iter__(self) -> Iterator[Any]:
        """Each new value as it is written (latest-value semantics: a slow loop skips values)."""
        while True:
            yield self.wait()

    def close(self) -> None:
        """IxmFree: release the key (the daemon unlinks the segment after its last holder)."""
        if not self._state.closed:
            self._state.close()
            self._client._forget(self)

    def __enter__(self) -> IxmKey:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


class IxmClient:
    """A blocking connection to the IXM daemon. Not thread-safe: use one client per thread.

    ``trusted_uids``: uids besides root and our own that may run the daemon (see ``check_daemon``).
    """

    def __init__(
        self,
        socket_path: str | None = None,
        name: str | None = None,
        timeout: float = DEFAULT_TIMEOUT,
        *,
        trusted_uids: Iterable[int] | None = None,
    ) -> None:
        self.socket_path = socket_path or find_ixm_socket()
        self.timeout = timeout
        trusted = _trusted(trusted_uids)
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(timeout)
        try:
            sock.connect(self.socket_path)
            check_daemon(sock, self.socket_path, trusted)
        except OSError as exc:
            sock.close()
            raise IxmError(f"cannot reach the IXM daemon at {self.socket_path}: {exc.strerror or exc}") from exc
        except IxmError:
            sock.close()
            raise
        # non-blocking from here on: writers drain pushed wake lists without ever waiting; blocking waits
        # for replies go through poll() with the client's timeout
        sock.setblocking(False)
        self._sock = sock
        self._sock_poll = select.poll()
        self._sock_poll.register(sock.fileno(), select.POLLIN)
        self._conn = ClientConnection()
        self._keys: dict[str, IxmKey] = {}
        self._closed = False
        try:
            hello = self._request(Hello(name or _default_name()))
            if isinstance(hello, Error):  # refused (a cap): the daemon closes the connection
                raise error_from(hello)
        except BaseException:
            self._closed = True
            self._conn.close()
            sock.close()
            raise

    # transport -------------------------------------------------------------------------------------------

    def _request(self, request: Request, fds: list[int] | None = None) -> Reply:
        if self._closed:
            raise IxmError("this IXM client is closed")
        frame = self._conn.send(request)
        deadline = time.monotonic() + self.timeout
        try:
            sent = send_frame(self._sock, frame, fds or [])
            if sent < len(frame):  # requests are < 4 KiB: only a full socket buffer gets here
                self._sock.settimeout(self.timeout)
                try:
                    self._sock.sendall(frame[sent:])
                finally:
                    self._sock.setblocking(False)
            while True:
                reply = self._next_reply(deadline)
                if reply is not None:
                    return reply
        except OSError as exc:
            if exc.errno in _GONE:
                self._raise_refusal()
            raise IxmError(f"lost the IXM daemon at {self.socket_path}: {exc}") from exc

    def _receive(self) -> None:
        """One recvmsg into the connection core; raises BlockingIOError when there is nothing."""
        data, fds = recv_with_fds(self._sock)
        self._conn.receive(data, fds)
        if not data:
            self._raise_refusal()
            raise IxmError(f"the IXM daemon at {self.socket_path} closed the connection")

    def _raise_refusal(self) -> None:
        """The daemon refused us at once (a cap) and closed: raise its one-line reason if it came."""
        with contextlib.suppress(OSError, RemoteProtocolError):
            while True:
                reply = self._conn.next_reply()
                if reply is None:
                    data, fds = recv_with_fds(self._sock, socket.MSG_DONTWAIT)
                    self._conn.receive(data, fds)
                    if not data:
                        break
                    continue
                if isinstance(reply, Error):
                    raise error_from(reply)

    def _next_reply(self, deadline: float | None) -> Reply | None:
        """Read until a reply that is not a push arrives (pushes are applied by the connection core).

        ``deadline`` None: do not wait, return None when nothing complete is buffered.
        """
        while True:
            reply = self._conn.next_reply()
            if reply is not None:
                return reply
            try:
                self._receive()
            except BlockingIOError:
                if deadline is None:
                    return None
                remaining = deadline - time.monotonic()
                if remaining <= 0 or not self._sock_poll.poll(int(remaining * 1000) + 1):
                    raise IxmError(f"the IXM daemon did not answer within {self.timeout} s") from None

    def _drain_pushes(self) -> None:
        try:
            reply = self._next_reply(None)
        except OSError as exc:
            raise IxmError(f"lost the IXM daemon at {self.socket_path}: {exc}") from exc
        if reply is not None:
            raise RemoteProtocolError(f"unexpected {type(reply).__name__} from the IXM daemon")

    # API ---------------------------------------------------------------------------------------------------

    def open(
        self,
        key: str,
        type: str | None = None,
        count: int | None = None,
        max_size: int | None = None,
        mode: Mode = "r",
    ) -> IxmKey:
        """IxmInit: get access to ``key`` (created with this type if it does not exist yet).

        Readers may omit the type to take whatever the key holds.

        Raises:
            IxmPermissionError: the daemon's rules refuse this process the mode.
            IxmError: a bad type or size, a type different from the existing key's, a cap, or no daemon.
        """
        request, efd, sent = open_request(key, type, count, max_size, mode)
        try:
            reply = self._request(request, sent)
        except BaseException:
            close_all([efd])
            raise
        finally:
            close_all(sent)  # the daemon and the writers hold the write end, never us
        state = self._conn.opened(reply, efd)
        state.refresh_targets = self._drain_pushes
        handle = IxmKey(self, state)
        self._keys[key] = handle
        return handle

    def list(self, key: str | None = None) -> Listing:
        """The keys this process's rules let it open and who holds them (``key``: only that key); root sees all."""
        return _listing(self._request(List(key)))

    def _forget(self, handle: IxmKey) -> None:
        self._conn.forget(handle._state)
        if self._keys.get(handle.key) is handle:
            del self._keys[handle.key]
            if not self._closed:
                reply = self._request(Close(handle.key))
                if isinstance(reply, Error):
                    raise error_from(reply)

    def close(self) -> None:
        """Release every key and disconnect (the daemon releases them anyway when the socket closes)."""
        if self._closed:
            return
        self._closed = True
        self._keys.clear()
        self._conn.close()
        # half-close and wait (bounded) for the daemon to close its end: when close() returns, the daemon
        # has released every key of this client and freed the segments no one else holds
        with contextlib.suppress(OSError):
            self._sock.shutdown(socket.SHUT_WR)
            deadline = time.monotonic() + min(self.timeout, 1.0)
            while time.monotonic() < deadline:
                try:
                    data, fds = recv_with_fds(self._sock)
                    close_all(fds)
                    if not data:
                        break
                except BlockingIOError:
                    self._sock_poll.poll(max(1, int((deadline - time.monotonic()) * 1000)))
                except RemoteProtocolError:
                    break
        self._sock.close()

    def __enter__(self) -> IxmClient:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def _trusted(given: Iterable[int] | None) -> frozenset[int]:
    return trusted_uids(given)


# asyncio -------------------------------------------------------------------------------------------------


class AsyncIxmKey(KeyBase):
    """A key opened by ``AsyncIxmClient.open``. ``write``/``read`` are plain calls: they never block."""

    def __init__(self, client: AsyncIxmClient, state: KeyState) -> None:
        self._client = client
        self._state = state
        self._event = asyncio.Event()
        #: see IxmKey._orphaned
        self._orphaned = False
        self._poke = loop_spinner(client._loop).poke
        state.lock_wait = ASYNC_LOCK_WAIT  # a write runs in the loop: never wait long for another writer
        if state.wake_fd is not None:
            client._loop.add_reader(state.wake_fd, self._on_wake)

    def _on_wake(self) -> None:
        if not self._state.drain_wake() and self._state.wake_fd is not None:
            # no one can wake us any more, and the pipe would stay readable: stop watching it, look instead
            self._client._loop.remove_reader(self._state.wake_fd)
            self._orphaned = True
        self._poke()
        self._event.set()

    async def wait(self, timeout: float | None = None) -> Any:
        """Wait until a value newer than the last one read here is written, and return it.

        Raises:
            TimeoutError: nothing new within ``timeout`` seconds.
        """
        st = self._state
        if st.wake_fd is None:
            raise IxmError(f"{st.key} is open for writing only; open it with mode 'r' or 'rw' to wait")
        async with backports.timeout(timeout):
            while True:
                if st.closed:  # the client lost its daemon (it closes every key then) or the key was closed
                    raise self._client._failure or IxmError(f"{st.key} is closed")
                if st.fresh():
                    return st.read()
                self._event.clear()
                if st.fresh():
                    return st.read()
                if self._orphaned:
                    await asyncio.sleep(_ORPHAN_POLL_MS / 1000)
                else:
                    await self._event.wait()

    def __aiter__(self) -> AsyncIterator[Any]:
        return self._iterate()

    async def _iterate(self) -> AsyncIterator[Any]:
        while not self._state.closed:
            yield await self.wait()

    async def close(self) -> None:
        """IxmFree."""
        st = self._state
        if st.closed:
            return
        if st.wake_fd is not None and not self._orphaned:
            self._client._loop.remove_reader(st.wake_fd)
        st.close()
        await self._client._forget(self)

    async def __aenter__(self) -> AsyncIxmKey:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()


class AsyncIxmClient:
    """An asyncio connection to the IXM daemon; ``await AsyncIxmClient.connect()`` or ``async with``."""

    def __init__(
        self,
        socket_path: str | None = None,
        name: str | None = None,
        timeout: float = DEFAULT_TIMEOUT,
        *,
        trusted_uids: Iterable[int] | None = None,
    ) -> None:
        self.socket_path = socket_path or find_ixm_socket()
        self.name = name or _default_name()
        self.timeout = timeout
        self._trusted = _trusted(trusted_uids)
        self._loop = asyncio.get_running_loop()
        self._sock: socket.socket | None = None
        self._conn = ClientConnection()
        self._keys: dict[str, AsyncIxmKey] = {}
        self._lock = asyncio.Lock()
        self._pending: asyncio.Future[Reply] | None = None
        self._closed = False
        self._failure: IxmError | None = None

    async def connect(self) -> AsyncIxmClient:
        """Raises: IxmError when no trusted daemon answers."""
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.setblocking(False)
        try:
            async with backports.timeout(self.timeout):
                await self._loop.sock_connect(sock, self.socket_path)
            check_daemon(sock, self.socket_path, self._trusted)
        except (OSError, TimeoutError) as exc:
            sock.close()
            raise IxmError(f"cannot reach the IXM daemon at {self.socket_path}: {exc}") from exc
        except IxmError:
            sock.close()
            raise
        self._sock = sock
        self._loop.add_reader(sock.fileno(), self._on_readable)
        hello = await self._request(Hello(self.name))
        if isinstance(hello, Error):  # refused (a cap): the daemon closes the connection
            self._shutdown()
            raise error_from(hello)
        return self

    def _on_readable(self) -> None:
        assert self._sock is not None
        conn = self._conn
        try:
            while True:
                data, fds = recv_with_fds(self._sock)
                conn.receive(data, fds)
                while (reply := conn.next_reply()) is not None:
                    if self._pending is not None and not self._pending.done():
                        self._pending.set_result(reply)
                    elif isinstance(reply, Error):
                        conn.refusal = reply
                    else:
                        raise RemoteProtocolError(f"unexpected {type_name(reply)} from the IXM daemon")
                if not data:
                    self._fail(IxmError(f"the IXM daemon at {self.socket_path} closed the connection"))
                    return
        except (BlockingIOError, InterruptedError):
            return
        except (OSError, RemoteProtocolError) as exc:
            self._fail(IxmError(f"lost the IXM daemon at {self.socket_path}: {exc}"))

    def _fail(self, exc: IxmError) -> None:
        if self._conn.refusal is not None:
            exc = error_from(self._conn.refusal)
        self._failure = exc
        if self._pending is not None and not self._pending.done():
            self._pending.set_exception(exc)
        self._shutdown()

    def _shutdown(self) -> None:
        if self._sock is not None:
            with contextlib.suppress(ValueError, OSError):
                self._loop.remove_reader(self._sock.fileno())
            self._sock.close()
        self._conn.close()
        self._closed = True

    async def _request(self, request: Request, fds: list[int] | None = None) -> Reply:
        if self._closed or self._sock is None:
            raise self._failure or IxmError("this IXM client is closed")
        async with self._lock:
            self._pending = self._loop.create_future()
            frame = self._conn.send(request)
            try:
                sent = send_frame(self._sock, frame, fds or [])
                if sent < len(frame):
                    await self._loop.sock_sendall(self._sock, frame[sent:])
                async with backports.timeout(self.timeout):
                    return await self._pending
            except TimeoutError as exc:
                raise IxmError(f"the IXM daemon did not answer within {self.timeout} s") from exc
            except OSError as exc:
                self._on_readable()  # a refusal may be waiting in the socket
                raise self._failure or IxmError(f"lost the IXM daemon at {self.socket_path}: {exc}") from exc
            finally:
                self._pending = None

    async def open(
        self,
        key: str,
        type: str | None = None,
        count: int | None = None,
        max_size: int | None = None,
        mode: Mode = "r",
    ) -> AsyncIxmKey:
        """IxmInit; see ``IxmClient.open``."""
        request, efd, sent = open_request(key, type, count, max_size, mode)
        try:
            reply = await self._request(request, sent)
        except BaseException:
            close_all([efd])
            raise
        finally:
            close_all(sent)  # the daemon and the writers hold the write end, never us
        state = self._conn.opened(reply, efd)
        state.refresh_targets = self._on_readable
        handle = AsyncIxmKey(self, state)
        self._keys[key] = handle
        return handle

    async def list(self, key: str | None = None) -> Listing:
        """See ``IxmClient.list``."""
        return _listing(await self._request(List(key)))

    async def _forget(self, handle: AsyncIxmKey) -> None:
        self._conn.forget(handle._state)
        if self._keys.get(handle.key) is handle:
            del self._keys[handle.key]
            if not self._closed:
                reply = await self._request(Close(handle.key))
                if isinstance(reply, Error):
                    raise error_from(reply)

    async def aclose(self) -> None:
        """Release every key and disconnect."""
        if self._closed:
            return
        for handle in list(self._keys.values()):
            if handle._state.wake_fd is not None:
                self._loop.remove_reader(handle._state.wake_fd)
        self._keys.clear()
        self._shutdown()

    async def __aenter__(self) -> AsyncIxmClient:
        return await self.connect()

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()
