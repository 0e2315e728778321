"""Property tests for the definition bounds and for nested types generated as calls.

- A definition is refused with ``MsgTooComplexError`` exactly when its expansion is over a bound, computed
  here independently, and a refusal or a load takes well under a second.
- Classes whose nested types are called (``_decode_at``, ``serialize``) encode and decode byte-identically
  to classes with everything inlined, for random nested definitions and random values.
"""

from __future__ import annotations

import itertools
import time
import typing
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mrosd.errors import DeserializationError, MsgTooComplexError
from mrosd.msg import bounds, get_message_class, load_type
from mrosd.msg.codegen import writer
from mrosd.msg.codegen.sizes import attribute_name
from mrosd.msg.parser import parse_definition
from mrosd.msg.spec import MsgSpec
from tests.unit.msg.test_msg_properties import field_strategy

SEP = "=" * 80
_PACKAGES = itertools.count()

BUILTINS = [
    "bool",
    "int8",
    "uint16",
    "int32",
    "uint64",
    "float32",
    "float64",
    "string",
    "time",
    "duration",
    "uint8[]",
    "uint8[3]",
    "float64[]",
    "int16[2]",
    "string[]",
    "time[]",
]


@st.composite
def definitions(draw: st.DrawFn, max_types: int = 5, max_fields: int = 5) -> tuple[str, str]:
    """(top type, message_definition): types T0..Tn, each using builtins and types after it (no cycles)."""
    package = f"prop{next(_PACKAGES)}"
    count = draw(st.integers(1, max_types))
    sections = []
    for i in range(count):
        lines = []
        for j in range(draw(st.integers(1 if i == 0 else 0, max_fields))):  # an empty definition means the files'
            if i + 1 < count and draw(st.booleans()):
                nested = draw(st.integers(i + 1, count - 1))
                lines.append(f"T{nested}{draw(st.sampled_from(['', '', '[]', '[2]']))} f{j}")
            else:
                lines.append(f"{draw(st.sampled_from(BUILTINS))} f{j}")
        head = "" if i == 0 else f"MSG: {package}/T{i}\n"
        sections.append(head + "\n".join(lines))
    return f"{package}/T0", f"\n{SEP}\n".join(sections)


def _load(name: str, text: str, inline_max: int) -> Any:
    saved = writer.INLINE_MAX_FIELDS
    writer.INLINE_MAX_FIELDS = inline_max
    try:
        return load_type(name, text)
    finally:
        writer.INLINE_MAX_FIELDS = saved


def _value(data: st.DataObject, cls: Any, specs: dict[str, MsgSpec]) -> Any:
    kwargs: dict[str, Any] = {}
    hints = typing.get_type_hints(cls)
    for f in specs[cls._type].fields:
        attr = attribute_name(f.name)
        if f.is_builtin:
            kwargs[attr] = data.draw(field_strategy(f, None))  # type: ignore[arg-type]
        elif f.is_array:
            (sub,) = typing.get_args(hints[attr])
            n = f.length if f.length is not None else data.draw(st.integers(0, 2))
            kwargs[attr] = [_value(data, sub, specs) for _ in range(n)]
        else:
            kwargs[attr] = _value(data, hints[attr], specs)
    return cls(**kwargs)


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(definition=definitions(), data=st.data())
def test_called_nested_types_encode_and_decode_byte_identically_to_inlined_ones(
    definition: tuple[str, str], data: st.DataObject
) -> None:
    name, text = definition
    package, _, short = name.partition("/")
    inlined = _load(name, text, 1 << 30)
    # the same definition under another package: its own classes, every nested type called
    called_name = f"{package}c/{short}"
    called = _load(called_name, text.replace(f"MSG: {package}/", f"MSG: {package}c/"), 0)
    assert called._md5sum == inlined._md5sum
    specs = parse_definition(name, text)
    msg = _value(data, inlined, specs)
    body = msg.serialize()
    assert called.serialize(msg) == body  # serialize needs only the fields: the one message, both ways
    back = called.deserialize(body)
    assert back.serialize() == body
    assert inlined.serialize(back) == body
    assert called.deserialize(memoryview(body)).serialize() == body
    if hasattr(inlined, "serialize_parts"):
        assert b"".join(bytes(p) for p in called.serialize_parts(back)) == body
    cut = data.draw(st.integers(0, max(0, len(body) - 1)))
    if cut < len(body):
        for cls in (inlined, called):
            with pytest.raises(DeserializationError):
                cls.deserialize(body[:cut])
    for cls in (inlined, called):
        with pytest.raises(DeserializationError):
            cls.deserialize(body + b"\0")


