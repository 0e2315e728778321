"""The rosbridge v2 protocol (roslibjs, roslibpy) as pure functions: ops in, JSON out, messages <-> JSON.

No sockets (the shell is ``mrosd.web.rosbridge_server``). Messages are mrosd's msgspec classes, so the JSON
form is msgspec's: ``uint8[]``/``char[]`` as base64, ``time``/``duration`` as ``{"secs", "nsecs"}``, NaN and
infinities as ``null`` — what rosbridge sends. A client's message dict may leave fields out (they take
their defaults, as rosbridge fills them) and is refused with a reason when a value has the wrong type.
Also here: the ``png`` op a ``compression: png`` subscription gets (``png_image``: rosbridge's layout, written
with zlib), and the ``Defragmenter`` that joins a client's ``fragment`` ops within bounds rosbridge lacks.
"""

from __future__ import annotations

import base64
import math
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Annotated, Any

import msgspec

from mrosd.errors import RemoteProtocolError
from mrosd.images.png import PNG_SIGNATURE as _PNG_SIGNATURE
from mrosd.images.png import png_chunk as _png_chunk
from mrosd.web.jsonvalue import TooDeep, check_depth, decode_bounded
from mrosd.web.queue import Ledger

__all__ = [
    "Advertise",
    "AdvertiseService",
    "Auth",
    "CallService",
    "Defragmenter",
    "Fragment",
    "Op",
    "Publish",
    "RosbridgeRefusal",
    "ServiceResponse",
    "SetLevel",
    "Subscribe",
    "Unadvertise",
    "UnadvertiseService",
    "Unsubscribe",
    "decode_auth",
    "decode_op",
    "decode_value",
    "encode_message",
    "iter_fragments",
    "message_from_json",
    "op_json",
    "png_image",
    "png_op",
    "png_op_pieces",
]

Name = Annotated[str, msgspec.Meta(max_length=4096)]
NonNegative = Annotated[int, msgspec.Meta(ge=0, le=2**31)]


class RosbridgeRefusal(RemoteProtocolError):
    """A client op we refuse; answered with a ``status`` (level error) naming the op's id when it has one."""


class _Op(msgspec.Struct, tag_field="op", frozen=True):
    id: str | None = None


class Advertise(_Op, tag="advertise", frozen=True):
    topic: Name = ""
    type: Name = ""
    latch: bool = False
    queue_size: NonNegative = 100


class Unadvertise(_Op, tag="unadvertise", frozen=True):
    topic: Name = ""


class Publish(_Op, tag="publish", frozen=True):
    topic: Name = ""
    msg: dict[str, Any] = msgspec.field(default_factory=dict)


class Subscribe(_Op, tag="subscribe", frozen=True):
    topic: Name = ""
    type: Name | None = None
    throttle_rate: NonNegative = 0
    queue_length: NonNegative = 0
    fragment_size: NonNegative | None = None
    compression: str = "none"


class Unsubscribe(_Op, tag="unsubscribe", frozen=True):
    topic: Name = ""


class CallService(_Op, tag="call_service", frozen=True):
    service: Name = ""
    args: dict[str, Any] | list[Any] | None = None
    type: Name | None = None
    timeout: float | None = None
    compression: str = "none"


class AdvertiseService(_Op, tag="advertise_service", frozen=True):
    service: Name = ""
    type: Name = ""


class UnadvertiseService(_Op, tag="unadvertise_service", frozen=True):
    service: Name = ""


class ServiceResponse(_Op, tag="service_response", frozen=True):
    service: Name = ""
    values: Any = None
    result: bool = True


class SetLevel(_Op, tag="set_level", frozen=True):
    level: str = "error"


class Auth(_Op, tag="auth", frozen=True):
    mac: str = ""


class Fragment(_Op, tag="fragment", frozen=True, kw_only=True):
    """One piece of a client's message cut into ``total`` pieces (rosbridge's ``fragment``; id may be a number)."""

    id: str | int | None = None  # type: ignore[assignment]
    data: str
    num: NonNegative
    total: Annotated[int, msgspec.Meta(ge=1, le=2**31)]


Op = (
    Advertise
    | Unadvertise
    | Publish
    | Subscribe
    | Unsubscribe
    | CallService
    | AdvertiseService
    | UnadvertiseService
    | ServiceResponse
    | SetLevel
    | Auth
    | Fragment
)

