"""The pure parts behind the rostopic/rosparam/rosservice/rosmsg look-alikes: delay statistics, --filter, name
resolution, rosparam's pretty print, rosservice's argument names, field-path matching and rosmsg's short-name
search. The interop tests compare the same commands against the real tools."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mros_cli.echo import MessageFilter, split_topic
from mros_cli.msg import find_short, package_order
from mros_cli.output import PlotRenderer
from mros_cli.param import pretty_text
from mros_cli.stats import DelayStats
from mros_cli.values import printable_args

from mrosd.errors import MrosError
from mrosd.msg import Time, get_message_class
from mrosd.msg.typestore import TypeStore
from mrosd.names import script_resolve


def test_delay_ignores_the_first_message_and_prints_rostopics_lines() -> None:
    stats = DelayStats(window=100)
    assert stats.report() is None
    stats.on_message(now=100.0, stamp=99.0)  # starts the clock only, as rostopic
    assert stats.report() is None
    stats.on_message(now=101.0, stamp=100.75)
    stats.on_message(now=102.0, stamp=101.75)
    assert stats.report() == "average delay: 0.250\n\tmin: 0.250s max: 0.250s std dev: 0.00000s window: 3"
    assert stats.report() == "no new messages"


def test_delay_window_keeps_the_last_messages_and_restarts_when_the_clock_goes_back() -> None:
    stats = DelayStats(window=3)
    for i in range(10):
        stats.on_message(now=10.0 + i, stamp=10.0 + i - i / 10)
    assert list(stats.delays) == pytest.approx([0.8, 0.9])
    stats.on_message(now=1.0, stamp=0.5)  # time went backwards: start over
    assert stats.report() is None


def test_filter_sees_m_and_topic_and_a_failing_expression_skips_the_message_with_one_warning(
    capsys: pytest.CaptureFixture[str],
) -> None:
    string = get_message_class("std_msgs/String")
    keep = MessageFilter("'hi' in m.data and topic == '/chatter'", "/chatter")
    assert keep(string(data="oh hi"))
    assert not keep(string(data="bye"))
    broken = MessageFilter("m.nope > 1", "/chatter")
    assert not broken(string(data="x"))
    assert not broken(string(data="y"))
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "AttributeError" in err
    with pytest.raises(MrosError, match="not a Python expression"):
        MessageFilter("m.data ==", "/chatter")


@pytest.mark.parametrize(
    ("name", "namespace", "expected"),
    [
        ("/chatter", "", "/chatter"),
        ("chatter", "", "/chatter"),
        ("chatter", "/robot", "/robot/chatter"),
        ("chatter", "robot/", "/robot/chatter"),
        ("/a//b/", "/x", "/a/b"),
        ("", "/robot", "/robot"),
        ("", "", "/"),
        ("~private", "/robot", "/robot/mros/private"),
        ("odom/pose/points[0]", "/r", "/r/odom/pose/points[0]"),
    ],
)
def test_command_line_names_resolve_against_ros_namespace(name: str, namespace: str, expected: str) -> None:
    assert script_resolve(name, "mros", {"ROS_NAMESPACE": namespace}) == expected


def test_pretty_print_is_rosparams() -> None:
    value = {
        "b": {"z": 1, "a": "one\ntwo"},
        "a": "text",
        "list": [1, 2],
        "f": 1.5,
        "t": True,
    }
    assert pretty_text(value) == ("a: text\nb:\n  a: |\n    one\n    two\n  z: 1\nf: 1.5\nlist: - 1\n- 2\nt: true\n")


def test_service_args_flatten_nested_messages_as_rosservice() -> None:
    pose = get_message_class("geometry_msgs/PoseStamped")
    assert " ".join(printable_args(pose)) == (
        "header.seq header.stamp header.frame_id pose.position.x pose.position.y pose.position.z "
        "pose.orientation.x pose.orientation.y pose.orientation.z pose.orientation.w"
    )
    joints = get_message_class("sensor_msgs/JointState")
    assert printable_args(joints)[-4:] == ["name", "position", "velocity", "effort"]


def test_a_field_path_matches_only_a_topic_whose_known_type_has_the_field() -> None:
    types = {"/chatter": "std_msgs/String", "/pose": "geometry_msgs/PoseStamped", "/odd": "nope_msgs/Unknown"}
    assert split_topic("/chatter", types) == ("/chatter", "std_msgs/String", [])
    assert split_topic("/chatter/data", types) == ("/chatter", "std_msgs/String", ["data"])
    assert split_topic("/chatter/nope", types) is None  # rostopic keeps waiting for it
    assert split_topic("/pose/pose/position/x", types) == ("/pose", types["/pose"], ["pose", "position", "x"])
    assert split_topic("/odd/anything", types) == ("/odd", "nope_msgs/Unknown", ["anything"])  # type not local
    assert split_topic("/nothing", types) is None


def _package(root: Path, name: str, types: list[str]) -> None:
    (root / name / "msg").mkdir(parents=True)
    (root / name / "package.xml").write_text(f"<package><name>{name}</name></package>")
    for type_name in types:
        (root / name / "msg" / f"{type_name}.msg").write_text("int32 x\n")


def test_short_names_are_searched_in_rospack_order(tmp_path: Path) -> None:
    system, first, last = tmp_path / "share", tmp_path / "rpp1", tmp_path / "rpp2"
    _package(system, "sys_msgs", ["Thing"])
    _package(first, "one_msgs", ["Thing", "Other"])
    _package(last / "deeper", "two_msgs", ["Thing"])
    (last / "ignored").mkdir()
    (last / "ignored" / "CATKIN_IGNORE").touch()
    _package(last / "ignored", "hidden_msgs", ["Thing"])
    store = TypeStore(builtin=False, ros_package_path=f"{first}:{last}", system_dirs=[str(system)])
    # rospack crawls the system share first, then ROS_PACKAGE_PATH from its last entry to its first.
    assert package_order(store) == ["sys_msgs", "two_msgs", "one_msgs"]
    assert find_short(store, "Thing", "msg") == ["sys_msgs/Thing", "two_msgs/Thing", "one_msgs/Thing"]
    assert find_short(store, "Other", "msg") == ["one_msgs/Other"]
    assert find_short(store, "Missing", "msg") == []


@settings(deadline=None)  # the first example builds the JointState class
@given(
    positions=st.lists(st.floats(allow_nan=False), max_size=6),
    names=st.lists(st.text(alphabet="abc_", min_size=1, max_size=5), max_size=4),
    secs=st.integers(0, 2**31 - 1),
)
def test_plot_rows_have_one_value_per_heading_column(positions: list[float], names: list[str], secs: int) -> None:
    joints = get_message_class("sensor_msgs/JointState")(name=names, position=positions)
    joints.header.stamp = Time(secs, 5)
    for nostr in (False, True):
        for noarr in (False, True):
            plot = PlotRenderer(nostr=nostr, noarr=noarr)
            heading, row = plot.heading(joints), plot.row(joints, 0)
            assert len(heading.split(",")) == len(row.split(","))
            assert row.startswith(f"{secs * 1_000_000_000 + 5},")
