"""The control protocol between IXM clients and the daemon: tagged msgpack Structs in length-prefixed frames.

This module owns the message types and their encoding (``encode``, ``decode_request``, ``decode_reply``) in
the style of msgspec's asyncio key-value example; it has no socket. Frames are TCPROS frames, cut by the one
``FrameDecoder`` of ``mrosd.wire.framing`` with the limits below. File descriptors
travel beside the bytes (SCM_RIGHTS): a message states how many it carries (``Open.wake``: the write end
of the reader's wake-up pipe;
``Opened``: one segment fd; ``WakeList.count``) and the receiver takes them, in order, from the fds that
arrived with the stream. Data never flows through this protocol: it is only for opening, closing and
listing keys, and for telling writers whom to wake.

Limits: a request frame is at most ``MAX_REQUEST_SIZE`` bytes (every request is a few names and numbers,
so anything bigger is an attack or a bug); replies may be up to ``MAX_REPLY_SIZE`` (a listing of every key
and process). A frame over the limit or a body that does not decode as a known message is a
``RemoteProtocolError``: the daemon closes only that client's connection and logs why.
"""

from __future__ import annotations

from typing import Literal

import msgspec

from mrosd.errors import RemoteProtocolError
from mrosd.wire.framing import encode_frame

__all__ = [
    "MAX_REPLY_SIZE",
    "MAX_REQUEST_SIZE",
    "Close",
    "Error",
    "Hello",
    "List",
    "Listing",
    "Ok",
    "Open",
    "Opened",
    "ProcessView",
    "Reply",
    "Request",
    "SegmentView",
    "WakeList",
    "decode_reply",
    "decode_request",
    "encode",
]

#: 4 KiB: a request carries a key (<= 256 chars), a type name and a few integers.
MAX_REQUEST_SIZE = 4096
#: 16 MiB: a full listing of a busy daemon (thousands of keys and processes) fits easily.
MAX_REPLY_SIZE = 16 << 20


class Hello(msgspec.Struct, tag_field="op", tag="hello", gc=False):
    """Optional first message: the client's display name (rules never trust it; they use /proc)."""

    name: str


class Open(msgspec.Struct, tag_field="op", tag="open", gc=False, kw_only=True):
    """IxmInit. ``wake``: the write end of the reader's wake-up pipe follows, which writers write on each write."""

    key: str
    type: str | None = None
    count: int | None = None
    max_size: int | None = None
    mode: Literal["r", "w", "rw"] = "r"
    wake: bool = False


class Close(msgspec.Struct, tag_field="op", tag="close", gc=False):
    """IxmFree."""

    key: str


class List(msgspec.Struct, tag_field="op", tag="list", gc=False):
    """Ask for the process and segment lists (``key`` restricts to one key)."""

    key: str | None = None


Request = Hello | Open | Close | List


class Ok(msgspec.Struct, tag_field="op", tag="ok", gc=False):
    """Success without data."""


class Error(msgspec.Struct, tag_field="op", tag="error", gc=False):
    """Failure; ``kind`` is "permission" (IxmPermissionError), "invalid", "limit" (a cap refused it) or "protocol"."""

    kind: str
    message: str


class Opened(msgspec.Struct, tag_field="op", tag="opened", gc=False, kw_only=True):
    """Open granted; fds follow: the segment (read-only for a reader); for a writer, the writers' lock file
    (``flock`` it around each write); at a connection's first open for writing (``notice``), its notice page
    (read-only: the count of WakeList pushes sent to it, ``generation`` so far); then, for a writer, the
    ``wake`` pipes (write ends) of the key's current readers; later changes come as WakeList."""

    key: str
    type: str
    count: int
    max_size: int
    capacity: int
    mode: str
    shm_name: str
    wake: int = 0
    generation: int = 0
    notice: bool = False


class WakeList(msgspec.Struct, tag_field="op", tag="wake", gc=False, kw_only=True):
    """Pushed to writers: ``count`` readers' wake-up pipes (write ends) follow, replacing the previous list for ``key``;
    ``generation`` is the connection's push count, which its notice page shows once this is queued."""

    key: str
    generation: int
    count: int


class ProcessView(msgspec.Struct, gc=False, kw_only=True):
    name: str
    pid: int
    uid: int
    keys: dict[str, str]


class SegmentView(msgspec.Struct, gc=False, kw_only=True):
    key: str
    shm_name: str
    type: str
    count: int
    max_size: int
    capacity: int
    creator_uid: int
    readers: list[int]
    writers: list[int]


class Listing(msgspec.Struct, tag_field="op", tag="listing", gc=False, kw_only=True):
    """Reply to List: readers and writers are pids."""

    processes: list[ProcessView]
    segments: list[SegmentView]


Reply = Ok | Error | Opened | WakeList | Listing

_encoder = msgspec.msgpack.Encoder()
_request_decoder = msgspec.msgpack.Decoder(Request)
_reply_decoder = msgspec.msgpack.Decoder(Reply)


def encode(message: Request | Reply) -> bytes:
    """One frame: 4-byte little-endian length, then the msgpack body."""
    return encode_frame(_encoder.encode(message))


def decode_request(body: bytes | memoryview) -> Request:
    """Raises: RemoteProtocolError when the body is not a known request."""
    try:
        request: Request = _request_decoder.decode(body)
    except (msgspec.DecodeError, UnicodeDecodeError) as exc:
        raise RemoteProtocolError(f"malformed IXM request: {exc}") from exc
    return request


def decode_reply(body: bytes | memoryview) -> Reply:
    """Raises: RemoteProtocolError when the body is not a known reply."""
    try:
        reply: Reply = _reply_decoder.decode(body)
    except (msgspec.DecodeError, UnicodeDecodeError) as exc:
        raise RemoteProtocolError(f"malformed IXM reply: {exc}") from exc
    return reply
