"""``load_type_async``: a peer's message_definition becomes a class without costing the event loop.

The loop only looks up the cache and checks the definition's length; parsing, the bounds of
``mrosd.msg.bounds``, code generation and ``compile()`` run in one dedicated worker thread, so that a flood of
definitions cannot occupy the loop's default executor (which resolves names, among other things). Loads of
the same (type, definition) share one job, so it compiles once however many callers wait for it; at most
``MAX_PENDING_LOADS`` distinct jobs wait at a time, beyond which a load is refused at once; and a caller
waits at most ``LOAD_TIMEOUT`` seconds (the job finishes anyway and its class is cached for the next one).

The bounds are what keep the loop responsive while the worker compiles: ``compile()`` holds the GIL for the
whole of one class, and the bounds (with nested types called, not inlined, past
``mrosd.msg.codegen.writer.INLINE_MAX_FIELDS``) keep one class's source small.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import threading
from typing import Any

from mrosd import backports
from mrosd.errors import MsgTooComplexError
from mrosd.msg import bounds
from mrosd.msg.loader import cached_definition, load_type
from mrosd.msg.typestore import TypeStore, normalize_type_name

#: Distinct definitions being loaded or waiting for the worker; one more is refused at once.
MAX_PENDING_LOADS = 32
#: Seconds a caller waits for one definition's class (generous: a bounded definition takes well under 1 s).
LOAD_TIMEOUT = 10.0

_PENDING: dict[tuple[str, str], concurrent.futures.Future[type[Any]]] = {}
_PENDING_LOCK = threading.Lock()
_EXECUTOR: concurrent.futures.ThreadPoolExecutor | None = None


def _executor() -> concurrent.futures.ThreadPoolExecutor:
    global _EXECUTOR
    with _PENDING_LOCK:
        if _EXECUTOR is None:
            _EXECUTOR = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="mrosd-msg")
        return _EXECUTOR


def _job(key: tuple[str, str], store: TypeStore | None, future: concurrent.futures.Future[type[Any]]) -> None:
    # The job leaves _PENDING before its callers wake: a load that starts in between finds the class cached.
    try:
        cls = load_type(key[0], key[1], store)
    except BaseException as exc:  # handed to every caller waiting for it
        _done(key)
        future.set_exception(exc)
    else:
        _done(key)
        future.set_result(cls)


def _done(key: tuple[str, str]) -> None:
    with _PENDING_LOCK:
        _PENDING.pop(key, None)


def pending_loads() -> int:
    """How many distinct definitions are being loaded now (for tests and status)."""
    return len(_PENDING)


async def load_type_async(
    name: str, definition: str, store: TypeStore | None = None, timeout: float = LOAD_TIMEOUT
) -> type[Any]:
    """``load_type`` for code on an event loop: the same class, bounds and errors, with the work in a worker
    thread (one compile per definition however many callers ask), at most ``timeout`` seconds of waiting.

    Raises:
        MsgParseError: as ``load_type``.
        MsgNotFoundError: as ``load_type``.
        MsgTooComplexError: as ``load_type``; also when ``MAX_PENDING_LOADS`` definitions are already being
            loaded, or when the class is not ready within ``timeout`` seconds.
    """
    name = normalize_type_name(name)
    key = (name, definition)
    cls = cached_definition(key)
    if cls is not None:
        return cls
    bounds.check_definition(name, definition)
    with _PENDING_LOCK:
        future = _PENDING.get(key)
        if future is None:
            if len(_PENDING) >= MAX_PENDING_LOADS:
                raise MsgTooComplexError(
                    f"{name}: {MAX_PENDING_LOADS} message definitions are already being loaded (refused)"
                )
            future = _PENDING[key] = concurrent.futures.Future()
            start = True
        else:
            start = False
    if start:
        try:
            _executor().submit(_job, key, store, future)
        except BaseException:
            with _PENDING_LOCK:
                _PENDING.pop(key, None)
            raise
    try:
        return await backports.wait_for(asyncio.shield(asyncio.wrap_future(future)), timeout)
    except TimeoutError:
        raise MsgTooComplexError(f"{name}: message definition not loaded within {timeout:g} s (refused)") from None
