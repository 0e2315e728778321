"""The fleet's body checker agrees with the generated deserializer on every body, valid or mangled."""

from __future__ import annotations

import struct
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mrosd.errors import MrosError
from mrosd.fleet.check import body_checker
from mrosd.msg import get_message_class

g = get_message_class


def _samples() -> list[tuple[str, Any]]:
    ts = g("geometry_msgs/TransformStamped")
    marker = g("visualization_msgs/Marker")
    point = g("geometry_msgs/Point")
    return [
        ("std_msgs/String", g("std_msgs/String")(data="héllo")),
        ("geometry_msgs/Twist", g("geometry_msgs/Twist")()),
        ("tf2_msgs/TFMessage", g("tf2_msgs/TFMessage")(transforms=[ts(child_frame_id=f"f{i}") for i in range(3)])),
        ("sensor_msgs/Image", g("sensor_msgs/Image")(height=2, width=2, encoding="mono8", step=2, data=bytes(4))),
        ("sensor_msgs/LaserScan", g("sensor_msgs/LaserScan")(ranges=[1.0, 2.0], intensities=[0.5])),
        ("sensor_msgs/JointState", g("sensor_msgs/JointState")(name=["a", "bb", ""], position=[1.0])),
        ("visualization_msgs/MarkerArray", g("visualization_msgs/MarkerArray")(markers=[marker(points=[point()] * 2)])),
        ("sensor_msgs/CameraInfo", g("sensor_msgs/CameraInfo")(distortion_model="plumb_bob", D=[0.1] * 5)),
        ("std_msgs/Empty", g("std_msgs/Empty")()),
    ]


SAMPLES = _samples()


def _decodes(cls: Any, body: bytes) -> bool:
    try:
        cls.deserialize(body)
    except (MrosError, ValueError, struct.error, IndexError, OverflowError, MemoryError):
        return False
    return True


@pytest.mark.parametrize(("name", "msg"), SAMPLES, ids=[n for n, _ in SAMPLES])
def test_valid_bodies_pass(name: str, msg: Any) -> None:
    assert body_checker(g(name)).check(msg.serialize()) is None


@settings(max_examples=400, deadline=None)
@given(
    st.sampled_from(SAMPLES),
    st.sampled_from(["truncate", "append", "overwrite"]),
    st.integers(0, 10_000),
    st.binary(min_size=1, max_size=8),
)
def test_the_checker_and_the_deserializer_agree_on_mangled_bodies(
    sample: tuple[str, Any], how: str, where: int, junk: bytes
) -> None:
    name, msg = sample
    cls = g(name)
    body = msg.serialize()
    at = where % (len(body) + 1)
    if how == "truncate":
        body = body[:at]
    elif how == "append":
        body = body + junk
    else:
        body = body[:at] + junk + body[at + len(junk) :]
    verdict = body_checker(cls).check(body)
    assert (verdict is None) == _decodes(cls, body), (name, body, verdict)


def test_lying_length_prefixes_are_named() -> None:
    check = body_checker(g("std_msgs/String")).check
    assert "past the end" in str(check(struct.pack("<I", 1_000_000) + b"lies"))
    assert "trailing" in str(check(struct.pack("<I", 2) + b"ok" + b"x"))
    huge_array = struct.pack("<I", 0xFFFFFFFF)
    assert "needs more than" in str(body_checker(g("tf2_msgs/TFMessage")).check(huge_array))
