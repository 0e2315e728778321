"""`mros bag info` lays a summary out exactly as Debian's `rosbag info` does (text captured from rosbag 1.15)."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

from mrosd.bag.info import BagSummary, ChunkSummary, TopicSummary, duration_text, format_info, human_size


@pytest.fixture
def utc(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.setenv("TZ", "UTC")
    time.tzset()
    yield
    monkeypatch.undo()
    time.tzset()


# `rosbag info real.bag` for a 2.5 s recording of /chatter (127 String) and a latched /lat (1 Int32), TZ=UTC.
ROSBAG_TEXT = """\
path:        real.bag
version:     2.0
duration:    2.5s
start:       Nov 23 2026 12:57:31.06 (1795438651.06)
end:         Nov 23 2026 12:57:33.59 (1795438653.59)
size:        13.1 KB
messages:    128
compression: none [1/1 chunks]
types:       std_msgs/Int32  [da5909fbe378aeaf85e547e830cc1bb7]
             std_msgs/String [992ce8a1687cec8c8bd883ec73ca41d1]
topics:      /chatter   127 msgs    : std_msgs/String
             /lat         1 msg     : std_msgs/Int32"""


def test_the_layout_matches_rosbag_info_byte_for_byte(utc: None) -> None:
    summary = BagSummary(
        path="real.bag",
        version="2.0",
        size=13414,
        start_ns=1795438651_060000000,
        end_ns=1795438653_590000000,
        messages=128,
        chunks=[ChunkSummary("none", 13000, 13000)],
        types={
            "std_msgs/String": "992ce8a1687cec8c8bd883ec73ca41d1",
            "std_msgs/Int32": "da5909fbe378aeaf85e547e830cc1bb7",
        },
        topics=[TopicSummary("/lat", "std_msgs/Int32", 1), TopicSummary("/chatter", "std_msgs/String", 127)],
    )
    assert format_info(summary) == ROSBAG_TEXT


def test_compressed_bags_show_ratios_and_several_connections_are_counted(utc: None) -> None:
    summary = BagSummary(
        path="c.bag",
        version="2.0",
        size=2048,
        start_ns=0,
        end_ns=10_000_000_000,
        messages=3,
        chunks=[ChunkSummary("bz2", 4096, 1024), ChunkSummary("bz2", 4096, 1024)],
        types={"std_msgs/String": "992ce8a1687cec8c8bd883ec73ca41d1"},
        topics=[TopicSummary("/a", "std_msgs/String", 3, connections=2)],
    )
    lines = format_info(summary).splitlines()
    assert "compression:  bz2 [2/2 chunks; 25.00%]" in lines
    assert "uncompressed: 8.0 KB @ 0.8 KB/s" in lines
    assert "compressed:   2.0 KB @ 0.2 KB/s (25.00%)" in lines
    assert lines[-1] == "topics:       /a   3 msgs    : std_msgs/String (2 connections)"


def test_an_empty_bag_shows_only_path_version_and_size() -> None:
    summary = BagSummary("e.bag", "2.0", 4117, None, None, 0, [], {}, [])
    assert format_info(summary) == "path:    e.bag\nversion: 2.0\nsize:    4.0 KB"


@pytest.mark.parametrize(("seconds", "text"), [(2.46, "2.5s"), (65.0, "1:05s (65s)"), (3605.0, "1hr 0:05s (3605s)")])
def test_durations_print_as_rosbag_prints_them(seconds: float, text: str) -> None:
    assert duration_text(seconds) == text


def test_sizes_use_binary_units_from_kilobytes() -> None:
    assert human_size(100) == "0.1 KB"
    assert human_size(13414) == "13.1 KB"
    assert human_size(3 * 1024**3) == "3.0 GB"
