"""The one generator: a MsgSpec becomes Python source for a msgspec Struct with inlined (de)serializers.

Used two ways: ``loader.py`` compiles the source for runtime classes, and ``mros msg gen`` writes it to
files. The source refers to other message classes by symbol (``_T_std_msgs__Header``); the caller binds
those symbols (a namespace at runtime, imports in files).

Speed comes from flattening: nested messages are inlined, consecutive fixed-size fields (through nested
messages, time/duration, and the uint32 length prefix of the next string or array) are packed or unpacked
with one precompiled ``struct.Struct``; uint8[] is copied as bytes (or viewed when large), numeric
variable arrays go through ``array.array`` without per-element objects, flat fixed-size message arrays
through ``Struct.iter_unpack``. Decoders check every untrusted length against the bytes that remain
before they allocate or loop.
"""

from __future__ import annotations

import keyword
import math
import re
import struct
from collections.abc import Callable
from dataclasses import dataclass, field

from mrosd.errors import MsgError
from mrosd.msg.spec import PRIMITIVE_FORMATS, Field, MsgSpec

#: Bound on the item count of an array of messages that occupy no bytes (an empty message type):
#: nothing in the buffer limits such a count, so without it a forged header could spin for hours.
MAX_EMPTY_ITEMS = 1 << 16

Lookup = Callable[[str], MsgSpec]

_BYTE_TYPES = ("uint8", "char")
_TIME_FORMATS = {"time": "I", "duration": "i"}
_PY_SCALARS = {"bool": "bool", "float32": "float", "float64": "float", "string": "str"}


def symbol(type_name: str) -> str:
    """The identifier generated code uses for a message class (``pkg/Type`` -> ``_T_pkg__Type``)."""
    return "_T_" + type_name.replace("/", "__")


def attribute_name(field_name: str) -> str:
    """The Python attribute of a field: genpy's rule appends ``_`` to keywords and ``self``."""
    return field_name + "_" if keyword.iskeyword(field_name) or field_name == "self" else field_name


def class_name(spec: MsgSpec) -> str:
    """The Python class name of a message (its short name)."""
    return spec.short_name


def min_size(spec: MsgSpec, lookup: Lookup) -> int:
    """The smallest number of bytes a serialized ``spec`` can take."""
    total = 0
    for f in spec.fields:
        item = _element_min_size(f.base, lookup)
        if not f.is_array:
            total += item
        elif f.length is None:
            total += 4
        else:
            total += item * f.length
    return total


def _element_min_size(base: str, lookup: Lookup) -> int:
    if base in PRIMITIVE_FORMATS:
        return PRIMITIVE_FORMATS[base][1]
    if base in _TIME_FORMATS:
        return 8
    if base == "string":
        return 4
    return min_size(lookup(base), lookup)


def fixed_size(spec: MsgSpec, lookup: Lookup) -> int | None:
    """The serialized size if every field has a fixed size, else None."""
    total = 0
    for f in spec.fields:
        if f.base == "string" or (f.is_array and f.length is None):
            return None
        if f.base in PRIMITIVE_FORMATS or f.base in _TIME_FORMATS:
            item: int | None = _element_min_size(f.base, lookup)
        else:
            item = fixed_size(lookup(f.base), lookup)
        if item is None:
            return None
        total += item * (f.length if f.is_array and f.length is not None else 1)
    return total


def _is_flat(spec: MsgSpec) -> bool:
    """True if every field is a primitive scalar (so ``Struct.iter_unpack`` yields constructor arguments)."""
    return bool(spec.fields) and all(not f.is_array and f.base in PRIMITIVE_FORMATS for f in spec.fields)


