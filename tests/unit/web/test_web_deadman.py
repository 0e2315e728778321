"""The dead-man policy (mrosd/web/deadman.py) over an injected clock: who is owed a zero, and what it is."""

from __future__ import annotations

import asyncio
import math
from typing import Any

from mrosd.msg import get_message_class
from mrosd.web.deadman import DeadMan, is_moving, zero_body

Twist = get_message_class("geometry_msgs/Twist")
TwistStamped = get_message_class("geometry_msgs/TwistStamped")
String = get_message_class("std_msgs/String")


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class Pub:
    def __init__(self, topic: str, fail: bool = False) -> None:
        self.topic = topic
        self.sent: list[bytes] = []
        self.fail = fail

    def publish_serialized(self, body: bytes) -> None:
        if self.fail:
            raise RuntimeError("publisher of x is closed")
        self.sent.append(body)


def twist(x: float = 0.0, wz: float = 0.0) -> Any:
    t = Twist()
    t.linear.x, t.angular.z = x, wz
    return t


def test_moving_is_any_non_zero_component_and_nan_is_not_a_stop() -> None:
    assert not is_moving("geometry_msgs/Twist", twist().serialize())
    assert is_moving("geometry_msgs/Twist", twist(wz=-0.1).serialize())
    assert is_moving("geometry_msgs/Twist", twist(x=math.nan).serialize())
    assert not is_moving("geometry_msgs/Twist", b"\x01" * 7)  # not a Twist at all


def test_the_zero_of_a_twist_stamped_keeps_seq_and_frame_and_is_stamped_now() -> None:
    msg = TwistStamped()
    msg.header.seq, msg.header.frame_id = 7, "base_link"
    msg.twist.linear.x = 1.0
    zero = TwistStamped.deserialize(zero_body("geometry_msgs/TwistStamped", msg.serialize(), 5_000_000_123))
    assert (zero.header.seq, zero.header.frame_id) == (7, "base_link")
    assert (zero.header.stamp.secs, zero.header.stamp.nsecs) == (5, 123)
    assert zero.twist.linear.x == 0.0
    assert zero_body("geometry_msgs/Twist", twist(1.0).serialize(), 0) == bytes(48)


def test_only_a_recent_moving_command_is_owed_a_zero_and_only_once() -> None:
    clock = FakeClock()
    dm = DeadMan("test", clock=clock, window=1.0)
    drive, stopped, old, chat = Pub("/cmd_vel"), Pub("/other/cmd_vel"), Pub("/old/cmd_vel"), Pub("/chatter")
    dm.published(old, "geometry_msgs/Twist", twist(1.0).serialize())
    clock.now += 1.5
    dm.published(drive, "geometry_msgs/Twist", twist(0.5).serialize())
    dm.published(stopped, "geometry_msgs/Twist", twist(0.5).serialize())
    dm.published(stopped, "geometry_msgs/Twist", twist().serialize())
    dm.published_message(chat, String(data="hi"))
    clock.now += 0.5
    assert asyncio.run(dm.stop()) == 1
    assert drive.sent == [bytes(48)] and not stopped.sent and not old.sent and not chat.sent
    assert asyncio.run(dm.stop()) == 0


def test_a_closed_publisher_is_logged_not_raised() -> None:
    dm = DeadMan("test", clock=FakeClock())
    dm.published_message(Pub("/cmd_vel", fail=True), twist(1.0))
    assert asyncio.run(dm.stop()) == 0
