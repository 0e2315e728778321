"""The sending half of a rosbridge session: control frames and fragments first, then subscription data in a
fair order (``mrosd.web.fairsend``), each message encoded as its subscription asks (JSON, CBOR, CBOR-raw,
PNG) only when it is its turn to go.

When the client negotiated permessage-deflate, aiohttp deflates what goes through it; ``png`` ops (compressed
already) and messages from ``DEFLATE_MAX_BYTES`` on are written past it, uncompressed (``_write_plain``).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import itertools
import logging
import os
import sys
import threading
import time
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

from mrosd.errors import MrosError
from mrosd.web import rosbridge as rb
from mrosd.web.fairsend import (
    DEFLATE_MAX_BYTES,
    FairSender,
    frame_head,
    is_precompressed,
    settle_deflate_writes,
)
from mrosd.web.hub import PAUSE_BYTES
from mrosd.web.queue import trim_to_budget
from mrosd.web.session import ClientSession

if TYPE_CHECKING:
    from aiohttp.abc import AbstractStreamWriter

log = logging.getLogger(__name__)

__all__ = ["PNG_INLINE_BYTES", "PNG_NICENESS", "PNG_THREADS", "RosbridgeSender", "png_op_off_loop"]


class RosbridgeSender(ClientSession):
    """The sender task of a rosbridge session (``RosbridgeSession`` sets up what is declared here)."""

    _writer: AbstractStreamWriter | None
    _fair: FairSender[str, Any]
    _request_ids: itertools.count[int]

    async def _next_message(self) -> tuple[bool, bytes, bool] | None:
        """The next frame of subscription data (binary, data, deflate it), from the subscription the fair
        sender picks."""
        now = time.monotonic()

        def ready(sub: Any) -> bool:
            return not sub.throttle_s or now - sub.last_sent >= sub.throttle_s

        while True:
            sub = self._fair.pick(self.subs, ready)
            if sub is None:
                return None
            if sub.throttle_s:
                while len(sub.queue) > 1:
                    sub.queue.drop_oldest()  # the newest waited for its turn; older ones go
            body, receipt_ns = sub.queue.get()
            sub.last_sent = now
            if sub.queue.backlog() < PAUSE_BYTES:
                self.hub.resume(sub.topic)
            if sub.compression == "cbor-raw":  # passthrough: the body is never decoded
                data = rb.publish_cbor_raw(sub.topic, body, receipt_ns)
                return True, data, len(data) < DEFLATE_MAX_BYTES and not is_precompressed(sub.msg_class._type)
            try:
                msg = sub.msg_class.deserialize(body)
            except MrosError as exc:
                log.info("web: %s: a message does not decode: %s", sub.topic, exc)
                continue
            if sub.compression == "cbor":
                data = rb.publish_cbor(sub.topic, msg)
                return True, data, len(data) < DEFLATE_MAX_BYTES and not is_precompressed(sub.msg_class._type)
            data = rb.publish_json(sub.topic, msg)
            if sub.compression == "png":
                data = await png_op_off_loop(data)
            if sub.fragment_size and len(data) > max(sub.fragment_size, rb.MIN_FRAGMENT_SIZE):
                # Made one at a time as the sender takes them (ahead of anything else), from the one text:
                # the client holds this message, not its fragments, until the last is sent.
                pieces = rb.iter_fragments(
                    data.decode(), sub.fragment_size, f"publish:{sub.topic}:{next(self._request_ids)}"
                )
                self._fragment_rest: Iterator[bytes] | None = pieces
                # The text is this client's until its last piece is sent: counted in the server's budget, and
                # its queues make room for it within the client's own.
                self._hold(len(data))
                budget = max(0, self.limits.client_bytes - self.held)
                trim_to_budget([s.queue for s in self.subs.values()], budget, sub.queue)
                return False, next(pieces), True
            # a png op is compressed already; big texts are not deflated (CPU per client, see fairsend)
            return False, data, sub.compression != "png" and len(data) < DEFLATE_MAX_BYTES

    async def _sender(self) -> None:
        try:
            await self._send_loop()
        finally:
            self._fair.close()
            settle_deflate_writes(self.ws)

    async def _write_plain(self, opcode: int, data: bytes) -> None:
        """One frame not deflated (RSV1 clear), written past aiohttp's compressor (``mrosd.web.fairsend``)."""
        writer = self._writer
        transport = writer.transport if writer is not None else None
        if writer is None or transport is None or self.ws.closed or transport.is_closing():
            raise ConnectionResetError("the client's connection is closing")
        transport.write(frame_head(opcode, len(data)))
        transport.write(data)
        if self._fair.must_drain(len(data)):
            await writer.drain()

    async def _send_loop(self) -> None:
        ws = self.ws
        plain_ok = bool(ws.compress) and self._writer is not None
        while not self._closed:
            await self._wake.wait()
            self._wake.clear()
            while not self._closed:
                deflate = True
                frame: tuple[bool, bytes, bool] | None = None
                rest: Iterator[bytes] | None = getattr(self, "_fragment_rest", None)
                piece = next(rest, None) if rest is not None else None
                if piece is not None:
                    binary, data = False, piece
                elif rest is not None:
                    self._fragment_rest = None
                    self._unhold()
                    continue
                elif self._control:
                    binary, data = self._control.pop()
                else:
                    frame = await self._next_message()
                    if frame is None:
                        break
                    binary, data, deflate = frame
                if not deflate and plain_ok:
                    await self._write_plain(0x2 if binary else 0x1, data)
                elif binary:
                    await ws.send_bytes(data)
                else:
                    await ws.send_str(data.decode())
                # not kept while the loop waits for the next one: an op is this client's own copy of a message
                # (a latched 40 MiB one replayed to each client stayed, one per client)
                del data, frame
            throttled = [s for s in self.subs.values() if len(s.queue) and s.throttle_s]
            if throttled:
                delay = min(s.throttle_s - (time.monotonic() - s.last_sent) for s in throttled)
                asyncio.get_running_loop().call_later(max(delay, 0.001), self._wake.set)