@dataclass
class _Writer:
    """Accumulates indented lines, temporaries and precompiled struct formats for one generated class."""

    type_name: str
    lookup: Lookup
    lines: list[str] = field(default_factory=list)
    structs: dict[str, int] = field(default_factory=dict)
    helpers: dict[str, str] = field(default_factory=dict)
    counter: int = 0
    tag: str = ""  #: distinguishes the structs of several classes generated into one module

    def emit(self, indent: int, text: str) -> None:
        self.lines.append("    " * indent + text)

    def tmp(self, prefix: str = "v") -> str:
        self.counter += 1
        return f"_{prefix}{self.counter}"

    def _index(self, fmt: str) -> int:
        index = self.structs.get(fmt)
        if index is None:
            index = self.structs[fmt] = len(self.structs)
        return index

    def struct(self, fmt: str) -> str:
        """The module-level ``struct.Struct`` for ``fmt`` (little-endian)."""
        return f"_S{self.tag}{self._index(fmt)}"

    def pack(self, fmt: str) -> str:
        """The prebound ``pack`` of that struct (saves an attribute lookup per call)."""
        return f"_P{self.tag}{self._index(fmt)}"

    def unpack(self, fmt: str) -> str:
        """The prebound ``unpack_from`` of that struct."""
        return f"_U{self.tag}{self._index(fmt)}"

    def helper(self, name: str, expr: str) -> str:
        self.helpers[name] = expr
        return name

    def prelude(self) -> list[str]:
        out = []
        for fmt in self.structs:
            out.append(f"{self.struct(fmt)} = _struct.Struct({'<' + fmt!r})")
            out.append(f"{self.pack(fmt)} = {self.struct(fmt)}.pack")
            out.append(f"{self.unpack(fmt)} = {self.struct(fmt)}.unpack_from")
        out += [f"{name} = {expr}" for name, expr in sorted(self.helpers.items())]
        return out


def _fmt_size(fmt: str) -> int:
    return struct.calcsize("<" + fmt)


# ---------------------------------------------------------------------------------------------- serialize


class _Encoder:
    """Emits the body of ``serialize``: a pending run of (format, expression) flushed into one pack call.

    Until the first loop the parts are kept as expressions and joined once at the end (no list, no
    appends); a loop switches to appending to ``_p``.
    """

    def __init__(self, w: _Writer, parts: list[str] | None = None) -> None:
        self.w = w
        self.run: list[tuple[str, str]] = []
        self.parts = parts  #: expression mode while not None
        self.appended = False  #: True once anything was appended to ``_p``

    def add(self, indent: int, expr: str) -> None:
        if self.parts is not None:
            self.parts.append(expr)
        else:
            self.w.emit(indent, f"_a({expr})")
            self.appended = True

    def flush(self, indent: int) -> None:
        if not self.run:
            return
        fmt = "".join(f for f, _ in self.run)
        args = ", ".join(e for _, e in self.run)
        self.run = []
        self.add(indent, f"{self.w.pack(fmt)}({args})")

    def to_append_mode(self, indent: int) -> None:
        if self.parts is not None:
            self.w.emit(indent, f"_p: list[_Any] = [{', '.join(self.parts)}]")
            self.w.emit(indent, "_a = _p.append")
            self.parts = None
            self.appended = True

    def fields(self, spec: MsgSpec, expr: str, indent: int, path: str) -> None:
        for f in spec.fields:
            self.one(f, f"{expr}.{attribute_name(f.name)}", indent, f"{path}{f.name}")

    def one(self, f: Field, acc: str, indent: int, path: str) -> None:
        w = self.w
        base = f.base
        if not f.is_array:
            if base in PRIMITIVE_FORMATS:
                self.run.append((PRIMITIVE_FORMATS[base][0], acc))
            elif base == "string":
                s = w.tmp("s")
                w.emit(indent, f"{s} = {acc}")
                w.emit(indent, f"if {s}.__class__ is str:")
                w.emit(indent + 1, f"{s} = {s}.encode()")
                self.run.append(("I", f"len({s})"))
                self.flush(indent)
                self.add(indent, s)
            elif base in _TIME_FORMATS:
                t = w.tmp("t")
                w.emit(indent, f"{t} = {acc}")
                c = _TIME_FORMATS[base]
                self.run += [(c, f"{t}.secs"), (c, f"{t}.nsecs")]
            else:
                v = w.tmp("m")
                w.emit(indent, f"{v} = {acc}")
                self.fields(w.lookup(base), v, indent, path + ".")
            return
        a = w.tmp("a")
        w.emit(indent, f"{a} = {acc}")
        n = f.length
        if n is not None:
            w.emit(indent, f"if len({a}) != {n}:")
            w.emit(indent + 1, f"raise _bad_length({w.type_name!r}, {path!r}, {n}, len({a}))")
        if base in _BYTE_TYPES:
            w.emit(indent, f"if {a}.__class__ is not bytes:")
            w.emit(indent + 1, f"{a} = _to_bytes({a})")
            if n is None:
                self.run.append(("I", f"len({a})"))
                self.flush(indent)
                self.add(indent, a)
            else:
                self.run.append((f"{n}s", a))
            return
        if base in PRIMITIVE_FORMATS:
            code = PRIMITIVE_FORMATS[base][0]
            if n is None:
                self.run.append(("I", f"len({a})"))
                self.flush(indent)
                if code == "?":
                    self.add(indent, f"bytes(map(bool, {a}))")
                else:
                    enc = w.helper(f"_enc_{code}", f"_array_encoder({code!r})")
                    self.add(indent, f"{enc}({a})")
            elif n:
                self.run.append((f"{n}{code}", f"*{a}"))
            return
        if n is None:
            self.run.append(("I", f"len({a})"))
        self.flush(indent)
        self.to_append_mode(indent)
        item = w.tmp("i")
        w.emit(indent, f"for {item} in {a}:")
        inner = _Encoder(w)
        inner.one(Field(name=f.name, type=base, base=base, line=f.line), item, indent + 1, path + "[]")
        inner.flush(indent + 1)
        if not inner.appended:
            w.emit(indent + 1, "pass")


