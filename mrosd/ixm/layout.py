"""The bytes of one IXM segment: a fixed header with a seqlock, then the payload.

This module owns the layout of a shared-memory segment and the seqlock protocol over it, on a plain
``memoryview``: it knows nothing of sockets, file descriptors or the daemon, so that it can be tested on a
``bytearray``. Layout (little-endian, 64-byte header so the payload starts on its own cache line)::

    0   4s  magic b"IXM1"
    4   H   layout version
    6   H   type code (``mrosd.ixm.types``)
    8   Q   sequence counter: odd while a write is in progress, +2 per completed write
    16  I   payload capacity in bytes
    20  I   length of the current value in bytes (written inside the seqlock)
    24  I   element count for fixed arrays (0 otherwise)
    28  I   reader-set generation, bumped by the daemon when the set of readers to wake changes
    32  32s type name (UTF-8, NUL padded, informational)
    64  ... payload

Why a seqlock: a writer must never wait for readers (a slow or stopped reader cannot stall a control loop),
and a reader must never see a torn value. The writer makes the counter odd, writes, makes it even again;
a reader copies the payload between two reads of the counter and retries when they differ or are odd.
CPython performs each ``pack_into``/slice copy as one C call, and x86-64 keeps stores in program order, so
the counter updates are seen no earlier than the data they guard. Several writers on one key are
serialised by the client with ``flock`` on the segment's file (not here): this module assumes one writer at
a time. A writer that died mid-write leaves the counter odd; the next writer repairs it.
"""

from __future__ import annotations

import struct
import time

from mrosd.errors import IxmError

__all__ = [
    "HEADER_SIZE",
    "LAYOUT_VERSION",
    "MAGIC",
    "MAX_TORN_WAIT",
    "SegmentLayout",
]

MAGIC = b"IXM1"
LAYOUT_VERSION = 1
HEADER_SIZE = 64

#: How long a reader keeps retrying while the counter stays odd before it concludes that the writer died
#: mid-write (a live writer holds the counter odd only for the duration of one copy).
MAX_TORN_WAIT = 0.5

_HEAD = struct.Struct("<4sHHQIIII32s")
_SEQ = struct.Struct("<Q")
_U32 = struct.Struct("<I")
_SEQ_OFF = 8
_LEN_OFF = 20
_GEN_OFF = 28
assert _HEAD.size == HEADER_SIZE


