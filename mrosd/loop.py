"""The one place that chooses the event loop: uvloop when installed, asyncio's own with ``MROSD_LOOP=asyncio``.

The daemon, ``python -m mrosd.master`` and the ``mros`` CLI all run their coroutines through
``event_loop_factory()`` (or ``run()``), so one environment variable switches every mrosd program back to the
standard loop, to debug or to rule uvloop out.
"""

from __future__ import annotations

import asyncio
import os
from collections.abc import Callable, Coroutine, Mapping
from typing import Any, TypeVar

__all__ = ["event_loop_factory", "run"]

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
    with asyncio.Runner(loop_factory=event_loop_factory(use_uvloop=use_uvloop)) as runner:
        return runner.run(main)
