"""The Python 3.11 standard-library names mrosd uses, for Python 3.10 too: one import site for each.

On 3.11 and later every name here is the standard library's own object. On 3.10 (Ubuntu 22.04, JetPack 6, the
jammy builds of ROS-O) they come from the backports ``dependencies`` names for ``python_version < '3.11'``
(``tomli``, ``typing_extensions``) or, where no backport behaves the same, from the few lines below:

- ``timeout``: ``asyncio.timeout``'s contract (``async with timeout(seconds):``, None for no limit, the builtin
  ``TimeoutError`` on expiry). async-timeout raises ``asyncio.TimeoutError``, which 3.10 does not unify with
  the builtin one that mrosd's handlers catch, so it is not used.
- ``Runner``: ``asyncio.Runner``'s (``loop_factory``, ``run``, ``get_loop``, a first Ctrl-C cancels the main
  task and re-raises as KeyboardInterrupt, ``close`` cancels what is left and shuts async generators down).
- ``wait_for``: ``asyncio.wait_for`` raising the builtin ``TimeoutError``, as it does from 3.11 on.
- ``StrEnum``: members are ``str``, and ``str()``/``format()`` give the value.

Code elsewhere imports these from here, never ``sys.version_info`` branches of its own, so that dropping 3.10
is deleting this module's second half and one sed over the imports.
"""

from __future__ import annotations

import sys

__all__ = ["Runner", "Self", "StrEnum", "timeout", "tomllib", "wait_for"]

if sys.version_info >= (3, 11):
    from asyncio import Runner, timeout, wait_for
    from enum import StrEnum
    from typing import Self

    import tomllib
else:  # pragma: no cover - exercised by CI's Python 3.10 run
    import asyncio
    import contextvars
    import enum
    import functools
    import signal
    import threading
    from collections.abc import Awaitable, Callable, Coroutine
    from types import TracebackType
    from typing import Any, TypeVar

    import tomli as tomllib
    from typing_extensions import Self

    _T = TypeVar("_T")

    class StrEnum(str, enum.Enum):
        """Members are strings; ``str(member)`` and ``format(member)`` are the value, as 3.11's ``StrEnum``."""

        def __str__(self) -> str:
            return str.__str__(self)

        def __format__(self, spec: str) -> str:
            return str.__format__(str(self), spec)

    async def wait_for(fut: Awaitable[_T], timeout: float | None) -> _T:
        """``asyncio.wait_for`` raising the builtin ``TimeoutError`` (3.10's raises ``asyncio.TimeoutError``)."""
        try:
            return await asyncio.wait_for(fut, timeout)
        except asyncio.TimeoutError as exc:
            raise TimeoutError from exc

    class timeout:
        """``async with timeout(delay):`` cancels the body after ``delay`` seconds and raises ``TimeoutError``.

        A cancellation from outside during the body stays a ``CancelledError``: only the cancel this timer
        made becomes the timeout.
        """

        def __init__(self, delay: float | None) -> None:
            self._delay = delay
            self._handle: asyncio.TimerHandle | None = None
            self._task: asyncio.Task[Any] | None = None
            self._expired = False

        async def __aenter__(self) -> timeout:
            task = asyncio.current_task()
            if task is None:
                raise RuntimeError("timeout() must be used inside a task")
            self._task = task
            if self._delay is not None:
                loop = asyncio.get_running_loop()
                self._handle = loop.call_at(loop.time() + max(self._delay, 0.0), self._expire)
            return self

        def _expire(self) -> None:
            assert self._task is not None
            if not self._task.done():
                self._expired = True
                self._task.cancel()

        def expired(self) -> bool:
            return self._expired

        async def __aexit__(
            self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
        ) -> None:
            if self._handle is not None:
                self._handle.cancel()
                self._handle = None
            if self._expired and exc_type is asyncio.CancelledError:
                raise TimeoutError from exc

    class Runner:
        """``with Runner(loop_factory=...) as runner: runner.run(coro)`` as 3.11's ``asyncio.Runner``."""

        def __init__(
            self, *, debug: bool | None = None, loop_factory: Callable[[], asyncio.AbstractEventLoop] | None = None
        ) -> None:
            self._debug = debug
            self._loop_factory = loop_factory
            self._loop: asyncio.AbstractEventLoop | None = None
            self._closed = False
            self._interrupts = 0

        def __enter__(self) -> Runner:
            self._lazy_init()
            return self

        def __exit__(
            self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
        ) -> None:
            self.close()

        def get_loop(self) -> asyncio.AbstractEventLoop:
            return self._lazy_init()

        def run(self, coro: Coroutine[Any, Any, _T], *, context: contextvars.Context | None = None) -> _T:
            loop = self._lazy_init()
            task = loop.create_task(coro) if context is None else context.run(loop.create_task, coro)
            sigint = None
            if threading.current_thread() is threading.main_thread() and (
                signal.getsignal(signal.SIGINT) is signal.default_int_handler
            ):
                sigint = functools.partial(self._on_sigint, main_task=task)
                try:
                    signal.signal(signal.SIGINT, sigint)
                except ValueError:  # not the main interpreter
                    sigint = None
            self._interrupts = 0
            try:
                return loop.run_until_complete(task)
            except asyncio.CancelledError:
                if self._interrupts > 0:
                    raise KeyboardInterrupt from None
                raise
            finally:
                if sigint is not None and signal.getsignal(signal.SIGINT) is sigint:
                    signal.signal(signal.SIGINT, signal.default_int_handler)

        def close(self) -> None:
            if self._loop is None or self._closed:
                self._closed = True
                return
            loop = self._loop
            try:
                tasks = [t for t in asyncio.all_tasks(loop) if not t.done()]
                for t in tasks:
                    t.cancel()
                if tasks:
                    loop.run_until_complete(asyncio.gather(*tasks, return_exceptions=True))
                loop.run_until_complete(loop.shutdown_asyncgens())
                loop.run_until_complete(loop.shutdown_default_executor())
            finally:
                asyncio.set_event_loop(None)
                loop.close()
                self._loop = None
                self._closed = True

        def _lazy_init(self) -> asyncio.AbstractEventLoop:
            if self._closed:
                raise RuntimeError("Runner is closed")
            if self._loop is None:
                self._loop = asyncio.new_event_loop() if self._loop_factory is None else self._loop_factory()
                if self._loop_factory is None:
                    asyncio.set_event_loop(self._loop)
                if self._debug is not None:
                    self._loop.set_debug(self._debug)
            return self._loop

        def _on_sigint(self, signum: int, frame: object, main_task: asyncio.Task[Any]) -> None:
            self._interrupts += 1
            if self._interrupts == 1 and not main_task.done():
                main_task.cancel()
                assert self._loop is not None
                self._loop.call_soon_threadsafe(lambda: None)  # wake the loop up
                return
            raise KeyboardInterrupt
