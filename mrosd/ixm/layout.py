"""The bytes of one IXM segment: a fixed header with a seqlock, then two payload slots (double buffering).

This module owns the layout of a shared-memory segment and the seqlock protocol over it, on a plain
``memoryview``: it knows nothing of sockets, file descriptors or the daemon, so that it can be tested on a
``bytearray``. Layout (the host's byte order: a segment never leaves its host; 64-byte header so the first
slot starts on its own cache line)::

    0   4s  magic b"IXM1"
    4   H   layout version (2: two slots)
    6   H   type code (``mrosd.ixm.types``)
    8   Q   sequence counter: +2 per completed write, odd while a write is in progress
    16  I   capacity of one slot in bytes (exact for fixed-size types)
    20  I   element count for fixed arrays (0 otherwise)
    24  I   reserved (0; the daemon never writes a segment after handing it out)
    28  I   reserved (0)
    32  I   length of the value in slot 0 (written with that slot's data)
    36  I   length of the value in slot 1
    40  24s type name (UTF-8, NUL padded, informational)
    64  ... slot 0, then slot 1 (``capacity`` bytes each)

The active slot is part of the counter, so publishing a value and flipping the slot are one 8-byte store:
the value of completed write number ``k`` (counter ``2k``) lives in slot ``k & 1``, and the slot readers
are directed to is ``(seq >> 1) & 1`` for an even *and* an odd counter. A write of value ``k + 1`` makes the
counter odd (``2k + 1``: readers still go to slot ``k & 1``), copies into the other slot, then stores
``2k + 2``. So a writer that dies mid-copy (counter left odd) leaves the last complete value where readers
look, and they keep reading it with no error; the next writer finishes the interrupted slot from the odd
counter without touching the active one.

Why a seqlock as well: a writer must never wait for readers (a slow or stopped reader cannot stall a control
loop), so a reader copying slot ``k & 1`` can be lapped: the writer publishes ``k + 1`` and then starts
``k + 2`` into the very slot being copied. The reader reads the counter before and after its copy and retries
only in that case (counter after >= ``2k + 3``); a reader that merely raced one flip keeps its consistent copy.
The counter and the lengths are read and written through ``memoryview.cast`` items: one aligned 8-byte (or
4-byte) load or store each, which x86-64 performs atomically. (``struct.pack_into`` is not usable here: it
zeroes its target before packing, so a reader spinning on the counter saw 0 between two values.) x86-64 keeps
stores (and loads) in program order, so the counter updates are seen no earlier than the data they guard.
Several writers on one key are serialised by the client with ``flock`` on the writers' lock file (not
here): this module assumes one writer at a time.
"""

from __future__ import annotations

import struct
import time

from mrosd.errors import IxmError

__all__ = [
    "HEADER_SIZE",
    "LAYOUT_VERSION",
    "MAGIC",
    "MAX_LAPPED_WAIT",
    "SLOTS",
    "SegmentLayout",
]

MAGIC = b"IXM1"
LAYOUT_VERSION = 2
HEADER_SIZE = 64
SLOTS = 2

#: How long a reader keeps retrying while a live writer keeps overwriting the slot it is copying (possible
#: only when the writer completes two writes during one copy, over and over) before it gives up.
MAX_LAPPED_WAIT = 0.5

_HEAD = struct.Struct("=4sHHQIIIIII24s")
_SEQ_OFF = 8
_LEN_OFF = 32  # two 4-byte lengths, one per slot
assert _HEAD.size == HEADER_SIZE


