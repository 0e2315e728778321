"""The bytes of one shared-memory topic ring: a header, then N slots each under its own seqlock (pure).

One publisher serializes each message once into the next slot; every same-host subscriber reads it from
there. This module knows nothing of file descriptors or sockets, so that it can be tested on a
``bytearray``. Layout (the host's byte order; a ring never leaves its host; 64-byte aligned)::

    header (64 bytes)
    0   4s  magic b"MSHM"
    4   H   layout version (3)
    6   H   flags: bit 0 (``POPULATED``) = the publisher faulted every page in at creation, so a subscriber
            maps the whole ring at once (``MAP_POPULATE``) instead of faulting it page by page
    8   I   slots N
    12  I   directory entries D (``dir_entries(N)``)
    16  Q   capacity of one slot's data, bytes
    24  Q   head: number of the last completed message (messages are numbered from 1; 0 = none yet)
    32  Q   retired: 1 once the publisher moved to a bigger ring (its messages up to ``head`` stay final)
    40  Q   waiting: 1 while the publisher holds messages back until a subscriber frees a slot (it then wants
            to be woken: see ``mrosd.shm.publisher``)
    directory at 64: D words; word ``m % D`` is the slot that holds (or held) message ``m``
    slot i at base + i * stride, base = 64 + 8 D rounded up to 64, stride = 64 + capacity rounded up to 64:
    0   Q   seq: 2m - 1 while message m is being written into the slot, 2m once it is complete
    8   Q   length of message m
    16  Q   start of message m in the slot's data (0, except for a loaned slot: the fixed part of a message
            is written in front of an array filled in place, ``mrosd.shm.loan``)
    64  ... data (``capacity`` bytes)

The publisher chooses the slot of each message (``begin(slot)``; by default ``(m - 1) % N``, a plain ring):
it skips slots that a subscriber holds a lease on (``mrosd.shm.publisher``), so message numbers and slots
are related only through the directory. The writer of message ``m`` into slot ``s`` stores ``seq = 2m - 1``
in ``s`` (readers of the older message there now know it is going), copies, stores the length, stores
``seq = 2m``, then the directory word ``m % D = s``, then ``head = m``. A reader that wants message ``m <=
head`` looks its slot up in the directory; the slot's seq then says everything: ``2m`` is the message, more
is a newer one (the message is lost), less is a publisher that lies. A reader checks ``seq == 2m`` before
and after its copy: anything else after means the slot was overwritten meanwhile (the reader was lapped)
and the copy is discarded and counted as a drop. A reader more than N messages behind jumps to the oldest
message still in the ring and counts what it skipped. The ring itself never makes the writer wait: whether
the publisher writes into a slot that a subscriber has not read yet is the publisher's decision (it queues
messages for a while first, as a TCPROS publisher's queue does; ``mrosd.shm.publisher``).
Every word is read and written as one aligned 8-byte ``memoryview.cast('Q')`` item (atomic on x86-64 and
arm64, stores kept in order by x86-64's memory model), as ``mrosd.ixm.layout`` does.

A reader maps the ring read-only and trusts none of it: a ``length`` above the capacity, a ``head`` that
goes backwards or a slot that claims to be older than ``head`` says is a ``RemoteProtocolError``, never an
out-of-bounds read or an allocation beyond one slot.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable

from mrosd.errors import LocalProtocolError, RemoteProtocolError
from mrosd.msg.runtime import FrameBuffer
from mrosd.wire.framing import LARGE_FRAME
from mrosd.wire.spares import SparePool

__all__ = [
    "HEADER_SIZE",
    "LAYOUT_VERSION",
    "MAGIC",
    "MAX_SLOTS",
    "POPULATED",
    "SLOT_HEADER",
    "RingCursor",
    "RingLayout",
    "ring_size",
    "slot_stride",
]

MAGIC = b"MSHM"
LAYOUT_VERSION = 3
HEADER_SIZE = 64
SLOT_HEADER = 64
#: More slots than this is refused (a subscriber's drop-oldest queue is at most this long).
MAX_SLOTS = 4096
#: Header flag: every page of the ring was touched when it was made (``RingSegment(populate=True)``).
POPULATED = 1

_HEAD = struct.Struct("=4sHHIIQQQQ16x")
assert _HEAD.size == HEADER_SIZE
_HEAD_OFF = 24
_RETIRED_OFF = 32
_WAITING_OFF = 40


def dir_entries(slots: int) -> int:
    """Directory words of a ring of ``slots`` slots: four per slot (a reader that far behind has lost the
    message anyway), a whole number of cache lines."""
    return (4 * slots + 7) // 8 * 8


def slot_stride(capacity: int) -> int:
    """Bytes between two slots: the slot header and the data, rounded up to a cache line."""
    return SLOT_HEADER + (capacity + 63) // 64 * 64


def ring_size(slots: int, capacity: int) -> int:
    """Bytes a ring of ``slots`` slots of ``capacity`` bytes needs."""
    return HEADER_SIZE + 8 * dir_entries(slots) + slots * slot_stride(capacity)


class RingLayout:
    """A view of one ring: header words, per-slot seqlock words and data views.

    ``buf`` may be a read-only mapping (subscribers); the write methods then fail in memoryview itself.
    """

    __slots__ = (
        "_dir",
        "_head",
        "_retired",
        "_waiting",
        "_writing",
        "buf",
        "capacity",
        "data",
        "dir_size",
        "flags",
        "slots",
        "words",
    )

    def __init__(self, buf: memoryview) -> None:
        if len(buf) < HEADER_SIZE:
            raise RemoteProtocolError(f"shared-memory ring of {len(buf)} bytes is smaller than its header")
        magic, version, flags, slots, dsize, capacity, _head, _retired, _waiting = _HEAD.unpack_from(buf, 0)
        if magic != MAGIC or version != LAYOUT_VERSION:
            raise RemoteProtocolError(f"not an mrosd shared-memory ring v{LAYOUT_VERSION} ({magic!r}, v{version})")
        if not 1 <= slots <= MAX_SLOTS:
            raise RemoteProtocolError(f"shared-memory ring claims {slots} slots (1..{MAX_SLOTS} allowed)")
        if dsize != dir_entries(slots):
            raise RemoteProtocolError(f"shared-memory ring of {slots} slots claims {dsize} directory entries")
        if ring_size(slots, capacity) > len(buf):
            raise RemoteProtocolError(
                f"shared-memory ring claims {slots} slots of {capacity} bytes but the mapping has {len(buf)}"
            )
        self.buf = buf
        self.slots: int = slots
        self.capacity: int = capacity
        self.flags: int = flags
        self.dir_size: int = dsize
        self._dir = buf[HEADER_SIZE : HEADER_SIZE + 8 * dsize].cast("Q")
        base = HEADER_SIZE + 8 * dsize
        #: the slot the writer is filling (between ``begin`` and ``commit``)
        self._writing = 0
        self._head = buf[_HEAD_OFF : _HEAD_OFF + 8].cast("Q")
        self._retired = buf[_RETIRED_OFF : _RETIRED_OFF + 8].cast("Q")
        self._waiting = buf[_WAITING_OFF : _WAITING_OFF + 8].cast("Q")
        stride = slot_stride(capacity)
        #: per slot: [seq, length] as native 8-byte words
        self.words = [buf[base + i * stride : base + i * stride + 24].cast("Q") for i in range(slots)]
        self.data = [
            buf[base + i * stride + SLOT_HEADER : base + i * stride + SLOT_HEADER + capacity] for i in range(slots)
        ]

    @staticmethod
    def header(slots: int, capacity: int, head: int = 0, flags: int = 0) -> bytes:
        """A fresh header whose first message will be ``head + 1`` (a replacement ring continues the count)."""
        return _HEAD.pack(MAGIC, LAYOUT_VERSION, flags, slots, dir_entries(slots), capacity, head, 0, 0)

    @classmethod
    def initialize(cls, buf: memoryview, slots: int, capacity: int, head: int = 0, flags: int = 0) -> RingLayout:
        """Write a fresh header into ``buf`` (zeroed slots) and view it."""
        if not 1 <= slots <= MAX_SLOTS:
            raise LocalProtocolError(f"a ring has 1..{MAX_SLOTS} slots, not {slots}")
        if ring_size(slots, capacity) > len(buf):
            raise LocalProtocolError(f"buffer of {len(buf)} bytes cannot hold {slots} slots of {capacity} bytes")
        buf[:HEADER_SIZE] = cls.header(slots, capacity, head, flags)
        return cls(buf)

    def release(self) -> None:
        """Release every view so that the mapping can be closed."""
        for view in (*self.words, *self.data, self._dir, self._head, self._retired, self._waiting):
            view.release()
        self.buf.release()

    @property
    def head(self) -> int:
        """Number of the last completed message (0 before the first)."""
        return int(self._head[0])

    @property
    def retired(self) -> bool:
        return bool(self._retired[0])

    def retire(self) -> None:
        """Mark the ring final: the publisher continues in a bigger one it announces over the socket."""
        self._retired[0] = 1

    @property
    def waiting(self) -> bool:
        """The publisher holds messages back and wants to be woken when a subscriber frees a slot."""
        return bool(self._waiting[0])

    @waiting.setter
    def waiting(self, value: bool) -> None:
        self._waiting[0] = 1 if value else 0

    # writing (the publisher: one writer per ring) ----------------------------------------------------------

    def begin(self, slot: int | None = None) -> tuple[int, memoryview]:
        """Start message ``head + 1`` in ``slot`` (default: ``(m - 1) % N``): mark it in progress; returns the
        message's number and the slot's data view."""
        m = int(self._head[0]) + 1
        if slot is None:
            slot = (m - 1) % self.slots
        self._writing = slot
        self.words[slot][0] = 2 * m - 1
        return m, self.data[slot]

    def commit(self, m: int, length: int, start: int = 0) -> None:
        """Publish message ``m`` of ``length`` bytes (from ``start`` in its slot): length, seq, directory,
        then head (in this order)."""
        slot = self._writing
        words = self.words[slot]
        words[2] = start
        words[1] = length
        words[0] = 2 * m
        self._dir[m % self.dir_size] = slot
        self._head[0] = m

    def held(self, slot: int) -> int:
        """The message ``slot`` holds (0: none yet); the publisher's own bookkeeping, from its own words."""
        return int(self.words[slot][0]) // 2

    def slot_of(self, m: int) -> int:
        """The slot the directory gives for message ``m`` (check its seq before trusting it).

        Raises:
            RemoteProtocolError: the directory names a slot the ring does not have.
        """
        slot = int(self._dir[m % self.dir_size])
        if slot >= self.slots:
            raise RemoteProtocolError(f"the ring's directory names slot {slot} of {self.slots}")
        return slot

    def write(self, data: bytes | bytearray | memoryview, slot: int | None = None) -> int:
        """Copy one serialized message into the next slot and publish it; returns its number."""
        n = len(data)
        if n > self.capacity:
            raise LocalProtocolError(f"message of {n} bytes does not fit the ring's {self.capacity}-byte slots")
        m, view = self.begin(slot)
        view[:n] = data
        self.commit(m, n)
        return m

    def write_parts(self, parts: Iterable[bytes | bytearray | memoryview], size: int, slot: int | None = None) -> int:
        """``write(b"".join(parts))`` (``size`` bytes in all) without building the concatenation."""
        if size > self.capacity:
            raise LocalProtocolError(f"message of {size} bytes does not fit the ring's {self.capacity}-byte slots")
        m, view = self.begin(slot)
        at = 0
        for part in parts:
            end = at + len(part)
            if end > size:
                raise LocalProtocolError("message parts are longer than their announced size")
            view[at:end] = part
            at = end
        self.commit(m, at)
        return m