def _serialize_source(spec: MsgSpec, w: _Writer) -> list[str]:
    parts: list[str] = []
    enc = _Encoder(w, parts)
    start = len(w.lines)
    enc.fields(spec, "self", 3, "")
    enc.flush(3)
    body = w.lines[start:]
    del w.lines[start:]
    out = [
        "    def serialize(self) -> bytes:",
        '        """The message body (no length prefix), byte-identical to genpy."""',
        "        try:",
        *body,
    ]
    if enc.parts is None:
        out.append('            return b"".join(_p)')
    elif not parts:
        out.append('            return b""')
    elif len(parts) == 1:
        out.append(f"            return {parts[0]}  # type: ignore[no-any-return]")
    elif len(parts) == 2:
        out.append(f"            return {parts[0]} + {parts[1]}  # type: ignore[no-any-return]")
    else:
        out.append(f'            return b"".join(({", ".join(parts)}))')
    out.append("        except (_struct_error, TypeError, ValueError, AttributeError, OverflowError) as exc:")
    out.append(f"            raise _serialize_failed({spec.full_name!r}, exc) from None")
    return out


# -------------------------------------------------------------------------------------------- deserialize

#: Placeholder for the string decode call; the strict variant is tried first, the lenient one (invalid
#: UTF-8 replaced by U+FFFD, as genpy does) only after a UnicodeDecodeError.
_DECODE = "\x00DECODE\x00"


