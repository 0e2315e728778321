"""The pure rules of mros bag: durations, file names, splitting, remapping arguments and replay timing."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.bag.model import (
    BagError,
    ReplaySchedule,
    SplitPolicy,
    output_stem,
    parse_duration,
    parse_play_args,
    split_path,
)


@pytest.mark.parametrize(
    ("text", "seconds"),
    [("30", 30.0), ("30s", 30.0), ("1.5m", 90.0), ("2h", 7200.0), (" 5m ", 300.0), (".5", 0.5)],
)
def test_durations_use_rosbags_units(text: str, seconds: float) -> None:
    assert parse_duration(text) == seconds


@pytest.mark.parametrize("text", ["", "0", "-3", "5d", "m", "1e3", "five"])
def test_a_bad_duration_is_one_clear_error(text: str) -> None:
    with pytest.raises(BagError, match="positive number of seconds"):
        parse_duration(text)


@given(st.text(max_size=20))
def test_any_duration_text_parses_or_raises_bag_error(text: str) -> None:
    try:
        assert parse_duration(text) > 0
    except BagError:
        pass


def test_output_names_follow_rosbag_record() -> None:
    now = 0.0
    assert output_stem("run1", None, ".bag", now) == "run1"
    assert output_stem("run1.bag", None, ".bag", now) == "run1"
    stamp = output_stem(None, None, ".bag", now)
    assert len(stamp) == len("1970-01-01-00-00-00")
    assert output_stem(None, "logs/robot", ".bag", now) == f"logs/robot_{stamp}"
    assert output_stem(None, "logs/", ".bag", now) == f"logs/{stamp}"
    assert split_path("run1", ".bag", None) == "run1.bag"
    assert split_path("run1", ".bag", 0) == "run1_0.bag"
    assert split_path("run1", ".mcap", 3) == "run1_3.mcap"


def test_a_file_is_full_at_its_size_or_after_its_duration_of_bag_time() -> None:
    policy = SplitPolicy(max_bytes=1000, max_seconds=2.0)
    assert not policy.full(999, 0, 1_999_999_999)
    assert policy.full(1000, 0, 0)
    assert policy.full(0, 0, 2_000_000_000)
    assert not policy.full(0, None, 10**12)  # no message yet: no duration
    assert not SplitPolicy().full(10**12, 0, 10**18)


def test_play_arguments_split_into_bags_and_remappings() -> None:
    files, remaps = parse_play_args(["a.bag", "/scan:=/scan_old", "odom:=odom2", "b.bag", "__name:=player"])
    assert files == ["a.bag", "b.bag"]
    assert remaps == {"/scan": "/scan_old", "/odom": "/odom2"}
    with pytest.raises(BagError, match="FROM:=TO"):
        parse_play_args([":=/x"])


def test_replay_schedule_scales_bag_time_by_the_rate_and_restarts_for_a_loop() -> None:
    sched = ReplaySchedule(bag_start_ns=10_000_000_000, rate=2.0, wall_start=100.0)
    assert sched.due(10_000_000_000) == 100.0
    assert sched.due(12_000_000_000) == 101.0
    assert sched.bag_time(101.0) == 12_000_000_000
    assert sched.bag_time(99.0) == 10_000_000_000  # never before the start
    sched.restart(500.0)
    assert sched.due(11_000_000_000) == 500.5
    with pytest.raises(BagError):
        ReplaySchedule(0, 0.0, 0.0)
