"""What generated message code calls at run time: precompiled structs, array and bytes helpers, errors.

Generated modules (runtime classes and ``mros msg gen`` files alike) import only from here and from
msgspec, so this module is the stable surface of the codegen. Keep it small and fast.
"""

from __future__ import annotations

import struct
import sys
from array import array
from collections.abc import Callable, Iterable
from typing import Any

from mrosd.errors import DeserializationError, SerializationError
from mrosd.msg.time import Duration, Time

__all__ = [
    "UINT32",
    "ZERO_COPY_MIN",
    "DeserializationError",
    "Duration",
    "FrameBuffer",
    "SerializationError",
    "Time",
    "array_decoder",
    "array_encoder",
    "array_view_decoder",
    "as_bytes",
    "bad_length",
    "blob",
    "blob_view",
    "is_immutable",
    "serialize_failed",
    "struct_error",
    "to_bytes",
    "trailing",
    "truncated",
    "truncated_message",
]

struct_error = struct.error

#: The uint32 that prefixes every string and variable-length array on the wire.
UINT32 = struct.Struct("<I")

#: uint8[]/char[] payloads at least this large are returned as a read-only memoryview over the received
#: (immutable) bytes instead of a copy: a 1 MB image costs no memcpy to decode. Smaller ones are bytes.
ZERO_COPY_MIN = 64 * 1024


class FrameBuffer(bytearray):
    """A received frame's storage, owned by whoever it is delivered to; nobody writes to it afterwards.

    The TCPROS decoder receives a large frame straight into one of these and never touches it again. A
    message decoded from it keeps its large ``uint8[]`` fields as read-only views into it (no copy), and
    publishing such a message again sends those views as they are (no copy either). The rule that makes
    this safe: once handed to ``deserialize``, a FrameBuffer is never modified (it stays alive as long as
    any view of it does).
    """

    __slots__ = ()


#: Array typecodes whose item size matches the wire size of each ROS numeric type on every CPython.
_TYPECODES = {"b": "b", "B": "B", "h": "h", "H": "H", "i": "i", "I": "I", "q": "q", "Q": "Q", "f": "f", "d": "d"}
_SWAP = sys.byteorder != "little"


def blob(b: Any, start: int, end: int) -> bytes | memoryview:
    """A uint8[] payload: a read-only zero-copy view when large and the input cannot change under us
    (bytes, a FrameBuffer, or a read-only view of either), else bytes."""
    cls = b.__class__
    if end - start >= ZERO_COPY_MIN:
        if cls is bytes:
            return memoryview(b)[start:end]
        if cls is FrameBuffer:
            return memoryview(b)[start:end].toreadonly()
        if cls is memoryview and b.readonly and b.obj.__class__ in _IMMUTABLE:
            return b[start:end]  # type: ignore[no-any-return]
    if cls is bytes:
        return b[start:end]  # type: ignore[no-any-return]
    return bytes(memoryview(b)[start:end])


_IMMUTABLE = (bytes, FrameBuffer)


def blob_view(b: memoryview, start: int, end: int, views: list[memoryview]) -> bytes | memoryview:
    """A uint8[] payload of memory that does not change while the message lives (a leased slot): a view of
    it when large (noted in ``views``, which the lease releases), else bytes."""
    if end - start >= ZERO_COPY_MIN:
        view = b[start:end]
        views.append(view)
        return view
    return bytes(b[start:end])


def array_view_decoder(code: str) -> Callable[[memoryview, int, int, list[memoryview]], Any]:
    """``array_decoder`` for memory that does not change while the message lives: a large array is a view
    of it cast to its element type (little-endian hosts; noted in ``views``), a small one an ``array``."""
    copy = array_decoder(code)

    def decode(b: memoryview, start: int, end: int, views: list[memoryview]) -> Any:
        if end - start >= ZERO_COPY_MIN and not _SWAP:
            view = b[start:end].cast(code)  # type: ignore[call-overload]
            views.append(view)
            return view
        return copy(b, start, end)

    return decode