class _Decoder:
    """Emits the body of ``deserialize``: fields become locals, messages are built by one expression.

    The read offset is tracked symbolically as ``base + pending`` (``base`` a local holding an offset,
    or the constant 0), so fixed runs need no ``o += k`` statements; ``o`` is only materialized for loops.
    """

    def __init__(self, w: _Writer, base: str = "") -> None:
        self.w = w
        self.run: list[tuple[str, str, int]] = []  #: (format, target local, item count or 0 for a scalar)
        self.base = base
        self.pending = 0
        self.last_check: tuple[int, str] = (-1, "")  #: (line index of the latest bounds check, its end local)

    def off(self) -> str:
        if not self.base:
            return str(self.pending)
        return self.base if not self.pending else f"{self.base} + {self.pending}"

    def rebase(self, var: str) -> None:
        self.base, self.pending = var, 0

    def materialize(self, indent: int) -> None:
        if self.base != "o" or self.pending:
            self.w.emit(indent, f"o = {self.off()}")
            self.rebase("o")

    def flush(self, indent: int) -> None:
        if not self.run:
            return
        w = self.w
        fmt = "".join(f for f, _, _ in self.run)
        call = f"{w.unpack(fmt)}(b)" if self.off() == "0" else f"{w.unpack(fmt)}(b, {self.off()})"
        arrays = [r for r in self.run if r[2]]
        if len(arrays) <= 1:
            targets = ", ".join(("*" + t) if count else t for _, t, count in self.run)
            w.emit(indent, f"{targets}, = {call}")
        else:
            u = w.tmp("u")
            w.emit(indent, f"{u} = {call}")
            pos = 0
            for _, t, count in self.run:
                if count:
                    w.emit(indent, f"{t} = list({u}[{pos}:{pos + count}])")
                    pos += count
                else:
                    w.emit(indent, f"{t} = {u}[{pos}]")
                    pos += 1
        self.pending += _fmt_size(fmt)
        self.run = []

    def fields(self, spec: MsgSpec, indent: int, path: str) -> list[str]:
        return [self.one(f, indent, f"{path}{f.name}") for f in spec.fields]

    def _span(self, count: str, item_size: int, indent: int, path: str) -> str:
        """Emit the bounds check for ``count`` items of ``item_size`` bytes; returns the end offset local."""
        w = self.w
        e = w.tmp("e")
        start = self.off()
        w.emit(indent, f"{e} = {start} + {count}" + (f" * {item_size}" if item_size != 1 else ""))
        self.last_check = (len(w.lines), e)
        w.emit(indent, f"if {e} > n:")
        w.emit(indent + 1, f"raise _truncated({w.type_name!r}, {path!r}, {e} - ({start}), n - ({start}))")
        return e

    def _length(self, indent: int) -> str:
        ln = self.w.tmp("n")
        self.run.append(("I", ln, 0))
        self.flush(indent)
        return ln

    def one(self, f: Field, indent: int, path: str) -> str:
        w = self.w
        base = f.base
        if not f.is_array:
            if base in PRIMITIVE_FORMATS:
                v = w.tmp()
                self.run.append((PRIMITIVE_FORMATS[base][0], v, 0))
                return v
            if base in _TIME_FORMATS:
                s, ns = w.tmp(), w.tmp()
                c = _TIME_FORMATS[base]
                self.run += [(c, s, 0), (c, ns, 0)]
                return f"{'_Time' if base == 'time' else '_Duration'}({s}, {ns})"
            if base == "string":
                ln = self._length(indent)
                e = self._span(ln, 1, indent, path)
                v = w.tmp()
                w.emit(indent, f"{v} = b[{self.off()}:{e}]{_DECODE}")
                self.rebase(e)
                return v
            sub = w.lookup(base)
            args = self.fields(sub, indent, path + ".")
            return f"{symbol(base)}({', '.join(args)})"
        n = f.length
        v = w.tmp()
        if base in _BYTE_TYPES:
            if n is None:
                ln = self._length(indent)
                e = self._span(ln, 1, indent, path)
                w.emit(indent, f"{v} = _blob(b, {self.off()}, {e})")
                self.rebase(e)
            else:
                self.run.append((f"{n}s", v, 0))
            return v
        if base in PRIMITIVE_FORMATS:
            code, size = PRIMITIVE_FORMATS[base]
            if n is not None:
                if n == 0:
                    return "[]"
                self.run.append((f"{n}{code}", v, n))
                return v
            ln = self._length(indent)
            e = self._span(ln, size, indent, path)
            if code == "?":
                w.emit(indent, f"{v} = [x != 0 for x in b[{self.off()}:{e}]]")
            else:
                dec = w.helper(f"_dec_{code}", f"_array_decoder({code!r})")
                w.emit(indent, f"{v} = {dec}(b, {self.off()}, {e})")
            self.rebase(e)
            return v
        # arrays of strings, times and messages: check the count against the bytes left before looping
        count = self._length(indent) if n is None else str(n)
        self.flush(indent)
        if base in _TIME_FORMATS or (base != "string" and _is_flat(w.lookup(base))):
            if base in _TIME_FORMATS:
                fmt = _TIME_FORMATS[base] * 2
                ctor = "_Time" if base == "time" else "_Duration"
            else:
                fmt = "".join(PRIMITIVE_FORMATS[x.base][0] for x in w.lookup(base).fields)
                ctor = symbol(base)
            e = self._span(count, _fmt_size(fmt), indent, path)
            iterator = f"{w.struct(fmt)}.iter_unpack(memoryview(b)[{self.off()}:{e}])"
            w.emit(indent, f"{v} = list(_starmap({ctor}, {iterator}))")
            self.rebase(e)
            return v
        item_min = _element_min_size(base, w.lookup)
        start = self.off()
        if item_min:
            w.emit(indent, f"if {count} * {item_min} > n - ({start}):")
            w.emit(indent + 1, f"raise _truncated({w.type_name!r}, {path!r}, {count} * {item_min}, n - ({start}))")
        else:
            w.emit(indent, f"if {count} > {MAX_EMPTY_ITEMS}:")
            w.emit(indent + 1, f"raise _truncated({w.type_name!r}, {path!r}, {count}, {MAX_EMPTY_ITEMS})")
        self.materialize(indent)
        w.emit(indent, f"{v} = []")
        ap = w.tmp("ap")
        w.emit(indent, f"{ap} = {v}.append")
        w.emit(indent, f"for _ in range({count}):")
        inner = _Decoder(w, "o")
        expr = inner.one(Field(name=f.name, type=base, base=base, line=f.line), indent + 1, path + "[]")
        inner.flush(indent + 1)
        inner.materialize(indent + 1)
        w.emit(indent + 1, f"{ap}({expr})")
        return v