class RingCursor:
    """One subscriber's position in a ring: the next message it wants, and the messages it lost.

    Reading message ``m`` is ``begin`` (is it there, how long), the copy, then ``finish`` (was it overwritten
    meanwhile); ``read`` does the three. The halves exist so that tests can interleave a writer between them.
    """

    __slots__ = ("dropped", "next", "ring", "slot", "start")

    def __init__(self, ring: RingLayout, next_message: int) -> None:
        self.ring = ring
        #: number of the next message to read
        self.next = next_message
        #: messages lost: overwritten before they were read, or while they were being copied
        self.dropped = 0
        #: the slot of the message ``begin`` returned last, and where in the slot that message starts
        self.slot = 0
        self.start = 0

    def available(self) -> bool:
        """Is there a completed message this cursor has not read yet?"""
        return self.ring.head >= self.next

    def begin(self) -> tuple[int, int] | None:
        """The next readable message as (number, length) without copying; None when there is none yet.

        Skips (and counts) messages already overwritten.

        Raises:
            RemoteProtocolError: the ring's words contradict each other (a publisher that lies).
        """
        ring = self.ring
        slots = ring.slots
        while True:
            head = ring.head
            nxt = self.next
            if head < nxt:
                if nxt - head > 1 and nxt > 1:
                    raise RemoteProtocolError(f"the ring's head went back from {nxt - 1} to {head}")
                return None
            oldest = head - slots + 1
            if nxt < oldest:
                self.dropped += oldest - nxt
                self.next = nxt = oldest
            slot = ring.slot_of(nxt)
            words = ring.words[slot]
            want = 2 * nxt
            seq = words[0]
            if seq != want:
                if seq > want:  # already being overwritten by a newer message: lost
                    self.dropped += 1
                    self.next = nxt + 1
                    continue
                raise RemoteProtocolError(f"ring slot {slot} holds sequence {seq} but the head says {head}")
            n = words[1]
            start = words[2]
            if n > ring.capacity or start > ring.capacity - n:
                raise RemoteProtocolError(
                    f"ring slot {slot} claims a {n}-byte message at {start} but slots hold {ring.capacity} bytes"
                )
            self.slot = slot
            self.start = int(start)
            return nxt, int(n)

    def finish(self, m: int) -> bool:
        """After copying message ``m``: True if the copy is consistent (the cursor moves on either way)."""
        ok = self.ring.words[self.slot][0] == 2 * m
        if not ok:
            self.dropped += 1
        if self.next == m:
            self.next = m + 1
        return ok

    def read(self, pool: SparePool | None = None) -> bytes | FrameBuffer | None:
        """The next message, copied out and consistent; None when no new one is complete. The copy of a message
        over ``LARGE_FRAME`` is a buffer from ``pool`` when one is given (reused when free: no fresh pages to
        fault in), as TCPROS receives large frames into FrameBuffers; anything else is copied into bytes.

        Raises:
            RemoteProtocolError: the ring's words contradict each other (a publisher that lies).
        """
        while True:
            got = self.begin()
            if got is None:
                return None
            m, n = got
            slot = self.ring.data[self.slot][self.start : self.start + n]
            data = pool.copy(slot) if pool is not None and n > LARGE_FRAME else bytes(slot)
            if self.finish(m):
                return data

    def view(self) -> tuple[int, memoryview] | None:
        """Zero-copy: the next message's number and a read-only view of its bytes in the slot, or None.

        The view is consistent only while ``intact(m)`` holds: check it after using the bytes.
        """
        got = self.begin()
        if got is None:
            return None
        m, n = got
        if self.next == m:
            self.next = m + 1
        return m, self.ring.data[self.slot][self.start : self.start + n].toreadonly()

    def intact(self, m: int, slot: int | None = None) -> bool:
        """Message ``m`` is still in ``slot`` (default: the directory's; a view of it taken earlier shows its
        bytes, not a newer one's)."""
        ring = self.ring
        return bool(ring.words[ring.slot_of(m) if slot is None else slot][0] == 2 * m)
