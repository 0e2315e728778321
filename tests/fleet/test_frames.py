"""tf frames prefixed with the robot's name (pure)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.errors import MrosError
from mrosd.fleet.frames import prefix_tf_frames, prefixed_frame, wants_tf_prefix
from mrosd.msg import get_message_class

TFMessage = get_message_class("tf2_msgs/TFMessage")
TransformStamped = get_message_class("geometry_msgs/TransformStamped")


def test_frames_get_the_robot_name() -> None:
    t = TransformStamped(child_frame_id="base_link")
    t.header.frame_id = "/odom"
    t.transform.translation.x = 1.5
    out = TFMessage.deserialize(prefix_tf_frames(TFMessage(transforms=[t]).serialize(), "robot1"))
    assert out.transforms[0].header.frame_id == "robot1/odom"
    assert out.transforms[0].child_frame_id == "robot1/base_link"
    assert out.transforms[0].transform.translation.x == 1.5


def test_prefixing_is_idempotent_and_leaves_empty_frames() -> None:
    assert prefixed_frame("r1", "r1/odom") == "r1/odom"
    assert prefixed_frame("r1", "") == ""


def test_only_tf_topics_of_the_tf_type() -> None:
    assert wants_tf_prefix("/tf", "tf2_msgs/TFMessage")
    assert wants_tf_prefix("/tf_static", "tf2_msgs/TFMessage")
    assert not wants_tf_prefix("/tf", "std_msgs/String")
    assert not wants_tf_prefix("/odom", "tf2_msgs/TFMessage")


@given(st.binary(max_size=200))
def test_garbage_raises_an_mrosd_error_or_decodes(body: bytes) -> None:
    try:
        prefix_tf_frames(body, "r1")
    except MrosError:
        pass


def test_a_truncated_body_is_refused() -> None:
    t = TransformStamped(child_frame_id="base_link")
    body = TFMessage(transforms=[t]).serialize()
    with pytest.raises(MrosError):
        prefix_tf_frames(body[:-5], "r1")
