"""`mros topic pub` argument rules: rostopic's YAML forms, and errors that name the wrong field."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st
from mros_cli.topic import build_message, parse_pub_args

from mrosd.errors import MrosError
from mrosd.msg import get_message_class


def build(msg_type: str, *args: str) -> object:
    return build_message(get_message_class(msg_type), parse_pub_args(args))


def test_a_dictionary_fills_fields_by_name_and_leaves_the_rest_at_zero() -> None:
    msg = build("geometry_msgs/Twist", "{linear: {x: 0.5}, angular: {z: -1}}")
    assert msg.linear.x == 0.5  # type: ignore[attr-defined]
    assert msg.angular.z == -1.0  # type: ignore[attr-defined]
    assert msg.linear.y == 0.0  # type: ignore[attr-defined]


def test_positional_values_fill_fields_in_order_as_rostopic() -> None:
    assert build("geometry_msgs/Point", "1", "2", "3").y == 2.0  # type: ignore[attr-defined]
    assert build("std_msgs/String", "hello").data == "hello"  # type: ignore[attr-defined]
    assert build("std_msgs/String", "data: hello").data == "hello"  # type: ignore[attr-defined]


def test_now_and_auto_fill_times_and_headers() -> None:
    msg = build("geometry_msgs/PoseStamped", "{header: auto}")
    assert msg.header.stamp.secs > 0  # type: ignore[attr-defined]
    msg = build("std_msgs/Time", "{data: now}")
    assert msg.data.secs > 0  # type: ignore[attr-defined]
    msg = build("std_msgs/Duration", "{data: {secs: 2, nsecs: 5}}")
    assert (msg.data.secs, msg.data.nsecs) == (2, 5)  # type: ignore[attr-defined]


def test_uint8_arrays_take_lists_of_numbers_and_serialize() -> None:
    msg = build("std_msgs/UInt8MultiArray", "{data: [1, 2, 255]}")
    assert bytes(msg.data) == b"\x01\x02\xff"  # type: ignore[attr-defined]
    msg.serialize()  # type: ignore[attr-defined]


@pytest.mark.parametrize(
    ("msg_type", "arg", "needle"),
    [
        ("geometry_msgs/Twist", "{lnear: {x: 1}}", "field lnear: geometry_msgs/Twist has no such field"),
        ("geometry_msgs/Twist", "{linear: {x: fast}}", "field linear.x: expected float64"),
        ("geometry_msgs/Twist", "{linear: {q: 1}}", "field linear.q"),
        ("std_msgs/UInt8", "{data: 300}", "field data: 300 is out of range for uint8"),
        ("std_msgs/Int32", "{data: 1.5}", "field data: expected int32"),
        ("std_msgs/String", "{data: [1, 2]}", "field data: expected string"),
        ("std_msgs/Float64MultiArray", "{data: 3}", "field data: expected a list"),
        ("geometry_msgs/Point", "[1, 2, 3]", "got 1 values for 3 fields"),  # as rostopic: one arg, one field
        ("sensor_msgs/NavSatFix", "{position_covariance: [1]}", "needs exactly 9 items"),
    ],
)
def test_a_wrong_value_is_an_error_naming_the_field(msg_type: str, arg: str, needle: str) -> None:
    with pytest.raises(MrosError) as info:
        build(msg_type, arg)
    assert needle in str(info.value)


def test_invalid_yaml_is_an_error_quoting_the_argument() -> None:
    with pytest.raises(MrosError, match="not valid YAML"):
        parse_pub_args(("{unclosed: [",))


@given(st.dictionaries(st.text(max_size=8), st.one_of(st.integers(), st.text(max_size=8), st.floats()), max_size=4))
def test_arbitrary_dictionaries_either_build_a_message_or_raise_mros_error(value: dict[str, object]) -> None:
    try:
        build_message(get_message_class("geometry_msgs/Twist"), value)
    except MrosError:
        pass