_decoder: msgspec.json.Decoder[Op] = msgspec.json.Decoder(Op)  # type: ignore[arg-type]
_KNOWN = frozenset(
    {
        "advertise",
        "unadvertise",
        "publish",
        "subscribe",
        "unsubscribe",
        "call_service",
        "advertise_service",
        "unadvertise_service",
        "service_response",
        "set_level",
        "auth",
        "fragment",
    }
)
#: Ops of the protocol that mrosd does not take from clients, with why (rather than "unknown op").
NOT_SERVED = {
    "png": "op png is not accepted from clients (rosbridge_server does not accept it either); send JSON, "
    "or cut a long op into fragment ops",
}


class _Peek(msgspec.Struct):
    op: Any = None
    id: Any = None


_peek = msgspec.json.Decoder(_Peek)


def decode_op(data: str | bytes) -> Op:
    """One client op; what it carries for a message or a service may nest at most ``jsonvalue.MAX_DEPTH`` levels.

    Raises:
        RosbridgeRefusal: not a JSON object, an unknown op, fields of the wrong type, or nested too deep
            (whatever the decoder would otherwise raise: never RecursionError).
    """
    try:
        op = decode_bounded(_decoder.decode, data)
    except (msgspec.DecodeError, msgspec.ValidationError) as exc:
        try:
            peek = decode_bounded(_peek.decode, data)
        except (msgspec.DecodeError, msgspec.ValidationError, ValueError):
            raise RosbridgeRefusal(f"not a JSON object: {exc}") from None
        if isinstance(peek.op, str) and peek.op in NOT_SERVED:
            raise RosbridgeRefusal(NOT_SERVED[peek.op]) from None
        if not isinstance(peek.op, str) or peek.op not in _KNOWN:
            raise RosbridgeRefusal(f"unknown op {_shown(peek.op)}") from None
        raise RosbridgeRefusal(f"malformed {peek.op}: {exc}") from None
    except ValueError as exc:  # TooDeep, or more than memory holds
        raise RosbridgeRefusal(f"not accepted: {exc}") from None
    value = op.msg if isinstance(op, Publish) else op.args if isinstance(op, CallService) else None
    if isinstance(op, ServiceResponse):
        value = op.values
    try:
        check_depth(value)
    except TooDeep as exc:
        raise RosbridgeRefusal(f"{type(op).__struct_config__.tag}: the value is {exc}") from None
    return op


def decode_value(text: str) -> Any:
    """A JSON value a client gives as text (rosapi ``set_param``'s ``value``), nested at most ``MAX_DEPTH``.

    Raises:
        ValueError: not JSON, or nested too deep.
    """
    try:
        value = decode_bounded(msgspec.json.decode, text)
    except msgspec.DecodeError as exc:
        raise ValueError(str(exc)) from None
    check_depth(value)
    return value


class AuthOnly(msgspec.Struct, frozen=True):
    """What is read of a connection's ops before it has authenticated: the op's name and id, and the ``mac`` of
    ``auth``; the other fields (roslibjs's client, dest, rand, t, level, end; any op's body) are skipped."""

    op: Annotated[str, msgspec.Meta(max_length=64)] = ""
    mac: Annotated[str, msgspec.Meta(max_length=4096)] = ""
    id: Annotated[str, msgspec.Meta(max_length=256)] | int | None = None


_auth_decoder = msgspec.json.Decoder(AuthOnly)


def decode_auth(data: str | bytes) -> AuthOnly:
    """An op of a client that did not give the token in its URL, read only as far as ``AuthOnly``.

    Raises:
        RosbridgeRefusal: not a JSON object of that shape.
    """
    try:
        return decode_bounded(_auth_decoder.decode, data)
    except (msgspec.DecodeError, msgspec.ValidationError, ValueError) as exc:
        raise RosbridgeRefusal(f"authenticate first (op auth with the token): {exc}") from None


def _shown(op: object) -> str:
    """An op name for a refusal: a string (cut short), else only its JSON type (a nested value's repr recurses)."""
    return repr(op[:80]) if isinstance(op, str) else f"of type {type(op).__name__}"


_encoder = msgspec.json.Encoder()


