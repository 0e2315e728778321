"""tf2_web_republisher's rules (``mrosd.tf.republish``), without a network: request checks, thresholds, rate,
the unused timer; and the shipped definitions' md5s, known answers from genmsg."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.errors import RequestRefused
from mrosd.msg import get_message_class, get_service_class
from mrosd.msg.action import generate_action
from mrosd.tf.core import FrameNotFoundError, Pose
from mrosd.tf.republish import (
    MAX_RATE,
    MIN_RATE,
    FramePair,
    Limits,
    Republisher,
    Request,
    Subscription,
    check_request,
    clamp_timeout,
    half_angle,
    topic_name,
)

#: genmsg's md5s (Debian's genmsg 0.6.0 over the package's texts and genaction's output; RepublishTFs also as
#: gennodejs/genlisp wrote it in generated code of the package).
KNOWN_MD5 = {
    "tf2_web_republisher/TFArray": "94810edda583a504dfda3829e70d7eec",
    "tf2_web_republisher/TFSubscriptionAction": "15787ffd6a2492c0022abe990c898794",
    "tf2_web_republisher/TFSubscriptionActionGoal": "ef8da891ba3ba9b13d97bca8154eaeb5",
    "tf2_web_republisher/TFSubscriptionActionFeedback": "de686654be3ef0f8970616dd702bb360",
    "tf2_web_republisher/TFSubscriptionActionResult": "1eb06eeff08fa7ea874431638cb52332",
    "tf2_web_republisher/TFSubscriptionGoal": "b2dae39608227a5c1c4a91ad77023a27",
    "tf2_web_republisher/TFSubscriptionResult": "d41d8cd98f00b204e9800998ecf8427e",
    "tf2_web_republisher/TFSubscriptionFeedback": "94810edda583a504dfda3829e70d7eec",
}
REPUBLISH_TFS_MD5 = "ec8570dea2e6015c309eb6611d1a57d0"
#: the package's action/TFSubscription.action
ACTION_TEXT = """# goal
string[] source_frames
string target_frame
float32 angular_thres
float32 trans_thres
float32 rate
---
# result
---
# feedback
geometry_msgs/TransformStamped[] transforms
"""


@pytest.mark.parametrize(("name", "md5"), sorted(KNOWN_MD5.items()))
def test_shipped_definitions_have_genmsgs_md5(name: str, md5: str) -> None:
    assert get_message_class(name)._md5sum == md5


def test_republish_tfs_has_genmsgs_md5() -> None:
    assert get_service_class("tf2_web_republisher/RepublishTFs")._md5sum == REPUBLISH_TFS_MD5


def test_the_shipped_action_types_are_what_genaction_writes_from_the_action_file() -> None:
    from mrosd.msg.typestore import BUILTIN_DIR

    for name, text in generate_action("tf2_web_republisher/TFSubscription", ACTION_TEXT).items():
        shipped = (BUILTIN_DIR / "tf2_web_republisher" / "msg" / (name.split("/")[1] + ".msg")).read_text()
        assert [line for line in shipped.splitlines() if line.strip()] == [
            line for line in text.splitlines() if line.strip()
        ], name


finite = st.floats(allow_nan=False, allow_infinity=False, min_value=-1e6, max_value=1e6)
unit_quat = st.tuples(finite, finite, finite, finite).filter(lambda q: sum(v * v for v in q) > 1e-6)


def pose(t: tuple[float, float, float], q: tuple[float, float, float, float]) -> Pose:
    return (*t, *q)


@given(rate=st.floats(min_value=1e-300, max_value=1e300))
def test_any_positive_rate_is_clamped_into_the_bounds(rate: float) -> None:
    request = check_request(["a"], "w", 0.1, 0.1, rate)
    assert MIN_RATE <= request.rate <= MAX_RATE


@given(
    rate=st.floats(allow_nan=True, allow_infinity=True),
    angular=st.floats(allow_nan=True, allow_infinity=True),
    trans=st.floats(allow_nan=True, allow_infinity=True),
)
def test_a_request_is_refused_or_every_number_in_it_is_finite_and_sane(
    rate: float, angular: float, trans: float
) -> None:
    try:
        request = check_request(["/a", "b", "a"], "/w", angular, trans, rate)
    except RequestRefused as exc:
        assert str(exc).startswith("tf2_web_republisher: ")
        return
    assert request.source_frames == ("a", "b") and request.target_frame == "w"
    assert math.isfinite(request.period) and request.period > 0
    assert request.angular_thres >= 0 and request.trans_thres >= 0


@given(timeout=st.floats(allow_nan=True, allow_infinity=True))
def test_any_timeout_is_clamped(timeout: float) -> None:
    limits = Limits()
    assert limits.min_topic_timeout <= clamp_timeout(timeout, limits) <= limits.max_topic_timeout


def test_half_angle_is_tfs_quaternion_angle_not_the_shortest_path() -> None:
    identity = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
    negated = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0)  # the same rotation
    quarter = (0.0, 0.0, 0.0, 0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4))  # 90 degrees about z
    assert half_angle(identity, negated) == pytest.approx(math.pi)
    assert half_angle(identity, quarter) == pytest.approx(math.pi / 4)


@given(
    poses=st.lists(st.tuples(st.tuples(finite, finite, finite), unit_quat), min_size=1, max_size=30),
    angular=st.floats(min_value=0, max_value=3),
    trans=st.floats(min_value=0, max_value=100),
)
def test_a_pose_is_sent_exactly_when_it_moved_past_a_threshold_since_the_last_one_sent(
    poses: list[tuple[tuple[float, float, float], tuple[float, float, float, float]]], angular: float, trans: float
) -> None:
    pair = FramePair("a")
    last: Pose | None = None
    for t, q in poses:
        p = pose(t, q)
        expected = (
            last is None
            or angular == 0
            or trans == 0
            or math.dist(last[:3], p[:3]) > trans
            or half_angle(last, p) > angular
        )
        sent = pair.update_needed(p, angular, trans)
        assert sent == expected
        if sent:
            pair.sent = last = p


def test_a_tick_sends_moved_frames_reports_a_broken_one_once_and_its_recovery_once() -> None:
    request = check_request(["arm", "ghost"], "world", 0.1, 0.01, 10.0)
    sub = Subscription(0, request, created=100.0)
    world: dict[str, Pose] = {"arm": (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)}

    def lookup(target: str, source: str) -> Pose:
        if source not in world:
            raise FrameNotFoundError(f'"{source}" passed to lookupTransform argument source_frame does not exist. ')
        return world[source]

    first = sub.tick(lookup, 100.1)
    assert [s for s, _ in first.transforms] == ["arm"] and [s for s, _ in first.broke] == ["ghost"]
    second = sub.tick(lookup, 100.2)
    assert second.transforms == [] and second.broke == []  # nothing moved; the failure is not reported again
    world["arm"] = (0.02, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
    world["ghost"] = (1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
    third = sub.tick(lookup, 100.3)
    assert [s for s, _ in third.transforms] == ["arm", "ghost"] and third.recovered == ["ghost"]


@given(periods_late=st.floats(min_value=0, max_value=50))
def test_ticks_keep_their_period_and_a_late_one_does_not_burst(periods_late: float) -> None:
    sub = Subscription(0, check_request(["a"], "w", 0, 0, 10.0), created=0.0)
    assert sub.next_tick == pytest.approx(0.1)
    now = sub.next_tick + periods_late * 0.1
    sub.tick(lambda _t, _s: (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0), now)
    assert now < sub.next_tick <= now + 0.1 + 1e-9


def test_the_unused_timer_runs_from_creation_stops_with_a_subscriber_and_restarts_without() -> None:
    sub = Subscription(0, check_request(["a"], "w", 0, 0, 1.0), created=0.0, timeout=2.0)
    assert sub.next_wake() == 1.0  # the first tick comes before the timer's end
    assert not sub.observe_subscribers(0, 1.0, 2.0)
    assert not sub.observe_subscribers(1, 1.5, 2.0)  # a subscriber: stopped
    assert not sub.observe_subscribers(0, 3.0, 2.0)  # none again: restarted at 3.0
    assert not sub.observe_subscribers(0, 4.9, 2.0)
    assert sub.observe_subscribers(0, 5.0, 2.0)


def test_ids_count_for_topics_and_goals_together_and_the_caps_refuse() -> None:
    core = Republisher(Limits(max_subscriptions=2, max_total_frames=3))
    two = Request(("a", "b"), "w", 0, 0, 1.0)
    first = core.add(two, 0.0, timeout=2.0)
    with pytest.raises(RequestRefused, match="would pass the bound of 3"):
        core.add(two, 0.0)
    second = core.add(Request(("c",), "w", 0, 0, 1.0), 0.0)
    with pytest.raises(RequestRefused, match="2 subscriptions are held"):
        core.add(Request(("d",), "w", 0, 0, 1.0), 0.0)
    core.remove(first.id)
    assert core.add(Request(("d",), "w", 0, 0, 1.0), 0.0).id == second.id + 1
    assert topic_name("/tf2_web_republisher", 7) == "/tf2_web_republisher/tf_repub_7"
