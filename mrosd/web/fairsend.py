"""What both servers' senders share to be fair to a client over a slow link: the deficit round robin of its
subscriptions (``mrosd.web.delivery``), the gate that hands a big message to the socket only when the link is
clear, the frames written past aiohttp's compressor, and the per-topic delivery counts.

Why a gate on big messages: a camera frame written to the socket sits in the kernel's send buffer (Linux
autotunes it up to 4 MiB, seconds of a Wi-Fi link) and in the transport's buffer until it has crossed the link;
frames queued there cannot be replaced by newer ones, so a client would see frames seconds old. The next big
message is handed over only when what the socket has not yet delivered (the transport's buffer plus the
kernel's unacknowledged bytes, ``TIOCOUTQ``) is under 50 ms of the link's delivery rate (measured on how
fast the last big frame went), and never less than ``LINK_CLEAR_BYTES``: a fast link (loopback) stays busy,
a slow one holds one frame in flight. Until then the frames wait in OUR queue and small topics go ahead of
them; once the link clears, the newest goes and the older ones are dropped (counted). While the link keeps up
they go in order: a loop that reads two frames at once must not drop one. No event says that the kernel's
queue has drained, so a held-back message is retried on a timer, when the excess should have gone at the
delivery rate (0.5 to 16 ms), and on every wake-up of the sender.

Why some frames bypass aiohttp's writer: once permessage-deflate is negotiated, aiohttp deflates every message
it sends (its per-message ``compress`` argument picks another window size, never "off"). A message that is
already compressed (a JPEG or PNG ``CompressedImage``, a rosbridge ``png`` op) or big (deflate at level 1 costs
7 ms per MB of odometry and 19-23 ms per MB of point clouds or camera noise on this machine's cores, which
shrink to 0.7 and 1.0: a 2.7 MB camera frame at 30 Hz would take most of a core per client for next to
nothing) is written as an uncompressed frame (RSV1 clear, which RFC 7692 allows per message), by us, with the
head before the payload and no copy of it. The level is aiohttp's, 1: ``python -m bench web --link 20mbit``
measures levels 1, 6 and 9 on the bridges' payloads, and 6 saves 1 % of odometry's bytes for 1.6x the CPU,
9 for 7x. aiohttp's compressor keeps its own window: frames it did not compress are not part of its stream,
so the client's inflater stays in step.
"""

from __future__ import annotations

import asyncio
import contextlib
import fcntl
import struct
import termios
import time
from collections.abc import Callable, Hashable, Mapping
from typing import TYPE_CHECKING, Any, Generic, Protocol, TypeVar

from mrosd.web.delivery import BIG_MESSAGE_BYTES, DeficitRoundRobin

if TYPE_CHECKING:
    from mrosd.web.queue import ByteQueue

__all__ = [
    "DEFLATE_MAX_BYTES",
    "IN_FLIGHT_BYTES",
    "LINK_CLEAR_BYTES",
    "FairSender",
    "frame_head",
    "is_precompressed",
    "unsent_bytes",
]

#: A big message goes to the socket only when less than this is still to be delivered: 0.1 s of a 20 Mbit/s
#: link, about 1 ms of loopback (where it does not hold anything back: a reading client acknowledges at once).
LINK_CLEAR_BYTES = 256 * 1024
#: Messages from this size on are never deflated (see the module's docstring): the CPU a client can make the
#: daemon spend on deflate is then at most its small topics' rates, not its cameras'.
DEFLATE_MAX_BYTES = BIG_MESSAGE_BYTES
#: message types whose payload is already compressed (deflating it again costs CPU and saves nothing)
PRECOMPRESSED_TYPES = frozenset({"sensor_msgs/CompressedImage", "theora_image_transport/Packet"})
#: Bytes of small frames a sender may have in flight (written, not yet acknowledged) beyond the big message
#: on the wire before it waits for the transport to drain: a big frame takes a second to cross a Wi-Fi link,
#: and the small topics' messages of that second go behind it rather than wait in the sender (a rosbridge
#: client's ``queue_length`` of 1 would otherwise drop them). aiohttp's writer gets the same limit.
IN_FLIGHT_BYTES = 1024 * 1024
#: How much of the link's measured delivery rate may be in flight before the next big message: 50 ms of it
#: (over 20 Mbit/s that is below ``LINK_CLEAR_BYTES``, which then holds; over loopback, megabytes: a fast link
#: is kept busy), at most ``MAX_CLEAR_BYTES`` (the transport's buffer is memory of ours).
CLEAR_SECONDS = 0.05
MAX_CLEAR_BYTES = 16 * 1024 * 1024
_POLL_MIN = 0.0005
_POLL_MAX = 0.016
#: the shortest time over which the delivery rate is measured
_RATE_SAMPLE = 0.002
_OUTQ = struct.Struct("i")


