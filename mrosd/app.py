"""``mrosd.run(main)``: run an application built on mrosd nodes the way ``rospy.spin()`` ends, quietly.

``asyncio.run(main())`` turns Ctrl-C into a ``KeyboardInterrupt`` traceback, and SIGTERM (``systemctl stop``,
``docker stop``, roslaunch) kills the process before any ``async with Node(...)`` has unregistered: the
master keeps the node's topics and services until its dead-node sweep. ``run`` instead:

- runs ``main`` on the loop mrosd prefers (``mrosd.loop``: uvloop when installed, ``MROSD_LOOP=asyncio``
  for asyncio's own);
- turns the first SIGINT or SIGTERM into the cancellation of ``main``, so every ``async with`` unwinds and
  every node unregisters from the master (each call bounded, 2 s) and closes its connections;
- closes, after ``main``, any node that was started while it ran and is still open (a node started with
  ``await node.start()`` and never closed);
- returns None after such a signal, so the script ends with status 0 and nothing on stderr. A second signal
  while closing gives up at once (status 130 for SIGINT, 143 for SIGTERM, as a shell reports them).

``await node.spin()`` is the wait for an application with nothing else to await: it returns when the node is
told to shut down (``rosnode kill``, a master giving its name to another node) and is cancelled by the signal.
"""

from __future__ import annotations

import asyncio
import contextlib
import inspect
import os
import signal
from collections.abc import Awaitable, Callable, Coroutine
from typing import Any, TypeVar

from mrosd.loop import event_loop_factory

__all__ = ["CLOSE_TIMEOUT", "STOP_SIGNALS", "run"]

T = TypeVar("T")

#: The signals that stop the application cleanly.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: Bound on closing the nodes ``main`` left open.
CLOSE_TIMEOUT = 5.0


def run(main: Coroutine[Any, Any, T] | Callable[[], Awaitable[T]], *, use_uvloop: bool = True) -> T | None:
    """Run ``main`` (a coroutine, or a function returning one) until it ends or SIGINT/SIGTERM stops it.

    Returns ``main``'s result, or None when a signal stopped it. Any other exception of ``main`` propagates.
    """
    from mrosd.tcpros.node import open_nodes

    with asyncio.Runner(loop_factory=event_loop_factory(use_uvloop=use_uvloop)) as runner:
        loop = runner.get_loop()
        before = set(open_nodes())
        stopped: list[int] = []
        task_box: list[asyncio.Task[Any]] = []

        def on_signal(signum: int) -> None:
            if stopped:  # a second signal: the user does not want to wait for the clean-up
                os._exit(128 + signum)
            stopped.append(signum)
            if task_box:
                task_box[0].cancel()

        installed = []
        for signum in STOP_SIGNALS:
            try:
                loop.add_signal_handler(signum, on_signal, signum)
            except (ValueError, RuntimeError, NotImplementedError):  # not the main thread: no signals here
                continue
            installed.append(signum)

        async def supervise() -> T | None:
            coro = main if inspect.iscoroutine(main) else main()  # type: ignore[operator]
            task: asyncio.Task[T] = asyncio.ensure_future(coro)
            task_box.append(task)
            if stopped:  # a signal came before the task existed
                task.cancel()
            try:
                return await task
            except asyncio.CancelledError:
                if not stopped:
                    raise
                return None
            finally:
                await _close_left_open(before)

        try:
            return runner.run(supervise())
        finally:
            for signum in installed:
                with contextlib.suppress(Exception):
                    loop.remove_signal_handler(signum)


async def _close_left_open(before: set[Any]) -> None:
    from mrosd.tcpros.node import open_nodes

    left = [node for node in open_nodes() if node not in before]
    if not left:
        return
    with contextlib.suppress(TimeoutError):
        async with asyncio.timeout(CLOSE_TIMEOUT):
            await asyncio.gather(*(node.aclose() for node in left), return_exceptions=True)
