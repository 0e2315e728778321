"""Type specs: capacities, codecs for every primitive, arrays, strings and ROS messages."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.errors import IxmError
from mrosd.ixm.types import PRIMITIVES, codec, resolve_type


@pytest.mark.parametrize(
    ("name", "size"),
    [
        ("bool", 1),
        ("int8", 1),
        ("uint8", 1),
        ("int16", 2),
        ("uint16", 2),
        ("int32", 4),
        ("uint32", 4),
        ("int64", 8),
        ("uint64", 8),
        ("float32", 4),
        ("float64", 8),
        ("char", 1),
        ("byte", 1),
        ("time", 8),
        ("duration", 8),
    ],
)
def test_every_fixed_primitive_gets_exactly_its_size(name: str, size: int) -> None:
    assert resolve_type(name).capacity == size
    assert resolve_type(name, count=3).capacity == 3 * size


def test_every_primitive_is_known() -> None:
    assert len(PRIMITIVES) == 16


def test_a_string_needs_max_size() -> None:
    with pytest.raises(IxmError, match="max_size"):
        resolve_type("string")
    assert resolve_type("string", max_size=10).capacity == 10


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (("nope",), "unknown type"),
        (("float64", 0), "positive"),
        (("float64", 2, 16), "not both"),
        (("float64", None, 12), "multiple"),
        (("float64", 1 << 28), "limit"),
    ],
)
def test_bad_specs_are_refused_with_a_reason(args: tuple, match: str) -> None:  # type: ignore[type-arg]
    with pytest.raises(IxmError, match=match):
        resolve_type(*args)


def test_a_fixed_size_message_gets_exactly_its_serialized_size() -> None:
    t = resolve_type("std_msgs/Float64")
    assert (t.capacity, t.is_message) == (8, True)
    assert resolve_type("geometry_msgs/Pose").capacity == 56


def test_a_variable_size_message_needs_max_size() -> None:
    with pytest.raises(IxmError, match="variable size"):
        resolve_type("std_msgs/String")
    assert resolve_type("std_msgs/String", max_size=100).capacity == 100


def test_an_unknown_message_is_a_clear_error() -> None:
    with pytest.raises(IxmError, match="unknown message type"):
        resolve_type("nope_msgs/Nope")


@given(st.floats(allow_nan=False))
def test_float64_round_trips(x: float) -> None:
    enc, dec = codec(resolve_type("float64"))
    assert dec(bytes(enc(x))) == x


@given(st.lists(st.integers(-(2**31), 2**31 - 1), min_size=4, max_size=4))
def test_fixed_int32_arrays_round_trip(xs: list[int]) -> None:
    enc, dec = codec(resolve_type("int32", count=4))
    assert dec(bytes(enc(xs))) == xs


def test_array_length_and_range_errors_are_clear() -> None:
    enc, _ = codec(resolve_type("int8", count=2))
    with pytest.raises(IxmError, match="exactly 2"):
        enc([1, 2, 3])
    with pytest.raises(IxmError, match="valid int8"):
        enc([1, 1000])
    enc1, _ = codec(resolve_type("float64"))
    with pytest.raises(IxmError, match="not a valid float64"):
        enc1("x")


def test_bytes_strings_time_and_messages_round_trip() -> None:
    enc, dec = codec(resolve_type("uint8", max_size=16))
    assert dec(bytes(enc(b"\x01\x02"))) == b"\x01\x02"
    enc, dec = codec(resolve_type("string", max_size=16))
    assert dec(bytes(enc("héllo"))) == "héllo"
    enc, dec = codec(resolve_type("time"))
    assert dec(bytes(enc((3, 4)))) == (3, 4)
    enc, dec = codec(resolve_type("bool", count=2))
    assert dec(bytes(enc([True, False]))) == [True, False]
    from mrosd.msg import get_message_class

    Pose = get_message_class("geometry_msgs/Pose")
    enc, dec = codec(resolve_type("geometry_msgs/Pose"))
    pose = Pose()
    pose.orientation.w = 1.0
    assert dec(bytes(enc(pose))).orientation.w == 1.0
    with pytest.raises(IxmError, match="holds geometry_msgs/Pose"):
        enc(1.0)
    enc, dec = codec(resolve_type("float32"))
    assert math.isclose(dec(bytes(enc(0.5))), 0.5)
