"""Rendering messages for people and scripts: rostopic's YAML text, exactly, and one JSON object per line.

The text form is what ``rostopic echo`` prints (genpy's ``strify_message``), so scripts that parse it keep
working: ``field: value`` lines, nested messages indented by two spaces, arrays of numbers as Python lists,
``uint8[]`` as a list of numbers, arrays of messages as ``- `` items, time and duration as ``secs``/``nsecs``
lines (nsecs right-aligned in 9 columns), strings double-quoted as PyYAML's ``default_style='"'`` does, an
empty string as ``''``, and ``---`` after each message. ``--noarr`` replaces every array by the quoted text
``<array type: T, length: N>`` just as rostopic does (including its ``rstrip('[]')`` of fixed-size types).

Speed matters here (``mros topic echo`` must keep up with camera streams), so each message class gets a
cached rendering plan, short ASCII strings skip PyYAML, and ``uint8[]`` is turned into decimal text with
bytes.translate and slice assignment instead of one Python object per byte.

This module knows message instances only through their ``__struct_fields__`` and ``_field_types`` (the
contract of ``mrosd.msg``); it does no I/O.
"""

from __future__ import annotations

import base64
import threading
from collections.abc import Callable, Sequence
from typing import Any

import msgspec
import yaml

__all__ = ["SEPARATOR", "JsonRenderer", "TextRenderer", "extract_field", "quote_string", "uint8_bytes", "uint8_text"]

#: What rostopic writes after each message ('---' is YAML's document separator).
SEPARATOR = "\n---\n"

_SAFE = frozenset(chr(c) for c in range(0x20, 0x7F)) - {'"', "\\"}
#: Beyond this length PyYAML may fold a double-quoted scalar at a space (its best_width is 80 columns).
_FAST_QUOTE_MAX = 70

