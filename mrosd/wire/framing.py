"""Length-prefixed framing, the one decoder and encoder of TCPROS topics, TCPROS services and IXM control.

Bytes go in with ``feed()``; ``maybe_next_frame()`` returns one complete frame body or None while
incomplete. ``feed_frames()`` is the batch form (one call per socket read). For
``asyncio.BufferedProtocol`` the decoder also lends the buffer to receive into: ``get_buffer()`` /
``buffer_updated()``. Once a large frame's length is known, ``get_buffer()`` is a view into that frame's
own ``FrameBuffer``, so the kernel writes the body straight where it is delivered from, and the buffer
becomes the decoded message's storage (see ``mrosd.msg.runtime.FrameBuffer`` for the ownership rule); once
delivered it is offered to the process's ``SparePool`` (``mrosd.wire.spares``), which lends it to a later large
frame of any connection once nobody holds it, within one bound for the whole process.
That buffer grows with the bytes that actually arrive, never with the announced length, and the length is
checked against the decoder's limit before anything is buffered: a 4 GB claim is refused at once, and a
1 GiB claim followed by 5 bytes costs kilobytes. No sockets, no asyncio.

Service responses put one ok byte (1 = success) before each frame: a decoder made with ``ok_byte=True``
reads them with ``feed_responses()``, and ``encode_frame(body, ok=...)`` writes them. The IXM control
protocol (``mrosd.ixm.protocol``) uses the same decoder with its own limits.
"""

from __future__ import annotations

import struct

from mrosd.errors import RemoteProtocolError
from mrosd.msg.runtime import FrameBuffer
from mrosd.wire.spares import SparePool, spare_pool

__all__ = [
    "GROWTH",
    "LARGE_FRAME",
    "MAX_FRAME_SIZE",
    "FrameBuffer",
    "FrameDecoder",
    "Response",
    "encode_frame",
    "frame_prefix",
]

#: Largest message frame accepted. roscpp refuses messages over 1 GB as well ("a message of over a
#: gigabyte was predicted"); an 8 MB image or a large point cloud is far below it.
MAX_FRAME_SIZE = 1024 * 1024 * 1024

_U32 = struct.Struct("<I")
_OK_U32 = struct.Struct("<BI")

#: A service response as ``feed_responses()`` returns it: (the ok byte was 1, the frame body).
Response = tuple[bool, bytes | bytearray]

#: Frames above this size that span socket reads get a buffer of their own size (one copy, no regrowth);
#: below it, joining a straddling tail costs less than a separate allocation.
LARGE_FRAME = 64 * 1024

#: A pending large frame's buffer is at most this many times the bytes of it received so far (and at least
#: LARGE_FRAME); once a 1/GROWTH share of it has arrived it gets its full size. Memory follows data, not the
#: length a peer announces: a buffer that grows is zero-filled to its new size, so all of its capacity is
#: resident at once (at 16, a peer that announced 256 MiB and sent 16 MiB held 256 MiB). Growing by doubling
#: costs no more than in large steps: the buffer is resized in place (the kernel moves no pages), and every
#: byte is zeroed once either way (a cold 8 MB frame in 256 KiB reads: 6-13 ms at 16, 7-23 ms at 2 on a
#: loaded 2-core machine; 40 MB: 76-128 ms and 63-107 ms).
GROWTH = 2

#: Size of the receive buffer lent by ``get_buffer()`` while no large frame is pending (allocated on
#: first use, per connection). Large bodies bypass it, so it only bounds how many small frames one read takes.
RECV_BUFFER_SIZE = 64 * 1024

#: Size of the receive buffer lent while the connection header is still incomplete (``header_max_size``).
#: Until a peer has identified itself it gets this much and no more: its header bytes are kept as they
#: arrive (memory follows bytes received), and the big receive buffer is allocated only after the header.
HEADER_RECV_SIZE = 4 * 1024

#: Compact the buffer once this many consumed bytes sit at its front (amortises the memmove).
_COMPACT_AT = 64 * 1024


