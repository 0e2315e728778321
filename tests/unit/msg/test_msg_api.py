"""The public API of mrosd.msg works with the shipped definitions alone (no ROS needed)."""

from __future__ import annotations

import pytest

from mrosd.errors import DeserializationError, MsgNotFoundError
from mrosd.msg import Duration, Time, get_message_class, get_service_class, load_type

STANDARD = [
    "std_msgs/String",
    "std_msgs/Header",
    "geometry_msgs/PoseStamped",
    "sensor_msgs/Image",
    "sensor_msgs/PointCloud2",
    "rosgraph_msgs/Log",
    "rosgraph_msgs/Clock",
    "nav_msgs/Odometry",
]


@pytest.mark.parametrize("name", STANDARD)
def test_standard_types_resolve_and_round_trip_their_defaults(name: str) -> None:
    cls = get_message_class(name)
    assert cls._type == name
    assert len(cls._md5sum) == 32
    msg = cls()
    assert cls.deserialize(msg.serialize()) == msg
    assert cls.deserialize(memoryview(msg.serialize())) == msg


def test_string_has_the_genmsg_md5_and_definition() -> None:
    cls = get_message_class("std_msgs/String")
    assert cls._md5sum == "992ce8a1687cec8c8bd883ec73ca41d1"
    assert cls._full_text == "string data\n"
    assert cls._fixed_size is None
    assert cls(data="hi").serialize() == b"\x02\x00\x00\x00hi"


def test_header_is_detected_and_fixed_sizes_are_computed() -> None:
    assert get_message_class("geometry_msgs/PoseStamped")._has_header is True
    assert get_message_class("geometry_msgs/Pose")._has_header is False
    assert get_message_class("geometry_msgs/Pose")._fixed_size == 56
    assert get_message_class("rosgraph_msgs/Clock")._fixed_size == 8


def test_service_classes_carry_request_and_response() -> None:
    srv = get_service_class("std_srvs/SetBool")
    assert srv._type == "std_srvs/SetBool"
    assert srv._md5sum == "09fb03525b03e7ea1fd3992bafd87e16"
    req = srv._request_class(data=True)
    assert srv._request_class.deserialize(req.serialize()) == req
    assert srv._response_class(success=True, message="ok").serialize() == b"\x01\x02\x00\x00\x00ok"


def test_unknown_types_raise_msg_not_found() -> None:
    with pytest.raises(MsgNotFoundError, match="nope_msgs/Nothing"):
        get_message_class("nope_msgs/Nothing")
    with pytest.raises(MsgNotFoundError, match="package/Type"):
        get_message_class("not a type")


def test_load_type_builds_a_class_from_a_connection_header_definition() -> None:
    pose = get_message_class("geometry_msgs/PoseStamped")
    dyn = load_type("geometry_msgs/PoseStamped", pose._full_text)
    assert dyn._md5sum == pose._md5sum
    assert load_type("geometry_msgs/PoseStamped", pose._full_text) is dyn
    other = load_type("my_pkg/Coordinate", "float32 x\nfloat32 y\nfloat32 z\ntime time\n")
    msg = other(x=1.0, y=2.0, z=3.0, time=Time(5, 6))
    assert other._fixed_size == 20
    assert other.deserialize(msg.serialize()) == msg


def test_truncated_and_trailing_input_raise_deserialization_error() -> None:
    cls = get_message_class("std_msgs/String")
    with pytest.raises(DeserializationError, match="truncated message: needs 1004 bytes, got 7"):
        cls.deserialize(b"\xe8\x03\x00\x00abc")
    with pytest.raises(DeserializationError, match="trailing"):
        cls.deserialize(b"\x01\x00\x00\x00ab")
    with pytest.raises(DeserializationError, match="truncated"):
        cls.deserialize(b"\x01\x00")


def test_time_and_duration_follow_ros_arithmetic() -> None:
    t = Time.from_sec(1.5)
    assert (t.secs, t.nsecs) == (1, 500_000_000)
    d = Duration.from_sec(-0.25)
    assert (d.secs, d.nsecs) == (-1, 750_000_000)
    assert (t + d).to_nsec() == 1_250_000_000
    assert t - Time(1, 0) == Duration(0, 500_000_000)
    assert Duration(1, 0) * 3 == Duration(3, 0)
    assert Time(1, 0) < Time(1, 1)


def test_load_type_with_an_empty_definition_uses_the_search_path() -> None:
    assert load_type("std_msgs/String", "") is get_message_class("std_msgs/String")


def test_load_type_reuses_the_builtin_class_for_nested_types_with_the_same_md5() -> None:
    text = get_message_class("geometry_msgs/PoseStamped")._full_text.replace("# A Pose", "# another comment")
    dyn = load_type("geometry_msgs/PoseStamped", text)
    assert type(dyn().header) is get_message_class("std_msgs/Header")
    assert dyn._full_text == text


def test_serializing_a_wrong_value_names_the_type_and_the_problem() -> None:
    from mrosd.errors import SerializationError

    with pytest.raises(SerializationError, match="std_msgs/UInt8"):
        get_message_class("std_msgs/UInt8")(data=256).serialize()
    with pytest.raises(SerializationError, match="fixed array of 9 items, got 2"):
        get_message_class("sensor_msgs/CameraInfo")(K=[1.0, 2.0]).serialize()
    with pytest.raises(SerializationError, match="std_msgs/String"):
        get_message_class("std_msgs/String")(data=5).serialize()  # type: ignore[arg-type]


def test_large_uint8_arrays_decode_as_zero_copy_views_of_immutable_input() -> None:
    image = get_message_class("sensor_msgs/Image")
    body = image(data=bytes(range(256)) * 512).serialize()
    big = image.deserialize(body).data
    assert isinstance(big, memoryview) and big.readonly and big == bytes(range(256)) * 512
    assert isinstance(image.deserialize(bytearray(body)).data, bytes)  # mutable input: copied, never aliased
    small = image.deserialize(image(data=b"abc").serialize()).data
    assert small == b"abc" and isinstance(small, bytes)


def test_keyword_field_names_get_an_underscore_as_in_genpy() -> None:
    cls = load_type("kw_msgs/Route", "string from\nstring to\nint32 self\n")
    assert cls.__struct_fields__ == ("from_", "to", "self_")
    msg = cls(from_="a", to="b", self_=3)
    assert cls.deserialize(msg.serialize()) == msg


def test_strings_of_many_sizes_decode_on_both_the_cached_and_the_generic_path() -> None:
    cls = get_message_class("std_msgs/Header")
    for size in range(1100):  # more sizes than the per-class cache of tail structs holds
        msg = cls(seq=size, stamp=Time(size, 1), frame_id="é" * (size // 2) + "x" * (size % 2))
        assert cls.deserialize(msg.serialize()) == msg
    with pytest.raises(DeserializationError, match="trailing"):
        cls.deserialize(cls(frame_id="abc").serialize() + b"z")
    with pytest.raises(DeserializationError):
        cls.deserialize(cls(frame_id="abc").serialize()[:10])
