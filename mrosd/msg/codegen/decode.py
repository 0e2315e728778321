"""The ``deserialize`` emitter: bounds-checked, flattened, with fast paths decided while generating."""

from __future__ import annotations

from mrosd.msg.codegen.sizes import (
    BYTE_TYPES,
    TIME_FORMATS,
    Lookup,
    class_name,
    element_min_size,
    fmt_size,
    is_flat,
    symbol,
)
from mrosd.msg.codegen.writer import Writer
from mrosd.msg.layout import MAX_EMPTY_ITEMS
from mrosd.msg.spec import PRIMITIVE_FORMATS, Field, MsgSpec

#: Placeholder for the string decode call; the strict variant is tried first, the lenient one (invalid
#: UTF-8 replaced by U+FFFD, as genpy does) only after a UnicodeDecodeError.
DECODE = "\x00DECODE\x00"
#: Placeholder for the method decoding a called nested type: ``_decode_at``, or ``_decode_at_lenient`` in
#: the lenient variant (so that a retry after invalid UTF-8 is lenient all the way down).
DECODE_AT = "\x00AT\x00"


class Decoder:
    """Emits the body of ``deserialize``: fields become locals, messages are built by one expression.

    The read offset is tracked symbolically as ``base + pending`` (``base`` a local holding an offset,
    or the constant 0), so fixed runs need no ``o += k`` statements; ``o`` is only materialized for loops.
    """

    def __init__(self, w: Writer, base: str = "", *, views: bool = False) -> None:
        self.w = w
        #: decoding a read-only view of memory that does not change while the message lives (see
        #: ``view_decoder_source``): large arrays become views of it, strings are decoded from it
        self.views = views
        self.run: list[tuple[str, str, int]] = []  #: (format, target local, item count or 0 for a scalar)
        self.base = base
        self.pending = 0
        self.last_check: tuple[int, str] = (-1, "")  #: (line index of the latest bounds check, its end local)
        #: The latest flushed run: (format, its targets' source, the offset it was read at).
        self.last_run: tuple[str, str, str] = ("", "", "")
        #: The latest string field: (fixed run read just before it, its length local, start offset, end local,
        #: value local), for the fast path of a message that is fixed fields then one final string.
        self.last_string: tuple[tuple[str, str, str], str, str, str, str] | None = None

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
            self.last_run = (fmt, targets, self.off())
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
        self.pending += fmt_size(fmt)
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
            if base in TIME_FORMATS:
                s, ns = w.tmp(), w.tmp()
                c = TIME_FORMATS[base]
                self.run += [(c, s, 0), (c, ns, 0)]
                return f"{'_Time' if base == 'time' else '_Duration'}({s}, {ns})"
            if base == "string":
                self.last_run = ("", "", "")
                ln = self._length(indent)
                run = self.last_run
                e = self._span(ln, 1, indent, path)
                v = w.tmp()
                self.last_string = (run, ln, self.off(), e, v)
                if self.views:  # a memoryview has no .decode(); str() decodes any buffer
                    w.emit(indent, f"{v} = str(b[{self.off()}:{e}], 'utf-8', 'replace')")
                else:
                    w.emit(indent, f"{v} = b[{self.off()}:{e}]{DECODE}")
                self.rebase(e)
                return v
            if self.views or w.inline(base):
                args = self.fields(w.lookup(base), indent, path + ".")
                return f"{symbol(base)}({', '.join(args)})"
            # too big to inline: its class's ``_decode_at`` reads it and says where it ended
            self.flush(indent)
            v, e = w.tmp(), w.tmp("e")
            w.emit(indent, f"{v}, {e} = {symbol(base)}.{DECODE_AT}(b, {self.off()}, n)")
            self.rebase(e)
            return v
        n = f.length
        v = w.tmp()
        if base in BYTE_TYPES:
            if n is None:
                ln = self._length(indent)
                e = self._span(ln, 1, indent, path)
                if self.views:
                    w.emit(indent, f"{v} = _blob_view(b, {self.off()}, {e}, views)")
                else:
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
            elif self.views:
                dec = w.helper(f"_vdec_{code}", f"_array_view_decoder({code!r})")
                w.emit(indent, f"{v} = {dec}(b, {self.off()}, {e}, views)")
            else:
                dec = w.helper(f"_dec_{code}", f"_array_decoder({code!r})")
                w.emit(indent, f"{v} = {dec}(b, {self.off()}, {e})")
            self.rebase(e)
            return v
        # arrays of strings, times and messages: check the count against the bytes left before looping
        count = self._length(indent) if n is None else str(n)
        self.flush(indent)
        if base in TIME_FORMATS or (base != "string" and is_flat(w.lookup(base))):
            if base in TIME_FORMATS:
                fmt = TIME_FORMATS[base] * 2
                ctor = "_Time" if base == "time" else "_Duration"
            else:
                fmt = "".join(PRIMITIVE_FORMATS[x.base][0] for x in w.lookup(base).fields)
                ctor = symbol(base)
            e = self._span(count, fmt_size(fmt), indent, path)
            iterator = f"{w.struct(fmt)}.iter_unpack(memoryview(b)[{self.off()}:{e}])"
            w.emit(indent, f"{v} = list(_starmap({ctor}, {iterator}))")
            self.rebase(e)
            return v
        item_min = element_min_size(base, w.lookup)
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
        inner = Decoder(w, "o", views=self.views)
        expr = inner.one(Field(name=f.name, type=base, base=base, line=f.line), indent + 1, path + "[]")
        inner.flush(indent + 1)
        inner.materialize(indent + 1)
        w.emit(indent + 1, f"{ap}({expr})")
        return v