def is_precompressed(msg_type: str) -> bool:
    return msg_type in PRECOMPRESSED_TYPES


def unsent_bytes(transport: asyncio.BaseTransport | None) -> int:
    """Bytes written to ``transport`` that the peer has not yet acknowledged: the transport's own buffer plus
    the kernel's send queue (``TIOCOUTQ``, as ``SIOCOUTQ``: unsent and unacknowledged bytes of a TCP socket)."""
    if transport is None:
        return 0
    size = 0
    with contextlib.suppress(AttributeError, NotImplementedError):
        size = transport.get_write_buffer_size()  # type: ignore[attr-defined]
    sock = transport.get_extra_info("socket")
    if sock is not None:
        with contextlib.suppress(OSError, ValueError):
            size += _OUTQ.unpack(fcntl.ioctl(sock.fileno(), termios.TIOCOUTQ, b"\0\0\0\0"))[0]
    return size


def frame_head(opcode: int, length: int) -> bytes:
    """The head of an unmasked, uncompressed (RSV1 clear) final WebSocket frame of ``length`` payload bytes."""
    first = 0x80 | opcode
    if length < 126:
        return struct.pack("!BB", first, length)
    if length < 65536:
        return struct.pack("!BBH", first, 126, length)
    return struct.pack("!BBQ", first, 127, length)


class _Lane(Protocol):
    """A subscription as the fair sender sees it: its queue and its counts."""

    queue: ByteQueue[Any]
    sent: int


K = TypeVar("K", bound=Hashable)
S = TypeVar("S", bound=_Lane)


