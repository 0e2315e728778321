"""The master's request bodies to response bodies: a sync fast path, a reply cache, a ``MethodTable`` for the rest.

No HTTP and no sockets: ``mrosd.master.httpserver`` hands over each complete body and writes what comes back
(bytes, or a coroutine for calls that need the event loop, producing bytes or a ``LargeReply``). The XML-RPC
codec is ``mrosd.xmlrpc``.

Big replies (a getSystemState of long names, a getParam of a big namespace) cost what the client reads, once:
their value is encoded once per change of state, a chunk per turn of the event loop, and the encoded bytes are
shared by every caller (``LargeReply``: each caller's own few bytes of status around the one shared value,
written in slices as the client reads). A per-reply limit (``MAX_REPLY_SIZE``) and a budget of bytes held for
replies in all (``REPLY_BUDGET``) bound the memory; beyond either the caller gets a fault saying which, and the
master goes on.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Coroutine
from typing import Any, cast

from mrosd.errors import LocalProtocolError, RemoteProtocolError
from mrosd.lograte import RateLimitedLog
from mrosd.xmlrpc.chunks import ValueEncoder, reply_parts, response_parts
from mrosd.xmlrpc.codec import (
    FAULT_INTERNAL_ERROR,
    FAULT_PARSE_ERROR,
    INCREMENTAL_DECODE_SIZE,
    MAX_REPLY_SIZE,
    Fault,
    decode_call,
    decode_call_async,
    encode_fault,
    encode_response,
)
from mrosd.xmlrpc.methods import MethodTable

log = logging.getLogger(__name__)
_ratelog = RateLimitedLog(log)

SyncHandler = Callable[..., Any]

#: Bounds of ``XmlRpcHttpHandler``'s reply cache: entries, total reply bytes, largest request body kept.
#: When full, new replies are simply not kept until the next change of state empties the cache.
REPLY_CACHE_SIZE = 1024
REPLY_CACHE_BYTES = 16 * 1024 * 1024
REPLY_CACHE_MAX_BODY = 4096

#: Methods whose reply value may be big (the rest answer a few bytes whatever the state).
BIG_VALUE_METHODS = frozenset(
    {"getSystemState", "getParam", "subscribeParam", "getPublishedTopics", "getTopicTypes", "getParamNames"}
)
#: A value estimated above this many bytes (or with more than ``BIG_REPLY_ITEMS`` items) takes the big path.
BIG_REPLY = 1024 * 1024
BIG_REPLY_ITEMS = 20_000
#: Bytes of encoded big values the master holds at once (cached, or being written to slow readers).
REPLY_BUDGET = 256 * 1024 * 1024
#: Fault code of a reply over ``MAX_REPLY_SIZE`` or ``REPLY_BUDGET`` (xmlrpc-epi: "application error").
FAULT_REPLY_BUDGET = -32500
#: Methods whose value is part of the parameter tree, which edits namespaces in place (the registry's values are
#: built anew on each change).
_EDITED_IN_PLACE = frozenset({"getParam", "subscribeParam"})
#: Times a big value is re-read and re-encoded when the state changed while it was being encoded.
_ENCODE_ATTEMPTS = 3


def estimate_size(value: Any, limit: int = BIG_REPLY, max_items: int = BIG_REPLY_ITEMS) -> int:
    """A lower bound of ``value``'s encoded size, or ``limit + 1`` once it is over ``limit`` or has more than
    ``max_items`` items (then it is treated as big: encoding it would hold the loop as long).

    Cheap where it matters: strings count by length (O(1) each) and the walk stops at the limit, so a small
    value costs a short walk and a big one a walk of at most ``max_items`` items.
    """
    total = 0
    items = 0
    stack = [value]
    while stack:
        item = stack.pop()
        items += 1
        if items > max_items:
            return limit + 1
        if isinstance(item, str):
            total += len(item) + 32
        elif isinstance(item, list | tuple):
            total += 32
            stack.extend(item)
        elif isinstance(item, dict):
            total += 32
            for key, sub in item.items():
                total += len(key) + 40 if isinstance(key, str) else 40
                stack.append(sub)
        elif isinstance(item, bytes | bytearray):
            total += len(item) * 4 // 3 + 32
        else:
            total += 32
        if total > limit:
            return limit + 1
    return total


class SharedBody:
    """One encoded big value (chunks of bytes), held by the cache and by each connection still writing it."""

    __slots__ = ("_budget", "chunks", "holds", "size")

    def __init__(self, chunks: list[bytes], size: int, budget: ReplyBudget) -> None:
        self.chunks = chunks
        self.size = size
        self.holds = 0
        self._budget = budget

    def hold(self) -> None:
        if not self.holds:
            self._budget.held += self.size
        self.holds += 1

    def release(self) -> None:
        self.holds -= 1
        if not self.holds:
            self._budget.held -= self.size


class ReplyBudget:
    """Bytes of encoded big values held right now (each counted once, however many callers share it)."""

    __slots__ = ("held", "limit")

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.held = 0


class LargeReply:
    """A reply made of this caller's ``prefix`` and ``suffix`` around a shared encoded value.

    The writer calls ``release()`` once, when it has written it all or its connection is gone.
    """

    __slots__ = ("body", "prefix", "suffix")

    def __init__(self, prefix: bytes, body: SharedBody, suffix: bytes) -> None:
        self.prefix = prefix
        self.body = body
        self.suffix = suffix
        body.hold()

    def __len__(self) -> int:
        return len(self.prefix) + self.body.size + len(self.suffix)

    def release(self) -> None:
        self.body.release()

    def to_bytes(self) -> bytes:
        """The whole reply as one bytes object (a copy; for servers that cannot write it in slices)."""
        return b"".join([self.prefix, *self.body.chunks, self.suffix])


Reply = bytes | LargeReply


class XmlRpcHttpHandler:
    """Turns one request body into one response body: sync fast path, else the shared ``MethodTable``.

    Replies of read-only methods (``cacheable``) are kept, keyed by the exact request body, for as
    long as ``state_version()`` returns the same value: a repeated getSystemState/lookupNode/getParam
    is answered without decoding, running or encoding anything. Any change of state empties the cache.
    """

    def __init__(
        self,
        sync_methods: dict[str, SyncHandler],
        fallback: MethodTable,
        *,
        cacheable: frozenset[str] = frozenset(),
        state_version: Callable[[], object] | None = None,
    ) -> None:
        self.sync_methods = sync_methods
        self.fallback = fallback
        self._cacheable = cacheable if state_version is not None else frozenset()
        self._state_version = state_version
        self._cache: dict[bytes, bytes] = {}
        self._cache_bytes = 0
        self._cache_version: object = None
        #: Big values being encoded or encoded for the current state, by the identity of the value object
        #: (the registry and the parameter tree hand out the same object until they change; the entry keeps
        #: it alive, so the id cannot be reused meanwhile).
        self._big: dict[int, tuple[Any, asyncio.Task[SharedBody]]] = {}
        self.budget = ReplyBudget(REPLY_BUDGET)

    def handle(self, body: bytes) -> bytes | Coroutine[Any, Any, Reply]:
        """The response body, or a coroutine producing it for calls that need the event loop."""
        if self._state_version is not None:
            version = self._state_version()
            if version != self._cache_version:
                self._cache.clear()
                self._cache_bytes = 0
                self._cache_version = version
                self._forget_big()
            else:
                hit = self._cache.get(body)
                if hit is not None:
                    return hit
        if len(body) > INCREMENTAL_DECODE_SIZE:
            return self._large(body)
        try:
            method, params = decode_call(body)
        except RemoteProtocolError as exc:
            _ratelog.log(logging.INFO, "parse", "master: %s", exc)
            return encode_fault(FAULT_PARSE_ERROR, str(exc))
        return self._run(body, method, params)

    def _run(self, body: bytes, method: str, params: tuple[Any, ...]) -> bytes | Coroutine[Any, Any, Reply]:
        handler = self.sync_methods.get(method)
        if handler is None:
            return self._slow(method, params)
        try:
            reply = handler(*params)
            if method in BIG_VALUE_METHODS and _is_big(reply):
                code, status, value = reply
                reread = (lambda: handler(*params)[2]) if method in _EDITED_IN_PLACE else None
                return self._big_reply(method, value, reply_parts(code, status), reread)
            out = encode_response(reply)
        except LocalProtocolError as exc:
            return encode_fault(FAULT_INTERNAL_ERROR, str(exc))
        except Exception as exc:  # the handlers catch their own errors; this is the last guard
            log.exception("master: %s failed", method)
            return encode_fault(FAULT_INTERNAL_ERROR, f"{method}: internal error: {exc!r}")
        if (
            method in self._cacheable
            and len(body) <= REPLY_CACHE_MAX_BODY
            and len(self._cache) < REPLY_CACHE_SIZE
            and self._cache_bytes + len(out) <= REPLY_CACHE_BYTES
        ):
            self._cache[body] = out
            self._cache_bytes += len(out)
        return out

    async def _large(self, body: bytes) -> Reply:
        """A big body: decoded in slices (the loop keeps running, a close cancels it), then run as usual."""
        try:
            method, params = await decode_call_async(body)
        except RemoteProtocolError as exc:
            _ratelog.log(logging.INFO, "parse", "master: %s", exc)
            return encode_fault(FAULT_PARSE_ERROR, str(exc))
        out = self._run(body, method, params)
        return out if type(out) is bytes else await cast(Coroutine[Any, Any, Reply], out)

    async def _big_reply(
        self,
        method: str,
        value: Any,
        parts: tuple[bytes, bytes],
        reread: Callable[[], Any] | None,
        *,
        share: bool = True,
    ) -> Reply:
        """A reply with a big value: the value encoded once per state and shared by all callers.

        ``parts`` go around the encoded value (``reply_parts``, or ``response_parts`` for a bare value);
        ``reread`` gives the value again if the state changes while it is encoded (None: the value is a
        snapshot nobody edits, such as the registry's, so a change does not matter). ``share``: the value is
        an object the state hands to every caller until it changes (not one built for this call alone,
        which would only hold its bytes in the budget until the next change).
        """
        try:
            if share:
                shared = await self._shared_body(value, reread)
            else:
                shared = await self._build(None, value, reread)
        except _OverBudget as exc:
            _ratelog.warning("budget", "master: %s: %s", method, exc)
            return encode_fault(FAULT_REPLY_BUDGET, f"{method}: {exc}")
        except LocalProtocolError as exc:
            return encode_fault(FAULT_INTERNAL_ERROR, str(exc))
        return LargeReply(parts[0], shared, parts[1])

    async def _shared_body(self, value: Any, reread: Callable[[], Any] | None) -> SharedBody:
        """The encoded value: built once (by a task of its own, so no caller's cancellation stops it), shared."""
        key = id(value)
        entry = self._big.get(key)
        if entry is None or entry[0] is not value:
            if self.budget.held + BIG_REPLY > self.budget.limit:
                raise _OverBudget(self._busy_text())
            task = asyncio.get_running_loop().create_task(self._build(key, value, reread))
            entry = (value, task)
            self._big[key] = entry
        return await asyncio.shield(entry[1])

    async def _build(self, key: int | None, value: Any, reread: Callable[[], Any] | None) -> SharedBody:
        this = asyncio.current_task() if key is not None else None
        try:
            chunks, size = await self._encode(value, reread)
            if size > MAX_REPLY_SIZE:
                raise _OverBudget(_too_big_text())
            if self.budget.held + size > self.budget.limit:
                raise _OverBudget(self._busy_text())
        except BaseException:
            if key is not None and self._big.get(key, (None, None))[1] is this:
                del self._big[key]
            raise
        shared = SharedBody(chunks, size, self.budget)
        if key is not None and self._big.get(key, (None, None))[1] is this:
            shared.hold()  # the cache's hold, released by _forget_big; else the state changed meanwhile
        return shared

    def _busy_text(self) -> str:
        return (
            f"the master holds {self.budget.held >> 20} MiB of replies for slow readers already"
            f" (REPLY_BUDGET {self.budget.limit >> 20} MiB); retry later"
        )

    async def _encode(self, value: Any, reread: Callable[[], Any] | None) -> tuple[list[bytes], int]:
        """The value's encoded chunks, a chunk per turn of the event loop (each a millisecond or so of work).

        Other calls run between chunks. The registry's values are snapshots, never edited; a parameter tree's
        namespace is edited in place, so when the state changes meanwhile its value is read again
        (``reread``) and encoding starts over, at most ``_ENCODE_ATTEMPTS`` times, the last one in one go.
        (A worker thread instead would make every loop wake-up wait for the GIL: getPid took 185 ms.)
        """
        version = self._state_version if self._state_version is not None and reread is not None else _no_version
        for _ in range(_ENCODE_ATTEMPTS):
            before = version()
            encoder = ValueEncoder(value, MAX_REPLY_SIZE)
            try:
                while encoder.step():
                    await asyncio.sleep(0)
                    if version() != before:
                        break
                else:
                    return encoder.chunks, encoder.size
            except RuntimeError:  # a dict changed size between two chunks
                pass
            if reread is not None:
                value = reread()
        encoder = ValueEncoder(value, MAX_REPLY_SIZE)
        while encoder.step():
            pass
        return encoder.chunks, encoder.size

    def _forget_big(self) -> None:
        """The state changed: cached big bodies go (those still being written stay until their writers finish)."""
        for _, task in self._big.values():
            if task.done() and not task.cancelled() and task.exception() is None:
                task.result().release()
        self._big.clear()

    def close(self) -> None:
        """Drop cached big bodies and cancel encodings under way."""
        for _, task in self._big.values():
            task.cancel()
        self._forget_big()

    async def _slow(self, method: str, params: tuple[Any, ...]) -> Reply:
        """Calls that need the loop (waitSystemStateChange) and multicalls, whose results may be big too (a
        multicall of N getParam of one big key is N times it): those go through the same budgets."""
        try:
            result = await self.fallback.call(method, params)
            if estimate_size(result) > BIG_REPLY:
                if method == "waitSystemStateChange" and _is_big(result):
                    # the graph's one snapshot per version (never edited): shared like getSystemState's
                    code, status, value = result
                    return await self._big_reply(method, value, reply_parts(code, status), None)
                return await self._big_reply(method, result, response_parts(), lambda: result, share=False)
            return encode_response(result)
        except Fault as exc:
            return encode_fault(exc.code, exc.message)
        except LocalProtocolError as exc:
            return encode_fault(FAULT_INTERNAL_ERROR, str(exc))


class _OverBudget(Exception):
    """A big reply refused for ``MAX_REPLY_SIZE`` or ``REPLY_BUDGET``; the message goes to the caller."""


def _no_version() -> None:
    return None


def _too_big_text() -> str:
    return f"the reply exceeds MAX_REPLY_SIZE ({MAX_REPLY_SIZE >> 20} MiB); ask for less (e.g. a sub-key)"


def _is_big(reply: Any) -> bool:
    return type(reply) is tuple and len(reply) == 3 and reply[0] == 1 and estimate_size(reply[2]) > BIG_REPLY
