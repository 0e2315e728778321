"""Rendering messages for people and scripts: rostopic's YAML text, exactly, and one JSON object per line.

The text form is what ``rostopic echo`` prints (genpy's ``strify_message``), so scripts that parse it keep
working: ``field: value`` lines, nested messages indented by two spaces, arrays of numbers as Python lists,
``uint8[]`` as a list of numbers, arrays of messages as ``- `` items, time and duration as ``secs``/``nsecs``
lines (nsecs right-aligned in 9 columns), strings double-quoted as PyYAML's ``default_style='"'`` does, an
empty string as ``''``, and ``---`` after each message. ``--noarr`` replaces every array by the quoted text
``<array type: T, length: N>`` just as rostopic does (including its ``rstrip('[]')`` of fixed-size types).

Speed matters here (``mros topic echo`` must keep up with camera streams), so each message class gets a
cached rendering plan, short ASCII strings skip PyYAML, and ``uint8[]`` is turned into decimal text with
bytes.translate and slice assignment instead of one Python object per byte, a cache-sized slice at a time,
as pieces that are written as they are, never joined.

``PlotRenderer`` prints ``rostopic echo -p``'s CSV. ``Decoder`` turns received bytes into messages with the
publisher's own definition; writing is ``mros_cli.writer``'s. The renderers know message instances only
through their ``__struct_fields__`` and ``_field_types`` (the contract of ``mrosd.msg``).
"""

from __future__ import annotations

import base64
from collections.abc import Callable, Sequence
from typing import Any

import msgspec
import yaml

__all__ = [
    "SEPARATOR",
    "Decoder",
    "JsonRenderer",
    "PlotRenderer",
    "TextRenderer",
    "extract_field",
    "quote_string",
    "uint8_bytes",
    "uint8_pieces",
    "uint8_text",
]

#: What rostopic writes after each message ('---' is YAML's document separator).
SEPARATOR = "\n---\n"

_SAFE = frozenset(chr(c) for c in range(0x20, 0x7F)) - {'"', "\\"}
#: Beyond this length PyYAML may fold a double-quoted scalar at a space (its best_width is 80 columns).
_FAST_QUOTE_MAX = 70