# uint8 -> decimal digits, one translate table per digit position; 0 marks a leading zero to delete.
_HUNDREDS = bytes(0 if b < 100 else 0x30 + b // 100 for b in range(256))
_TENS = bytes(0 if b < 10 else 0x30 + (b // 10) % 10 for b in range(256))
_UNITS = bytes(0x30 + b % 10 for b in range(256))


def quote_string(value: str) -> str:
    """A string as genpy's strify_message prints it (PyYAML double-quoted style; ``''`` when empty)."""
    if not value:
        return "''"
    if len(value) <= _FAST_QUOTE_MAX and _SAFE.issuperset(value):
        return f'"{value}"'
    return yaml.dump(value, default_style='"').rstrip("\n")


#: uint8[] arrays longer than this are spliced in as bytes by ``render_chunks`` (saves a decode and two copies).
_BLOB_MIN = 4096


class _Scratch:
    """The cell buffer of the last array size, reused while no other thread holds it.

    A camera sends the same size every frame, so the separators (and the brackets) are written once and
    each frame only overwrites the three digit columns.
    """

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.buf = bytearray()


_SCRATCH = _Scratch()


def _cells(n: int) -> bytearray:
    """``[`` + ``n`` five-byte cells ``???, `` with the last ``, `` turned into ``]`` + NUL."""
    buf = bytearray(b"[" + b"\0\0\0, " * n)
    buf[-2:] = b"]\0"
    return buf


def uint8_bytes(data: bytes | bytearray | memoryview) -> bytes:
    """``str(list(data)).encode()`` for a byte string (``b"[1, 2, 255]"``), without a million ints.

    Each byte becomes a five-byte cell ``HTU, `` filled by three ``bytes.translate`` passes (one per digit)
    and strided slice assignment; leading zero digits are marked NUL and deleted by one ``translate`` that
    also produces the result (brackets included), so a 1 MB array costs one 5 MB pass plus the digit passes.
    Faster here than a 65536-entry table of ``"a, b"`` pairs joined per element (that is ~8x slower on
    CPython 3.11: half a million lookups and a join over objects scattered in a 3 MB table).
    """
    n = len(data)
    if n == 0:
        return b"[]"
    raw = data if type(data) is bytes else bytes(data)
    scratch = _SCRATCH
    if not scratch.lock.acquire(blocking=False):
        return _fill(_cells(n), raw)
    try:
        if len(scratch.buf) != 5 * n + 1:
            scratch.buf = _cells(n)
        return _fill(scratch.buf, raw)
    finally:
        scratch.lock.release()


def _fill(buf: bytearray, raw: bytes) -> bytes:
    buf[1::5] = raw.translate(_HUNDREDS)
    buf[2::5] = raw.translate(_TENS)
    buf[3::5] = raw.translate(_UNITS)
    return bytes(buf.translate(None, b"\0"))


def uint8_text(data: bytes | bytearray | memoryview) -> str:
    """``str(list(data))`` for a byte string (``[1, 2, 255]``)."""
    return uint8_bytes(data).decode("ascii")


def _is_time(value: Any) -> bool:
    return hasattr(value, "secs") and hasattr(value, "nsecs") and not hasattr(type(value), "_field_types")


def _fields(cls: type) -> tuple[tuple[str, str], ...]:
    names: tuple[str, ...] = cls.__struct_fields__  # type: ignore[attr-defined]
    types: Sequence[str] = cls._field_types  # type: ignore[attr-defined]
    return tuple(zip(names, types, strict=True))


def extract_field(msg: Any, path: Sequence[str]) -> Any:
    """The value at ``path`` in ``msg``; a name may carry an index, ``points[0]``.

    Raises:
        KeyError: a name on the path is not a field, or an index is out of range.
    """
    value = msg
    for name in path:
        base, _, rest = name.partition("[")
        if not hasattr(type(value), "__struct_fields__") or base not in type(value).__struct_fields__:
            raise KeyError(f"no field {base!r} in {getattr(type(value), '_type', type(value).__name__)}")
        value = getattr(value, base)
        if rest:
            try:
                value = value[int(rest.rstrip("]"))]
            except (ValueError, IndexError, TypeError) as exc:
                raise KeyError(f"bad index [{rest} for field {base!r}") from exc
    return value


class TextRenderer:
    """rostopic echo's text for one message (without the separator); reuse one instance per topic.

    Args:
        noarr: replace arrays by ``<array type: T, length: N>`` as ``rostopic echo --noarr``.
        offset_ns: when not None, print time fields as offsets from this time (``rostopic echo --offset``).
    """

    def __init__(self, *, noarr: bool = False) -> None:
        self.noarr = noarr
        self.offset_ns: int | None = None
        #: while ``render_bytes`` runs: uint8[] texts kept as bytes, marked by NUL in the text (which never
        #: contains a NUL otherwise: strings are quoted with escapes, char[] printed as a repr).
        self._blobs: list[bytes] | None = None
        self._plans: dict[type, tuple[tuple[str, str, Callable[[Any, str], str]], ...]] = {}

    def render(self, value: Any, type_info: str | None = None) -> str:
        """The text rostopic prints for ``value`` (a message, or a field value of ROS type ``type_info``)."""
        if type_info is not None and "[" in type_info:
            if self.noarr:
                return quote_string(f"<array type: {type_info.rstrip('[]')}, length: {len(value)}>")
            return self._field_renderer(type_info)(value, "")
        return self._value(value, "")

    def render_bytes(self, value: Any, type_info: str | None = None) -> bytes:
        """``render(...).encode()``, but big ``uint8[]`` texts are spliced in as bytes, never decoded."""
        return b"".join(self.render_chunks(value, type_info))

    def render_chunks(self, value: Any, type_info: str | None = None) -> list[bytes]:
        """``render_bytes`` as pieces to write in order (no copy of a multi-megabyte ``uint8[]`` text)."""
        blobs: list[bytes] = []
        self._blobs = blobs
        try:
            text = self.render(value, type_info)
        finally:
            self._blobs = None
        if not blobs:
            return [text.encode()]
        parts = text.split("\0")
        out = [parts[0].encode()] if parts[0] else []
        for blob, part in zip(blobs, parts[1:], strict=True):
            out.append(blob)
            if part:
                out.append(part.encode())
        return out

    # -- internals ---------------------------------------------------------------------------------------

    def _plan(self, cls: type) -> tuple[tuple[str, str, Callable[[Any, str], str]], ...]:
        plan = self._plans.get(cls)
        if plan is None:
            plan = tuple((name, rostype, self._field_renderer(rostype)) for name, rostype in _fields(cls))
            self._plans[cls] = plan
        return plan

    def _field_renderer(self, rostype: str) -> Callable[[Any, str], str]:
        if "[" in rostype:
            if self.noarr:
                element = rostype.rstrip("[]")
                return lambda v, _i: quote_string(f"<array type: {element}, length: {len(v)}>")
            if rostype.startswith("uint8["):
                return self._uint8_field
            if rostype.startswith("bool["):
                # genpy turns bool[] into a list of bools; decoders may hand us 0/1 ints.
                return lambda v, _i: str([bool(x) for x in v]) if len(v) else "[]"
            if rostype.startswith("char["):
                # genpy keeps char[] as bytes and prints their repr.
                return self._char_field
            return self._value
        if rostype == "string":
            return lambda v, _i: quote_string(v) if isinstance(v, str) else self._value(v, _i)
        if rostype in ("time", "duration"):
            return self._time if rostype == "time" else self._duration
        return self._value

    def _uint8_field(self, value: Any, indent: str) -> str:
        if isinstance(value, bytes | bytearray | memoryview):
            if self._blobs is not None and len(value) > _BLOB_MIN:
                self._blobs.append(uint8_bytes(value))
                return "\0"
            return uint8_text(value)
        return self._value(value, indent)

    def _char_field(self, value: Any, indent: str) -> str:
        if isinstance(value, bytes | bytearray | memoryview):
            return str(bytes(value))
        return self._value(value, indent)

    def _time(self, value: Any, indent: str) -> str:
        secs, nsecs = int(value.secs), int(value.nsecs)
        if self.offset_ns is not None:
            secs, nsecs = divmod(secs * 1_000_000_000 + nsecs - self.offset_ns, 1_000_000_000)
        return f"\n{indent}secs: {secs}\n{indent}nsecs: {nsecs:9d}"

    def _duration(self, value: Any, indent: str) -> str:
        return f"\n{indent}secs: {int(value.secs)}\n{indent}nsecs: {int(value.nsecs):9d}"

    def _message(self, msg: Any, indent: str) -> str:
        inner = indent + "  "
        text = "\n".join(f"{indent}{name}: {fn(getattr(msg, name), inner)}" for name, _t, fn in self._plan(type(msg)))
        return "\n" + text if indent else text

    def _value(self, value: Any, indent: str) -> str:
        kind = type(value)
        if kind is bool or kind is int or kind is float:
            return str(value)
        if kind is str:
            return quote_string(value)
        if hasattr(kind, "_field_types"):
            return self._message(value, indent)
        if _is_time(value):
            return self._time(value, indent) if kind.__name__ == "Time" else self._duration(value, indent)
        if kind is list or kind is tuple or hasattr(value, "tolist"):
            items = list(value) if kind is not list else value
            if not items:
                return "[]"
            first = items[0]
            if isinstance(first, str):
                dumped = yaml.dump(items).rstrip("\n")
                if dumped.startswith("["):
                    return dumped
                return "\n" + "\n".join(indent + line for line in dumped.splitlines())
            if type(first) in (int, float, bool):
                return str(items)
            pref = indent + "- "
            inner = indent + "  "
            return "\n" + "\n".join(pref + self._value(v, inner) for v in items)
        return str(value)


def _json_default(value: Any) -> Any:
    if _is_time(value):
        return {"secs": int(value.secs), "nsecs": int(value.nsecs)}
    if isinstance(value, memoryview):
        return base64.b64encode(value).decode("ascii")
    if hasattr(value, "tolist"):
        return value.tolist()
    raise NotImplementedError(f"cannot encode {type(value).__name__} as JSON")


class JsonRenderer:
    """One compact JSON object per message; ``uint8[]`` as base64 (as rosbridge does), time as secs/nsecs."""

    def __init__(self) -> None:
        self._encoder = msgspec.json.Encoder(enc_hook=_json_default)

    def render(self, value: Any) -> bytes:
        """The JSON bytes for ``value`` (no trailing newline)."""
        if isinstance(value, msgspec.Struct) and not hasattr(type(value), "_field_types") and _is_time(value):
            return self._encoder.encode(_json_default(value))
        if _is_time(value) and not isinstance(value, msgspec.Struct):
            return self._encoder.encode(_json_default(value))
        return self._encoder.encode(value)
