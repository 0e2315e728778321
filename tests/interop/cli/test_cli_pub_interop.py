"""`mros topic pub` is heard by `rostopic echo`, and `rostopic pub` by `mros topic echo`, hz and bw."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.interop.cli.cliutil import mros, mros_process, ros_tool
from tests.rosenv import Processes, iter_lines_until, needs_ros, ros_env

pytestmark = [needs_ros, pytest.mark.interop]


@pytest.mark.parametrize(
    ("msg_type", "args", "expected"),
    [
        ("std_msgs/String", ["data: hello"], ['data: "hello"', "---"]),
        ("std_msgs/String", ["hello"], ['data: "hello"', "---"]),
        ("std_msgs/Int32", ["--", "-5"], ["data: -5", "---"]),
        ("geometry_msgs/Point", ["{x: 1, y: 2.5}"], ["x: 1.0", "y: 2.5", "z: 0.0", "---"]),
        ("geometry_msgs/Point", ["1", "2", "3"], ["x: 1.0", "y: 2.0", "z: 3.0", "---"]),
    ],
)
def test_a_message_published_once_by_mros_is_echoed_by_rostopic(
    procs: Processes, rosmaster: str, msg_type: str, args: list[str], expected: list[str]
) -> None:
    env = ros_env(rosmaster, procs.tmp)
    echo = procs.start(["rostopic", "echo", "-n", "1", "/pubtest"], env)
    pub = mros_process(procs, rosmaster, "topic", "pub", "-1", "/pubtest", msg_type, *args)
    lines = list(iter_lines_until(echo, len(expected), timeout=30))
    assert lines == expected
    assert pub.wait(timeout=30) == 0


def test_a_rate_publication_reaches_a_rospy_subscriber_repeatedly(procs: Processes, rosmaster: str) -> None:
    env = ros_env(rosmaster, procs.tmp)
    echo = procs.start(["rostopic", "echo", "-n", "3", "/rated"], env)
    mros_process(procs, rosmaster, "topic", "pub", "-r", "20", "/rated", "std_msgs/String", "data: tick")
    assert list(iter_lines_until(echo, 6, timeout=30)) == ['data: "tick"', "---"] * 3


def test_mros_echo_hz_and_bw_follow_a_rostopic_publisher(procs: Processes, rosmaster: str) -> None:
    env = ros_env(rosmaster, procs.tmp)
    procs.start(["rostopic", "pub", "-r", "20", "/ticks", "std_msgs/String", "data: tick"], env)
    echo = mros_process(procs, rosmaster, "topic", "echo", "/ticks", "-n", "2")
    assert list(iter_lines_until(echo, 4, timeout=30)) == ['data: "tick"', "---"] * 2
    hz = mros_process(procs, rosmaster, "topic", "hz", "/ticks", "--duration", "2.5")
    lines = list(iter_lines_until(hz, 3, timeout=30))
    assert lines[0] == "subscribed to [/ticks]"
    assert lines[1].startswith("average rate: ")
    assert 10 < float(lines[1].split()[-1]) < 30
    bw = mros_process(procs, rosmaster, "topic", "bw", "/ticks", "--duration", "2.5")
    lines = list(iter_lines_until(bw, 3, timeout=30))
    assert lines[1].startswith("average: ") and lines[1].endswith("B/s")
    assert "mean: 8.00B" in lines[2]


@pytest.mark.parametrize(
    ("msg_type", "yaml_arg", "needle", "args_are"),
    [
        ("geometry_msgs/Twist", "{lnear: {x: 1}}", "lnear", "linear.x linear.y linear.z angular.x angular.y angular.z"),
        ("geometry_msgs/Twist", "{linear: {x: fast}}", "linear.x", None),
        ("std_msgs/UInt8", "{data: 300}", "data", "data"),
        ("std_msgs/String", "{data: [1, 2]}", "data", "data"),
    ],
)
def test_a_wrong_field_is_an_error_naming_it_with_rostopics_hint(
    rosmaster: str, tmp_path: Path, msg_type: str, yaml_arg: str, needle: str, args_are: str | None
) -> None:
    out = mros(rosmaster, tmp_path, "topic", "pub", "-1", "/bad", msg_type, yaml_arg)
    assert out.returncode == 1
    # rostopic pub prints "ERROR: No field name [lnear]\n\nArgs are: [linear.x ... angular.z]"; mros names the
    # field and its type in the first line, then gives the same hint.
    first, blank, hint = out.stderr.splitlines()
    assert first.startswith("ERROR: ") and needle in first
    assert blank == ""
    assert hint == f"Args are: [{args_are or 'linear.x linear.y linear.z angular.x angular.y angular.z'}]"
    if needle == "lnear":  # rostopic checks names only (it publishes 300 in a uint8, a list as a string)
        theirs = ros_tool(rosmaster, tmp_path, "rostopic", "pub", "-1", "/bad", msg_type, yaml_arg)
        assert (theirs.returncode, theirs.stderr.splitlines()[-1]) == (1, hint)


def test_an_unknown_type_is_one_error_line(rosmaster: str, tmp_path: Path) -> None:
    out = mros(rosmaster, tmp_path, "topic", "pub", "-1", "/bad", "no_such_pkg/Nothing", "{}")
    assert out.returncode == 1
    assert out.stderr.startswith("ERROR: ") and "no_such_pkg/Nothing" in out.stderr
    assert len(out.stderr.splitlines()) == 1