# uint8 -> decimal digits, one translate table per digit position; 0 marks a leading zero to delete.
_HUNDREDS = bytes(0 if b < 100 else 0x30 + b // 100 for b in range(256))
_TENS = bytes(0 if b < 10 else 0x30 + (b // 10) % 10 for b in range(256))
_UNITS = bytes(0x30 + b % 10 for b in range(256))


#: Field types that are not messages (their arrays are transformed by --nostr; arrays of messages are not).
_NOT_MESSAGES = frozenset({
    "bool", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64",
    "float32", "float64", "string", "time", "duration", "char", "byte",
})  # fmt: skip


def quote_string(value: str) -> str:
    """A string as genpy's strify_message prints it (PyYAML double-quoted style; ``''`` when empty)."""
    if not value:
        return "''"
    if len(value) <= _FAST_QUOTE_MAX and _SAFE.issuperset(value):
        return f'"{value}"'
    return yaml.dump(value, default_style='"').rstrip("\n")


#: uint8[] arrays longer than this are spliced in as bytes by ``render_chunks`` (saves a decode and two copies).
_BLOB_MIN = 4096

#: uint8[] arrays are rendered this many bytes at a time: the slice, its three digit planes and its 160 KB of
#: cells stay in the CPU's L2 cache through every pass, and no multi-megabyte buffer is allocated per frame.
#: Measured on 1 MB arrays beside a process streaming through memory (as the publisher does when echo runs at
#: capacity): 8.8-9.1 ms against 10.7 ms (medians) for one pass over a whole 5 MB cell buffer; 8 KiB to
#: 128 KiB slices are all within noise of each other. In ``mros topic echo`` of flat-out 1 MB images: ~20 %
#: more messages shown than with the whole-array passes.
_SLICE = 32768
_CELL = b"\0\0\0, "


def uint8_pieces(data: bytes | bytearray | memoryview) -> list[bytes | bytearray]:
    """``str(list(data)).encode()`` for a byte string, as pieces to write in order, without a million ints.

    Each byte becomes a five-byte cell ``HTU, `` filled by three ``bytes.translate`` passes (one per digit)
    and strided slice assignment; leading zero digits are marked NUL and deleted by one ``translate`` that
    also produces the piece. The deleting pass is most of the cost (its branch on each byte mispredicts at
    every NUL: ~6 of ~9 ms for 1 MB of random bytes); the ways measured to avoid it were all slower on
    CPython 3.11: ``bytes.replace``, ``decode('ascii', 'ignore')``, numpy boolean indexing, a charmap codec
    or a ``join`` of per-byte (or per-pair) strings, ``'%d, ' * n % tuple(data)``, msgspec's JSON.
    """
    n = len(data)
    if n <= _SLICE:
        return [_uint8_slice(data, b"[", b"]")]
    view = memoryview(data)
    cells = bytearray(_CELL * _SLICE)  # reused by every whole slice
    pieces: list[bytes | bytearray] = [b"["]
    start = 0
    while n - start > _SLICE:
        raw = view[start : start + _SLICE].tobytes()
        cells[0::5] = raw.translate(_HUNDREDS)
        cells[1::5] = raw.translate(_TENS)
        cells[2::5] = raw.translate(_UNITS)
        pieces.append(cells.translate(None, b"\0"))
        start += _SLICE
    pieces.append(_uint8_slice(view[start:], b"", b"]"))
    return pieces


def _uint8_slice(data: bytes | bytearray | memoryview, head: bytes, tail: bytes) -> bytearray:
    """``head`` + the bytes' decimals joined by ``, `` + ``tail`` (``tail`` replaces the last ``, ``)."""
    n = len(data)
    if n == 0:
        return bytearray(head + tail)
    raw = data if type(data) is bytes else bytes(data)
    k = len(head)
    cells = bytearray(head + _CELL * (n - 1) + b"\0\0\0" + tail)
    cells[k : k + 5 * n : 5] = raw.translate(_HUNDREDS)
    cells[k + 1 : k + 5 * n : 5] = raw.translate(_TENS)
    cells[k + 2 : k + 5 * n : 5] = raw.translate(_UNITS)
    return cells.translate(None, b"\0")


def uint8_bytes(data: bytes | bytearray | memoryview) -> bytes:
    """``str(list(data)).encode()`` for a byte string (``b"[1, 2, 255]"``); see ``uint8_pieces``."""
    pieces = uint8_pieces(data)
    return bytes(pieces[0]) if len(pieces) == 1 else b"".join(pieces)


def uint8_text(data: bytes | bytearray | memoryview) -> str:
    """``str(list(data))`` for a byte string (``[1, 2, 255]``)."""
    pieces = uint8_pieces(data)
    return pieces[0].decode("ascii") if len(pieces) == 1 else b"".join(pieces).decode("ascii")


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
        nostr: replace ``string`` fields by ``<string length: N>`` and ``string[]`` ones by
            ``<array type: string, length: N>`` as ``rostopic echo --nostr`` (which, like rostopic, leaves the
            strings inside arrays of messages alone).
        offset_ns: when not None, print time fields as offsets from this time (``rostopic echo --offset``).
    """

    def __init__(self, *, noarr: bool = False, nostr: bool = False) -> None:
        self.noarr = noarr
        self.nostr = nostr
        #: arrays of messages under --nostr: rostopic does not transform their elements.
        self._plain: TextRenderer | None = TextRenderer() if nostr else None
        self.offset_ns: int | None = None
        #: while ``render_chunks`` runs: uint8[] texts kept as pieces of bytes, marked by NUL in the text
        #: (which never contains a NUL otherwise: strings are quoted with escapes, char[] printed as a repr).
        self._blobs: list[list[bytes | bytearray]] | None = None
        self._plans: dict[type, tuple[tuple[str, str, Callable[[Any, str], str]], ...]] = {}

    def render(self, value: Any, type_info: str | None = None) -> str:
        """The text rostopic prints for ``value`` (a message, or a field value of ROS type ``type_info``)."""
        if type_info is not None and ("[" in type_info or (self.nostr and type_info == "string")):
            return self._field_renderer(type_info)(value, "")
        return self._value(value, "")

    def render_bytes(self, value: Any, type_info: str | None = None) -> bytes:
        """``render(...).encode()``, but big ``uint8[]`` texts are spliced in as bytes, never decoded."""
        return b"".join(self.render_chunks(value, type_info))

    def render_chunks(self, value: Any, type_info: str | None = None) -> list[bytes | bytearray]:
        """``render_bytes`` as pieces to write in order (no copy of a multi-megabyte ``uint8[]`` text)."""
        blobs: list[list[bytes | bytearray]] = []
        self._blobs = blobs
        try:
            text = self.render(value, type_info)
        finally:
            self._blobs = None
        if not blobs:
            return [text.encode()]
        parts = text.split("\0")
        out: list[bytes | bytearray] = [parts[0].encode()] if parts[0] else []
        for blob, part in zip(blobs, parts[1:], strict=True):
            out.extend(blob)
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
            if self.noarr or (self.nostr and rostype == "string[]"):
                element = rostype.rstrip("[]")
                return lambda v, _i: quote_string(f"<array type: {element}, length: {len(v)}>")
            if self._plain is not None and rostype.partition("[")[0] not in _NOT_MESSAGES:
                return self._plain._value
            if rostype.startswith("uint8["):
                return self._uint8_field
            if rostype.startswith("bool["):
                # genpy turns bool[] into a list of bools; decoders may hand us 0/1 ints.
                return lambda v, _i: str([bool(x) for x in v]) if len(v) else "[]"
            if rostype.startswith("char["):
                # genpy keeps char[] as bytes and prints their repr.
                return self._char_field
            return self._value
        if rostype == "string" and self.nostr:
            return lambda v, _i: quote_string(f"<string length: {len(v)}>")
        if rostype == "string":
            return lambda v, _i: quote_string(v) if isinstance(v, str) else self._value(v, _i)
        if rostype in ("time", "duration"):
            return self._time if rostype == "time" else self._duration
        return self._value

    def _uint8_field(self, value: Any, indent: str) -> str:
        if isinstance(value, bytes | bytearray | memoryview):
            if self._blobs is not None and len(value) > _BLOB_MIN:
                self._blobs.append(uint8_pieces(value))
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


# -- rostopic echo -p ------------------------------------------------------------------------------------


class PlotRenderer:
    """``rostopic echo -p``'s CSV: a ``%time,field.a,field.b`` heading, then ``<time>,a,b`` per message.

    The time column is a bag message's record time, else the message's ``header.stamp`` in nanoseconds
    when it has a Header, else the receive time; numbers print as Python prints them, bools as 1/0, times as
    nanoseconds, strings unquoted; ``uint8[]`` and ``char[]`` (bytes) and empty arrays print nothing, as under
    rostopic on Python 3. ``noarr``/``nostr`` drop array and string fields (columns and values), as
    rostopic's field filter does.
    """

    def __init__(self, *, noarr: bool = False, nostr: bool = False) -> None:
        self.noarr = noarr
        self.nostr = nostr

    def _fields(self, msg: Any) -> list[str]:
        return [
            name
            for name, rostype in _fields(type(msg))
            if not (self.noarr and "[" in rostype) and not (self.nostr and "string" in rostype)
        ]

    def heading(self, value: Any) -> str:
        """The first line rostopic -p prints (``%time,`` and the column names)."""
        return "%time," + (self._names(value, "field") or "")

    def row(self, value: Any, now_ns: int, offset_ns: int | None = None, *, recorded_ns: int | None = None) -> str:
        """One message's line (no newline); ``offset_ns`` as ``--offset``: times relative to it.

        ``recorded_ns`` (a bag message's record time) is the time column when given, before any
        ``header.stamp``, as ``rostopic echo -p -b`` prints it.
        """
        text = self._values(value, offset_ns) or ""
        if recorded_ns is not None:
            stamp = recorded_ns
        elif _has_header(value):
            stamp = int(value.header.stamp.secs) * 1_000_000_000 + int(value.header.stamp.nsecs)
        else:
            stamp = now_ns
        return f"{stamp - (offset_ns or 0)},{text}"

    def _names(self, value: Any, prefix: str) -> str | None:
        kind = type(value)
        if kind in (bool, int, float, str) or _is_time(value):
            return prefix
        if hasattr(kind, "_field_types"):
            subs = [s for f in self._fields(value) if (s := self._names(getattr(value, f), f"{prefix}.{f}"))]
            return ",".join(subs) if subs else None
        items = _as_list(value)
        if not items:
            return None
        first = items[0]
        if type(first) in (bool, int, float, str) or _is_time(first):
            return ",".join(f"{prefix}{i}" for i in range(len(items)))
        if hasattr(type(first), "_field_types"):
            subs = [s for i, v in enumerate(items) if (s := self._names(v, f"{prefix}{i}"))]
            return ",".join(subs) if subs else None
        return None

    def _values(self, value: Any, offset_ns: int | None) -> str | None:
        kind = type(value)
        if kind is bool:
            return "1" if value else "0"
        if kind in (int, float):
            return str(value)
        if kind is str:
            return str(value)
        if _is_time(value):
            nsec = int(value.secs) * 1_000_000_000 + int(value.nsecs)
            if offset_ns is not None and kind.__name__ == "Time":
                nsec -= offset_ns
            return str(nsec)
        if hasattr(kind, "_field_types"):
            subs = [s for f in self._fields(value) if (s := self._values(getattr(value, f), offset_ns)) is not None]
            return ",".join(subs) if subs else None
        items = _as_list(value)
        if not items:
            return None
        first = items[0]
        if type(first) is bool:
            return ",".join("1" if v else "0" for v in items)
        if type(first) in (int, float, str) or _is_time(first):
            return ",".join(self._values(v, offset_ns) or "" for v in items)
        if hasattr(type(first), "_field_types"):
            subs = [s for v in items if (s := self._values(v, offset_ns)) is not None]
            return ",".join(subs) if subs else None
        return None


def _has_header(value: Any) -> bool:
    """genpy's ``_has_header``: the message's first field is ``Header header``."""
    types = getattr(type(value), "_field_types", None)
    if not types:
        return False
    first: str = type(value).__struct_fields__[0]
    return first == "header" and types[0] in ("Header", "std_msgs/Header")


def _as_list(value: Any) -> list[Any] | None:
    """A message array as a list; None for bytes (``uint8[]``/``char[]``), which rostopic -p leaves out."""
    if isinstance(value, list):
        return value
    if isinstance(value, tuple):
        return list(value)
    if hasattr(value, "tolist") and not isinstance(value, bytes | bytearray | memoryview):
        items: list[Any] = value.tolist()
        return items
    return None


def _header_value(header: Any, key: str) -> str:
    if isinstance(header, dict):
        return str(header.get(key, ""))
    value = getattr(header, key, None)
    if value is None:
        extra = getattr(header, "extra", None) or {}
        value = extra.get(key, "")
    return str(value)


class Decoder:
    """Message classes built from each publisher's connection header, cached by (type, md5)."""

    def __init__(self) -> None:
        self._classes: dict[tuple[str, str], Any] = {}

    def decode(self, raw: Any) -> Any:
        header = raw.header
        key = (_header_value(header, "type"), _header_value(header, "md5sum"))
        cls = self._classes.get(key)
        if cls is None:
            from mrosd.msg import load_type  # the message runtime: only when a message arrives

            cls = load_type(key[0], _header_value(header, "message_definition"))
            self._classes[key] = cls
        return cls.deserialize(raw.data)