class SegmentLayout:
    """A typed view of one segment: header fields, seqlocked read and double-buffered write of the value.

    ``buf`` is the whole mapping (header + slots); it may be read-only for readers, in which case
    the write methods raise ``TypeError`` from memoryview itself (and the kernel refuses the mapping first).
    """

    __slots__ = ("buf", "capacity", "counter", "lengths", "slots")

    def __init__(self, buf: memoryview) -> None:
        if len(buf) < HEADER_SIZE:
            raise IxmError(f"segment of {len(buf)} bytes is smaller than the {HEADER_SIZE}-byte IXM header")
        self.buf = buf
        magic, version, _code, _seq, capacity, *_rest = _HEAD.unpack_from(buf, 0)
        if magic != MAGIC or version != LAYOUT_VERSION:
            raise IxmError(f"not an IXM v{LAYOUT_VERSION} segment (magic {magic!r}, version {version})")
        if self.segment_size(capacity) > len(buf):
            raise IxmError(f"segment header claims {SLOTS} slots of {capacity} bytes but the mapping has {len(buf)}")
        self.capacity: int = capacity
        #: The sequence counter as one native 8-byte item (atomic loads and stores, see the module doc).
        self.counter = buf[_SEQ_OFF : _SEQ_OFF + 8].cast("Q")
        #: The value lengths of slot 0 and slot 1.
        self.lengths = buf[_LEN_OFF : _LEN_OFF + 8].cast("I")
        self.slots = (
            buf[HEADER_SIZE : HEADER_SIZE + capacity],
            buf[HEADER_SIZE + capacity : HEADER_SIZE + 2 * capacity],
        )

    @staticmethod
    def segment_size(capacity: int) -> int:
        """Bytes to allocate for values of up to ``capacity`` bytes: the header and two slots."""
        return HEADER_SIZE + SLOTS * capacity

    @staticmethod
    def header(type_code: int, capacity: int, count: int, type_name: str) -> bytes:
        """A fresh header (counter 0, empty value): the daemon writes it with ``pwrite`` before sealing."""
        name = type_name.encode("utf-8")[:24]
        return _HEAD.pack(MAGIC, LAYOUT_VERSION, type_code, 0, capacity, count, 0, 0, 0, 0, name)

    @classmethod
    def initialize(cls, buf: memoryview, type_code: int, capacity: int, count: int, type_name: str) -> SegmentLayout:
        """Write a fresh header into ``buf`` (tests and in-memory use)."""
        if cls.segment_size(capacity) > len(buf):
            raise IxmError(f"buffer of {len(buf)} bytes cannot hold {SLOTS} slots of {capacity} bytes")
        buf[:HEADER_SIZE] = cls.header(type_code, capacity, count, type_name)
        return cls(buf)

    def release(self) -> None:
        """Release the views so that the underlying mmap can be closed."""
        for view in (*self.slots, self.counter, self.lengths):
            view.release()
        self.buf.release()

    # header fields -------------------------------------------------------------------------------------

    @property
    def type_code(self) -> int:
        return int(struct.unpack_from("=H", self.buf, 6)[0])

    @property
    def count(self) -> int:
        return int(struct.unpack_from("=I", self.buf, 20)[0])

    @property
    def type_name(self) -> str:
        raw: bytes = struct.unpack_from("24s", self.buf, 40)[0]
        return raw.rstrip(b"\0").decode("utf-8", "replace")

    @property
    def seq(self) -> int:
        """The sequence counter; ``seq // 2`` completed writes, odd while one is in progress."""
        return int(self.counter[0])

    @staticmethod
    def slot_of(seq: int) -> int:
        """The slot readers are directed to while the counter is ``seq`` (even or odd)."""
        return (seq >> 1) & 1

    def active(self) -> tuple[int, memoryview]:
        """The published counter (even) and the slot holding its value; no copy, no consistency check."""
        seq = self.counter[0] & ~1
        return seq, self.slots[(seq >> 1) & 1]

    # writing -------------------------------------------------------------------------------------------

    def begin_write(self) -> int:
        """Make the counter odd (readers stay on the active slot) and return the value to pass to ``end_write``.

        The new value goes into ``slots[slot_of(returned value)]``, the slot readers are not directed to.
        An odd counter means a writer died mid-copy: its slot is the inactive one, so it is simply reused.
        """
        seq = self.counter[0]
        if not seq & 1:
            self.counter[0] = seq + 1
        return (seq | 1) + 1

    def target(self, seq: int) -> memoryview:
        """The slot that ``end_write(seq, ...)`` publishes (the inactive one while the write is in progress)."""
        return self.slots[(seq >> 1) & 1]

    def end_write(self, seq: int, length: int) -> None:
        """Publish ``length`` bytes of the target slot: set its length, then flip slot and counter at once."""
        self.lengths[(seq >> 1) & 1] = length
        self.counter[0] = seq

    def write(self, data: bytes | bytearray | memoryview) -> int:
        """Copy ``data`` into the inactive slot and publish it; returns the new counter value.

        Raises:
            IxmError: the value is larger than the segment's capacity (the published value is kept).
        """
        n = len(data)
        if n > self.capacity:
            raise IxmError(f"value of {n} bytes does not fit the segment's {self.capacity}-byte capacity")
        seq = self.begin_write()
        self.slots[(seq >> 1) & 1][:n] = data
        self.end_write(seq, n)
        return seq

    def copy_active_to_target(self, seq: int) -> None:
        """Start the write ``seq`` from the published value (for in-place partial updates)."""
        current = seq - 2
        n = self.lengths[(current >> 1) & 1]
        n = min(n, self.capacity)
        self.slots[(seq >> 1) & 1][:n] = self.slots[(current >> 1) & 1][:n]

    # reading -------------------------------------------------------------------------------------------

    def read(self) -> tuple[int, bytes]:
        """A consistent copy of the published value and its (even) counter; never torn, never an error
        because a writer died: a write in progress or abandoned leaves the published value readable.

        Raises:
            IxmError: a live writer overwrote the slot being copied for ``MAX_LAPPED_WAIT`` seconds.
        """
        counter = self.counter
        slots = self.slots
        deadline = 0.0
        while True:
            seq = counter[0] & ~1
            slot = (seq >> 1) & 1
            n = self.lengths[slot]
            if n <= self.capacity:
                data = bytes(slots[slot][:n])
                if counter[0] <= seq + 2:
                    return seq, data
            deadline = self._spin(deadline)

    def read_into(self, out: bytearray | memoryview) -> tuple[int, int]:
        """Copy the published value into ``out`` (one copy, consistent); returns (counter, length).

        Raises:
            IxmError: ``out`` is too small, or a live writer kept overwriting the slot being copied.
        """
        counter = self.counter
        slots = self.slots
        deadline = 0.0
        while True:
            seq = counter[0] & ~1
            slot = (seq >> 1) & 1
            n = self.lengths[slot]
            if n <= self.capacity:
                if n > len(out):
                    raise IxmError(f"buffer of {len(out)} bytes is too small for a {n}-byte value")
                out[:n] = slots[slot][:n]
                if counter[0] <= seq + 2:
                    return seq, n
            deadline = self._spin(deadline)

    @staticmethod
    def _spin(deadline: float) -> float:
        now = time.monotonic()
        if deadline == 0.0:
            return now + MAX_LAPPED_WAIT
        if now > deadline:
            raise IxmError(f"the writer overwrote the value faster than it could be copied for {MAX_LAPPED_WAIT} s")
        time.sleep(0)
        return deadline