def has_strings(spec: MsgSpec, lookup: Lookup) -> bool:
    return any(f.base == "string" or (not f.is_builtin and has_strings(lookup(f.base), lookup)) for f in spec.fields)


#: How many distinct message sizes one class caches a tail struct for (then the generic path is used).
MAX_TAIL_STRUCTS = 1024


def tail_string_fast_path(body: list[str], dec: Decoder, w: Writer) -> list[str]:
    """Fixed fields then one final string (std_msgs/String, std_msgs/Header): one unpack for everything.

    ``body`` is then exactly: the unpack of the fixed run (ending with the string's length) at offset 0,
    the end offset, the string slice. The message size fixes the string's size, so a struct
    ``<fixed...I{size}s`` cached per size reads the fixed fields, the length and the string bytes in one C
    call (no separate slice); the usual end check still compares the length prefix with the size. Other
    sizes, once the cache is full, take the generic path.
    """
    tail = dec.last_string
    if len(body) != 3 or tail is None:
        return body
    (fmt, targets, run_offset), length, start, end, value = tail
    if not fmt or run_offset != "0" or not start.isdigit() or fmt_size(fmt) != int(start):
        return body
    indent = body[0][: len(body[0]) - len(body[0].lstrip())]
    tails = w.helper(f"_TAIL{w.tag}", "{}")
    return [
        f"{indent}_u = {tails}.get(n)",
        f"{indent}if _u is None and len({tails}) < {MAX_TAIL_STRUCTS} and n >= {start}:",
        f"{indent}    _u = {tails}[n] = _struct.Struct({'<' + fmt!r} + str(n - {start}) + 's').unpack_from",
        f"{indent}if _u is not None:",
        f"{indent}    {targets}, _raw = _u(b)",
        f"{indent}    {end} = {start} + {length}",
        f"{indent}    {value} = _raw{DECODE}",
        f"{indent}else:",
        *("    " + line for line in body),
    ]


