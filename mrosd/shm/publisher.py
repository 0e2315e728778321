"""A topic's publishing end of the shared-memory transport: its ring, its backlog, its subscribers' links.

``ShmPublisherEndpoint`` owns one topic's ring (a sealed memfd, ``mrosd.shm.segment``), the door on which
same-host subscribers attach (an abstract Unix socket, ``mrosd.shm.door``: it must not know the ring), and
one link per attached subscriber (``mrosd.shm.link``: its acknowledgement page and a socket pair for
wake-ups both ways, each end receiving only what the other sends). ``publish`` copies the
serialized message once into the ring and sends one byte to each subscriber, ``MSG_DONTWAIT``: its cost
does not grow with the number of subscribers, and it never waits for anyone, whatever the subscriber did
to its end (``mrosd.ixm.channel``).

The ring is small (``RING_BYTES``, at least ``MIN_SLOTS`` slots): it is there to pipeline, and fresh shared
memory is expensive to touch. The publisher's queue is kept beside it, as a TCPROS publisher keeps one per
connection: each subscriber writes the number of the next message it wants into its own acknowledgement
page, and a message whose slot still holds one that a subscriber has not read waits in the backlog (as
references, never copied twice) until that subscriber moves on and, seeing the ring's ``waiting`` word,
wakes the publisher through its end of the pair. A subscriber that holds the ring back too long stops being waited
for ("lagging": it is overwritten and counts drops, drop-oldest) once the backlog holds more than
``queue_size`` messages, or when it has delayed a subscriber that keeps up for ``STALL`` seconds; it is
waited for again once it has caught up. Memory is bounded by the ring plus ``queue_size`` messages.

A message bigger than the slots makes the publisher retire the ring and continue in a bigger one, announced
with its descriptor over each subscriber's socket. A subscriber's end (exit, crash) is its socket closing;
every problem with a subscriber closes only that subscriber's connection, with one log line.
"""

from __future__ import annotations

import asyncio
import collections
import logging
import os
import time
from collections.abc import Callable, Iterable
from typing import Any

from mrosd.errors import HandshakeError, LocalProtocolError, RemoteProtocolError
from mrosd.ixm.channel import drain_socket, wake_socket
from mrosd.lograte import RateLimitedLog
from mrosd.msg.runtime import is_immutable
from mrosd.shm import control
from mrosd.shm.channel import (
    ControlChannel,
    close_fds,
)
from mrosd.shm.door import MAX_PENDING, AttachDoor
from mrosd.shm.door import refuse as refuse_attach
from mrosd.shm.link import ShmSubscriberLink, grant_leases
from mrosd.shm.negotiate import TRANSPORT, publisher_answer, trusted_uids
from mrosd.shm.ring import MAX_SLOTS, slot_stride
from mrosd.shm.segment import RingSegment
from mrosd.spin import loop_spinner
from mrosd.wire.header import ConnectionHeader, decode_connection_header, encode_header

__all__ = [
    "DEFAULT_LEASE_SLOTS",
    "DEFAULT_MAX_RING_BYTES",
    "INITIAL_CAPACITY",
    "LOAN_HEAD",
    "LOAN_TAIL",
    "MAX_PENDING",
    "MIN_SLOTS",
    "RING_BYTES",
    "STALL",
    "ShmPublisherEndpoint",
    "ShmSubscriberLink",
    "slots_for",
]

log = logging.getLogger(__name__)
#: every line a peer can trigger (connect, refuse, drop, in a loop) goes through this: 5 per kind per 10 s,
#: the rest counted (issue 24: 170k lines in 10 s from one peer connecting and closing)
_ratelog = RateLimitedLog(log)

#: A publisher's ring is at most this big (more slots than fit are not made; at least 2 always are).
DEFAULT_MAX_RING_BYTES = 128 << 20
#: A ring has as many slots as fit in this many bytes (at least ``MIN_SLOTS``, at most ``queue_size + 1``).
RING_BYTES = 4 << 20
MIN_SLOTS = 2
#: Seconds a subscriber may hold the ring back while another one waits for messages, before it is overwritten.
STALL = 0.05
#: Longest pause between two looks at the acknowledgements while messages wait (a lost wake-up's bound).
_RECHECK_MAX = 0.1
#: First slot size; the ring grows (by replacement) when a bigger message comes.
INITIAL_CAPACITY = 64 << 10
#: Slots a ring has beyond its queue for zero-copy subscribers' leases: the sum of all leases granted (each
#: subscriber's share, decided when it attaches) stays within them, so a slot to write always exists.
DEFAULT_LEASE_SLOTS = 4
#: Room in a declared pool's slots around a loaned array: its message's fields before it (header, strings,
#: sizes) are written in front of it, those after it behind it (``mrosd.shm.loan``).
LOAN_HEAD = 4096
LOAN_TAIL = 4096


