"""Length-prefixed TCPROS framing: an incremental decoder and the frame encoder.

Bytes go in with ``feed()``; ``maybe_next_frame()`` returns one complete frame body or None while
incomplete. ``feed_frames()`` is the batch form (one call per socket read). For
``asyncio.BufferedProtocol`` the decoder also lends the buffer to receive into: ``get_buffer()`` /
``buffer_updated()``. Once a large frame's length is known, ``get_buffer()`` is a view into that frame's
own exact-size buffer, so the kernel writes the body straight where it is delivered from (no copies).
The length prefix is checked against the decoder's limit before any byte of the body is buffered, so a
4 GB claim is refused at once instead of allocating. No sockets, no asyncio.
"""

from __future__ import annotations

import struct

from mrosd.errors import RemoteProtocolError

#: Largest message frame accepted. roscpp refuses messages over 1 GB as well ("a message of over a
#: gigabyte was predicted"); an 8 MB image or a large point cloud is far below it.
MAX_FRAME_SIZE = 1024 * 1024 * 1024

_U32 = struct.Struct("<I")

#: Frames above this size that span socket reads get a buffer of their own size (one copy, no regrowth);
#: below it, joining a straddling tail costs less than a separate allocation.
LARGE_FRAME = 64 * 1024

#: Size of the receive buffer lent by ``get_buffer()`` while no large frame is pending (allocated on
#: first use, per connection). Large bodies bypass it, so it only bounds how many small frames one read takes.
RECV_BUFFER_SIZE = 64 * 1024

#: Compact the buffer once this many consumed bytes sit at its front (amortises the memmove).
_COMPACT_AT = 64 * 1024


def encode_frame(body: bytes | bytearray | memoryview) -> bytes:
    """Prefix a serialized body with its 4-byte little-endian length (one copy of the body)."""
    return _U32.pack(len(body)) + bytes(body)