def _has_strings(spec: MsgSpec, lookup: Lookup) -> bool:
    return any(f.base == "string" or (not f.is_builtin and _has_strings(lookup(f.base), lookup)) for f in spec.fields)


#: How many distinct message sizes one class caches a tail struct for (then the generic path is used).
MAX_TAIL_STRUCTS = 1024

_TAIL_PATTERN = (
    re.compile(r"(?P<indent>\s*)(?P<targets>.*), = (?P<unpack>_U\w+)\(b\)\Z"),
    re.compile(r"\s*(?P<end>_e\d+) = (?P<start>\d+) \+ (?P<length>_n\d+)\Z"),
    re.compile(r"\s*(?P<value>_v\d+) = b\[(?P<start>\d+):(?P<end>_e\d+)\]" + _DECODE + r"\Z"),
)


def _tail_string_fast_path(body: list[str], w: _Writer) -> list[str]:
    """Fixed fields then one final string (std_msgs/String, std_msgs/Header): one unpack for everything.

    The message size fixes the string's size, so a struct ``<fixed...I{size}s`` cached per size reads the
    fixed fields, the length and the string bytes in one C call (no separate slice); the usual end check
    still compares the length prefix with the size. Other sizes, once the cache is full, take the
    generic path.
    """
    if len(body) != 3:
        return body
    matches = [pattern.match(line) for pattern, line in zip(_TAIL_PATTERN, body, strict=True)]
    first, second, third = matches
    if first is None or second is None or third is None or second["start"] != third["start"]:
        return body
    fmt = next((f for f in w.structs if w.unpack(f) == first["unpack"]), None)
    if fmt is None or _fmt_size(fmt) != int(second["start"]):
        return body
    indent = first["indent"]
    tails = w.helper(f"_TAIL{w.tag}", "{}")
    return [
        f"{indent}_u = {tails}.get(n)",
        f"{indent}if _u is None and len({tails}) < {MAX_TAIL_STRUCTS} and n >= {second['start']}:",
        f"{indent}    _u = {tails}[n] = _struct.Struct({'<' + fmt!r} + str(n - {second['start']}) + 's').unpack_from",
        f"{indent}if _u is not None:",
        f"{indent}    {first['targets']}, _raw = _u(b)",
        f"{indent}    {second['end']} = {second['start']} + {second['length']}",
        f"{indent}    {third['value']} = _raw{_DECODE}",
        f"{indent}else:",
        *("    " + line for line in body),
    ]