def is_immutable(part: Any) -> bool:
    """Whether ``part`` (a serialized piece) can never change: bytes, a FrameBuffer, or a read-only view
    of either. Only such pieces may be handed to a transport without a copy."""
    cls = part.__class__
    if cls is memoryview:
        return part.readonly and part.obj.__class__ in _IMMUTABLE  # type: ignore[no-any-return]
    return cls is bytes or cls is FrameBuffer


def as_bytes(data: Any) -> bytes:
    """The input of a decoder as bytes: a whole-buffer view of bytes is unwrapped, anything else copied.

    Decoders work on immutable bytes so that the zero-copy views they hand out can never change later.
    """
    if data.__class__ is memoryview:
        obj = data.obj
        if obj.__class__ is bytes and data.c_contiguous and data.nbytes == len(obj):
            return obj  # type: ignore[no-any-return]
    try:
        return bytes(memoryview(data).cast("B"))
    except TypeError:
        raise TypeError(f"messages decode from bytes-like objects, not {type(data).__name__}") from None


def to_bytes(value: Any) -> bytes | bytearray | memoryview:
    """A uint8[]/char[] value ready to write: byte buffers pass through, sequences of ints become bytes."""
    if value.__class__ is bytearray:
        return value  # type: ignore[no-any-return]
    if value.__class__ is memoryview:
        return value if value.c_contiguous and value.itemsize == 1 else value.tobytes()  # type: ignore[no-any-return]
    if isinstance(value, bytes):
        return bytes(value)
    if isinstance(value, str):
        raise SerializationError("uint8[]/char[] needs bytes, not str (encode it first)")
    try:
        return bytes(value)
    except (TypeError, ValueError) as exc:
        raise SerializationError(f"uint8[]/char[] needs bytes or a sequence of 0..255 ints: {exc}") from None


def array_decoder(code: str) -> Callable[[Any, int, int], array[Any]]:
    """A decoder of a little-endian numeric array slice into ``array.array`` (no per-element objects)."""
    typecode = _TYPECODES[code]

    def decode(b: Any, start: int, end: int) -> array[Any]:
        out = array(typecode)
        out.frombytes(memoryview(b)[start:end])
        if _SWAP:
            out.byteswap()
        return out

    return decode


def array_encoder(code: str) -> Callable[[Iterable[Any]], bytes]:
    """An encoder of a numeric sequence (array.array of the right typecode is copied without a loop)."""
    typecode = _TYPECODES[code]

    def encode(values: Any) -> bytes:
        if values.__class__ is array and values.typecode == typecode and not _SWAP:
            return values.tobytes()  # type: ignore[no-any-return]
        return struct.pack(f"<{len(values)}{code}", *values)

    return encode


def truncated(type_name: str, field: str, need: int, have: int) -> DeserializationError:
    """The error for a length prefix that points past the end of the buffer (nothing is allocated)."""
    return DeserializationError(
        f"{type_name}: field {field!r} needs {need} bytes but only {have} remain (truncated or corrupt message)"
    )


def truncated_message(type_name: str, size: int, exc: Exception) -> DeserializationError:
    """The error for a buffer that ends inside a fixed-size run of fields."""
    return DeserializationError(f"{type_name}: truncated message ({size} bytes): {exc}")


def trailing(type_name: str, used: int, size: int) -> DeserializationError:
    """The error for bytes left over after a complete message (or missing, when ``used > size``)."""
    if used > size:
        return DeserializationError(f"{type_name}: truncated message: needs {used} bytes, got {size}")
    return DeserializationError(f"{type_name}: {size - used} trailing bytes after a {used}-byte message")


def bad_length(type_name: str, field: str, expected: int, got: int) -> SerializationError:
    """The error for a fixed-size array given the wrong number of items."""
    return SerializationError(f"{type_name}: field {field!r} is a fixed array of {expected} items, got {got}")


def serialize_failed(type_name: str, exc: Exception) -> SerializationError:
    """Translate struct/type errors of a generated encoder into one clear error."""
    return SerializationError(f"{type_name}: cannot serialize: {exc}")