def deserialize_source(spec: MsgSpec, w: Writer) -> list[str]:
    dec = Decoder(w)
    start = len(w.lines)
    args = dec.fields(spec, 3, "")
    dec.flush(3)
    body = w.lines[start:]
    del w.lines[start:]
    name = class_name(spec)
    end = dec.off()
    lenient = has_strings(spec, w.lookup)
    check_at, check_end = dec.last_check
    if check_end == end and check_at - start == len(body) - 3 and "_dec_" not in body[-1]:
        # The last field is a string or uint8[] ending the message: the final ``end != n`` check covers
        # truncation too (a short slice allocates nothing beyond the buffer), so skip the separate check.
        del body[-3:-1]
        body = tail_string_fast_path(body, dec, w)

    def fill(line: str, decode: str, at: str) -> str:
        return line.replace(DECODE, decode).replace(DECODE_AT, at)

    def variant(method: str, decode: str, at: str, doc: str, fallback: bool) -> list[str]:
        # A staticmethod (not a classmethod): looking it up allocates no bound method on every call.
        out = [
            "    @staticmethod",
            f"    def {method}(data: bytes | bytearray | memoryview) -> {name!r}:",
            f'        """{doc}"""',
            "        b = data",
            "        n = len(b)",
            "        try:",
        ]
        out += [fill(line, decode, at) for line in body] or ["            pass"]
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

    strict, replace = ".decode()", ".decode('utf-8', 'replace')"
    doc = "Decode a message body; raises DeserializationError on truncated, oversized or trailing input."
    out = variant("deserialize", strict, "_decode_at", doc, lenient)
    if lenient:
        out.append("")
        out += variant("_deserialize_lenient", replace, "_decode_at_lenient", "Decode, replacing invalid UTF-8.", False)
    if not w.inline_spec(spec):
        out += decode_at_source(spec, w, lenient)
    return out


def decode_at_source(spec: MsgSpec, w: Writer, lenient: bool) -> list[str]:
    """``_decode_at(b, o, n) -> (message, end)`` (and ``_decode_at_lenient``) for a type too big to inline,
    which the types holding it call: it reads one message at offset ``o`` of ``b`` (``n`` bytes), with the
    same bounds checks as ``deserialize``; errors propagate to the caller's ``deserialize``, which handles
    them as its own (truncation, invalid UTF-8, a memoryview)."""
    dec = Decoder(w, "o")
    start = len(w.lines)
    args = dec.fields(spec, 2, "")
    dec.flush(2)
    body = w.lines[start:]
    del w.lines[start:]
    name = class_name(spec)

    def method(label: str, decode: str, at: str) -> list[str]:
        return [
            "",
            "    @staticmethod",
            f"    def {label}(b: _Any, o: int, n: int) -> tuple[{name!r}, int]:",
            '        """One message at offset o of b (n bytes): (message, end offset); for the types holding it."""',
            *(line.replace(DECODE, decode).replace(DECODE_AT, at) for line in body),
            f"        return {name}({', '.join(args)}), {dec.off()}",
        ]

    out = method("_decode_at", ".decode()", "_decode_at")
    if lenient:
        out += method("_decode_at_lenient", ".decode('utf-8', 'replace')", "_decode_at_lenient")
    else:
        out += ["", "    _decode_at_lenient = _decode_at"]
    return out


def view_decoder_source(spec: MsgSpec, w: Writer, func: str) -> list[str]:
    """A module-level ``func(data, cls, views)``: ``deserialize`` for a read-only memoryview of memory that
    does not change while the message lives (a leased shared-memory slot).

    The same flattened, bounds-checked reads as ``deserialize``, with three differences: uint8[]/char[] and
    numeric arrays of at least ``ZERO_COPY_MIN`` bytes are views of ``data`` (each appended to ``views``,
    which the lease releases), strings are decoded from the view (invalid UTF-8 replaced, as genpy does),
    and the message is built as ``cls`` (a subclass of the type's class that carries the lease).
    """
    dec = Decoder(w, views=True)
    start = len(w.lines)
    args = dec.fields(spec, 2, "")
    dec.flush(2)
    body = w.lines[start:]
    del w.lines[start:]
    end = dec.off()
    return [
        f"def {func}(data, cls, views):",
        "    b = data",
        "    n = len(b)",
        "    try:",
        *(body or ["        pass"]),
        "    except _struct_error as exc:",
        f"        raise _truncated_message({spec.full_name!r}, n, exc) from None",
        f"    if {end} != n:",
        f"        raise _trailing({spec.full_name!r}, {end}, n)",
        f"    return cls({', '.join(args)})",
    ]
