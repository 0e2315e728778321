"""The ``serialize`` (and ``serialize_parts``) emitter: runs of fixed fields become one pack call."""

from __future__ import annotations

from mrosd.msg.codegen.sizes import BYTE_TYPES, TIME_FORMATS, Lookup, attribute_name, symbol
from mrosd.msg.codegen.writer import Writer
from mrosd.msg.spec import PRIMITIVE_FORMATS, Field, MsgSpec


class Encoder:
    """Emits the body of ``serialize``: a pending run of (format, expression) flushed into one pack call.

    Until the first loop the parts are kept as expressions and joined once at the end (no list, no
    appends); a loop switches to appending to ``_p``.
    """

    def __init__(self, w: Writer, parts: list[str] | None = None) -> None:
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
            elif base in TIME_FORMATS:
                t = w.tmp("t")
                w.emit(indent, f"{t} = {acc}")
                c = TIME_FORMATS[base]
                self.run += [(c, f"{t}.secs"), (c, f"{t}.nsecs")]
            else:
                v = w.tmp("m")
                w.emit(indent, f"{v} = {acc}")
                if w.inline(base):
                    self.fields(w.lookup(base), v, indent, path + ".")
                else:
                    self.call(base, v, indent)
            return
        a = w.tmp("a")
        w.emit(indent, f"{a} = {acc}")
        n = f.length
        if n is not None:
            w.emit(indent, f"if len({a}) != {n}:")
            w.emit(indent + 1, f"raise _bad_length({w.type_name!r}, {path!r}, {n}, len({a}))")
        if base in BYTE_TYPES:
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
        inner = Encoder(w)
        inner.one(Field(name=f.name, type=base, base=base, line=f.line), item, indent + 1, path + "[]")
        inner.flush(indent + 1)
        if not inner.appended:
            w.emit(indent + 1, "pass")

    def call(self, base: str, v: str, indent: int) -> None:
        """Encode the nested message ``v`` by calling its class's encoder (a type too big to inline). Like the
        inlined code it needs only the fields' attributes, so any object with them encodes the same."""
        self.flush(indent)
        if has_blobs(self.w.lookup(base), self.w.lookup):  # keep its payload uncopied in serialize_parts()
            self.to_append_mode(indent)
            self.w.emit(indent, f"_p.extend({symbol(base)}.serialize_parts({v}))")
            self.appended = True
        else:
            self.add(indent, f"{symbol(base)}.serialize({v})")


def has_blobs(spec: MsgSpec, lookup: Lookup) -> bool:
    """Whether a variable-length uint8[]/char[] (a payload that may be megabytes) is anywhere in ``spec``."""
    return any(
        (f.base in BYTE_TYPES and f.is_array and f.length is None)
        or (not f.is_builtin and has_blobs(lookup(f.base), lookup))
        for f in spec.fields
    )


def serialize_source(spec: MsgSpec, w: Writer) -> list[str]:
    parts: list[str] = []
    enc = Encoder(w, parts)
    start = len(w.lines)
    enc.fields(spec, "self", 3, "")
    enc.flush(3)
    body = w.lines[start:]
    del w.lines[start:]
    failed = [
        "        except (_struct_error, TypeError, ValueError, AttributeError, OverflowError) as exc:",
        f"            raise _serialize_failed({spec.full_name!r}, exc) from None",
    ]
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
    out += failed
    if has_blobs(spec, w.lookup):
        # The same encoder without the final join: a large uint8[] stays the very object the message holds
        # (a view into a received frame, or bytes), so a publisher can write it without copying it.
        out += [
            "",
            "    def serialize_parts(self) -> _Sequence[_Any]:",
            '        """``serialize()`` as the pieces whose concatenation it is (large payloads not copied)."""',
            "        try:",
            *body,
            "            return _p" if enc.parts is None else f"            return ({', '.join(parts)},)",
            *failed,
        ]
    return out
