"""The one layout walk: valid serializations always pass, any bytes raise nothing but DeserializationError,
and the walk agrees with the generated deserializer and with the generator's fixed sizes."""

from __future__ import annotations

import struct
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mrosd.errors import DeserializationError, MsgNotFoundError, MsgTooComplexError
from mrosd.msg.codegen import fixed_size
from mrosd.msg.layout import Layout, Layouts, class_layout
from mrosd.msg.loader import default_store
from mrosd.msg.parser import parse_definition
from tests.unit.msg.test_msg_properties import CLASSES, STORE, message

LAYOUTS = {cls._type: class_layout(cls, STORE.msg_spec) for cls in CLASSES}


def _layout(cls: Any) -> Layout:
    return LAYOUTS[cls._type]


def _decodes(cls: Any, body: bytes) -> bool:
    try:
        cls.deserialize(body)
    except DeserializationError:
        return False
    return True


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c._type)
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_every_valid_serialization_passes(cls: Any, data: st.DataObject) -> None:
    body = data.draw(message(cls, STORE)).serialize()
    _layout(cls).check(body)
    _layout(cls).check(memoryview(body))
    _layout(cls).check(bytearray(body))


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c._type)
@settings(max_examples=100, deadline=None)
@given(junk=st.binary(max_size=300))
def test_random_bytes_pass_or_raise_deserialization_error_as_the_deserializer_does(cls: Any, junk: bytes) -> None:
    try:
        _layout(cls).check(junk)
    except DeserializationError:
        assert not _decodes(cls, junk)
    else:
        assert _decodes(cls, junk)


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c._type)
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_lying_lengths_and_cuts_raise_deserialization_error_as_the_deserializer_does(
    cls: Any, data: st.DataObject
) -> None:
    body = bytearray(data.draw(message(cls, STORE)).serialize())
    if len(body) >= 4 and data.draw(st.booleans()):
        at = data.draw(st.integers(0, len(body) - 4))
        lie = data.draw(st.sampled_from([0, 1, 2**32 - 1, 2**31, 10**9, len(body) + 1]))
        body[at : at + 4] = struct.pack("<I", lie)
    else:
        body = body[: data.draw(st.integers(0, len(body)))]
    try:
        _layout(cls).check(bytes(body))
    except DeserializationError:
        assert not _decodes(cls, bytes(body))
    else:
        assert _decodes(cls, bytes(body))


def test_the_generators_fixed_size_is_the_layouts_for_every_type_on_the_search_path() -> None:
    store = default_store()
    layouts = Layouts(store.msg_spec)
    names = store.list_types("msg")
    assert len(names) > 100
    for name in names:
        spec = store.msg_spec(name)
        assert layouts.of(spec).fixed == fixed_size(spec, store.msg_spec), name


def test_a_type_that_contains_itself_is_refused_by_depth_not_recursion() -> None:
    specs = parse_definition("a/Loop", "string s\nLoop[] more\n")
    with pytest.raises(MsgTooComplexError):
        Layouts(specs.__getitem__).of(specs["a/Loop"])


def test_a_type_neither_the_definition_nor_the_fallback_defines_is_named() -> None:
    cls = type("Partial", (), {"_type": "a/Partial", "_full_text": "b/Missing inner\n"})
    with pytest.raises(MsgNotFoundError, match="b/Missing"):
        class_layout(cls)