def _deserialize_source(spec: MsgSpec, w: _Writer) -> list[str]:
    dec = _Decoder(w)
    start = len(w.lines)
    args = dec.fields(spec, 3, "")
    dec.flush(3)
    body = w.lines[start:]
    del w.lines[start:]
    name = class_name(spec)
    end = dec.off()
    lenient = _has_strings(spec, w.lookup)
    check_at, check_end = dec.last_check
    if check_end == end and check_at - start == len(body) - 3 and "_dec_" not in body[-1]:
        # The last field is a string or uint8[] ending the message: the final ``end != n`` check covers
        # truncation too (a short slice allocates nothing beyond the buffer), so skip the separate check.
        del body[-3:-1]
        body = _tail_string_fast_path(body, w)

    def variant(method: str, decode: str, doc: str, fallback: bool) -> list[str]:
        # A staticmethod (not a classmethod): looking it up allocates no bound method on every call.
        out = [
            "    @staticmethod",
            f"    def {method}(data: bytes | bytearray | memoryview) -> {name!r}:",
            f'        """{doc}"""',
            "        b = data",
            "        n = len(b)",
            "        try:",
        ]
        out += [line.replace(_DECODE, decode) for line in body] or ["            pass"]
        if fallback:
            out += ["        except UnicodeDecodeError:", f"            return {name}._deserialize_lenient(b)"]
        if lenient:
            # memoryview has no .decode(): strings need bytes (other fields decode from any buffer).
            out += [
                "        except AttributeError:",
                "            if data.__class__ is bytes:",
                "                raise",
                f"            return {name}.{method}(_as_bytes(data))",
            ]
        out += [
            "        except _struct_error as exc:",
            f"            raise _truncated_message({spec.full_name!r}, n, exc) from None",
            f"        if {end} != n:",
            f"            raise _trailing({spec.full_name!r}, {end}, n)",
            f"        return {name}({', '.join(args)})",
        ]
        return out

    doc = "Decode a message body; raises DeserializationError on truncated, oversized or trailing input."
    out = variant("deserialize", ".decode()", doc, lenient)
    if lenient:
        out.append("")
        out += variant("_deserialize_lenient", ".decode('utf-8', 'replace')", "Decode, replacing invalid UTF-8.", False)
    return out


# ------------------------------------------------------------------------------------------------- class


def _annotation(f: Field) -> str:
    base = f.base
    if base in _BYTE_TYPES and f.is_array:
        return "bytes"
    if base in PRIMITIVE_FORMATS:
        item = _PY_SCALARS.get(base, "int")
    elif base in _PY_SCALARS:
        item = _PY_SCALARS[base]
    elif base in _TIME_FORMATS:
        item = "_Time" if base == "time" else "_Duration"
    else:
        item = symbol(base)
    if not f.is_array:
        return item
    if base in PRIMITIVE_FORMATS:
        return f"_Sequence[{item}]"
    return f"list[{item}]"


def _default(f: Field) -> str:
    base = f.base
    n = f.length
    if f.is_array:
        if base in _BYTE_TYPES:
            return repr(b"\0" * n) if n else 'b""'
        if n is None and base in PRIMITIVE_FORMATS and base != "bool":
            return f"_msgspec.field(default_factory=_partial(_array, {PRIMITIVE_FORMATS[base][0]!r}))"
        if n is None or n == 0:
            return "_msgspec.field(default_factory=list)"
        if base in PRIMITIVE_FORMATS or base == "string":
            return f"_msgspec.field(default_factory=lambda: [{_scalar_default(base)}] * {n})"
        return f"_msgspec.field(default_factory=lambda: [{_scalar_default(base)} for _ in range({n})])"
    if base in PRIMITIVE_FORMATS or base == "string":
        return _scalar_default(base)
    return f"_msgspec.field(default_factory={_scalar_default(base)[:-2]})"


def _scalar_default(base: str) -> str:
    if base == "bool":
        return "False"
    if base in ("float32", "float64"):
        return "0.0"
    if base in PRIMITIVE_FORMATS:
        return "0"
    if base == "string":
        return '""'
    if base == "time":
        return "_Time()"
    if base == "duration":
        return "_Duration()"
    return f"{symbol(base)}()"


