"""RIHS01 hashes cross-checked with ros2-pyterfaces, an implementation we did not write."""

from __future__ import annotations

from typing import Any

import pytest

from mrosd.ros2.types import TypeMapper

core: Any = pytest.importorskip("ros2_pyterfaces.core")

TIME = {"__typename": "builtin_interfaces/msg/Time", "sec": "int32", "nanosec": "uint32"}
HEADER = {"__typename": "std_msgs/msg/Header", "stamp": TIME, "frame_id": "string"}
STRING = {"__typename": "std_msgs/msg/String", "data": "string"}
IMAGE = {
    "__typename": "sensor_msgs/msg/Image",
    "header": HEADER,
    "height": "uint32",
    "width": "uint32",
    "encoding": "string",
    "is_bigendian": "uint8",
    "step": "uint32",
    "data": core.Sequence("uint8"),
}
POINT = {"__typename": "my_pkg/msg/Point", "x": "float64", "names": core.Sequence("string")}
CLOUD = {
    "__typename": "my_pkg/msg/Cloud",
    "header": HEADER,
    "pts": core.Sequence(POINT),
    "t": TIME,
    "c": "uint8",
    "b": "int8",
}
CLOUD_ROS1 = """Header header
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
string[] names
"""


@pytest.mark.parametrize(("ros1_type", "schema"), [("std_msgs/String", STRING), ("sensor_msgs/Image", IMAGE)])
def test_standard_types_hash_as_ros2_pyterfaces_hashes_them(ros1_type: str, schema: dict[str, Any]) -> None:
    assert TypeMapper().mapping(ros1_type).type_hash == core.hash_rihs01(schema)


def test_a_custom_ros1_type_derived_from_its_definition_hashes_as_its_ros2_twin_in_ros2_pyterfaces() -> None:
    assert TypeMapper().mapping("my_pkg/Cloud", CLOUD_ROS1).type_hash == core.hash_rihs01(CLOUD)