def frame_prefix(size: int, *, ok: bool | None = None) -> bytes:
    """What goes on the wire before a body of ``size`` bytes: its 4-byte little-endian length, after the ok
    byte of a service response when ``ok`` is given. For vectored writes (prefix, then the body's pieces)."""
    if ok is None:
        return _U32.pack(size)
    return _OK_U32.pack(1 if ok else 0, size)


def encode_frame(body: bytes | bytearray | memoryview, *, ok: bool | None = None) -> bytes:
    """``frame_prefix(len(body), ok=ok)`` and the body in one bytes (one copy of the body)."""
    return frame_prefix(len(body), ok=ok) + bytes(body)


def _grown(buf: FrameBuffer, filled: int, size: int) -> FrameBuffer:
    """``buf`` with capacity ``size``, its first ``filled`` bytes kept (resized in place when possible)."""
    try:
        buf.extend(_zeros(size - len(buf)))
        return buf
    except BufferError:  # a view of it is still alive (the caller's read buffer): move once
        new = FrameBuffer(size)
        new[:filled] = memoryview(buf)[:filled]
        return new


def _zeros(count: int) -> bytes:
    return bytes(count)  # calloc'd: large zero runs cost no memset of their own


class FrameDecoder:
    """Incremental decoder of ``<uint32 length><body>`` frames with a size limit.

    A large frame that spans reads is received into a ``FrameBuffer`` whose capacity follows the bytes that
    actually arrived (at most ``GROWTH`` times them, and ``LARGE_FRAME`` to start), never the length the
    peer announced: a peer that claims 1 GiB and sends 5 bytes costs about LARGE_FRAME.
    """

    __slots__ = (
        "_buf",
        "_large",
        "_large_filled",
        "_large_ok",
        "_large_size",
        "_pos",
        "_recv",
        "_spares",
        "_then_max",
        "max_size",
        "ok_byte",
    )

    def __init__(
        self,
        max_size: int = MAX_FRAME_SIZE,
        *,
        header_max_size: int | None = None,
        ok_byte: bool = False,
        spares: SparePool | None = None,
    ) -> None:
        #: Every frame after the connection header (every frame without ``header_max_size``) follows an ok
        #: byte, as service responses do: read them with ``feed_responses()``, not the frame methods (which
        #: do not check it on the data path; ``maybe_next_frame`` refuses).
        self.ok_byte = ok_byte
        self._large_ok = True
        self._buf = bytearray()
        self._pos = 0
        self._large: FrameBuffer | None = None
        self._large_filled = 0
        self._large_size = 0
        self._recv: bytearray | None = None
        #: Where delivered large frames' buffers are kept for reuse (default: the process's pool, shared by
        #: every connection and bounded for all of them). Once nothing refers to one any more (the message
        #: built on it is gone, no transport still writes it), a later large frame is received into it again:
        #: steady streams of images cost no allocation, no zero-filling and no page faults per frame.
        self._spares = spare_pool() if spares is None else spares
        #: The limit of the frame being decoded. With ``header_max_size`` the first frame (a connection
        #: header) is judged by that limit and every later one by ``max_size``: the switch happens inside
        #: the decoder, between two frames of the same read (as h11 switches from headers to body).
        self.max_size = max_size if header_max_size is None else header_max_size
        self._then_max: int | None = None if header_max_size is None else max_size

    @property
    def buffered(self) -> int:
        """Bytes received and not yet returned as frames."""
        return len(self._buf) - self._pos + self._large_filled

    def feed(self, data: bytes | bytearray | memoryview) -> None:
        """Append received bytes."""
        self._buf += data

    def _capacity_for(self, filled: int) -> int:
        """The pending large frame's buffer size once ``filled`` bytes of it arrived: the whole frame once
        a 1/GROWTH share of it is here, else GROWTH times what arrived (LARGE_FRAME at least)."""
        size = self._large_size
        if filled * GROWTH >= size:
            return size
        return min(size, max(LARGE_FRAME, filled * GROWTH))

    def _start_large(self, length: int, first: memoryview) -> None:
        self._large_size = length
        avail = len(first)
        capacity = self._capacity_for(max(avail, 1))
        large = self._spares.take(capacity)
        if large is None:
            large = FrameBuffer(capacity)
        elif len(large) > length:
            del large[length:]
        large[:avail] = first
        self._large = large
        self._large_filled = avail

    def _finish_large(self) -> FrameBuffer:
        large = self._large
        assert large is not None
        self._large = None
        self._large_filled = 0
        self._large_size = 0
        self._spares.keep(large)
        return large

    def feed_frames(self, data: bytes | bytearray | memoryview) -> list[bytes | bytearray]:
        """``feed(data)`` and return every frame now complete (the hot path: one call per socket read).

        Frames are sliced straight out of ``data``; only an incomplete tail is kept. A large frame
        (over LARGE_FRAME) that spans reads is collected in a FrameBuffer that grows with the bytes received
        and is returned as is: large bodies are copied once. Do not mix with ``maybe_next_frame`` while a
        large frame is pending.

        Raises:
            RemoteProtocolError: a length prefix exceeds ``max_size``; the connection must be closed.
        """
        frames: list[bytes | bytearray] = []
        view = memoryview(data)
        if self._large is not None:
            take = self._fill_large(view)
            if self._large_filled < self._large_size:
                return frames
            frames.append(self._finish_large())
            self._first_out()
            view = view[take:]
        if len(self._buf) != self._pos:
            view = self._join_tail(view)
        size = len(view)
        pos = 0
        unpack = _U32.unpack_from
        while size - pos >= 4:
            (length,) = unpack(view, pos)
            if length > self.max_size:
                raise RemoteProtocolError(f"frame of {length} bytes announced, the limit is {self.max_size}")
            end = pos + 4 + length
            if end > size:
                if length > LARGE_FRAME:
                    self._start_large(length, view[pos + 4 : size])
                    return frames
                break
            frames.append(bytes(view[pos + 4 : end]))
            pos = end
            if self._then_max is not None:
                self._first_out()
        if pos < size:
            self._buf += view[pos:]
        return frames

    def feed_responses(self, data: bytes | bytearray | memoryview) -> list[Response]:
        """``feed_frames`` for a decoder made with ``ok_byte=True``: every complete (ok, body), ok being
        whether the frame's ok byte was 1. The connection header, which has no ok byte, comes out as ok.

        Same limits, large-frame handling and errors as ``feed_frames``; the length after an ok byte is
        judged before anything of the frame is kept.

        Raises:
            RemoteProtocolError: a length prefix exceeds ``max_size``; the connection must be closed.
            RuntimeError: the decoder was not made with ``ok_byte=True``.
        """
        if not self.ok_byte:
            raise RuntimeError("feed_responses() needs a FrameDecoder(ok_byte=True)")
        out: list[Response] = []
        view = memoryview(data)
        if self._large is not None:
            take = self._fill_large(view)
            if self._large_filled < self._large_size:
                return out
            out.append((self._large_ok, self._finish_large()))
            self._first_out()
            view = view[take:]
        if len(self._buf) != self._pos:
            view = self._join_tail(view)
        size = len(view)
        pos = 0
        unpack = _U32.unpack_from
        while True:
            skip = 0 if self._then_max is not None else 1  # the header has no ok byte
            start = pos + skip + 4
            if start > size:
                break
            (length,) = unpack(view, start - 4)
            if length > self.max_size:
                raise RemoteProtocolError(f"frame of {length} bytes announced, the limit is {self.max_size}")
            ok = view[pos] == 1 if skip else True
            end = start + length
            if end > size:
                if length > LARGE_FRAME:
                    self._large_ok = ok
                    self._start_large(length, view[start:size])
                    return out
                break
            out.append((ok, bytes(view[start:end])))
            pos = end
            self._first_out()
        if pos < size:
            self._buf += view[pos:]
        return out

    def _fill_large(self, view: memoryview) -> int:
        """Copy the pending large frame's next bytes from the front of ``view``; return how many."""
        large = self._large
        assert large is not None
        filled = self._large_filled
        take = min(self._large_size - filled, len(view))
        if filled + take > len(large):
            large = self._large = _grown(large, filled, max(filled + take, self._capacity_for(filled + take)))
        large[filled : filled + take] = view[:take]
        self._large_filled = filled + take
        return take

    def _join_tail(self, view: memoryview) -> memoryview:
        """A short tail (a length prefix or a small frame) straddled the previous read: join it to ``view``."""
        joined = memoryview(bytes(self._buf[self._pos :]) + bytes(view))
        self._buf.clear()
        self._pos = 0
        return joined

    # --- receiving in place (asyncio.BufferedProtocol) -------------------------------------------------

    def get_buffer(self) -> memoryview:
        """Where the next received bytes go: the rest of a pending large frame, else the receive buffer.

        A pending large frame's view ends at most at the frame's end, so a read never spills the next
        frame into it; its buffer grows here, between reads, as its bytes arrive. Follow every call with
        ``buffer_updated(n)`` (or ``received(n)``).
        """
        large = self._large
        if large is not None:
            filled = self._large_filled
            if filled == len(large):
                large = self._large = _grown(large, filled, self._capacity_for(filled))
            return memoryview(large)[filled:]
        if self._recv is None:
            self._recv = bytearray(HEADER_RECV_SIZE if self._then_max is not None else RECV_BUFFER_SIZE)
        elif self._then_max is None and len(self._recv) < RECV_BUFFER_SIZE:
            self._recv = bytearray(RECV_BUFFER_SIZE)  # the header is done: full-size reads from now on
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
        very FrameBuffer the kernel wrote into.

        Raises:
            RemoteProtocolError: a length prefix exceeds ``max_size``; the connection must be closed.
        """
        if self._large is not None:
            self._large_filled += nbytes
            if self._large_filled < self._large_size:
                return []
            frame = self._finish_large()
            self._first_out()
            return [frame]
        if self._recv is None:
            raise RuntimeError("buffer_updated() without get_buffer()")
        if self._then_max is not None:
            return self._feed_header(memoryview(self._recv)[:nbytes])
        return self.feed_frames(memoryview(self._recv)[:nbytes])

    def _feed_header(self, data: memoryview) -> list[bytes | bytearray]:
        """Received bytes while the connection header is incomplete: kept as they come (no buffer sized by
        the claimed length, no large-frame path), the claim judged by ``header_max_size`` as soon as its 4
        bytes are here; appending keeps a header that arrives in many small reads linear."""
        buf = self._buf
        buf += data
        if len(buf) < 4:
            return []
        (length,) = _U32.unpack_from(buf, 0)
        if length > self.max_size:
            raise RemoteProtocolError(f"frame of {length} bytes announced, the limit is {self.max_size}")
        end = 4 + length
        if len(buf) < end:
            return []
        with memoryview(buf) as view:
            header = bytes(view[4:end])
            rest = bytes(view[end:])
        buf.clear()
        self._first_out()
        return [header, *self.feed_frames(rest)] if rest else [header]

    def maybe_next_frame(self) -> bytes | None:
        """The next complete frame body, or None while incomplete.

        Raises:
            RemoteProtocolError: the length prefix exceeds ``max_size``; the connection must be closed.
            RuntimeError: the decoder reads service responses (``ok_byte=True``): use ``feed_responses``.
        """
        if self.ok_byte:
            raise RuntimeError("a FrameDecoder(ok_byte=True) is read with feed_responses()")
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
        self._first_out()
        return body

    def _first_out(self) -> None:
        """A frame was returned: from now on ``max_size`` is the message limit (the header is done)."""
        if self._then_max is not None:
            self.max_size = self._then_max
            self._then_max = None

    def _advance(self, count: int) -> None:
        self._pos += count
        if self._pos == len(self._buf):
            self._buf.clear()
            self._pos = 0
        elif self._pos >= _COMPACT_AT and self._pos * 2 >= len(self._buf):
            del self._buf[: self._pos]
            self._pos = 0
