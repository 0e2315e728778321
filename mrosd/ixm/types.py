"""What a key holds: ROS primitives, fixed or bounded arrays of them, and ROS message types.

This module owns the mapping from a type spec (``"float64"``, ``count=6``; ``"uint8"``, ``max_size=8 MiB``;
``"std_msgs/Float64"``) to a payload capacity, a header type code and an encoder/decoder pair. It is pure:
it never touches shared memory. The paper's IXM carried only int32 and float64; here every ROS primitive,
arrays of them and any message known to ``mrosd.msg`` can live in a segment:

- a primitive without ``count``/``max_size`` is a scalar (``float64`` takes exactly 8 bytes);
- ``count=N`` makes a fixed array of N elements (exactly ``N * size`` bytes);
- ``max_size=B`` on a numeric primitive makes a variable-length array of at most B bytes (``uint8`` with
  ``max_size`` is the raw-bytes case, e.g. an image); ``string`` always needs ``max_size``;
- a message type with a fixed serialized size gets exactly that many bytes; a variable one needs
  ``max_size`` and is stored serialized.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from typing import Any

import msgspec

from mrosd.errors import IxmError, MrosError

__all__ = ["MAX_SEGMENT_SIZE", "PRIMITIVES", "TYPE_CODE_MESSAGE", "IxmType", "resolve_type"]

#: Largest payload one key may hold (1 GiB): a bound on what a client can make the daemon allocate.
MAX_SEGMENT_SIZE = 1 << 30

#: ROS primitive -> (struct format character, type code). char/byte are ROS's aliases of uint8/int8.
PRIMITIVES: dict[str, tuple[str, int]] = {
    "bool": ("?", 1),
    "int8": ("b", 2),
    "uint8": ("B", 3),
    "int16": ("h", 4),
    "uint16": ("H", 5),
    "int32": ("i", 6),
    "uint32": ("I", 7),
    "int64": ("q", 8),
    "uint64": ("Q", 9),
    "float32": ("f", 10),
    "float64": ("d", 11),
    "char": ("B", 12),
    "byte": ("b", 13),
    "string": ("s", 14),
    "time": ("II", 15),
    "duration": ("ii", 16),
}
TYPE_CODE_MESSAGE = 100


class IxmType(msgspec.Struct, frozen=True, kw_only=True):
    """A resolved type: its canonical name, shape and payload capacity (what the registry compares)."""

    name: str
    count: int = 0
    max_size: int = 0
    capacity: int
    code: int

    @property
    def is_message(self) -> bool:
        return self.code == TYPE_CODE_MESSAGE

    @property
    def fmt(self) -> str:
        """struct format of one element ("" for strings and messages)."""
        if self.is_message or self.name == "string":
            return ""
        return PRIMITIVES[self.name][0]

    @property
    def is_raw_array(self) -> bool:
        """Arrays of single-character numeric formats can be exposed as a typed memoryview."""
        return len(self.fmt) == 1 and (self.count > 0 or self.max_size > 0)

    def describe(self) -> str:
        if self.count:
            return f"{self.name}[{self.count}]"
        if self.max_size and not self.is_message and self.name != "string":
            return f"{self.name}[<={self.max_size // struct.calcsize('<' + self.fmt)}]"
        return self.name


def _positive(value: int | None, what: str) -> int:
    if value is None:
        return 0
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise IxmError(f"{what} must be a positive integer, got {value!r}")
    return value


def _message_class(name: str) -> Any:
    try:
        from mrosd.msg import get_message_class

        return get_message_class(name)
    except MrosError as exc:
        raise IxmError(f"unknown message type {name!r}: {exc}") from exc


def resolve_type(name: str, count: int | None = None, max_size: int | None = None) -> IxmType:
    """Check a type spec and compute its capacity.

    Raises:
        IxmError: unknown type, a missing or contradictory count/max_size, or a size over MAX_SEGMENT_SIZE.
    """
    if not isinstance(name, str) or not name:
        raise IxmError(f"type must be a ROS primitive or a message type name, got {name!r}")
    n = _positive(count, "count")
    m = _positive(max_size, "max_size")
    if n and m:
        raise IxmError("give either count (a fixed array) or max_size (a bounded value), not both")
    if name in PRIMITIVES:
        fmt, code = PRIMITIVES[name]
        if name == "string":
            if n or not m:
                raise IxmError("type string needs max_size (its largest length in bytes) and takes no count")
            capacity = m
        elif n:
            capacity = n * struct.calcsize("<" + fmt)
        elif m:
            size = struct.calcsize("<" + fmt)
            if m % size:
                raise IxmError(f"max_size {m} is not a multiple of the {size}-byte {name} element")
            capacity = m
        else:
            capacity = struct.calcsize("<" + fmt)
    elif "/" in name:
        if n:
            raise IxmError(f"count applies to primitives only; {name} is a message type")
        cls = _message_class(name)
        name = str(cls._type)
        code = TYPE_CODE_MESSAGE
        fixed = cls._fixed_size
        if fixed is not None:
            if m and m != fixed:
                raise IxmError(f"{name} is always {fixed} bytes; max_size {m} does not apply")
            capacity, m = int(fixed), 0
        elif not m:
            raise IxmError(f"{name} has a variable size: give max_size (its largest serialized size in bytes)")
        else:
            capacity = m
    else:
        raise IxmError(f"unknown type {name!r}: use a ROS primitive ({', '.join(PRIMITIVES)}) or pkg/Message")
    if capacity > MAX_SEGMENT_SIZE:
        raise IxmError(f"{capacity} bytes is more than the {MAX_SEGMENT_SIZE}-byte limit of one key")
    return IxmType(name=name, count=n, max_size=m, capacity=capacity, code=code)


Encoder = Callable[[Any], bytes | bytearray | memoryview]
Decoder = Callable[[bytes], Any]


def codec(t: IxmType) -> tuple[Encoder, Decoder]:
    """The encoder (value -> payload bytes) and decoder (payload bytes -> value) for ``t``.

    Scalars decode to Python numbers (bool for ``bool``, ``(secs, nsecs)`` for time/duration), fixed and
    bounded numeric arrays to lists, ``uint8``/``char``/``byte`` arrays to ``bytes``, strings to ``str``
    and messages to instances of their ``mrosd.msg`` class. Encoders raise ``IxmError`` on a wrong value.
    """
    if t.is_message:
        cls = _message_class(t.name)

        def enc_msg(value: Any) -> bytes:
            if not isinstance(value, cls):
                raise IxmError(f"key holds {t.name}, got {type(value).__name__}")
            try:
                return bytes(value.serialize())
            except MrosError as exc:
                raise IxmError(f"cannot serialize {t.name}: {exc}") from exc

        def dec_msg(data: bytes) -> Any:
            return cls.deserialize(data)

        return enc_msg, dec_msg
    if t.name == "string":

        def enc_str(value: Any) -> bytes:
            if isinstance(value, str):
                return value.encode("utf-8")
            if isinstance(value, bytes | bytearray):
                return bytes(value)
            raise IxmError(f"key holds a string, got {type(value).__name__}")

        return enc_str, lambda data: data.decode("utf-8", "replace")
    fmt = t.fmt
    size = struct.calcsize("<" + fmt)
    if t.name in ("time", "duration"):
        return _pair_codec(t, fmt)
    if t.count == 0 and t.max_size == 0:
        one = struct.Struct("<" + fmt)

        def enc_scalar(value: Any) -> bytes:
            try:
                return one.pack(value)
            except struct.error as exc:
                raise IxmError(f"value {value!r} is not a valid {t.name}: {exc}") from exc

        def dec_scalar(data: bytes) -> Any:
            return one.unpack(data)[0]

        return enc_scalar, dec_scalar
    byte_like = t.name in ("uint8", "char", "byte")

    def enc_array(value: Any) -> bytes | bytearray | memoryview:
        if byte_like and isinstance(value, bytes | bytearray | memoryview):
            data = memoryview(value).cast("B") if isinstance(value, memoryview) else value
            if t.count and len(data) != t.count:
                raise IxmError(f"key holds exactly {t.count} bytes, got {len(data)}")
            return data
        if not isinstance(value, Sequence) and not isinstance(value, memoryview):
            raise IxmError(f"key holds an array of {t.name}, got {type(value).__name__}")
        n = len(value)
        if t.count and n != t.count:
            raise IxmError(f"key holds exactly {t.count} {t.name} values, got {n}")
        try:
            return struct.pack(f"<{n}{fmt}", *value)
        except struct.error as exc:
            raise IxmError(f"values are not all valid {t.name}: {exc}") from exc

    def dec_array(data: bytes) -> Any:
        if byte_like:
            return data
        return list(struct.unpack(f"<{len(data) // size}{fmt}", data))

    return enc_array, dec_array


def _pair_codec(t: IxmType, fmt: str) -> tuple[Encoder, Decoder]:
    pair = struct.Struct("<" + fmt)
    n = t.count

    def as_pair(value: Any) -> tuple[int, int]:
        if hasattr(value, "secs") and hasattr(value, "nsecs"):
            return int(value.secs), int(value.nsecs)
        if isinstance(value, tuple | list) and len(value) == 2:
            return int(value[0]), int(value[1])
        raise IxmError(f"a {t.name} is (secs, nsecs) or an object with secs/nsecs, got {value!r}")

    def enc(value: Any) -> bytes:
        try:
            if n == 0 and t.max_size == 0:
                return pair.pack(*as_pair(value))
            items = [as_pair(v) for v in value]
            if n and len(items) != n:
                raise IxmError(f"key holds exactly {n} {t.name} values, got {len(items)}")
            return b"".join(pair.pack(*p) for p in items)
        except struct.error as exc:
            raise IxmError(f"value out of range for {t.name}: {exc}") from exc

    def dec(data: bytes) -> Any:
        if n == 0 and t.max_size == 0:
            return pair.unpack(data)
        return [pair.unpack_from(data, i) for i in range(0, len(data), pair.size)]

    return enc, dec