@dataclass
class GeneratedClass:
    """Source of one message class and the message types (by full name) its symbols refer to."""

    full_name: str
    class_name: str
    source: str
    dependencies: list[str]


def generate_class(spec: MsgSpec, md5: str, full_text: str, lookup: Lookup, tag: str = "") -> GeneratedClass:
    """Generate the class for ``spec``; ``lookup`` resolves nested types (already parsed).

    Raises:
        MsgError: a field name cannot be a Python attribute (a keyword).
    """
    for f in spec.fields:
        if f.name in ("serialize", "deserialize"):
            raise MsgError(f"{spec.full_name}: field name {f.name!r} would hide the {f.name}() method")
    name = class_name(spec)
    w = _Writer(type_name=spec.full_name, lookup=lookup, tag=tag)
    ser = _serialize_source(spec, w)
    des = _deserialize_source(spec, w)
    size = fixed_size(spec, lookup)
    deps = sorted({d for d in _all_deps(spec, lookup)})
    lines = [f"class {name}(_msgspec.Struct, gc=False):"]
    doc = f"ROS message {spec.full_name} (GENERATED by mrosd.msg.codegen from its definition)."
    lines.append(f'    """{doc}"""')
    lines.append("")
    for f in spec.fields:
        lines.append(f"    {attribute_name(f.name)}: {_annotation(f)} = {_default(f)}")
    if spec.fields:
        lines.append("")
    lines += [
        f"    _type: _ClassVar[str] = {spec.full_name!r}",
        f"    _md5sum: _ClassVar[str] = {md5!r}",
        f"    _full_text: _ClassVar[str] = {full_text!r}",
        f"    _has_header: _ClassVar[bool] = {spec.has_header!r}",
        f"    _fixed_size: _ClassVar[int | None] = {size!r}",
        f"    _field_types: _ClassVar[tuple[str, ...]] = {tuple(f.type for f in spec.fields)!r}",
        "    _slot_types: _ClassVar[tuple[str, ...]] = _field_types",
    ]
    for c in spec.constants:
        lines.append(f"    {c.name}: _ClassVar[{type(c.value).__name__}] = {_literal(c.value)}")
    lines.append("")
    lines += ser
    lines.append("")
    lines += des
    prelude = w.prelude()
    source = "\n".join([*prelude, "", "", *lines]) + "\n"
    return GeneratedClass(spec.full_name, name, source, deps)


def _all_deps(spec: MsgSpec, lookup: Lookup) -> list[str]:
    out: list[str] = []
    for f in spec.fields:
        if not f.is_builtin:
            out.append(f.base)
            out += _all_deps(lookup(f.base), lookup)
    return out


#: Imports every generated class needs (files and runtime namespaces alike).
PRELUDE = """\
import struct as _struct
from array import array as _array
from collections.abc import Sequence as _Sequence
from functools import partial as _partial
from itertools import starmap as _starmap
from typing import Any as _Any
from typing import ClassVar as _ClassVar

import msgspec as _msgspec

from mrosd.msg.runtime import DeserializationError as _DeserializationError
from mrosd.msg.runtime import Duration as _Duration
from mrosd.msg.runtime import Time as _Time
from mrosd.msg.runtime import array_decoder as _array_decoder
from mrosd.msg.runtime import array_encoder as _array_encoder
from mrosd.msg.runtime import as_bytes as _as_bytes
from mrosd.msg.runtime import bad_length as _bad_length
from mrosd.msg.runtime import blob as _blob
from mrosd.msg.runtime import serialize_failed as _serialize_failed
from mrosd.msg.runtime import struct_error as _struct_error
from mrosd.msg.runtime import to_bytes as _to_bytes
from mrosd.msg.runtime import trailing as _trailing
from mrosd.msg.runtime import truncated as _truncated
from mrosd.msg.runtime import truncated_message as _truncated_message
"""


def _literal(value: object) -> str:
    """Python source for a constant's value; repr() of inf/nan is not valid source."""
    if isinstance(value, float) and not math.isfinite(value):
        return f"float({str(value)!r})"
    return repr(value)
