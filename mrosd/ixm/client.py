"""The IXM client API, sync (``IxmClient``) and asyncio (``AsyncIxmClient``): the paper's IxmInit/Write/Read/Free.

This module owns the client's side of a key: asking the daemon for it (``open``, IxmInit), mapping the
segment it hands over, writing (IxmWrite) and reading (IxmRead) straight in shared memory, waiting for
writes, and releasing the key (``close``, IxmFree). The daemon is only involved at open and close.

Wake-ups without polling (the paper's open point): each reader creates an eventfd and gives it to the
daemon at open; the daemon hands every writer of the key the current readers' eventfds (SCM_RIGHTS) and
publishes a generation number in the segment header whenever that set changes. A write is: take the
writers' ``flock``, seqlock-copy the value, release, then one 8-byte ``write`` to each reader's eventfd.
A reader blocks in ``poll`` (or the event loop) on its own eventfd. Readers never block the writer: a
reader that does not keep up simply sees the latest value (IXM keys hold the latest value, not a queue).

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
import fcntl
import mmap
import os
import select
import socket
import sys
import time
from collections.abc import AsyncIterator, Callable, Iterator
from typing import Any, Literal

from mrosd.config import default_ixm_socket
from mrosd.errors import IxmError, IxmPermissionError, RemoteProtocolError
from mrosd.ixm.channel import FdReader, send_frame
from mrosd.ixm.layout import SegmentLayout
from mrosd.ixm.protocol import (
    MAX_REPLY_SIZE,
    Close,
    Error,
    Hello,
    List,
    Listing,
    Open,
    Opened,
    Reply,
    Request,
    WakeList,
    decode_reply,
    encode,
)
from mrosd.ixm.types import IxmType, codec
from mrosd.spin import AdaptiveSpin, default_max_ns, loop_spinner

_now_ns = time.monotonic_ns
_yield = os.sched_yield

__all__ = ["DEFAULT_TIMEOUT", "AsyncIxmClient", "AsyncIxmKey", "IxmClient", "IxmKey"]

#: Bound on one request/reply exchange with the daemon.
DEFAULT_TIMEOUT = 5.0
_ONE = (1).to_bytes(8, sys.byteorder)

Mode = Literal["r", "w", "rw"]


def _error_from(reply: Error) -> IxmError:
    if reply.kind == "permission":
        return IxmPermissionError(reply.message)
    return IxmError(reply.message)


def _close_all(fds: list[int]) -> None:
    for fd in fds:
        with contextlib.suppress(OSError):
            os.close(fd)


def _default_name() -> str:
    return os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else f"pid{os.getpid()}"


def _open_request(
    key: str, type: str | None, count: int | None, max_size: int | None, mode: Mode
) -> tuple[Open, int | None]:
    """The Open request, and the eventfd this process will be woken through when it reads."""
    wake = "r" in mode
    efd = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC) if wake else None
    return Open(key=key, type=type, count=count, max_size=max_size, mode=mode, wake=wake), efd


def _state_from_reply(reply: Any, reader: FdReader, efd: int | None) -> _KeyState:
    """The key state for the daemon's answer to Open (shared by the sync and asyncio clients).

    Raises:
        IxmError: the daemon refused (the eventfd is closed).
        RemoteProtocolError: the daemon answered with something other than Opened.
    """
    if not isinstance(reply, Opened):
        _close_all([efd] if efd is not None else [])
        if isinstance(reply, Error):
            raise _error_from(reply)
        raise RemoteProtocolError(f"unexpected {type_name(reply)} in answer to open")
    fd = reader.take_fds(1)[0]
    targets = reader.take_fds(reply.wake)
    try:
        state = _KeyState(reply, fd, efd)
    except BaseException:
        _close_all([*targets, *([efd] if efd is not None else [])])
        raise
    state.set_targets(reply.generation, targets)
    return state


class _KeyState:
    """One open key: the mapping, the codec, the reader's eventfd, the writer's list of eventfds to signal."""

    def __init__(self, opened: Opened, fd: int, wake_fd: int | None) -> None:
        self.key = opened.key
        self.mode = opened.mode
        self.writable = "w" in opened.mode
        self.fd = fd
        try:
            size = os.fstat(fd).st_size
            prot = mmap.PROT_READ | (mmap.PROT_WRITE if self.writable else 0)
            self.map = mmap.mmap(fd, size, mmap.MAP_SHARED, prot)
        except OSError as exc:
            os.close(fd)
            raise IxmError(f"cannot map the segment of {opened.key}: {exc}") from exc
        self.layout = SegmentLayout(memoryview(self.map))
        self.type = IxmType(
            name=opened.type, count=opened.count, max_size=opened.max_size, capacity=opened.capacity,
            code=self.layout.type_code,
        )
        self.encode, self.decode = codec(self.type)
        self.wake_fd = wake_fd
        self.targets: list[int] = []
        self.generation = -1
        #: set by the owning client: reads pending WakeList pushes without blocking
        self.refresh_targets: Callable[[], None] = lambda: None
        self.last_seq = 0
        self.closed = False

    # writing ---------------------------------------------------------------------------------------------

    def write_bytes(self, data: bytes | bytearray | memoryview) -> int:
        if not self.writable:
            raise IxmError(f"{self.key} is open for reading only (mode {self.mode!r})")
        fd = self.fd
        fcntl.flock(fd, fcntl.LOCK_EX)
        try:
            seq = self.layout.write(data)
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)
        if self.wake_fd is not None:
            self.last_seq = seq  # in "rw" mode, our own write is not news to our own wait()
        if self.layout.generation != self.generation:
            # checked after the data is in place: a reader whose open completed before this point is
            # already announced by the daemon, and its eventfd is in our socket buffer
            self.refresh_targets()
        self.signal()
        return seq

    def signal(self) -> None:
        for target in self.targets:
            try:
                os.write(target, _ONE)
            except (BlockingIOError, OSError):
                pass  # a reader that never reads its eventfd only misses wake-ups it would coalesce anyway

    @contextlib.contextmanager
    def writing(self) -> Iterator[memoryview]:
        if not self.writable:
            raise IxmError(f"{self.key} is open for reading only (mode {self.mode!r})")
        if not self.type.is_raw_array:
            raise IxmError(f"{self.key} holds {self.type.describe()}: zero-copy views are for numeric arrays")
        fmt = self.type.fmt
        fcntl.flock(self.fd, fcntl.LOCK_EX)
        try:
            layout = self.layout
            seq = layout.begin_write()
            layout.copy_active_to_target(seq)  # a partial update starts from the published value
            view = layout.target(seq).cast(fmt)  # type: ignore[call-overload]
            try:
                yield view
            finally:
                view.release()
                self.layout.end_write(seq, self.type.capacity)
        finally:
            fcntl.flock(self.fd, fcntl.LOCK_UN)
        if self.layout.generation != self.generation:
            self.refresh_targets()
        self.signal()

    def set_targets(self, generation: int, fds: list[int]) -> None:
        for fd in self.targets:
            with contextlib.suppress(OSError):
                os.close(fd)
        self.targets = fds
        self.generation = generation

    # reading ---------------------------------------------------------------------------------------------

    def read(self) -> Any:
        seq, data = self.layout.read()
        self.last_seq = seq
        if seq == 0:
            return None  # never written
        return self.decode(data)

    def read_into(self, out: bytearray | memoryview) -> int:
        seq, n = self.layout.read_into(out)
        self.last_seq = seq
        return n

    def view(self) -> memoryview:
        if not self.type.is_raw_array:
            raise IxmError(f"{self.key} holds {self.type.describe()}: zero-copy views are for numeric arrays")
        _seq, slot = self.layout.active()
        view: memoryview = slot.toreadonly().cast(self.type.fmt)  # type: ignore[call-overload]
        return view

    def fresh(self) -> bool:
        seq = self.layout.seq
        return seq != self.last_seq and not seq & 1

    def drain_wake(self) -> None:
        if self.wake_fd is not None:
            with contextlib.suppress(BlockingIOError, OSError):
                os.read(self.wake_fd, 8)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self.set_targets(-1, [])
        self.layout.release()
        try:
            self.map.close()
        except BufferError as exc:
            raise IxmError(f"{self.key}: release every view() of this key before closing it") from exc
        for fd in (self.fd, self.wake_fd):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)


class _KeyBase:
    """What sync and async keys share: data access never needs the daemon."""

    _state: _KeyState

    @property
    def key(self) -> str:
        return self._state.key

    @property
    def mode(self) -> str:
        return self._state.mode

    @property
    def type(self) -> IxmType:
        return self._state.type

    @property
    def seq(self) -> int:
        """The key's write counter (``seq // 2`` writes so far; odd while a write is in progress)."""
        return self._state.layout.seq

    def read(self) -> Any:
        """IxmRead: the latest complete value, consistent (never torn); None before the first write.

        A write in progress, or one whose writer died mid-copy, is not visible: readers get the value before it.

        Raises:
            IxmError: a live writer kept overwriting the value faster than it could be copied (0.5 s).
        """
        return self._state.read()

    def read_into(self, out: bytearray | memoryview) -> int:
        """Copy the latest raw payload into ``out`` (one copy, consistent); returns its length in bytes."""
        return self._state.read_into(out)

    def view(self) -> memoryview:
        """A zero-copy, read-only memoryview of a numeric array key, typed like the array (e.g. format 'd').

        It shows the slot holding the latest value at the time of the call and does not follow later writes
        (call ``view()`` again for a newer value). That slot keeps its value through the next write and is
        overwritten from the one after: take ``s = seq`` before ``view()``; what you read was consistent if
        ``seq <= (s | 1) + 1`` after use (an unchanged ``seq`` always is). ``read_into`` gives a consistent copy.
        """
        return self._state.view()

    def writing(self) -> contextlib.AbstractContextManager[memoryview]:
        """Zero-copy write of a numeric array key: update the yielded view; readers are woken on exit.

        The view is the inactive slot, pre-filled with the published value (one internal copy), so a partial
        update keeps the other elements. Readers keep reading the previous value until the block exits; if
        the process dies inside the block, they keep it for good (until the next write).
        """
        return self._state.writing()

    def write_bytes(self, data: bytes | bytearray | memoryview) -> None:
        """Write an already-encoded payload (e.g. a serialized message) as it is."""
        self._state.write_bytes(data)

    def write(self, value: Any) -> None:
        """IxmWrite: store ``value`` and wake every reader. Never waits for readers.

        Raises:
            IxmError: the key is read-only here, or the value does not match the key's type or size.
        """
        st = self._state
        st.write_bytes(st.encode(value))


