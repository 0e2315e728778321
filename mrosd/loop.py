"""The one place that chooses the event loop: uvloop when installed, asyncio's own with ``MROSD_LOOP=asyncio``.

The daemon, ``python -m mrosd.master`` and the ``mros`` CLI all run their coroutines through
``event_loop_factory()`` (or ``run()``), so one environment variable switches every mrosd program back to the
standard loop, to debug or to rule uvloop out. ``close_server`` closes an asyncio server without losing the
connection it accepted last (a flaw of asyncio's own loop).
"""

from __future__ import annotations

import asyncio
import os
from asyncio.selector_events import BaseSelectorEventLoop
from collections.abc import Callable, Coroutine, Mapping
from typing import Any, TypeVar

from mrosd import backports

__all__ = ["close_server", "event_loop_factory", "run"]

T = TypeVar("T")


def event_loop_factory(
    *, use_uvloop: bool = True, environ: Mapping[str, str] | None = None
) -> Callable[[], asyncio.AbstractEventLoop] | None:
    """The ``loop_factory`` for ``asyncio.Runner``: uvloop's, or None for asyncio's default loop.

    asyncio's loop is chosen when ``use_uvloop`` is False, when ``$MROSD_LOOP`` is ``asyncio``, or when uvloop
    is not installed (it is a dependency on Linux only).
    """
    env = os.environ if environ is None else environ
    if not use_uvloop or env.get("MROSD_LOOP", "uvloop") == "asyncio":
        return None
    try:
        import uvloop
    except ImportError:
        return None
    factory: Callable[[], asyncio.AbstractEventLoop] = uvloop.new_event_loop
    return factory


def run(main: Coroutine[Any, Any, T], *, use_uvloop: bool = True) -> T:
    """Run ``main`` to completion on a fresh loop from ``event_loop_factory()`` and close the loop."""
    with backports.Runner(loop_factory=event_loop_factory(use_uvloop=use_uvloop)) as runner:
        return runner.run(main)


#: Loop turns from an accepted socket to its protocol's ``connection_made`` (asyncio's accept task, then the
#: transport's callbacks), with one to spare.
_ACCEPT_TURNS = 4


async def close_server(server: asyncio.AbstractServer) -> None:
    """``server.close()``, after the connections it has already accepted have reached their protocols.

    asyncio's own loop accepts a connection in one turn and makes its transport in a task, turns later;
    Python 3.11's ``Server.close()`` in between makes that task fail on an assertion that nobody sees, and the
    accepted socket stays open, owned by no one, until the garbage collector finds it (its peer sees neither
    data nor EOF meanwhile). So accepting stops first, the connections in flight arrive, and only then does
    the server close; the caller then closes them with the rest. (uvloop closes safely, but calls
    ``connection_made`` a turn later: the same wait lets those arrive too.)
    """
    loop = asyncio.get_running_loop()
    try:
        if isinstance(loop, BaseSelectorEventLoop):
            for sock in getattr(server, "sockets", None) or ():
                loop.remove_reader(sock.fileno())
        else:
            server.close()  # uvloop: closing is safe, but connection_made still comes a turn later
        for _ in range(_ACCEPT_TURNS):
            await asyncio.sleep(0)
    finally:
        server.close()  # cancelled meanwhile or not
