"""rostopic echo's text, reproduced: expected strings follow genpy's strify_message rules case by case.

The message classes here are minimal stand-ins with the `mrosd.msg` contract (Struct + `_field_types`), so
the renderer is tested on its own; the interop tests compare against real rostopic output.
"""

from __future__ import annotations

import json
import os
from typing import ClassVar

import msgspec
import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st
from mros_cli.output import JsonRenderer, PlotRenderer, TextRenderer, extract_field, quote_string, uint8_text


class Time(msgspec.Struct):
    secs: int = 0
    nsecs: int = 0


class Duration(msgspec.Struct):
    secs: int = 0
    nsecs: int = 0


class Header(msgspec.Struct):
    _type: ClassVar[str] = "std_msgs/Header"
    _field_types: ClassVar[tuple[str, ...]] = ("uint32", "time", "string")
    seq: int = 0
    stamp: Time = msgspec.field(default_factory=Time)
    frame_id: str = ""


class Point(msgspec.Struct):
    _type: ClassVar[str] = "geometry_msgs/Point"
    _field_types: ClassVar[tuple[str, ...]] = ("float64", "float64", "float64")
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


class Cloud(msgspec.Struct):
    _type: ClassVar[str] = "test/Cloud"
    _field_types: ClassVar[tuple[str, ...]] = (
        "std_msgs/Header",
        "geometry_msgs/Point[]",
        "uint8[]",
        "float32[3]",
        "string[]",
        "bool",
        "duration",
        "int32[]",
    )
    header: Header = msgspec.field(default_factory=Header)
    points: list[Point] = msgspec.field(default_factory=list)
    data: bytes = b""
    gains: list[float] = msgspec.field(default_factory=lambda: [0.0, 0.0, 0.0])
    names: list[str] = msgspec.field(default_factory=list)
    ok: bool = False
    timeout: Duration = msgspec.field(default_factory=Duration)
    ids: list[int] = msgspec.field(default_factory=list)


class Text(msgspec.Struct):
    _type: ClassVar[str] = "std_msgs/String"
    _field_types: ClassVar[tuple[str, ...]] = ("string",)
    data: str = ""


def sample() -> Cloud:
    return Cloud(
        header=Header(seq=7, stamp=Time(12, 5), frame_id="map"),
        points=[Point(1.0, 2.5, -3.0), Point()],
        data=b"\x00\x01\xff",
        gains=[0.5, 1.0, 2.0],
        names=[],
        ok=True,
        timeout=Duration(1, 500000000),
        ids=[3, -4],
    )


EXPECTED = "\n".join(
    [
        "header: ",
        "  seq: 7",
        "  stamp: ",
        "    secs: 12",
        "    nsecs:         5",
        '  frame_id: "map"',
        "points: ",
        "  - ",
        "    x: 1.0",
        "    y: 2.5",
        "    z: -3.0",
        "  - ",
        "    x: 0.0",
        "    y: 0.0",
        "    z: 0.0",
        "data: [0, 1, 255]",
        "gains: [0.5, 1.0, 2.0]",
        "names: []",
        "ok: True",
        "timeout: ",
        "  secs: 1",
        "  nsecs: 500000000",
        "ids: [3, -4]",
    ]
)


def test_a_nested_message_renders_exactly_as_rostopic_echo() -> None:
    assert TextRenderer().render(sample()) == EXPECTED


def test_noarr_replaces_every_array_with_rostopics_placeholder() -> None:
    text = TextRenderer(noarr=True).render(sample())
    assert 'points: "<array type: geometry_msgs/Point, length: 2>"' in text
    assert 'data: "<array type: uint8, length: 3>"' in text
    # rostopic strips trailing '[' and ']' characters only, so fixed sizes keep their opening bracket.
    assert 'gains: "<array type: float32[3, length: 3>"' in text
    assert "ok: True" in text


def test_offset_prints_time_fields_relative_to_now_but_not_durations() -> None:
    renderer = TextRenderer()
    renderer.offset_ns = 13 * 1_000_000_000
    text = renderer.render(sample())
    assert "  stamp: \n    secs: -1\n    nsecs:         5" in text
    assert "timeout: \n  secs: 1\n  nsecs: 500000000" in text


def test_a_field_value_renders_with_its_type_information() -> None:
    renderer = TextRenderer()
    assert renderer.render(b"\x05\x06", "uint8[]") == "[5, 6]"
    assert renderer.render("hi", "string") == '"hi"'
    assert renderer.render(Point(1.0, 2.0, 3.0), "geometry_msgs/Point") == "x: 1.0\ny: 2.0\nz: 3.0"
    assert TextRenderer(noarr=True).render([1, 2], "int32[]") == '"<array type: int32, length: 2>"'