class IxmKey(_KeyBase):
    """A key opened by ``IxmClient.open``: ``read``/``write``/``wait``/iteration/``close``."""

    def __init__(self, client: IxmClient, state: _KeyState) -> None:
        self._client = client
        self._state = state
        self._poll: select.poll | None = None
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
            # eventfd signal that comes with a write caught here is drained by the next blocking wait.
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
            if not self._poll.poll(remaining) and deadline is not None and time.monotonic() >= deadline:
                if fresh():
                    return
                raise TimeoutError(f"no write to {st.key} within {timeout} s")
            st.drain_wake()

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
    """A blocking connection to the IXM daemon. Not thread-safe: use one client per thread."""

    def __init__(
        self, socket_path: str | None = None, name: str | None = None, timeout: float = DEFAULT_TIMEOUT
    ) -> None:
        self.socket_path = socket_path or default_ixm_socket()
        self.timeout = timeout
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(timeout)
        try:
            sock.connect(self.socket_path)
        except OSError as exc:
            sock.close()
            raise IxmError(f"cannot reach the IXM daemon at {self.socket_path}: {exc.strerror or exc}") from exc
        # non-blocking from here on: writers drain pushed wake lists without ever waiting; blocking waits
        # for replies go through poll() with the client's timeout
        sock.setblocking(False)
        self._sock = sock
        self._sock_poll = select.poll()
        self._sock_poll.register(sock.fileno(), select.POLLIN)
        self._reader = FdReader(sock, MAX_REPLY_SIZE)
        self._keys: dict[str, IxmKey] = {}
        self._closed = False
        self._request(Hello(name or _default_name()))

    # transport -------------------------------------------------------------------------------------------

    def _request(self, request: Request, fds: list[int] | None = None) -> Reply:
        if self._closed:
            raise IxmError("this IXM client is closed")
        frame = encode(request)
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
            raise IxmError(f"lost the IXM daemon at {self.socket_path}: {exc}") from exc

    def _next_reply(self, deadline: float | None) -> Reply | None:
        """Read until a reply that is not a push arrives (pushes are applied).

        ``deadline`` None: do not wait, return None when nothing complete is buffered.
        """
        while True:
            body = self._reader.decoder.maybe_next()
            if body is None:
                try:
                    if not self._reader.recv():
                        raise IxmError(f"the IXM daemon at {self.socket_path} closed the connection")
                except BlockingIOError:
                    if deadline is None:
                        return None
                    remaining = deadline - time.monotonic()
                    if remaining <= 0 or not self._sock_poll.poll(int(remaining * 1000) + 1):
                        raise IxmError(f"the IXM daemon did not answer within {self.timeout} s") from None
                continue
            reply = decode_reply(body)
            if isinstance(reply, WakeList):
                self._apply_wake(reply)
                continue
            return reply

    def _apply_wake(self, push: WakeList) -> None:
        fds = self._reader.take_fds(push.count)
        key = self._keys.get(push.key)
        if key is None or key._state.closed:
            for fd in fds:
                os.close(fd)
            return
        key._state.set_targets(push.generation, fds)

    def _drain_pushes(self) -> None:
        try:
            reply = self._next_reply(None)
        except OSError as exc:
            raise IxmError(f"lost the IXM daemon at {self.socket_path}: {exc}") from exc
        if reply is not None:
            raise RemoteProtocolError(f"unexpected {type(reply).__name__} from the IXM daemon")

    # API ---------------------------------------------------------------------------------------------------

    def open(
        self, key: str, type: str | None = None, count: int | None = None, max_size: int | None = None,
        mode: Mode = "r",
    ) -> IxmKey:
        """IxmInit: get access to ``key`` (created with this type if it does not exist yet).

        Readers may omit the type to take whatever the key holds.

        Raises:
            IxmPermissionError: the daemon's rules refuse this process the mode.
            IxmError: a bad type or size, a type different from the existing key's, or no daemon.
        """
        request, efd = _open_request(key, type, count, max_size, mode)
        try:
            reply = self._request(request, [efd] if efd is not None else None)
        except BaseException:
            _close_all([efd] if efd is not None else [])
            raise
        state = _state_from_reply(reply, self._reader, efd)
        state.refresh_targets = self._drain_pushes
        handle = IxmKey(self, state)
        self._keys[key] = handle
        return handle

    def list(self, key: str | None = None) -> Listing:
        """The daemon's process and segment lists (``key``: only that key)."""
        reply = self._request(List(key))
        if isinstance(reply, Error):
            raise _error_from(reply)
        if not isinstance(reply, Listing):
            raise RemoteProtocolError(f"unexpected {type_name(reply)} in answer to list")
        return reply

    def _forget(self, handle: IxmKey) -> None:
        if self._keys.get(handle.key) is handle:
            del self._keys[handle.key]
            if not self._closed:
                reply = self._request(Close(handle.key))
                if isinstance(reply, Error):
                    raise _error_from(reply)

    def close(self) -> None:
        """Release every key and disconnect (the daemon releases them anyway when the socket closes)."""
        if self._closed:
            return
        self._closed = True
        for handle in list(self._keys.values()):
            handle._state.close()
        self._keys.clear()
        # half-close and wait (bounded) for the daemon to close its end: when close() returns, the daemon
        # has released every key of this client and unlinked the segments no one else holds
        with contextlib.suppress(OSError):
            self._sock.shutdown(socket.SHUT_WR)
            deadline = time.monotonic() + min(self.timeout, 1.0)
            while time.monotonic() < deadline:
                try:
                    if not self._reader.recv():
                        break
                    self._reader.close()
                except BlockingIOError:
                    self._sock_poll.poll(max(1, int((deadline - time.monotonic()) * 1000)))
        self._reader.close()
        self._sock.close()

    def __enter__(self) -> IxmClient:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def type_name(obj: object) -> str:
    return obj.__class__.__name__