#: A ``png`` op of a JSON text up to this long is encoded on the event loop (at most about 0.2 ms); a longer one
#: in ``_png_pool``, off the loop: a 640x480 camera image takes 30-40 ms to compress, which would otherwise stop
#: every other client for that long. The encoder works in steps whose zlib calls let go of the GIL
#: (``rb.PNG_STEP``), so the loop's thread never waits long for it.
PNG_INLINE_BYTES = 16 * 1024
#: Threads that compress ``png`` ops for every rosbridge client of the process. Each session waits for its own
#: message, so at most one per client is in flight; two threads keep a crowd of png clients from using more
#: than two cores, and from holding up the loop's default executor (name lookups).
PNG_THREADS = 2
#: Nice value of those threads (Linux sets it per thread): on a busy machine the event loop's thread gets the
#: CPU first, and compression takes what is left. In ``bench web`` on 2 shared cores, a 1 ms timer on the loop
#: was then late by about as much beside png encodes as beside the JSON path (99th percentile 0.9-2.3 ms
#: against 1.3-1.4 ms; 1.0-3.6 ms at the default priority).
PNG_NICENESS = 10
_png_pool: concurrent.futures.ThreadPoolExecutor | None = None


def _png_thread_start() -> None:
    if sys.platform == "linux":
        with contextlib.suppress(OSError):  # raising one's own nice value is always allowed; be safe anyway
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), PNG_NICENESS)


async def png_op_off_loop(text: bytes) -> bytes:
    """rosbridge's ``png`` op of ``text``, compressed off the event loop when it is long."""
    global _png_pool
    if len(text) <= PNG_INLINE_BYTES:
        return rb.png_op(text)
    if _png_pool is None:
        _png_pool = concurrent.futures.ThreadPoolExecutor(
            PNG_THREADS, thread_name_prefix="mrosd-png", initializer=_png_thread_start
        )
    return await asyncio.get_running_loop().run_in_executor(_png_pool, rb.png_op, text)