def slots_for(queue_size: int, capacity: int, max_ring_bytes: int) -> int:
    """Ring slots for slots of ``capacity`` bytes: as many as fit in ``RING_BYTES`` (and in
    ``max_ring_bytes``), no more than ``queue_size + 1``, never fewer than ``MIN_SLOTS``."""
    wanted = min(MAX_SLOTS, max(MIN_SLOTS, queue_size + 1))
    fit = min(RING_BYTES, max_ring_bytes) // slot_stride(capacity)
    return max(MIN_SLOTS, min(wanted, fit))


def _grown(capacity: int, needed: int) -> int:
    """The slot size of a replacement ring: room for ``needed`` plus an eighth, page-rounded, at least double
    the old one while that stays under twice ``needed``."""
    size = max(needed + needed // 8, min(capacity * 2, needed * 2))
    return (size + 4095) // 4096 * 4096


class ShmPublisherEndpoint:
    """One topic's shared-memory side: ``await start()``, answer requestTopic with ``answer()``, ``publish``.

    Args:
        topic: for names and log lines.
        queue_size: the ring keeps this many messages for a slow subscriber (see ``slots_for``).
        latch: a subscriber that attaches gets the last message first.
        handshake: checks a subscriber's TCPROS connection header and returns the publisher's (as
            ``mrosd.wire.handshake.publisher_reply`` does); raise ``HandshakeError`` to refuse.
        on_change: called when a subscriber attaches or goes.
        trusted: uids whose processes may attach (default root, ours, ``$MROSD_SHM_TRUSTED_UIDS``).
        lease_slots: slots beyond the queue for zero-copy subscribers' leases (their shares are granted
            from these at attach, first come, at most ``MAX_LEASES`` each; a subscriber granted none copies).
            Default: ``DEFAULT_LEASE_SLOTS`` for a pool declared with ``max_message_size``, else none (a
            ring sized on demand stays as small as it was; its subscribers copy).
        max_message_size: the publisher's largest message, declared up front: the ring (slots of this
            size) is made at ``start()`` with every page faulted in, so neither the first message nor a new
            subscriber pays for fresh memory (~0.7 ms per MB here); a bigger message still grows it.
    """

    def __init__(
        self,
        topic: str,
        *,
        queue_size: int = 100,
        latch: bool = False,
        handshake: Callable[[ConnectionHeader], ConnectionHeader] | None = None,
        on_change: Callable[[], None] | None = None,
        trusted: frozenset[int] | None = None,
        max_ring_bytes: int = DEFAULT_MAX_RING_BYTES,
        initial_capacity: int = INITIAL_CAPACITY,
        max_message_size: int | None = None,
        lease_slots: int | None = None,
    ) -> None:
        self.topic = topic
        self.queue_size = queue_size
        self.latch = latch
        #: messages up to this number were published unlatched: never a new subscriber's first (``set_latch``)
        self._unlatched_upto = 0
        self.handshake = handshake or (
            lambda header: ConnectionHeader(callerid="", latching="1" if self.latch else "0")
        )
        self.on_change = on_change or (lambda: None)
        trusted = trusted_uids() if trusted is None else trusted
        self.max_ring_bytes = max_ring_bytes
        self.capacity = max(
            64, initial_capacity if max_message_size is None else max_message_size + LOAN_HEAD + LOAN_TAIL
        )
        #: slots lent to the application (filled in place, not yet published), and slots a transport may
        #: still read (a TCPROS socket fed from a published loan): neither is written
        self._loaned: set[int] = set()
        self._pinned: list[tuple[int, Callable[[], bool]]] = []
        if lease_slots is None:
            lease_slots = DEFAULT_LEASE_SLOTS if max_message_size is not None else 0
        self.lease_slots = max(0, lease_slots)
        #: rings are made whole and faulted in up front (the publisher declared its message size)
        self.populate = max_message_size is not None
        self.label = topic.strip("/").replace("/", "-")
        self.links: list[ShmSubscriberLink] = []
        self.ring: RingSegment | None = None
        #: number of the first message written into the current ring
        self._ring_first = 1
        #: messages waiting for a free slot: (parts, size, monotonic time queued)
        self.backlog: collections.deque[tuple[tuple[Any, ...], int, float]] = collections.deque()
        self._recheck: asyncio.TimerHandle | None = None
        self._recheck_delay = 0.0
        #: rings made so far (the first and each replacement)
        self.rings_made = 0
        self.closed = False
        self._loop = asyncio.get_running_loop()
        #: the socket subscribers attach through (``address``, ``token``)
        self.door = AttachDoor(topic, trusted, self._attach, self._loop)
        self.token = self.door.token
        self.address = self.door.address
        self._poke = loop_spinner(self._loop).poke

    async def start(self) -> None:
        """Listen on the abstract Unix socket ``address``."""
        self.door.start()
        if self.populate:
            self._ring_for(0)  # the pool, once, now: not on the first message's path

    def answer(self) -> list[Any]:
        """requestTopic's protocol parameters that send a subscriber here."""
        return publisher_answer(self.address, self.token)

    def set_latch(self, latch: bool) -> None:
        """Latch from now on, or stop: only a message published while latched is a new subscriber's first."""
        if latch and not self.latch:
            self._unlatched_upto = (self.ring.layout.head if self.ring is not None else 0) + len(self.backlog)
        self.latch = latch

    # publishing ------------------------------------------------------------------------------------------

    def publish(self, body: bytes | bytearray | memoryview) -> None:
        """Copy one serialized message (no length prefix) into the ring once and wake every subscriber."""
        self.publish_parts((body,), len(body))

    def publish_parts(self, parts: Iterable[bytes | bytearray | memoryview], size: int) -> None:
        """``publish(b"".join(parts))`` without the join (``size`` bytes in all)."""
        if self.closed:
            raise LocalProtocolError(f"shared-memory publisher of {self.topic} is closed")
        if not self.links and not self.latch:
            return  # nobody reads it, and nobody will read this one later
        if not self.backlog:
            ring = self._ring_for(size)
            slot = self._pick()
            if slot is not None:
                ring.layout.write_parts(parts, size, slot)
                self._wake(size, 1)
                return
        # the slot is not free: queue the message (a piece the caller could change is copied, as over TCPROS)
        kept = tuple(p if is_immutable(p) else bytes(p) for p in parts)
        self.backlog.append((kept, size, time.monotonic()))
        self._flush()

    # loans -----------------------------------------------------------------------------------------------

    def loan_slot(self, size: int) -> tuple[RingSegment, int] | None:
        """A slot to fill in place with a message whose array is ``size`` bytes (at ``LOAN_HEAD``), taken
        out of the ring until ``publish_loaned`` or ``end_loan``; None when the ring cannot lend one now
        (no declared pool big enough, messages waiting, or every slot busy): the caller copies instead.
        The old message in the slot is invalidated first (readers see it is gone, never a mix)."""
        ring = self.ring
        if self.closed or self.backlog or ring is None or ring.layout.capacity < LOAN_HEAD + size + LOAN_TAIL:
            return None
        slot = self._pick()
        if slot is None:
            return None
        layout = ring.layout
        layout.words[slot][0] = 2 * (layout.head + 1) - 1
        self._loaned.add(slot)
        return ring, slot

    def can_lend(self, size: int) -> bool:
        """Would ``loan_slot(size)`` lend a slot now (a producer that would rather wait than copy asks)."""
        ring = self.ring
        return (
            not self.closed
            and not self.backlog
            and ring is not None
            and ring.layout.capacity >= LOAN_HEAD + size + LOAN_TAIL
            and self._pick() is not None
        )

    def end_loan(self, ring: RingSegment, slot: int) -> None:
        """A lent slot comes back unpublished."""
        if ring is self.ring:
            self._loaned.discard(slot)

    def publish_loaned(self, ring: RingSegment, slot: int, start: int, length: int) -> bool:
        """Publish the lent ``slot`` as it is (the message at ``start``, ``length`` bytes): no copy. False
        when it cannot go as it is (the ring was replaced, messages wait before it): copy it then."""
        if ring is not self.ring or slot not in self._loaned:
            return False
        self._loaned.discard(slot)
        if self.backlog:
            return False
        m, _ = ring.layout.begin(slot)
        ring.layout.commit(m, length, start)
        self._wake(length, 1)
        if self.links:
            # Where the scheduler put this publisher on the CPU of a subscriber spinning for the message (a
            # zero-copy subscriber's anticipation window, mrosd.spin), that subscriber reads it now, not once
            # this publisher next blocks: on 2 CPUs that was one loaned message in two, at 345-388 us against
            # 204-246 apart. Elsewhere this returns at once. Measured (bench shm --latency, loan 8 MB, 4 A/B
            # pairs): medians 112-128 us against 108-202 us without.
            os.sched_yield()
        return True

    def pin(self, slot: int, still: Callable[[], bool]) -> None:
        """Keep ``slot`` unwritten while ``still()`` (a transport still holds bytes of it to send)."""
        self._pinned.append((slot, still))

    def _wake(self, size: int, count: int) -> None:
        """Count ``count`` messages of ``size`` bytes in all for every subscriber, and wake them."""
        for link in list(self.links):
            link.messages_sent += count
            link.bytes_sent += size
            if not wake_socket(link.wake):  # a full buffer is a wake-up pending; this is its end gone
                self._drop(link, "cannot wake it: its wake-up channel is closed")
        self._poke()

    def _pick(self) -> int | None:
        """A slot the next message may go into, or None: one that holds nothing of this ring yet, or a
        message that no subscriber holds a lease on and every subscriber still waited for has read; never
        the last message (a latecomer's first). The oldest such, and first the plain ring's next slot, so
        that without leases this is the ring it always was."""
        assert self.ring is not None
        layout = self.ring.layout
        head = layout.head
        links = self.links
        for link in links:
            if link.lagging and link.acked(head) > head:
                link.lagging = False  # caught up: waited for again
        leased: set[int] = set()
        for link in links:
            if link.grant:
                leased.update(link.leases())
        waited = [link.acked(head) for link in links if not link.lagging]
        low = min(waited, default=head + 1)
        first = self._ring_first
        busy = self._loaned
        if self._pinned:
            self._pinned = [(s, still) for s, still in self._pinned if still()]
            busy = busy | {s for s, _ in self._pinned}
        best: int | None = None
        best_held = 0
        plain: int = head % layout.slots
        slot: int
        for slot in (plain, *range(layout.slots)):
            if busy and slot in busy:
                continue
            seq = layout.words[slot][0]
            # odd: no message (a loan given back unpublished left it invalidated): free
            held = first - 1 if seq & 1 else seq >> 1
            if held >= first and (held == head or held in leased or held >= low):
                continue
            if slot == plain or held < first:
                return slot
            if best is None or held < best_held:
                best, best_held = slot, held
        return best

    def _oldest_unleased(self) -> int:
        """The oldest message of this ring in a slot no lease holds (what waiting subscribers hold back)."""
        assert self.ring is not None
        layout = self.ring.layout
        leased: set[int] = set()
        for link in self.links:
            if link.grant:
                leased.update(link.leases())
        held = [layout.held(s) for s in range(layout.slots)]
        free = [h for h in held if h >= self._ring_first and h != layout.head and h not in leased]
        return min(free, default=layout.head)

    def _flush(self) -> None:
        """Write what the backlog holds while slots are free; leave the ring's ``waiting`` word saying whether
        messages still wait, and look again later in case a wake-up is lost."""
        backlog = self.backlog
        written = total = 0
        while backlog:
            parts, size, _queued = backlog[0]
            ring = self._ring_for(size)
            slot = self._pick()
            if slot is None and self._give_up_waiting():
                slot = self._pick()
            if slot is None:
                break
            backlog.popleft()
            ring.layout.write_parts(parts, size, slot)
            written += 1
            total += size
        if written:
            self._wake(total, written)
        if self.ring is None:
            return
        if not backlog:
            self.ring.layout.waiting = False
            if self._recheck is not None:
                self._recheck.cancel()
                self._recheck = None
            self._recheck_delay = 0.0
            return
        # Set, then look once more: a subscriber that moved on before it could see the word is caught here.
        self.ring.layout.waiting = True
        if self._pick() is not None:
            self._loop.call_soon(self._flush)
            return
        if self._recheck is None:
            self._recheck_delay = 0.001 if written else min(_RECHECK_MAX, max(0.001, self._recheck_delay * 2))
            self._recheck = self._loop.call_later(self._recheck_delay, self._recheck_now)

    def _recheck_now(self) -> None:
        self._recheck = None
        if not self.closed:
            self._flush()

    def _give_up_waiting(self) -> bool:
        """The next message waits for slow subscribers: stop waiting for them (they become ``lagging``) when
        the backlog is over ``queue_size`` or they have held back a subscriber that keeps up for ``STALL`` s.
        Leases are never given up: a lagging subscriber loses the messages it has not taken, not its leases."""
        assert self.ring is not None
        head = self.ring.layout.head
        old = self._oldest_unleased()
        slow = [lk for lk in self.links if not lk.lagging and lk.acked(head) <= old]
        over = len(self.backlog) > max(1, self.queue_size)
        if not over:
            if len(slow) == len([lk for lk in self.links if not lk.lagging]):
                return False  # everyone is behind: a burst, not one slow subscriber
            if time.monotonic() - self.backlog[0][2] < STALL:
                return False
        for link in slow:
            link.lagging = True
            log.debug("%s: shared-memory subscriber %s is behind: its oldest messages go", self.topic, link.callerid)
        return True

    def _on_progress(self, link: ShmSubscriberLink) -> None:
        if not drain_socket(link.wake):
            self._drop(link, "")  # its end closed: it went away (its control socket says so too, maybe later)
            return
        if self.backlog and not self.closed:
            self._recheck_delay = 0.0
            self._flush()

    def _ring_for(self, size: int) -> RingSegment:
        ring = self.ring
        if ring is not None and size <= ring.layout.capacity:
            return ring
        if ring is None:
            capacity = max(self.capacity, _grown(0, size) if size > self.capacity else self.capacity)
        else:
            capacity = _grown(ring.layout.capacity, size)
        head = ring.layout.head if ring is not None else 0
        slots = min(MAX_SLOTS, slots_for(self.queue_size, capacity, self.max_ring_bytes) + self.lease_slots)
        new = RingSegment(self.label, slots, capacity, head, populate=self.populate)
        new.layout.waiting = bool(self.backlog)
        self.rings_made += 1
        self.capacity = capacity
        self.ring = new
        self._ring_first = head + 1
        if ring is not None:
            ring.layout.retire()
            for link in list(self.links):
                self._send_ring(link, control.Ring(slots=new.layout.slots))
            ring.close()
        return new

    def _send_ring(self, link: ShmSubscriberLink, msg: control.Message, *more: int) -> bool:
        """Send ``msg`` with a read-only descriptor of the current ring (and ``more`` descriptors after it)."""
        assert self.ring is not None
        fd = self.ring.reader_fd()
        try:
            link.channel.send(msg, (fd, *more))
        except OSError as exc:
            self._drop(link, f"cannot send it the ring: {exc}")
            return False
        finally:
            os.close(fd)
        return True

    # subscribers ------------------------------------------------------------------------------------------

    def _attach(self, channel: ControlChannel, msg: control.Attach, pid: int, uid: int) -> None:
        """A subscriber that showed the token: check its header, make its link, send it the ring."""

        def refuse(why: str) -> None:
            refuse_attach(channel, self.topic, pid, why)

        try:
            header = decode_connection_header(msg.header)
            reply = self.handshake(header)
        except (HandshakeError, RemoteProtocolError) as exc:
            refuse(str(exc))
            return
        if self.closed:
            refuse("the publisher is closing")
            return
        ring = self._ring_for(0)
        head = ring.layout.head
        first = head if self.latch and head > self._unlatched_upto else head + 1
        try:
            link = ShmSubscriberLink(
                self.label, channel, callerid=header.callerid or "?", pid=pid, first=first, loop=self._loop
            )
        except OSError as exc:
            refuse(f"cannot make its acknowledgement page: {exc}")
            return
        link.uid = uid
        link.grant = grant_leases(self.links, self.lease_slots, uid, msg.leases)
        attached = control.Attached(header=encode_header(reply)[4:], first=first, leases=link.grant)
        if not self._send_ring(link, attached, link.ack.fd, link.peer_end.fileno()):
            return
        link.peer_end.close()  # only the subscriber holds its end
        link.ack.sent()
        if first <= head:  # the latched message
            link.messages_sent += 1
            link.bytes_sent += int(ring.layout.words[ring.layout.slot_of(head)][1])
        self.links.append(link)
        self._loop.add_reader(channel.sock.fileno(), self._on_link, link)
        self._loop.add_reader(link.wake.fileno(), self._on_progress, link)
        self.on_change()

    def _on_link(self, link: ShmSubscriberLink) -> None:
        try:
            got = link.channel.receive()
        except RemoteProtocolError as exc:
            self._drop(link, str(exc))
            return
        if got is None:
            self._drop(link, "")
            return
        link.channel.reader.close()  # nothing it sends carries a descriptor: none is held
        for msg, fds in got:
            close_fds(fds)
            if isinstance(msg, control.Progress):
                link.dropped = max(0, min(msg.dropped, 1 << 62))
            else:
                self._drop(link, f"unexpected {type(msg).__name__}")
                return

    def _drop(self, link: ShmSubscriberLink, why: str) -> None:
        if why:
            _ratelog.warning("drop", "%s: closing shared-memory subscriber %s: %s", self.topic, link.callerid, why)
        else:
            _ratelog.log(logging.DEBUG, "gone", "%s: shared-memory subscriber %s went away", self.topic, link.callerid)
        link.close()
        if link in self.links:
            self.links.remove(link)
            self.on_change()
            if self.backlog and not self.closed:
                self._loop.call_soon(self._flush)  # it may have been the one holding the ring back

    # introspection ---------------------------------------------------------------------------------------

    def stats(self) -> list[dict[str, Any]]:
        """Per subscriber: id, callerid, messages and bytes written for it, drops it reported, connected."""
        return [
            {
                "id": lk.id,
                "callerid": lk.callerid,
                "messages": lk.messages_sent,
                "bytes": lk.bytes_sent,
                "dropped": lk.dropped,
                "connected": lk.connected,
            }
            for lk in self.links
        ]

    def pool(self) -> dict[str, Any]:
        """The shared memory this topic holds (for introspection: its size is bounded and visible): slots,
        bytes per slot, total bytes, whether populated up front, lease slots and leases granted, loans out."""
        ring = self.ring
        return {
            "slots": ring.layout.slots if ring is not None else 0,
            "slot_bytes": ring.layout.capacity if ring is not None else 0,
            "bytes": ring.size if ring is not None else 0,
            "populated": self.populate,
            "lease_slots": self.lease_slots,
            "leases_granted": sum(lk.grant for lk in self.links),
            "loans_out": len(self._loaned),
        }

    def pool_summary(self) -> str:
        """``pool()`` in words, for getBusInfo's free-text column: ``pool 4 x 1.0 MiB = 4.0 MiB, populated``."""
        p = self.pool()
        text = f"pool {p['slots']} x {p['slot_bytes'] / 2**20:.1f} MiB = {p['bytes'] / 2**20:.1f} MiB"
        if p["populated"]:
            text += ", populated"
        if p["lease_slots"]:
            text += f", {p['leases_granted']}/{p['lease_slots']} lease slots granted"
        if p["loans_out"]:
            text += f", {p['loans_out']} loaned"
        return text

    def bus_info(self) -> list[list[Any]]:
        """getBusInfo rows of the shared-memory subscribers (transport ``SHMROS``); the free-text column names
        the subscriber's pid and the pool this topic holds, so its size is visible (``mros topic info``)."""
        pool = self.pool_summary()
        return [
            [lk.id, lk.callerid, "o", TRANSPORT, self.topic, lk.connected, f"pid {lk.pid}; {pool}"] for lk in self.links
        ]

    # lifecycle ------------------------------------------------------------------------------------------

    async def aclose(self) -> None:
        """Close every subscriber connection (they see their socket close), the listener and the ring."""
        if self.closed:
            return
        self.closed = True
        self.door.close()
        for link in list(self.links):
            link.close()
        self.links.clear()
        self.backlog.clear()
        if self._recheck is not None:
            self._recheck.cancel()
            self._recheck = None
        if self.ring is not None:
            self.ring.close()
            self.ring = None
