"""The thin asyncio layer over the sans-IO cores: one ``asyncio.BufferedProtocol`` per TCPROS connection.

``TcprosProtocol`` receives into the buffer its ``FrameDecoder`` lends (``get_buffer``): a small receive
buffer, or, once a large frame's length is known, that frame's own exact-size buffer, so a big message is
received by the kernel straight into the bytes that are delivered. The first frame is the peer's
connection header, every later one goes to ``frame_received``. Malformed or oversized input closes this connection
with a logged reason and touches nothing else. Small writes are plain ``transport.write`` calls; a large
frame's pieces go to the socket in one ``writev`` while the transport buffers nothing (``write_parts``).
Flow control (pause/resume_writing) is exposed as ``paused`` and ``drain()`` so the publisher can queue
and coalesce.
"""

from __future__ import annotations

import asyncio
import logging
import os
import socket
from collections.abc import Sequence
from typing import Any, cast

from mrosd.errors import RemoteProtocolError
from mrosd.lograte import RateLimitedLog
from mrosd.msg.runtime import FrameBuffer
from mrosd.spin import loop_spinner
from mrosd.wire.framing import MAX_FRAME_SIZE, FrameDecoder
from mrosd.wire.header import MAX_HEADER_SIZE, ConnectionHeader, decode_connection_header
from mrosd.wire.spares import spare_pool

log = logging.getLogger(__name__)
#: A peer decides how often its connections fail (a garbage header each time): a few lines per interval.
aborts = RateLimitedLog(log, period=10.0, burst=5)

#: Transport write buffer above which a connection counts as slow and the publisher queues instead of
#: writing (asyncio's pause_writing). 1 MiB keeps a burst of small messages in the kernel's hands while
#: a stalled peer costs at most this plus its bounded message queue.
WRITE_HIGH_WATER = 1024 * 1024

#: Most pieces handed to one ``writev`` (IOV_MAX is 1024 on Linux); longer lists go to the transport.
_MAX_IOV = 64


class TcprosProtocol(asyncio.BufferedProtocol):
    """A TCPROS connection: header first, then length-prefixed frames."""

    def __init__(self) -> None:
        self.transport: asyncio.Transport | None = None
        self.decoder = FrameDecoder(MAX_FRAME_SIZE, header_max_size=MAX_HEADER_SIZE)
        self.header: ConnectionHeader | None = None
        self.peer = "?"
        self.paused = False
        self._fd = -1  #: the socket's fd, for vectored writes that bypass the transport while it is idle
        self._drain: asyncio.Future[None] | None = None
        loop = asyncio.get_running_loop()
        self.closed: asyncio.Future[BaseException | None] = loop.create_future()
        #: Keeps the loop polling briefly after traffic (mrosd.spin): the answer to what we receive is near.
        self._poke = loop_spinner(loop).poke

    # --- hooks for subclasses ---------------------------------------------------------------

    def header_received(self, header: ConnectionHeader) -> None:
        """Called once with the peer's connection header."""

    def frame_received(self, body: bytes | bytearray) -> None:
        """Called for every complete frame after the header."""

    def connection_closed(self, exc: BaseException | None) -> None:
        """Called once when the connection is gone."""

    # --- asyncio.Protocol ------------------------------------------------------------------------

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        # uvloop's transports implement the interface without subclassing asyncio.Transport.
        transport = cast(asyncio.Transport, transport)
        self.transport = transport
        transport.set_write_buffer_limits(high=WRITE_HIGH_WATER)
        sock: Any = transport.get_extra_info("socket")
        if sock is not None:
            self._fd = sock.fileno()
        peer = transport.get_extra_info("peername")
        if peer:
            self.peer = f"{peer[0]}:{peer[1]}"

    def get_buffer(self, sizehint: int) -> memoryview:
        return self.decoder.get_buffer()

    def buffer_updated(self, nbytes: int) -> None:
        self._poke()
        try:
            frames = self.decoder.buffer_updated(nbytes)
            if self.header is None:
                # The decoder judged the first frame by MAX_HEADER_SIZE and the rest by MAX_FRAME_SIZE.
                if not frames:
                    return
                self.header = decode_connection_header(frames[0])
                self.header_received(self.header)
                del frames[0]
            if frames and type(frames[0]) is FrameBuffer:
                # a large frame's buffer was kept for reuse: the process's pool gives it back once idle
                spare_pool().watch(asyncio.get_running_loop())
            frame_received = self.frame_received
            for frame in frames:
                transport = self.transport
                if transport is None or transport.is_closing():
                    return
                frame_received(frame)
        except RemoteProtocolError as exc:
            self.abort(f"protocol error from {self.peer}: {exc}")

    def eof_received(self) -> bool | None:
        return None

    def pause_writing(self) -> None:
        self.paused = True

    def resume_writing(self) -> None:
        self.paused = False
        if self._drain is not None and not self._drain.done():
            self._drain.set_result(None)
        self._drain = None

    def connection_lost(self, exc: Exception | None) -> None:
        self.transport = None
        self._fd = -1
        if self._drain is not None and not self._drain.done():
            self._drain.set_exception(ConnectionResetError("connection lost"))
            self._drain.exception()  # mark retrieved
        if not self.closed.done():
            self.closed.set_result(exc)
        self.connection_closed(exc)

    # --- helpers ----------------------------------------------------------------------------------

    async def drain(self) -> None:
        """Wait until the transport accepts writes again.

        Raises:
            ConnectionResetError: the connection closed while waiting.
        """
        if self.transport is None:
            raise ConnectionResetError("connection closed")
        if not self.paused:
            return
        if self._drain is None:
            self._drain = asyncio.get_running_loop().create_future()
        await asyncio.shield(self._drain)

    def write(self, data: bytes) -> None:
        if self.transport is not None:
            self.transport.write(data)

    def write_parts(self, parts: Sequence[bytes | bytearray | memoryview]) -> None:
        """Write the concatenation of ``parts`` without building it.

        While the transport holds nothing back, the pieces go to the socket in one ``writev`` (the kernel's
        copy is the only one); only what the socket cannot take now is handed to the transport, whose
        ``writelines`` keeps the pieces (uvloop) rather than joining them.
        """
        transport = self.transport
        if transport is None:
            return
        fd = self._fd
        if fd < 0 or len(parts) > _MAX_IOV or transport.get_write_buffer_size() or transport.is_closing():
            transport.writelines(parts)
            return
        try:
            sent = os.writev(fd, parts)
        except (BlockingIOError, InterruptedError):
            sent = 0
        except OSError:
            transport.writelines(parts)  # the transport meets the same error and closes as usual
            return
        rest: list[bytes | bytearray | memoryview] = []
        for part in parts:
            if sent >= len(part):
                sent -= len(part)
                continue
            rest.append(memoryview(part)[sent:] if sent else part)
            sent = 0
        if rest:
            transport.writelines(rest)

    def set_nodelay(self, enabled: bool) -> None:
        """Set TCP_NODELAY on the socket as the peer asked (tcp_nodelay header)."""
        if self.transport is None:
            return
        sock: Any = self.transport.get_extra_info("socket")
        if sock is None:
            return
        try:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1 if enabled else 0)
        except OSError:
            pass

    def abort(self, reason: str) -> None:
        """Close this connection at once, logging why."""
        aborts.warning("abort", "closing TCPROS connection: %s", reason)
        if self.transport is not None:
            self.transport.abort()

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()