def test_invalid_utf8_inside_a_called_type_is_replaced_as_when_inlined() -> None:
    text = f"Inner a\nstring tail\n{SEP}\nMSG: utf_a/Inner\nstring s\nint32 x"
    inlined = _load("utf_a/T", text, 1 << 30)
    called = _load("utf_b/T", text.replace("utf_a/", "utf_b/"), 0)
    body = b"\x02\x00\x00\x00\xff\xfe" + b"\x07\x00\x00\x00" + b"\x01\x00\x00\x00\xff"
    assert called.deserialize(body).a.s == inlined.deserialize(body).a.s == "\ufffd\ufffd"
    assert called.deserialize(body).tail == "\ufffd"


def _reference(specs: dict[str, MsgSpec], name: str, memo: dict[str, tuple[int, int]]) -> tuple[int, int]:
    if name not in memo:
        fields, depth = 0, 0
        for f in specs[name].fields:
            fields += 1
            if not f.is_builtin:
                sub_fields, sub_depth = _reference(specs, f.base, memo)
                fields, depth = fields + sub_fields, max(depth, sub_depth)
        memo[name] = (fields, depth + 1)
    return memo[name]


@st.composite
def nests(draw: st.DrawFn) -> tuple[str, str]:
    """Chains of types, each holding ``width`` fields of the next: from harmless to exponential."""
    package = f"nest{next(_PACKAGES)}"
    depth = draw(st.integers(1, bounds.MAX_DEPTH + 3))
    widths = [draw(st.integers(1, 4)) for _ in range(depth)]
    sections = []
    for i, width in enumerate(widths):
        head = "" if i == 0 else f"MSG: {package}/T{i}\n"
        inner = [f"T{i + 1} f{j}" for j in range(width)] if i + 1 < depth else ["float64 v", "string s"]
        sections.append(head + "\n".join(inner))
    return f"{package}/T0", f"\n{SEP}\n".join(sections)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(definition=nests())
def test_a_definition_is_refused_exactly_when_its_expansion_is_over_a_bound(definition: tuple[str, str]) -> None:
    name, text = definition
    fields, depth = _reference(parse_definition(name, text), name, {})
    over = fields > bounds.MAX_FIELDS or depth > bounds.MAX_DEPTH
    start = time.process_time()  # this process's CPU (a loaded machine's other processes took 1.9 s of wall time)
    try:
        cls = load_type(name, text)
    except MsgTooComplexError as exc:
        assert over, (fields, depth, exc)
        assert name in str(exc)
    else:
        assert not over, (fields, depth)
        assert cls.deserialize(cls().serialize()) == cls()
    assert time.process_time() - start < 1.0


def test_every_shipped_type_is_under_the_bounds_with_a_margin() -> None:
    """The bounds come from real types: Debian's largest must pass with a wide margin (docs/messages.md)."""
    from mrosd.msg.typestore import TypeStore

    store = TypeStore()
    measure = bounds.Measure(store.msg_spec)
    names = store.list_types("msg")
    assert len(names) > 100
    worst = max(measure.size(n) for n in names)
    assert worst[0] * 10 <= bounds.MAX_FIELDS
    assert max(measure.size(n)[1] for n in names) * 4 <= bounds.MAX_DEPTH
    assert max(len(store.full_text(n)) for n in names) * 10 <= bounds.MAX_DEFINITION_CHARS
    for n in names:  # and every one of them is fully inlined, as before
        assert measure.fields(n) <= writer.INLINE_MAX_FIELDS
    assert not hasattr(get_message_class("visualization_msgs/InteractiveMarkerUpdate"), "_decode_at")