class FrameDecoder:
    """Incremental decoder of ``<uint32 length><body>`` frames with a size limit."""

    __slots__ = ("_buf", "_large", "_large_filled", "_pos", "_recv", "max_size")

    def __init__(self, max_size: int = MAX_FRAME_SIZE) -> None:
        self._buf = bytearray()
        self._pos = 0
        self._large: bytearray | None = None
        self._large_filled = 0
        self._recv: bytearray | None = None
        self.max_size = max_size

    @property
    def buffered(self) -> int:
        """Bytes received and not yet returned as frames."""
        return len(self._buf) - self._pos + self._large_filled

    def feed(self, data: bytes | bytearray | memoryview) -> None:
        """Append received bytes."""
        self._buf += data

    def feed_frames(self, data: bytes | bytearray | memoryview) -> list[bytes | bytearray]:
        """``feed(data)`` and return every frame now complete (the hot path: one call per socket read).

        Frames are sliced straight out of ``data``; only an incomplete tail is kept. A large frame
        (over LARGE_FRAME) that spans reads gets its own buffer of exactly its size, allocated once when its
        length is known and returned as is (a bytearray): large bodies are copied once, never regrown or
        re-sliced. Do not mix with ``maybe_next_frame`` while a large frame is pending.

        Raises:
            RemoteProtocolError: a length prefix exceeds ``max_size``; the connection must be closed.
        """
        frames: list[bytes | bytearray] = []
        view = memoryview(data)
        large = self._large
        if large is not None:
            take = min(len(large) - self._large_filled, len(view))
            large[self._large_filled : self._large_filled + take] = view[:take]
            self._large_filled += take
            if self._large_filled < len(large):
                return frames
            frames.append(large)
            self._large = None
            self._large_filled = 0
            view = view[take:]
        if len(self._buf) != self._pos:
            # A short tail (a length prefix or a small frame) straddled the previous read: join it.
            view = memoryview(bytes(self._buf[self._pos :]) + bytes(view))
            self._buf.clear()
            self._pos = 0
        size = len(view)
        pos = 0
        limit = self.max_size
        unpack = _U32.unpack_from
        while size - pos >= 4:
            (length,) = unpack(view, pos)
            if length > limit:
                raise RemoteProtocolError(f"frame of {length} bytes announced, the limit is {limit}")
            end = pos + 4 + length
            if end > size:
                if length > LARGE_FRAME:
                    large = bytearray(length)
                    avail = size - pos - 4
                    large[:avail] = view[pos + 4 : size]
                    self._large = large
                    self._large_filled = avail
                    return frames
                break
            frames.append(bytes(view[pos + 4 : end]))
            pos = end
        if pos < size:
            self._buf += view[pos:]
        return frames

    # --- receiving in place (asyncio.BufferedProtocol) -------------------------------------------------

    def get_buffer(self) -> memoryview:
        """Where the next received bytes go: the rest of a pending large frame, else the receive buffer.

        A pending large frame's view ends exactly at the frame's end, so a read never spills the next
        frame into it. Follow every call with ``buffer_updated(n)`` (or ``received(n)``).
        """
        large = self._large
        if large is not None:
            return memoryview(large)[self._large_filled :]
        if self._recv is None:
            self._recv = bytearray(RECV_BUFFER_SIZE)
        return memoryview(self._recv)

    def received(self, nbytes: int) -> memoryview:
        """The ``nbytes`` just written into the receive buffer, for callers that ``feed()`` them themselves
        (e.g. until a connection header is parsed). Only valid while no large frame is pending, which
        holds as long as ``feed_frames``/``buffer_updated`` were not used."""
        if self._large is not None or self._recv is None:
            raise RuntimeError("received() is only valid after get_buffer() lent the receive buffer")
        return memoryview(self._recv)[:nbytes]

    def buffer_updated(self, nbytes: int) -> list[bytes | bytearray]:
        """``nbytes`` were written into the last ``get_buffer()`` view: return every frame now complete.

        Same results, limits and errors as ``feed_frames`` on those bytes; a completed large frame is the
        very bytearray the kernel wrote into.

        Raises:
            RemoteProtocolError: a length prefix exceeds ``max_size``; the connection must be closed.
        """
        large = self._large
        if large is not None:
            self._large_filled += nbytes
            if self._large_filled < len(large):
                return []
            self._large = None
            self._large_filled = 0
            return [large]
        if self._recv is None:
            raise RuntimeError("buffer_updated() without get_buffer()")
        return self.feed_frames(memoryview(self._recv)[:nbytes])

    def take(self, count: int) -> bytes | None:
        """Return exactly ``count`` raw bytes (e.g. a service ok byte), or None while fewer are buffered."""
        if len(self._buf) - self._pos < count:
            return None
        out = bytes(self._buf[self._pos : self._pos + count])
        self._advance(count)
        return out

    def maybe_next_frame(self) -> bytes | None:
        """The next complete frame body, or None while incomplete.

        Raises:
            RemoteProtocolError: the length prefix exceeds ``max_size``; the connection must be closed.
        """
        buf = self._buf
        pos = self._pos
        avail = len(buf) - pos
        if avail < 4:
            return None
        (length,) = _U32.unpack_from(buf, pos)
        if length > self.max_size:
            raise RemoteProtocolError(f"frame of {length} bytes announced, the limit is {self.max_size}")
        if avail < 4 + length:
            return None
        start = pos + 4
        with memoryview(buf) as view:  # one copy of the body, not slice-then-copy
            body = bytes(view[start : start + length])
        self._advance(4 + length)
        return body

    def _advance(self, count: int) -> None:
        self._pos += count
        if self._pos == len(self._buf):
            self._buf.clear()
            self._pos = 0
        elif self._pos >= _COMPACT_AT and self._pos * 2 >= len(self._buf):
            del self._buf[: self._pos]
            self._pos = 0
