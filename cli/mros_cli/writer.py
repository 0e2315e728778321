"""Writing rendered output to stdout: what one event-loop turn rendered leaves together, optionally from a
writer thread (``mros topic echo``), so that rendering the next message overlaps a slow reader."""

from __future__ import annotations

import asyncio
import fcntl
import os
import queue
import select
import stat
import threading
from collections.abc import Callable
from typing import Any

__all__ = ["PIPE_SIZE", "CoalescedWriter", "grow_pipe"]

#: Pipe buffer asked for when stdout is a pipe: a 1 MB image prints ~3.6 MB, which through Linux's default
#: 64 KiB pipe costs ~60 writer/reader wake-ups per frame.
PIPE_SIZE = 1 << 20


def grow_pipe(out: Any) -> None:
    """Enlarge a pipe's buffer (Linux ``F_SETPIPE_SZ``); silently keep the default where not allowed."""
    setpipe = getattr(fcntl, "F_SETPIPE_SZ", None)
    try:
        fd = out.fileno()
        if setpipe is None or not stat.S_ISFIFO(os.fstat(fd).st_mode):
            return
        fcntl.fcntl(fd, setpipe, PIPE_SIZE)
    except (OSError, ValueError, AttributeError):
        return


#: Pieces at least this long are written as they are; shorter neighbours are joined into one piece first.
_JOIN_BELOW = 8192
#: Most pieces handed to one ``writev`` (IOV_MAX is 1024 on Linux).
_MAX_IOV = 256


def _coalesce(pieces: list[bytes | bytearray]) -> list[bytes | bytearray]:
    """``pieces`` with each run of short pieces joined (a burst of small messages becomes one write); the
    long ones (an image's ``uint8[]`` text) are kept as they are, never copied again."""
    if len(pieces) < 64:
        return pieces
    out: list[bytes | bytearray] = []
    run: list[bytes | bytearray] = []
    for piece in pieces:
        if len(piece) < _JOIN_BELOW:
            run.append(piece)
            continue
        if run:
            out.append(b"".join(run))
            run = []
        out.append(piece)
    if run:
        out.append(b"".join(run))
    return out


def _write_all(fd: int, pieces: list[bytes | bytearray]) -> None:
    """Write every piece to ``fd`` in order with ``writev`` (a blocking fd: each call writes all it is given
    unless a signal interrupts it; a non-blocking one is waited for)."""
    views = [memoryview(p) for p in pieces if p]
    first = 0
    while first < len(views):
        try:
            sent = os.writev(fd, views[first : first + _MAX_IOV])
        except BlockingIOError:
            select.select([], [fd], [])
            continue
        while sent:
            head = views[first]
            if sent >= len(head):
                sent -= len(head)
                first += 1
            else:
                views[first] = head[sent:]
                sent = 0


def _fileno(out: Any) -> int:
    try:
        fd: int = out.fileno()
    except (OSError, ValueError, AttributeError):
        return -1
    return fd


class CoalescedWriter:
    """Pieces queued during one event-loop turn leave stdout together (rostopic flushes after every message,
    which is why it falls behind fast topics). ``broken`` is set, and ``on_broken`` called, when the output
    went away: the reader closed the pipe (``mros topic echo | head``), or a write failed (then ``error`` says
    why).

    With ``background=True`` (and an ``out`` that has a file descriptor) a writer thread does the writes, so
    rendering the next messages overlaps waiting for a slow reader (a 1 MB image prints 3.6 MB: three to four
    fills of the pipe, each a wait for the reader). The thread writes to the descriptor itself, never through
    ``out``'s buffer (whose lock a daemon thread must not hold at exit); it is at most ``BACKLOG`` loop turns
    behind, after which a flush waits for it, as a blocking write would. ``close()`` waits until everything
    queued is written.
    """

    #: Loop turns of output the writer thread may be behind before ``flush`` blocks.
    BACKLOG = 2

    def __init__(self, out: Any, on_broken: Callable[[], None] | None = None, *, background: bool = False) -> None:
        self._out = out
        self._on_broken = on_broken
        grow_pipe(out)
        self._pending: list[bytes | bytearray] = []
        self._scheduled = False
        self.broken = False
        #: The error that ended the output, when it is not the reader closing the pipe.
        self.error: OSError | None = None
        self._fd = _fileno(out) if background else -1
        self._loop: asyncio.AbstractEventLoop | None = None
        self._queue: queue.Queue[list[bytes | bytearray] | None] | None = None
        self._thread: threading.Thread | None = None

    def add(self, pieces: list[bytes | bytearray]) -> None:
        """Queue pieces and make sure a flush runs at the end of this loop turn."""
        if self.broken:
            return
        self._pending.extend(pieces)
        if not self._scheduled:
            self._scheduled = True
            self._loop = asyncio.get_running_loop()
            self._loop.call_soon(self.flush)

    def flush(self) -> None:
        """Write everything queued (hand it to the writer thread, in the background mode)."""
        self._scheduled = False
        if not self._pending:
            return
        data = _coalesce(self._pending)
        self._pending = []
        if self.broken:
            return
        if self._fd < 0:
            try:
                self._out.writelines(data)
                self._out.flush()
            except OSError as exc:
                self._failed(exc)
            return
        if self._queue is None:
            try:
                self._out.flush()  # whatever went through ``out`` before goes first
            except OSError as exc:
                self._failed(exc)
                return
            self._queue = queue.Queue(self.BACKLOG)
            self._thread = threading.Thread(target=self._run, name="stdout writer", daemon=True)
            self._thread.start()
        self._queue.put(data)

    def close(self) -> None:
        """Flush, and wait until the writer thread has written everything (or the output broke)."""
        self.flush()
        if self._queue is not None and self._thread is not None:
            self._queue.put(None)
            self._thread.join()
        self._queue = self._thread = None
        self._fd = -1  # anything added later is written in the foreground

    def _run(self) -> None:
        assert self._queue is not None
        while (data := self._queue.get()) is not None:
            if self.broken:
                continue  # drain, so that a flush never waits for a thread that stopped writing
            try:
                _write_all(self._fd, data)
            except OSError as exc:
                self._failed(exc, in_thread=True)

    def _failed(self, exc: OSError, *, in_thread: bool = False) -> None:
        self.broken = True
        if not isinstance(exc, BrokenPipeError):
            self.error = exc
        if self._on_broken is None:
            return
        if not in_thread:
            self._on_broken()
            return
        try:
            if self._loop is not None:
                self._loop.call_soon_threadsafe(self._on_broken)
        except RuntimeError:  # the loop is closed: nobody is waiting any more
            pass