def op_json(op: str, **fields: Any) -> bytes:
    """A server op as JSON text (None fields left out)."""
    return _encoder.encode({"op": op, **{k: v for k, v in fields.items() if v is not None}})


def encode_message(msg: Any) -> bytes:
    """A decoded ROS message as the JSON rosbridge sends (base64 byte arrays, {secs, nsecs}, NaN as null)."""
    return _encoder.encode(msg)


def publish_json(topic: str, msg: Any) -> bytes:
    """``{"op": "publish", "topic": ..., "msg": ...}`` with the message encoded once, in place."""
    return b'{"op":"publish","topic":' + _encoder.encode(topic) + b',"msg":' + _encoder.encode(msg) + b"}"


#: Smallest ``fragment_size`` honoured (characters); a smaller one is raised to it. Each fragment op carries
#: about 70 bytes of JSON around its piece, so at 1024 the overhead stays under 7 % and a 2 MB message is at
#: most ~2,700 frames; at 1 it was 70x the message in frames and as many sends on the event loop. Every
#: rosbridge client reassembles fragments of any size, so raising it changes nothing they can see.
MIN_FRAGMENT_SIZE = 1024


def iter_fragments(text: str, fragment_size: int, message_id: str) -> Iterator[bytes]:
    """rosbridge's ``fragment`` ops for one JSON message longer than ``fragment_size`` characters, made one
    at a time as they are taken (at least ``MIN_FRAGMENT_SIZE`` characters each)."""
    size = max(MIN_FRAGMENT_SIZE, fragment_size)
    total = -(-len(text) // size)
    for i in range(total):
        yield op_json("fragment", id=message_id, data=text[i * size : (i + 1) * size], num=i, total=total)


def fragments(text: str, fragment_size: int, message_id: str) -> list[bytes]:
    """Every fragment op of ``iter_fragments`` at once."""
    return list(iter_fragments(text, fragment_size, message_id))


#: zlib level of ``png`` ops: Pillow's default, which rosbridge_server's PNGs get. On a 640x480 camera image
#: (noise) level 6 took 39 ms and level 1 34 ms, both leaving the op the size of the JSON it replaces (zlib
#: wins back what base64 added, and base64 adds it again); text and numbers shrink several times. The session
#: compresses off the event loop, so the level costs a thread's CPU, not other clients' latency.
PNG_LEVEL = 6


#: Text compressed per step of the PNG encoder: each step's zlib call lets go of the GIL, and what a step does
#: holding it (joining its rows, base64 of its output) takes about 0.1 ms, so the event loop's thread is never
#: kept waiting long by an encode running in another thread.
PNG_STEP = 64 * 1024


def _png_parts(text: bytes | bytearray | memoryview, level: int) -> Iterator[bytes]:
    """The PNG file of ``png_image`` in pieces: the head, then one IDAT chunk per step that zlib gave output
    for (PNG decoders join consecutive IDATs), then the last IDAT and IEND."""
    n = len(text)
    width = max(1, math.isqrt(n // 3))
    stride = width * 3
    height = max(1, -(-n // stride))
    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)  # 8-bit RGB, deflate, no interlace
    yield _PNG_SIGNATURE + _png_chunk(b"IHDR", header)
    view = memoryview(text)
    deflate = zlib.compressobj(level)
    rows_per_step = max(1, PNG_STEP // stride)
    for first in range(0, height, rows_per_step):
        rows: list[bytes | memoryview] = [b""]  # so that the join puts a filter byte before the first row too
        for y in range(first, min(height, first + rows_per_step)):
            row = view[y * stride : (y + 1) * stride]
            rows.append(row if len(row) == stride else bytes(row) + b"\n" * (stride - len(row)))
        out = deflate.compress(b"\0".join(rows))  # each row after its filter byte, 0 (none)
        if out:
            yield _png_chunk(b"IDAT", out)
    yield _png_chunk(b"IDAT", deflate.flush()) + _png_chunk(b"IEND", b"")


def png_image(text: bytes | bytearray | memoryview, level: int = PNG_LEVEL) -> bytes:
    """``text`` as the 8-bit RGB PNG that rosbridge_server makes of it (and roslibjs reads back as text).

    The layout is rosbridge's, so that any client decoding rosbridge's PNGs reads ours: three bytes a pixel,
    ``width = floor(sqrt(n / 3))``, as many rows as it takes, the last row padded with ``\n`` (whitespace
    that JSON.parse ignores). Written with zlib and struct (filter type 0 on every row: text gains nothing
    from PNG's pixel predictors), so no imaging library is needed.
    """
    return b"".join(_png_parts(text, level))


def png_op_pieces(text: bytes | bytearray | memoryview, level: int = PNG_LEVEL) -> Iterator[bytes]:
    """rosbridge's ``{"op": "png", "data": <base64 PNG of text>}`` (``compression: png``) in pieces, each made
    by a step of ``PNG_STEP`` bytes of text; ``text`` is the whole JSON op it replaces, which the client gets
    back by decoding the image."""
    yield b'{"op":"png","data":"'
    carry = b""
    for part in _png_parts(text, level):
        data = carry + part
        cut = len(data) - len(data) % 3  # base64 of whole 3-byte groups: the pieces join into one base64 text
        if cut:
            yield base64.b64encode(data[:cut])
        carry = data[cut:]
    if carry:
        yield base64.b64encode(carry)
    yield b'"}'


def png_op(text: bytes | bytearray | memoryview, level: int = PNG_LEVEL) -> bytes:
    """The whole ``png`` op of ``text`` (``png_op_pieces`` joined)."""
    return b"".join(png_op_pieces(text, level))


#: What a held fragment costs beyond its data (its bytes object, its key and its slot in the message's dict),
#: so that a client sending one-byte fragments pays for what it makes the bridge hold; a fragment op on the
#: wire is at least 50 bytes of JSON around its data.
FRAGMENT_OVERHEAD = 128


@dataclass(slots=True)
class _Unfinished:
    total: int
    parts: dict[int, bytes] = field(default_factory=dict)
    size: int = 0
    touched: float = 0.0


class Defragmenter:
    """A client's ``fragment`` ops, joined back into the ops they were cut from (rosbridge's defragmentation).

    Pieces are kept by message id and part number as they come (any order), and the message is whole when
    ``total`` distinct parts arrived; ``total`` is a claim, so nothing is sized by it. Bounds, each answered
    with a ``RosbridgeRefusal`` naming it: ``max_bytes`` over the client's unfinished messages (the largest
    goes first, so one runaway message does not take the small ones with it), ``shared.size <= shared_max``
    over every client of the server (beyond it the piece's own message is dropped), ``max_messages`` ids at
    once, and ``timeout`` seconds without a new piece (``expire``). Pure: the caller passes the time.
    """

    __slots__ = ("_pending", "max_bytes", "max_messages", "shared", "shared_max", "size", "timeout")

    def __init__(
        self,
        *,
        max_bytes: int,
        max_messages: int,
        timeout: float,
        shared: Ledger | None = None,
        shared_max: int | None = None,
    ) -> None:
        self.max_bytes = max_bytes
        self.max_messages = max_messages
        self.timeout = timeout
        #: the bytes every client of the server holds in unfinished messages, and their bound
        self.shared = shared if shared is not None else Ledger()
        self.shared_max = shared_max
        #: bytes this client holds (data + FRAGMENT_OVERHEAD a piece)
        self.size = 0
        self._pending: dict[str | int, _Unfinished] = {}

    def __len__(self) -> int:
        return len(self._pending)

    def feed(self, op: Fragment, now: float) -> bytes | None:
        """Keep one piece; the whole op's text when it was the last one missing.

        Raises:
            RosbridgeRefusal: a piece without id, a number not below ``total``, a ``total`` that changed, a
                part sent twice, or a bound reached (the message it belongs to is then dropped, but for a
                part sent twice or an id over ``max_messages``).
        """
        key = op.id
        if key is None:
            raise RosbridgeRefusal("fragment without an id")
        if op.num >= op.total:
            raise RosbridgeRefusal(f"fragment {key!r}: num {op.num} is not below total {op.total}")
        data = op.data.encode()
        message = self._pending.get(key)
        if message is None:
            if op.total == 1:
                return data
            if len(self._pending) >= self.max_messages:
                raise RosbridgeRefusal(
                    f"fragment {key!r}: at most {self.max_messages} fragmented messages unfinished per client"
                )
            message = self._pending[key] = _Unfinished(op.total)
        elif message.total != op.total:
            self.drop(key)
            raise RosbridgeRefusal(f"fragment {key!r}: total {op.total}, was {message.total}; message dropped")
        if op.num in message.parts:
            raise RosbridgeRefusal(f"fragment {key!r}: part {op.num} sent twice")
        cost = len(data) + FRAGMENT_OVERHEAD
        if self.size + cost > self.max_bytes:
            self._make_room(cost, key)
            if key not in self._pending:
                raise RosbridgeRefusal(
                    f"fragment {key!r}: more than {self.max_bytes} bytes of unfinished fragmented messages "
                    f"per client; message dropped"
                )
        if self.shared_max is not None and self.shared.size + cost > self.shared_max:
            self.drop(key)
            raise RosbridgeRefusal(
                f"fragment {key!r}: the bridge holds {self.shared_max} bytes of unfinished fragmented messages "
                f"from all clients; message dropped"
            )
        message.parts[op.num] = data
        message.size += cost
        message.touched = now
        self.size += cost
        self.shared.size += cost
        if len(message.parts) < message.total:
            return None
        self.drop(key)
        return b"".join(message.parts[i] for i in range(message.total))

    def _make_room(self, cost: int, key: str | int) -> None:
        """Drop the largest unfinished messages until ``cost`` more bytes fit (``key``'s too if need be)."""
        while self._pending and self.size + cost > self.max_bytes:
            largest = max(self._pending, key=lambda k: self._pending[k].size)
            self.drop(largest)
            if largest == key:
                return

    def drop(self, key: str | int) -> tuple[int, int]:
        """Forget an unfinished message; (parts received, total) of it, (0, 0) when there is none."""
        message = self._pending.pop(key, None)
        if message is None:
            return 0, 0
        self.size -= message.size
        self.shared.size -= message.size
        return len(message.parts), message.total

    def expire(self, now: float) -> list[tuple[str | int, int, int]]:
        """Drop the messages without a new piece for ``timeout`` seconds: (id, parts received, total) of each."""
        stale = [k for k, m in self._pending.items() if now - m.touched >= self.timeout]
        return [(k, *self.drop(k)) for k in stale]

    def deadline(self) -> float | None:
        """When the next unfinished message expires (the caller's clock), None when there is none."""
        if not self._pending:
            return None
        return min(m.touched for m in self._pending.values()) + self.timeout

    def clear(self) -> None:
        """Forget everything (the client left)."""
        for key in list(self._pending):
            self.drop(key)


def publish_cbor(topic: str, msg: Any) -> bytes:
    """The publish op as CBOR (``compression: cbor``): byte arrays as CBOR byte strings, floats as floats."""
    import cbor2  # only clients that ask for CBOR pay for the import

    fields = msgspec.to_builtins(msg, builtin_types=(bytes, bytearray, memoryview))
    return bytes(cbor2.dumps({"op": "publish", "topic": topic, "msg": _plain_bytes(fields)}))


def publish_cbor_raw(topic: str, body: bytes | bytearray, receipt_ns: int) -> bytes:
    """The publish op of ``compression: cbor-raw``: the TCPROS body untouched, with its receipt time."""
    import cbor2

    # bytes and bytearray (a received FrameBuffer) are CBOR byte strings as they are: no copy before dumps
    msg = {"secs": receipt_ns // 1_000_000_000, "nsecs": receipt_ns % 1_000_000_000, "bytes": body}
    return bytes(cbor2.dumps({"op": "publish", "topic": topic, "msg": msg}))


def _plain_bytes(value: Any) -> Any:
    """memoryview/bytearray fields (views into a received frame) as bytes, which every CBOR encoder takes."""
    if isinstance(value, dict):
        return {k: _plain_bytes(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_plain_bytes(v) for v in value]
    if isinstance(value, memoryview | bytearray):
        return bytes(value)
    return value


def message_from_json(cls: Any, value: Any) -> Any:
    """A message of ``cls`` from a client's JSON value (missing fields take their defaults).

    Raises:
        RosbridgeRefusal: a field has the wrong type or range (the message names it).
    """
    if value is None:
        value = {}
    try:
        return msgspec.convert(value, cls, strict=False)
    except msgspec.ValidationError as exc:
        raise RosbridgeRefusal(f"not a {getattr(cls, '_type', cls)}: {exc}") from None
