"""The daemon's POSIX signals, received on a thread of their own (``SignalThread``).

A blocked event loop must not hold the process past its shutdown deadline, so the signals are not asyncio
handlers: the thread hands each one to the loop and enforces the deadline itself. ``emergency_log`` writes
the one line that explains such a hard stop without logging's locks.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import threading
from collections.abc import Callable

__all__ = ["SignalThread", "emergency_log"]


class SignalThread:
    """Receives SIGTERM, SIGINT and SIGHUP with ``sigwait`` on a thread of its own.

    asyncio's signal handlers run on the event loop, so a part that blocks the loop would also block the
    shutdown it asked for. This thread hands each signal to the loop and, from the first stop request on,
    enforces the hard deadline itself: past it, ``on_deadline`` runs here (and should exit the process).
    The signals must be blocked on the main thread before any other thread starts (``main()`` does it;
    ``start()`` blocks them too), so that every thread inherits the mask and only this one receives them.
    """

    SIGNALS = frozenset({signal.SIGTERM, signal.SIGINT, signal.SIGHUP})

    def __init__(
        self,
        loop: asyncio.AbstractEventLoop,
        on_stop: Callable[[], None],
        on_reload: Callable[[], None],
        deadline: float,
        on_deadline: Callable[[], None],
    ) -> None:
        self._loop = loop
        self._on_stop = on_stop
        self._on_reload = on_reload
        self._deadline = deadline
        self._on_deadline = on_deadline
        self._done = threading.Event()
        self._closing = False
        self._old_mask: set[int | signal.Signals] | None = None
        self._thread = threading.Thread(target=self._run, name="mrosd-signals", daemon=True)

    def start(self) -> None:
        self._old_mask = signal.pthread_sigmask(signal.SIG_BLOCK, self.SIGNALS)
        self._thread.start()

    def _post(self, callback: Callable[[], None]) -> None:
        with contextlib.suppress(RuntimeError):  # the loop already closed
            self._loop.call_soon_threadsafe(callback)

    def _run(self) -> None:
        stopping = False
        while True:
            signum = signal.sigwait(self.SIGNALS)
            if self._closing:
                return
            if signum == signal.SIGHUP:
                self._post(self._on_reload)
            elif not stopping:
                stopping = True
                self._post(self._on_stop)
                if not self._done.wait(self._deadline) and not self._closing:
                    self._on_deadline()
                    return

    def close(self) -> None:
        """Stop the thread and restore the signal mask (``run()`` has finished its shutdown)."""
        self._closing = True
        self._done.set()
        if self._thread.ident is not None and self._thread.is_alive():
            with contextlib.suppress(OSError, ProcessLookupError):
                signal.pthread_kill(self._thread.ident, signal.SIGHUP)
            self._thread.join(1.0)
        if self._old_mask is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, self._old_mask)
            self._old_mask = None


def _emergency_log(message: str) -> None:
    """Write one log line without taking logging's locks (the loop thread may hold them forever)."""
    record = logging.LogRecord("mrosd", logging.ERROR, __file__, 0, message, None, None)
    handlers = logging.getLogger().handlers
    text = handlers[0].format(record) if handlers else message
    with contextlib.suppress(OSError):
        os.write(2, (text + "\n").encode(errors="replace"))


def emergency_log(message: str) -> None:
    """Write one log line without taking logging's locks (the loop thread may hold them forever)."""
    record = logging.LogRecord("mrosd", logging.ERROR, __file__, 0, message, None, None)
    handlers = logging.getLogger().handlers
    text = handlers[0].format(record) if handlers else message
    with contextlib.suppress(OSError):
        os.write(2, (text + "\n").encode(errors="replace"))
