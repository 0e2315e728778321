"""The .msg/.srv parser: genmsg's rules for names, constants and comments; errors carry file and line."""

from __future__ import annotations

import pytest

from mrosd.errors import MsgError, MsgParseError
from mrosd.msg.md5 import compute_md5, md5_text
from mrosd.msg.parser import parse_definition, parse_msg, parse_srv
from mrosd.msg.typestore import TypeStore


def test_relative_types_resolve_to_the_package_and_header_to_std_msgs() -> None:
    spec = parse_msg("Header header\nPoint p\nPoint[] ps\nstd_msgs/String s\nuint8[4] q\n", "geometry_msgs/T")
    assert [f.type for f in spec.fields] == [
        "std_msgs/Header",
        "geometry_msgs/Point",
        "geometry_msgs/Point[]",
        "std_msgs/String",
        "uint8[4]",
    ]
    assert spec.has_header
    assert spec.fields[2].is_array and spec.fields[2].length is None
    assert spec.fields[4].length == 4


def test_string_constants_keep_everything_after_the_equals_sign() -> None:
    spec = parse_msg("string A =  hello # world  \nint32 B = 7 # comment\nbool C=True\nfloat64 D=1.50\n", "p/T")
    values = {c.name: (c.value, c.text) for c in spec.constants}
    assert values == {"A": ("hello # world", "hello # world"), "B": (7, "7"), "C": (True, "True"), "D": (1.5, "1.50")}


def test_md5_text_puts_constants_first_and_nested_md5s_in_place_of_types() -> None:
    store = TypeStore()
    spec = parse_msg("geometry_msgs/Point[] pts\nint8 X=1\nfloat64[2] v  # c\n", "p/T")
    point_md5 = store.md5("geometry_msgs/Point")
    assert md5_text(spec, store.msg_spec) == f"int8 X=1\n{point_md5} pts\nfloat64[2] v"
    assert len(compute_md5(spec, store.msg_spec)) == 32


@pytest.mark.parametrize(
    ("text", "line", "reason"),
    [
        ("int32 x\nint32\n", 2, "expected 'type name'"),
        ("int32 x y z\n", 1, "expected 'type name'"),
        ("int32 1x\n", 1, "legal field name"),
        ("in-t32 x\n", 1, "legal field type"),
        ("int32[x] x\n", 1, "invalid array type"),
        ("int32[2][3] x\n", 1, "invalid array type"),
        ("a/b/c x\n", 1, "legal field type"),
        ("\n\nint32 x\nint32 x\n", 4, "duplicate field name 'x'"),
        ("time T=3\n", 1, "not a legal constant type"),
        ("uint8 X=256\n", 1, "out of bounds"),
        ("int32 X=abc\n", 1, "invalid value"),
        ("int32 X=1=2\n", 1, "invalid constant declaration"),
        ("float64[99999999999] x\n", 1, "exceeds"),
    ],
)
def test_malformed_lines_raise_msg_parse_error_with_file_and_line(text: str, line: int, reason: str) -> None:
    with pytest.raises(MsgParseError) as info:
        parse_msg(text, "p/T", file="p/msg/T.msg")
    assert (info.value.file, info.value.line) == ("p/msg/T.msg", line)
    assert reason in str(info.value)
    assert str(info.value).startswith(f"p/msg/T.msg:{line}: ")


def test_service_lines_are_numbered_from_the_top_of_the_file() -> None:
    srv = parse_srv("int32 a\n---\nbool ok\n", "p/S", file="S.srv")
    assert [f.name for f in srv.request.fields] == ["a"]
    with pytest.raises(MsgParseError) as info:
        parse_srv("int32 a\n---\nbool ok\nbad line here x\n", "p/S", file="S.srv")
    assert info.value.line == 4
    assert srv.request.full_name == "p/SRequest"


def test_a_message_definition_splits_into_its_types() -> None:
    text = "Header header\nPoint p\n" + "=" * 80 + "\nMSG: std_msgs/Header\nuint32 seq\ntime stamp\nstring frame_id\n"
    text += "=" * 80 + "\nMSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n"
    specs = parse_definition("geometry_msgs/Foo", text)
    assert list(specs) == ["geometry_msgs/Foo", "std_msgs/Header", "geometry_msgs/Point"]
    assert specs["geometry_msgs/Foo"].fields[1].type == "geometry_msgs/Point"


def test_a_section_without_its_msg_line_is_an_error_with_its_line() -> None:
    with pytest.raises(MsgParseError) as info:
        parse_definition("p/T", "int32 x\n" + "=" * 80 + "\nint32 y\n")
    assert info.value.line == 3


def test_recursive_types_are_rejected_clearly() -> None:
    store = TypeStore()
    store.add(parse_msg("p/B b\n", "p/A"))
    store.add(parse_msg("p/A a\n", "p/B"))
    with pytest.raises(MsgError, match="recursive message type: p/A -> p/B -> p/A"):
        store.md5("p/A")