# asyncio -------------------------------------------------------------------------------------------------


class AsyncIxmKey(_KeyBase):
    """A key opened by ``AsyncIxmClient.open``. ``write``/``read`` are plain calls: they never block."""

    def __init__(self, client: AsyncIxmClient, state: _KeyState) -> None:
        self._client = client
        self._state = state
        self._event = asyncio.Event()
        self._poke = loop_spinner(client._loop).poke
        if state.wake_fd is not None:
            client._loop.add_reader(state.wake_fd, self._on_wake)

    def _on_wake(self) -> None:
        self._state.drain_wake()
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
        async with asyncio.timeout(timeout):
            while True:
                if st.fresh():
                    return st.read()
                self._event.clear()
                if st.fresh():
                    return st.read()
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
        if st.wake_fd is not None:
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
        self, socket_path: str | None = None, name: str | None = None, timeout: float = DEFAULT_TIMEOUT
    ) -> None:
        self.socket_path = socket_path or default_ixm_socket()
        self.name = name or _default_name()
        self.timeout = timeout
        self._loop = asyncio.get_running_loop()
        self._sock: socket.socket | None = None
        self._reader: FdReader | None = None
        self._keys: dict[str, AsyncIxmKey] = {}
        self._lock = asyncio.Lock()
        self._pending: asyncio.Future[Reply] | None = None
        self._closed = False

    async def connect(self) -> AsyncIxmClient:
        """Raises: IxmError when no daemon answers."""
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.setblocking(False)
        try:
            async with asyncio.timeout(self.timeout):
                await self._loop.sock_connect(sock, self.socket_path)
        except (OSError, TimeoutError) as exc:
            sock.close()
            raise IxmError(f"cannot reach the IXM daemon at {self.socket_path}: {exc}") from exc
        self._sock = sock
        self._reader = FdReader(sock, MAX_REPLY_SIZE)
        self._loop.add_reader(sock.fileno(), self._on_readable)
        await self._request(Hello(self.name))
        return self

    def _on_readable(self) -> None:
        assert self._reader is not None
        try:
            if not self._reader.recv():
                self._fail(IxmError(f"the IXM daemon at {self.socket_path} closed the connection"))
                return
            while True:
                body = self._reader.decoder.maybe_next()
                if body is None:
                    return
                reply = decode_reply(body)
                if isinstance(reply, WakeList):
                    fds = self._reader.take_fds(reply.count)
                    key = self._keys.get(reply.key)
                    if key is None or key._state.closed:
                        for fd in fds:
                            os.close(fd)
                    else:
                        key._state.set_targets(reply.generation, fds)
                elif self._pending is not None and not self._pending.done():
                    self._pending.set_result(reply)
                else:
                    raise RemoteProtocolError(f"unexpected {type_name(reply)} from the IXM daemon")
        except (BlockingIOError, InterruptedError):
            return
        except (OSError, RemoteProtocolError) as exc:
            self._fail(IxmError(f"lost the IXM daemon at {self.socket_path}: {exc}"))

    def _fail(self, exc: IxmError) -> None:
        if self._pending is not None and not self._pending.done():
            self._pending.set_exception(exc)
        self._shutdown()

    def _shutdown(self) -> None:
        if self._sock is not None:
            with contextlib.suppress(ValueError, OSError):
                self._loop.remove_reader(self._sock.fileno())
            self._sock.close()
        if self._reader is not None:
            self._reader.close()
        self._closed = True

    async def _request(self, request: Request, fds: list[int] | None = None) -> Reply:
        if self._closed or self._sock is None:
            raise IxmError("this IXM client is closed")
        async with self._lock:
            self._pending = self._loop.create_future()
            frame = encode(request)
            try:
                sent = send_frame(self._sock, frame, fds or [])
                if sent < len(frame):
                    await self._loop.sock_sendall(self._sock, frame[sent:])
                async with asyncio.timeout(self.timeout):
                    return await self._pending
            except TimeoutError as exc:
                raise IxmError(f"the IXM daemon did not answer within {self.timeout} s") from exc
            except OSError as exc:
                raise IxmError(f"lost the IXM daemon at {self.socket_path}: {exc}") from exc
            finally:
                self._pending = None

    async def open(
        self, key: str, type: str | None = None, count: int | None = None, max_size: int | None = None,
        mode: Mode = "r",
    ) -> AsyncIxmKey:
        """IxmInit; see ``IxmClient.open``."""
        request, efd = _open_request(key, type, count, max_size, mode)
        try:
            reply = await self._request(request, [efd] if efd is not None else None)
        except BaseException:
            _close_all([efd] if efd is not None else [])
            raise
        assert self._reader is not None
        state = _state_from_reply(reply, self._reader, efd)
        state.refresh_targets = self._on_readable
        handle = AsyncIxmKey(self, state)
        self._keys[key] = handle
        return handle

    async def list(self, key: str | None = None) -> Listing:
        reply = await self._request(List(key))
        if isinstance(reply, Error):
            raise _error_from(reply)
        if not isinstance(reply, Listing):
            raise RemoteProtocolError(f"unexpected {type_name(reply)} in answer to list")
        return reply

    async def _forget(self, handle: AsyncIxmKey) -> None:
        if self._keys.get(handle.key) is handle:
            del self._keys[handle.key]
            if not self._closed:
                reply = await self._request(Close(handle.key))
                if isinstance(reply, Error):
                    raise _error_from(reply)

    async def aclose(self) -> None:
        """Release every key and disconnect."""
        if self._closed:
            return
        for handle in list(self._keys.values()):
            if handle._state.wake_fd is not None:
                self._loop.remove_reader(handle._state.wake_fd)
            handle._state.close()
        self._keys.clear()
        self._shutdown()

    async def __aenter__(self) -> AsyncIxmClient:
        return await self.connect()

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()

