"""One open IXM key in this process: its mapping, the seqlocked read and write, the wake-ups it sends.

This module owns what a key does without the daemon: writing (IxmWrite: ``flock`` between writers, the
seqlock copy, then one non-blocking wake-up into each reader's pipe) and reading (IxmRead). A writer checks
after each write whether the daemon pushed a new list of readers to wake: the daemon counts its pushes in
the connection's notice page (mapped read-only here) and the connection counts those it applied; only
when the two differ does the writer read its socket.
"""

from __future__ import annotations

import contextlib
import fcntl
import mmap
import os
import time
from collections.abc import Callable, Iterator
from typing import Any

from mrosd.errors import IxmError
from mrosd.ixm.channel import drain, wake
from mrosd.ixm.layout import SegmentLayout
from mrosd.ixm.protocol import Opened
from mrosd.ixm.types import IxmType, codec

__all__ = ["KeyBase", "KeyState", "Pushes"]

_NEVER = memoryview(bytearray(8)).cast("Q")
#: Seconds a write waits for the writers' lock while another writer holds it, then fails: a writer that
#: holds it for good (stopped, hostile) must not hold every other writer of the key for good. An asyncio
#: key's write runs in the event loop, so it waits far less (the daemon's bridges write this way).
LOCK_WAIT = 0.5
ASYNC_LOCK_WAIT = 0.005


class Pushes:
    """WakeList pushes of one connection: ``sent`` (the daemon's count, in shared memory) and ``applied``."""

    __slots__ = ("_map", "applied", "sent")

    def __init__(self) -> None:
        self.sent: memoryview = _NEVER
        self.applied = 0
        self._map: mmap.mmap | None = None

    def attach(self, fd: int) -> None:
        """Map the notice page the daemon sent (read-only); the descriptor is closed."""
        try:
            self._map = mmap.mmap(fd, mmap.PAGESIZE, mmap.MAP_SHARED, mmap.PROT_READ)
        finally:
            os.close(fd)
        self.sent = memoryview(self._map)[:8].cast("Q")

    def close(self) -> None:
        if self._map is not None:
            self.sent.release()
            self.sent = _NEVER
            self._map.close()
            self._map = None


class KeyState:
    """One open key: the mapping, the codec, the reader's wake-up pipe (read end), the writer's list of
    readers' pipes (write ends) to wake."""

    def __init__(
        self, opened: Opened, fd: int, wake_fd: int | None, pushes: Pushes | None = None, lock_fd: int | None = None
    ) -> None:
        self.key = opened.key
        self.mode = opened.mode
        self.writable = "w" in opened.mode
        self.fd = fd
        #: writers serialise on this file (readers never get it, so they cannot hold writers up)
        self.lock_fd = lock_fd if lock_fd is not None else fd
        try:
            size = os.fstat(fd).st_size
            prot = mmap.PROT_READ | (mmap.PROT_WRITE if self.writable else 0)
            self.map = mmap.mmap(fd, size, mmap.MAP_SHARED, prot)
        except OSError as exc:
            os.close(fd)
            raise IxmError(f"cannot map the segment of {opened.key}: {exc}") from exc
        self.layout = SegmentLayout(memoryview(self.map))
        if self.layout.capacity != opened.capacity:
            self.layout.release()
            self.map.close()
            os.close(fd)
            raise IxmError(f"the segment of {opened.key} does not have the capacity the daemon announced")
        self.type = IxmType(
            name=opened.type,
            count=opened.count,
            max_size=opened.max_size,
            capacity=opened.capacity,
            code=self.layout.type_code,
        )
        self.encode, self.decode = codec(self.type)
        self.wake_fd = wake_fd
        self.targets: list[int] = []
        #: the connection's WakeList count: the daemon's (notice page, read-only) and the ones applied
        self.pushes = pushes if pushes is not None else Pushes()
        #: set by the owning client: reads pending WakeList pushes without blocking
        self.refresh_targets: Callable[[], None] = lambda: None
        self.last_seq = 0
        self.closed = False
        #: see LOCK_WAIT
        self.lock_wait = LOCK_WAIT

    # writing ---------------------------------------------------------------------------------------------

    def write_bytes(self, data: bytes | bytearray | memoryview) -> int:
        if not self.writable:
            raise IxmError(f"{self.key} is open for reading only (mode {self.mode!r})")
        fd = self.lock_fd
        self._lock()
        try:
            seq = self.layout.write(data)
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)
        if self.wake_fd is not None:
            self.last_seq = seq  # in "rw" mode, our own write is not news to our own wait()
        pushes = self.pushes
        if pushes.sent[0] != pushes.applied:
            # checked after the data is in place: a reader whose open completed before this point is
            # already announced by the daemon, and its wake-up pipe is in our socket buffer
            self.refresh_targets()
        self.signal()
        return seq

    def _lock(self) -> None:
        """Take the writers' lock, waiting at most ``lock_wait`` seconds (yielding, then sleeping briefly).

        Raises:
            IxmError: another writer held it all that time; the value is not written.
        """
        fd = self.lock_fd
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return
        except BlockingIOError:
            pass
        deadline = time.monotonic() + self.lock_wait
        tries = 0
        while True:
            tries += 1
            if tries < 64:
                os.sched_yield()  # an honest writer holds it for one copy: usually microseconds
            else:
                time.sleep(min(0.002, self.lock_wait / 8))
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                return
            except BlockingIOError:
                if time.monotonic() >= deadline:
                    raise IxmError(
                        f"{self.key}: another writer has held the key's lock for {self.lock_wait} s; not written"
                    ) from None

    def signal(self) -> None:
        for target in self.targets:
            wake(target)  # never blocks; a full pipe is a wake-up pending, a reader gone leaves with the next list

    @contextlib.contextmanager
    def writing(self) -> Iterator[memoryview]:
        if not self.writable:
            raise IxmError(f"{self.key} is open for reading only (mode {self.mode!r})")
        if not self.type.is_raw_array:
            raise IxmError(f"{self.key} holds {self.type.describe()}: zero-copy views are for numeric arrays")
        fmt = self.type.fmt
        self._lock()
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
            fcntl.flock(self.lock_fd, fcntl.LOCK_UN)
        if self.pushes.sent[0] != self.pushes.applied:
            self.refresh_targets()
        self.signal()

    def set_targets(self, fds: list[int]) -> None:
        for fd in self.targets:
            with contextlib.suppress(OSError):
                os.close(fd)
        self.targets = fds

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

    def drain_wake(self) -> bool:
        """Consume pending wake-ups; False once no one can wake us any more (see ``drain``)."""
        return self.wake_fd is None or drain(self.wake_fd)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self.set_targets([])
        self.layout.release()
        try:
            self.map.close()
        except BufferError as exc:
            raise IxmError(f"{self.key}: release every view() of this key before closing it") from exc
        for fd in {self.fd, self.lock_fd, self.wake_fd}:
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)


class KeyBase:
    """What sync and async keys share: data access never needs the daemon."""

    _state: KeyState

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