@pytest.mark.parametrize(
    ("value", "expected"),
    [
        ("", "''"),
        ("hello world", '"hello world"'),
        ('say "hi"', yaml.dump('say "hi"', default_style='"').rstrip("\n")),
        ("tab\there", yaml.dump("tab\there", default_style='"').rstrip("\n")),
        ("é", yaml.dump("é", default_style='"').rstrip("\n")),
        ("word " * 30, yaml.dump("word " * 30, default_style='"').rstrip("\n")),
    ],
)
def test_strings_are_quoted_as_pyyaml_double_quoted_style(value: str, expected: str) -> None:
    assert quote_string(value) == expected


@given(st.text(max_size=120))
def test_the_fast_string_quoting_path_agrees_with_pyyaml(value: str) -> None:
    expected = "''" if not value else yaml.dump(value, default_style='"').rstrip("\n")
    assert quote_string(value) == expected


@given(st.binary(max_size=600))
def test_uint8_text_equals_str_of_the_list_of_bytes(data: bytes) -> None:
    assert uint8_text(data) == str(list(data))


def test_uint8_text_handles_a_megabyte() -> None:
    data = os.urandom(1 << 20)
    assert uint8_text(data) == str(list(data))


def test_string_arrays_render_as_a_yaml_block_list() -> None:
    msg = Cloud(names=["a", "b c"])
    assert "names: \n  - a\n  - b c\n" in TextRenderer().render(msg) + "\n"


def test_json_renders_one_compact_object_with_base64_bytes_and_secs_nsecs() -> None:
    line = JsonRenderer().render(sample())
    assert b"\n" not in line
    obj = json.loads(line)
    assert obj["header"]["stamp"] == {"secs": 12, "nsecs": 5}
    assert obj["data"] == "AAH/"
    assert obj["points"][0] == {"x": 1.0, "y": 2.5, "z": -3.0}


def test_extract_field_follows_a_path_with_indexes_and_names_a_bad_field() -> None:
    msg = sample()
    assert extract_field(msg, ["header", "frame_id"]) == "map"
    assert extract_field(msg, ["points[0]", "y"]) == 2.5
    with pytest.raises(KeyError, match="nope"):
        extract_field(msg, ["header", "nope"])
    with pytest.raises(KeyError):
        extract_field(msg, ["points[9]"])


def test_a_string_message_renders_as_a_single_data_line() -> None:
    assert TextRenderer().render(Text("hello")) == 'data: "hello"'
    assert TextRenderer().render(Text("")) == "data: ''"


class Flags(msgspec.Struct):
    _type: ClassVar[str] = "test/Flags"
    _field_types: ClassVar[tuple[str, ...]] = ("bool[]", "float32[]", "char[]", "uint8[2]")
    bits: list[int] = msgspec.field(default_factory=list)
    values: object = None
    chars: bytes = b""
    pair: object = None


def test_bool_arrays_print_as_bools_and_numeric_array_objects_as_lists() -> None:
    from array import array

    msg = Flags(bits=[1, 0], values=array("f", [0.5, 2.0]), chars=b"ab", pair=memoryview(b"\x01\x02"))
    text = TextRenderer().render(msg)
    assert text == "bits: [True, False]\nvalues: [0.5, 2.0]\nchars: b'ab'\npair: [1, 2]"
    assert JsonRenderer().render(msg) == b'{"bits":[1,0],"values":[0.5,2.0],"chars":"YWI=","pair":"AQI="}'


def test_render_bytes_equals_render_encoded_with_big_uint8_arrays_spliced_in() -> None:
    msg = Cloud(header=Header(frame_id="cam"), data=os.urandom(10_000), names=["x"])
    renderer = TextRenderer()
    assert renderer.render_bytes(msg) == renderer.render(msg).encode()
    assert renderer.render_bytes(Text("é")) == TextRenderer().render(Text("é")).encode()


def test_plot_time_column_is_the_record_time_then_the_header_stamp_then_now() -> None:
    from mrosd.msg import get_message_class

    point = get_message_class("geometry_msgs/PointStamped")()
    point.header.stamp.secs, point.header.stamp.nsecs = 3, 4
    plot = PlotRenderer()
    assert plot.row(point, 99).startswith("3000000004,")
    assert plot.row(point, 99, recorded_ns=7).startswith("7,")
    assert plot.row(point.point, 99).startswith("99,")
    assert plot.row(point.point, 99, recorded_ns=7).startswith("7,")