class FairSender(Generic[K, S]):
    """One client's fair-delivery state; its session's sender task asks ``pick`` for each message."""

    __slots__ = (
        "_behind",
        "_big",
        "_interval",
        "_poll",
        "_sent_at",
        "_sent_unsent",
        "_wake",
        "drr",
        "rate",
        "transport",
    )

    def __init__(self, wake: Callable[[], None]) -> None:
        self.drr: DeficitRoundRobin[K] = DeficitRoundRobin()
        self._wake = wake
        self._poll: asyncio.TimerHandle | None = None
        self._interval = _POLL_MIN
        #: the size of the last big frame written (what may be on the wire ahead of small ones)
        self._big = 0
        #: big subscriptions held back by the link since their last message went: the newest of theirs goes next
        self._behind: set[K] = set()
        #: the link's delivery rate, bytes/s, measured on the last big frame (0: not known yet)
        self.rate = 0.0
        #: when the last big frame was written, and what was then undelivered (the rate's sample)
        self._sent_at = 0.0
        self._sent_unsent = 0
        #: the client's connection (None: no gate, e.g. a test's fake socket)
        self.transport: asyncio.BaseTransport | None = None

    @staticmethod
    def queued(queue: ByteQueue[Any], size: int) -> None:
        """Called after a message of ``size`` bytes was put on ``queue``: from the first big message on, the
        queue is big (its frames wait for a clear link, and only the newest goes once the client fell behind)."""
        if size >= BIG_MESSAGE_BYTES:
            queue.big = True

    def must_drain(self, size: int) -> bool:
        """After a frame of ``size`` bytes was written past aiohttp's writer: wait for the transport to drain?

        After a big frame only on a fast link, one that delivers the frame within ``CLEAR_SECONDS`` at its
        measured rate (loopback, wired): the wait is short and ends on the transport's own event, and the next
        frame then finds the transport's buffer empty and goes to the kernel without being copied into it
        (holding frames back on the gate's timer instead kept megabytes in that buffer: 20 % of loopback's
        1 MB rate). On a slow link the gate holds the next big frame back until the link is clear, and small
        ones go meanwhile. After a small frame only when more than ``IN_FLIGHT_BYTES`` beyond the last big
        frame are still to be delivered (the client is not reading at all, or the small topics alone exceed
        the link).
        """
        if size >= BIG_MESSAGE_BYTES:
            self._big = size
            self._sent_at = time.monotonic()
            self._sent_unsent = unsent_bytes(self.transport)
            return self.rate * CLEAR_SECONDS >= size
        return unsent_bytes(self.transport) > self._big + IN_FLIGHT_BYTES

    def clear_bytes(self) -> int:
        """What may still be undelivered when the next big message is handed over (``CLEAR_SECONDS``)."""
        return int(min(MAX_CLEAR_BYTES, max(LINK_CLEAR_BYTES, self.rate * CLEAR_SECONDS)))

    def link_clear(self) -> bool:
        unsent = unsent_bytes(self.transport)
        if unsent < LINK_CLEAR_BYTES:
            return True
        self._measure(unsent)
        allowed = self.clear_bytes()
        if unsent < allowed:
            return True
        # retried when the excess should have gone at that rate (a timer: no event says so)
        wait = (unsent - allowed) / self.rate if self.rate else _POLL_MAX
        self._interval = min(max(wait, _POLL_MIN), _POLL_MAX)
        return False

    def _measure(self, unsent: int) -> None:
        """The delivery rate since the last big frame was written: what of it has gone, per second. Small
        frames written since count as not delivered, and an idle moment counts as time: an underestimate,
        which holds big frames back a little longer, never one that lets frames pile up in the kernel."""
        elapsed = time.monotonic() - self._sent_at
        delivered = self._sent_unsent - unsent
        if self._sent_at and elapsed >= _RATE_SAMPLE and delivered > 0:
            self.rate = delivered / elapsed

    def pick(self, subs: Mapping[K, S], ready: Callable[[S], bool] | None = None) -> S | None:
        """The subscription whose oldest message goes next (the caller takes it off the queue), or None.

        ``ready(sub)``: False while a subscription may not send (throttled). A big subscription waits for a
        clear link; while one waits and nothing else can go, the sender is woken again on a timer.
        """
        clear: bool | None = None
        blocked = False

        def head(key: K) -> int | None:
            nonlocal clear, blocked
            sub = subs[key]
            size = sub.queue.peek_size()
            if size is None or (ready is not None and not ready(sub)):
                return None
            if sub.queue.big:
                if clear is None:
                    clear = self.link_clear()
                if not clear:
                    blocked = True
                    self._behind.add(key)
                    return None
                if key in self._behind:
                    # the client fell behind while these waited: the newest goes, the older ones are dropped
                    self._behind.discard(key)
                    sub.queue.keep_newest()
                    size = sub.queue.peek_size()
            return size

        key = self.drr.pick(subs, head)
        if key is None:
            if blocked and self._poll is None:
                self._poll = asyncio.get_running_loop().call_later(self._interval, self._poll_due)
            return None
        sub = subs[key]
        sub.sent += 1
        return sub

    def _poll_due(self) -> None:
        self._poll = None
        self._wake()

    def close(self) -> None:
        if self._poll is not None:
            self._poll.cancel()
            self._poll = None


def settle_deflate_writes(ws: Any) -> None:
    """The session ends with its sender cancelled: let aiohttp's deflating writes that are still running end
    quietly. aiohttp deflates a message over 16 KiB in a task of its own, shielded from the sender's
    cancellation; a client that closes right after its handshake (the Foxglove server's first advertisements
    are that large) leaves the task to fail on the closing transport, and asyncio would log its error with
    a traceback ("Task exception was never retrieved") for every such client. The error is the client's
    going, already handled: it is retrieved here."""
    writer = getattr(ws, "_writer", None)
    for task in list(getattr(writer, "_background_tasks", ())):
        task.add_done_callback(_retrieve)


def _retrieve(task: asyncio.Future[Any]) -> None:
    if not task.cancelled():
        task.exception()


def delivery_counts(subs: Mapping[Any, Any], topic_of: Callable[[Any], str]) -> list[dict[str, Any]]:
    """Per subscription: its topic, messages sent, dropped (queue bound, newest-only, link) and bytes queued."""
    return [
        {"topic": topic_of(sub), "sent": sub.sent, "dropped": sub.queue.dropped, "queued": sub.queue.size}
        for sub in subs.values()
    ]
