"""``mrosd.run(main)``: run an application built on mrosd nodes the way ``rospy.spin()`` ends, quietly.

``asyncio.run(main())`` turns Ctrl-C into a ``KeyboardInterrupt`` traceback, and SIGTERM (``systemctl stop``,
``docker stop``, roslaunch, ``timeout``) kills the process before any ``async with Node(...)`` has
unregistered: the master keeps the node's topics and services until its dead-node sweep (rosmaster: for
good). ``run`` instead:

- runs ``main`` on the loop mrosd prefers (``mrosd.loop``: uvloop when installed, ``MROSD_LOOP=asyncio``
  for asyncio's own);
- turns the first SIGINT or SIGTERM into the cancellation of ``main``, so every ``async with`` unwinds and
  every node unregisters from the master (each call bounded, 2 s) and closes its connections;
- lets a repeated signal (Ctrl-C pressed again while the nodes close) change nothing: the clean-up is
  bounded, and skipping it would leave the registrations behind. Only a signal that comes more than
  ``ESCAPE_AFTER`` seconds after the first (a ``main`` that ignores its cancellation) ends the process at
  once, with 128 + the signal's number, as a shell reports a killed command;
- closes, after ``main``, any node that was started while it ran and is still open (a node started with
  ``await node.start()`` and never closed);
- returns None after such a signal, so the script ends with status 0 and nothing on stderr.

``run_until_signal`` is the same runner for programs that want to know which signal stopped them (the
``mros`` CLI exits 130 after SIGINT and 143 after SIGTERM, as rostopic's shell reports them), and
``on_stop_signal`` lets a part of ``main`` take the signal itself (``mros bag record`` closes its file).

``await node.spin()`` is the wait for an application with nothing else to await: it returns when the node is
told to shut down (``rosnode kill``, a master giving its name to another node) and is cancelled by the signal.
"""

from __future__ import annotations

import asyncio
import contextlib
import inspect
import os
import signal
import sys
import time
from collections.abc import Awaitable, Callable, Coroutine, Iterator
from typing import Any, TypeVar

from mrosd import backports
from mrosd.loop import event_loop_factory

__all__ = ["CLOSE_TIMEOUT", "ESCAPE_AFTER", "STOP_SIGNALS", "Interrupted", "on_stop_signal", "run", "run_until_signal"]

T = TypeVar("T")

#: The signals that stop the application cleanly.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: Bound on closing the nodes ``main`` left open.
CLOSE_TIMEOUT = 5.0
#: A stop signal this long after the first ends the process at once: by then the bounded clean-up (a node's
#: unregistration, 2 s a call; ``CLOSE_TIMEOUT``) is over, so ``main`` is ignoring its cancellation.
ESCAPE_AFTER = 2 * CLOSE_TIMEOUT


class Interrupted(Exception):
    """``main`` was cancelled by a stop signal (``signum``)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


#: Per running loop, the callbacks ``on_stop_signal`` installed (the innermost one takes the signal).
_takers: dict[asyncio.AbstractEventLoop, list[Callable[[], None]]] = {}


@contextlib.contextmanager
def on_stop_signal(callback: Callable[[], None]) -> Iterator[None]:
    """While inside, the first stop signal calls ``callback`` (on the loop) instead of cancelling ``main``.

    For a part of ``main`` that ends itself cleanly (a recorder that closes its file and returns). Only
    under ``run``/``run_until_signal``; elsewhere (no runner owns the signals) it does nothing.
    """
    takers = _takers.get(asyncio.get_running_loop())
    if takers is None:
        yield
        return
    takers.append(callback)
    try:
        yield
    finally:
        takers.remove(callback)


def run(main: Coroutine[Any, Any, T] | Callable[[], Awaitable[T]], *, use_uvloop: bool = True) -> T | None:
    """Run ``main`` (a coroutine, or a function returning one) until it ends or SIGINT/SIGTERM stops it.

    Returns ``main``'s result, or None when a signal stopped it. Any other exception of ``main`` propagates.
    """
    try:
        return run_until_signal(main, use_uvloop=use_uvloop)
    except Interrupted:
        return None


def run_until_signal(main: Coroutine[Any, Any, T] | Callable[[], Awaitable[T]], *, use_uvloop: bool = True) -> T:
    """``run``, but a stop signal that cancelled ``main`` raises ``Interrupted`` (after the clean-up).

    A ``main`` that returned normally although a signal came (one ``on_stop_signal`` gave to a callback)
    returns its result.
    """
    with backports.Runner(loop_factory=event_loop_factory(use_uvloop=use_uvloop)) as runner:
        loop = runner.get_loop()
        before = set(_open_nodes())
        stopped: list[tuple[int, float]] = []
        task_box: list[asyncio.Task[Any]] = []
        takers: list[Callable[[], None]] = []

        def on_signal(signum: int) -> None:
            now = time.monotonic()
            if stopped:  # repeated: the bounded clean-up goes on, unless main is ignoring its cancellation
                if now - stopped[0][1] > ESCAPE_AFTER:
                    os._exit(128 + signum)
                return
            stopped.append((signum, now))
            if takers:
                takers[-1]()
            elif task_box:
                task_box[0].cancel()

        installed = []
        for signum in STOP_SIGNALS:
            try:
                loop.add_signal_handler(signum, on_signal, signum)
            except (ValueError, RuntimeError, NotImplementedError):  # not the main thread: no signals here
                continue
            installed.append(signum)

        async def supervise() -> T:
            coro = main if inspect.iscoroutine(main) else main()  # type: ignore[operator]
            task: asyncio.Task[T] = asyncio.ensure_future(coro)
            task_box.append(task)
            if stopped and not takers:  # a signal came before the task existed
                task.cancel()
            try:
                return await task
            except asyncio.CancelledError:
                if not stopped:
                    raise
                raise Interrupted(stopped[0][0]) from None
            finally:
                await _close_left_open(before)

        _takers[loop] = takers
        try:
            return runner.run(supervise())
        finally:
            _takers.pop(loop, None)
            for signum in installed:
                with contextlib.suppress(Exception):
                    loop.remove_signal_handler(signum)


def _open_nodes() -> list[Any]:
    """The nodes open now; none when the node stack was never imported (the CLI's ``mros msg`` never pays
    for aiohttp here)."""
    node_module = sys.modules.get("mrosd.tcpros.node")
    return [] if node_module is None else list(node_module.open_nodes())


async def _close_left_open(before: set[Any]) -> None:
    left = [node for node in _open_nodes() if node not in before]
    if not left:
        return
    with contextlib.suppress(TimeoutError):
        async with backports.timeout(CLOSE_TIMEOUT):
            await asyncio.gather(*(node.aclose() for node in left), return_exceptions=True)
