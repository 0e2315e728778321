"""ROS 1 -> ROS 2 type mapping: standard names, Header.seq, custom types from a definition, refusals."""

from __future__ import annotations

import struct
import time
from typing import Any

import pytest

from mrosd.msg import get_message_class, load_type
from mrosd.ros2.types import TypeMapper, UnmappableTypeError, ros2_type_name

STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"


def test_standard_names_map_by_name() -> None:
    assert ros2_type_name("std_msgs/String") == "std_msgs/msg/String"
    assert ros2_type_name("tf/tfMessage") == "tf2_msgs/msg/TFMessage"
    with pytest.raises(UnmappableTypeError):
        ros2_type_name("String")


def test_std_msgs_string_has_rmw_zenohs_known_hash_and_its_body_becomes_cdr() -> None:
    mapper = TypeMapper()
    m = mapper.mapping("std_msgs/String")
    assert (m.ros2_type, m.type_hash) == ("std_msgs/msg/String", STRING_HASH)
    body = struct.pack("<I", 5) + b"hello"
    cdr = bytes(mapper.to_cdr(m.ros2_type, body))
    assert cdr == b"\x00\x01\x00\x00" + struct.pack("<I", 6) + b"hello\x00"
    assert bytes(mapper.to_ros1(m.ros2_type, cdr)) == body


def test_header_seq_is_dropped_and_time_keeps_its_bytes() -> None:
    mapper = TypeMapper()
    m = mapper.mapping("std_msgs/Header")
    body = struct.pack("<III", 99, 5, 6) + struct.pack("<I", 3) + b"map"
    cdr = bytes(mapper.to_cdr(m.ros2_type, body))
    assert cdr == b"\x00\x01\x00\x00" + struct.pack("<II", 5, 6) + struct.pack("<I", 4) + b"map\x00"


def test_tf_messages_cross_as_tf2_msgs() -> None:
    mapper = TypeMapper()
    assert mapper.mapping("tf/tfMessage").ros2_type == "tf2_msgs/msg/TFMessage"
    assert mapper.mapping("tf/tfMessage").type_hash == mapper.mapping("tf2_msgs/TFMessage").type_hash


CUSTOM = """Header header
Point[] pts
time t
char c
byte b
================================================================================
MSG: std_msgs/Header
uint32 seq
time stamp
string frame_id
================================================================================
MSG: my_pkg/Point
float64 x
uint8 FOO=3
string[] names
"""


def test_a_custom_type_with_an_array_of_a_nested_custom_type_is_derived_and_hashed_as_its_ros2_twin() -> None:
    mapper = TypeMapper()
    m = mapper.mapping("my_pkg/Cloud", CUSTOM)
    assert m.ros2_type == "my_pkg/msg/Cloud" and m.type_hash.startswith("RIHS01_")
    # the same type written as a ROS 2 package would write it
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    twin = get_typestore(Stores.ROS2_JAZZY)
    twin.register(get_types_from_msg("float64 x\nuint8 FOO=3\nstring[] names\n", "my_pkg/msg/Point"))
    twin.register(
        get_types_from_msg(
            "std_msgs/Header header\nPoint[] pts\nbuiltin_interfaces/Time t\nuint8 c\nint8 b\n", "my_pkg/msg/Cloud"
        )
    )
    assert twin.hash_rihs01("my_pkg/msg/Cloud") == m.type_hash
    cls = load_type("my_pkg/Cloud", CUSTOM)
    msg = cls()
    msg.header.seq, msg.header.frame_id = 4, "f"
    pt = load_type("my_pkg/Point", CUSTOM.split("MSG: my_pkg/Point\n")[1])()
    pt.x, pt.names = 1.5, ["a", "bc"]
    msg.pts = [pt, pt]
    msg.c, msg.b = 200, -3
    cdr = mapper.to_cdr(m.ros2_type, msg.serialize())
    back: Any = twin.deserialize_cdr(bytes(cdr), "my_pkg/msg/Cloud")
    assert back.header.frame_id == "f" and [p.names for p in back.pts] == [["a", "bc"]] * 2
    assert (back.c, back.b) == (200, -3)


def test_a_field_ros2_cannot_name_is_refused_in_one_line_naming_it() -> None:
    mapper = TypeMapper()
    with pytest.raises(UnmappableTypeError) as err:
        mapper.mapping("my_pkg/Bad", "float64 X\n")
    text = str(err.value)
    assert "\n" not in text and "'X'" in text and "my_pkg/Bad" in text


def test_an_unknown_type_without_a_definition_is_refused() -> None:
    with pytest.raises(UnmappableTypeError, match="no message_definition"):
        TypeMapper().mapping("nowhere_msgs/Thing")


def test_a_1080p_rgb8_image_converts_intact(capsys: pytest.CaptureFixture[str]) -> None:
    img = get_message_class("sensor_msgs/Image")()
    img.height, img.width, img.encoding, img.step = 1080, 1920, "rgb8", 5760
    img.data = bytes(range(256)) * (1920 * 1080 * 3 // 256)
    body = img.serialize()
    mapper = TypeMapper()
    m = mapper.mapping("sensor_msgs/Image")
    mapper.to_cdr(m.ros2_type, body)  # the converter is compiled on first use
    start = time.perf_counter()
    for _ in range(5):
        cdr = mapper.to_cdr(m.ros2_type, body)
    per = (time.perf_counter() - start) / 5
    assert bytes(cdr[-len(img.data) :]) == img.data
    with capsys.disabled():
        print(f"\n1080p rgb8 ROS 1 -> CDR: {per * 1e3:.2f} ms")


def test_ros2_names_map_back_to_ros1_names() -> None:
    from mrosd.ros2.inbound import ros1_type_name

    assert ros1_type_name("std_msgs/msg/String") == "std_msgs/String"
    assert ros1_type_name("tf2_msgs/msg/TFMessage") == "tf2_msgs/TFMessage"
    with pytest.raises(ValueError):
        ros1_type_name("std_srvs/srv/Trigger")


def test_a_big_array_is_copied_once_not_sliced_into_a_temporary_copy_first() -> None:
    """rosbags' converter slices its input: a ``bytes`` input makes each slice a copy (a 6 MB temporary per
    image, ~30x slower), a memoryview does not. Measured as the peak allocation of one conversion."""
    import tracemalloc

    img = get_message_class("sensor_msgs/Image")()
    img.height, img.width, img.encoding, img.step = 1080, 1920, "rgb8", 5760
    img.data = bytes(1920 * 1080 * 3)
    body = img.serialize()
    mapper = TypeMapper()
    ros2_type = mapper.mapping("sensor_msgs/Image").ros2_type
    mapper.to_cdr(ros2_type, body)  # compile the converter first
    tracemalloc.start()
    try:
        cdr = mapper.to_cdr(ros2_type, body)
        _now, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(cdr) >= len(img.data)
    assert peak < 1.25 * len(body), f"peak {peak} for a {len(body)}-byte body: the input was copied"


def test_a_cdr_body_claiming_a_huge_array_is_one_error_without_the_memory_it_claims() -> None:
    import tracemalloc

    from mrosd.errors import MsgError

    mapper = TypeMapper()
    ros2_type = mapper.mapping("std_msgs/String").ros2_type
    cdr = b"\x00\x01\x00\x00" + struct.pack("<I", 0x7FFFFFF0) + b"abc"
    tracemalloc.start()
    try:
        with pytest.raises(MsgError):
            mapper.to_ros1(ros2_type, cdr)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1 << 24