class SegmentLayout:
    """A typed view of one segment: header fields, seqlocked read and write of the payload.

    ``buf`` is the whole mapping (header + payload); it may be read-only for readers, in which case
    the write methods raise ``TypeError`` from memoryview itself (and the kernel refuses the mapping first).
    """

    __slots__ = ("buf", "capacity", "payload")

    def __init__(self, buf: memoryview) -> None:
        if len(buf) < HEADER_SIZE:
            raise IxmError(f"segment of {len(buf)} bytes is smaller than the {HEADER_SIZE}-byte IXM header")
        self.buf = buf
        magic, version, _code, _seq, capacity, _len, _count, _gen, _name = _HEAD.unpack_from(buf, 0)
        if magic != MAGIC or version != LAYOUT_VERSION:
            raise IxmError(f"not an IXM v{LAYOUT_VERSION} segment (magic {magic!r}, version {version})")
        if HEADER_SIZE + capacity > len(buf):
            raise IxmError(f"segment header claims {capacity} payload bytes but the mapping has {len(buf)}")
        self.capacity: int = capacity
        self.payload = buf[HEADER_SIZE : HEADER_SIZE + capacity]

    @staticmethod
    def segment_size(capacity: int) -> int:
        """Bytes to allocate for a payload of ``capacity`` bytes."""
        return HEADER_SIZE + capacity

    @classmethod
    def initialize(cls, buf: memoryview, type_code: int, capacity: int, count: int, type_name: str) -> SegmentLayout:
        """Write a fresh header (counter 0, empty value) into ``buf``; the daemon does this once at creation."""
        if HEADER_SIZE + capacity > len(buf):
            raise IxmError(f"buffer of {len(buf)} bytes cannot hold {capacity} payload bytes")
        name = type_name.encode("utf-8")[:32]
        _HEAD.pack_into(buf, 0, MAGIC, LAYOUT_VERSION, type_code, 0, capacity, 0, count, 0, name)
        return cls(buf)

    def release(self) -> None:
        """Release the views so that the underlying mmap can be closed."""
        self.payload.release()
        self.buf.release()

    # header fields -------------------------------------------------------------------------------------

    @property
    def type_code(self) -> int:
        return int(struct.unpack_from("<H", self.buf, 6)[0])

    @property
    def count(self) -> int:
        return int(_U32.unpack_from(self.buf, 24)[0])

    @property
    def type_name(self) -> str:
        raw: bytes = struct.unpack_from("32s", self.buf, 32)[0]
        return raw.rstrip(b"\0").decode("utf-8", "replace")

    @property
    def seq(self) -> int:
        """The sequence counter; ``seq // 2`` completed writes, odd while one is in progress."""
        return int(_SEQ.unpack_from(self.buf, _SEQ_OFF)[0])

    @property
    def generation(self) -> int:
        """The reader-set generation the daemon last published."""
        return int(_U32.unpack_from(self.buf, _GEN_OFF)[0])

    def bump_generation(self) -> int:
        """Daemon side: announce that the set of readers to wake changed; returns the new generation."""
        gen = (self.generation + 1) & 0xFFFFFFFF
        _U32.pack_into(self.buf, _GEN_OFF, gen)
        return gen

    # seqlock -------------------------------------------------------------------------------------------

    def begin_write(self) -> int:
        """Make the counter odd and return the value to pass to ``end_write``."""
        seq = self.seq
        if seq & 1:  # a writer died mid-write: start from the next even value
            seq += 1
        _SEQ.pack_into(self.buf, _SEQ_OFF, seq + 1)
        return seq + 2

    def end_write(self, seq: int, length: int) -> None:
        """Publish ``length`` bytes of payload and make the counter even again."""
        _U32.pack_into(self.buf, _LEN_OFF, length)
        _SEQ.pack_into(self.buf, _SEQ_OFF, seq)

    def write(self, data: bytes | bytearray | memoryview) -> int:
        """Copy ``data`` into the payload under the seqlock; returns the new counter value.

        Raises:
            IxmError: the value is larger than the segment's capacity.
        """
        n = len(data)
        if n > self.capacity:
            raise IxmError(f"value of {n} bytes does not fit the segment's {self.capacity}-byte capacity")
        seq = self.begin_write()
        self.payload[:n] = data
        self.end_write(seq, n)
        return seq

    def read(self) -> tuple[int, bytes]:
        """A consistent copy of the current value and the counter it belongs to (never torn).

        Raises:
            IxmError: the counter stayed odd for ``MAX_TORN_WAIT`` seconds (the writer died mid-write).
        """
        buf = self.buf
        payload = self.payload
        deadline = 0.0
        while True:
            seq = _SEQ.unpack_from(buf, _SEQ_OFF)[0]
            if not seq & 1:
                n = _U32.unpack_from(buf, _LEN_OFF)[0]
                if n <= self.capacity:
                    data = bytes(payload[:n])
                    if _SEQ.unpack_from(buf, _SEQ_OFF)[0] == seq:
                        return seq, data
            deadline = self._spin(deadline)

    def read_into(self, out: bytearray | memoryview) -> tuple[int, int]:
        """Copy the current value into ``out`` (one copy, consistent); returns (counter, length).

        Raises:
            IxmError: ``out`` is too small, or the writer died mid-write.
        """
        buf = self.buf
        deadline = 0.0
        while True:
            seq = _SEQ.unpack_from(buf, _SEQ_OFF)[0]
            if not seq & 1:
                n = _U32.unpack_from(buf, _LEN_OFF)[0]
                if n <= self.capacity:
                    if n > len(out):
                        raise IxmError(f"buffer of {len(out)} bytes is too small for a {n}-byte value")
                    out[:n] = self.payload[:n]
                    if _SEQ.unpack_from(buf, _SEQ_OFF)[0] == seq:
                        return seq, n
            deadline = self._spin(deadline)

    @staticmethod
    def _spin(deadline: float) -> float:
        now = time.monotonic()
        if deadline == 0.0:
            return now + MAX_TORN_WAIT
        if now > deadline:
            raise IxmError("the segment stayed mid-write too long: its writer probably died while writing")
        time.sleep(0)
        return deadline
