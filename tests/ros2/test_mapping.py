"""ros1_bridge's mapping-rule YAML (renamed packages, messages, fields, services), and ROS 2 types given a ROS 1
form (from a ROS 2 share tree, md5 computed as genmsg does), both through ``TypeMapper``."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from mrosd.msg import load_type
from mrosd.ros2.mapping import MappingRuleError, load_mapping_rules, parse_mapping_rules
from mrosd.ros2.types import TypeMapper, UnmappableTypeError

RULES = """
- ros1_package_name: 'old_msgs'
  ros2_package_name: 'new_msgs'
- ros1_package_name: 'robot'
  ros1_message_name: 'State'
  ros2_package_name: 'robot_interfaces'
  ros2_message_name: 'RobotState'
  fields_1_to_2:
    batteryLevel: 'battery_level'
    mode: 'mode'
- ros1_package_name: 'robot'
  ros1_service_name: 'Reset'
  ros2_package_name: 'robot_interfaces'
  ros2_service_name: 'ResetRobot'
"""


def test_the_documented_rule_kinds_map_both_ways() -> None:
    rules = parse_mapping_rules(RULES, "rules.yaml")
    assert rules.ros2_message("old_msgs/Thing") == "new_msgs/msg/Thing"
    assert rules.ros1_message("new_msgs/msg/Thing") == "old_msgs/Thing"
    assert rules.ros2_message("robot/State") == "robot_interfaces/msg/RobotState"
    assert rules.ros1_message("robot_interfaces/msg/RobotState") == "robot/State"
    assert rules.ros2_message("std_msgs/String") is None
    assert rules.ros2_service("robot/Reset") == "robot_interfaces/srv/ResetRobot"
    assert rules.ros1_service("robot_interfaces/srv/ResetRobot") == "robot/Reset"
    assert rules.ros2_service("old_msgs/Do") == "new_msgs/srv/Do"
    rule = rules.message_rule("robot/State")
    assert rule is not None and rule.field_renames() == {"batteryLevel": "battery_level", "mode": "mode"}


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("- [a, b", "line"),
        ("ros1_package_name: a", "a list of rules"),
        ("- 42", "rule 0: a rule is a mapping"),
        ("- {ros1_package_name: a}", "rule 0: 'ros2_package_name' is missing"),
        ("- {ros1_package_name: a, ros2_package_name: b, colour: red}", "rule 0: unknown key 'colour'"),
        (
            "- {ros1_package_name: a, ros2_package_name: b}\n- {ros1_package_name: a, ros2_package_name: 'b/c'}",
            "rule 1",
        ),
        ("- {ros1_package_name: a, ros2_package_name: b, ros1_message_name: M}", "'ros2_message_name' is missing"),
        (
            "- {ros1_package_name: a, ros2_package_name: b, ros1_message_name: M, ros2_message_name: N,"
            " ros1_service_name: S, ros2_service_name: T}",
            "not both",
        ),
        (
            "- {ros1_package_name: a, ros2_package_name: b, ros1_message_name: M, ros2_message_name: N,"
            " fields_1_to_2: [x]}",
            "fields_1_to_2 is a mapping",
        ),
    ],
)
def test_a_bad_file_or_rule_is_one_line_naming_the_file_and_the_rule(text: str, says: str) -> None:
    with pytest.raises(MappingRuleError) as info:
        parse_mapping_rules(text, "/etc/rules.yaml")
    message = str(info.value)
    assert "/etc/rules.yaml" in message and says in message and "\n" not in message


def test_files_are_read_in_order_and_a_missing_one_is_named(tmp_path: Path) -> None:
    path = tmp_path / "r.yaml"
    path.write_text(RULES)
    assert load_mapping_rules([str(path)]).ros2_message("robot/State") == "robot_interfaces/msg/RobotState"
    with pytest.raises(MappingRuleError, match=r"nope\.yaml"):
        load_mapping_rules([str(tmp_path / "nope.yaml")])


STATE_1 = "float32 batteryLevel\nuint8 mode\n"
STATE_2 = "float32 battery_level\nuint8 mode\n"


def test_a_renamed_type_with_a_renamed_field_hashes_as_the_ros2_package_defines_it() -> None:
    mapper = TypeMapper(parse_mapping_rules(RULES, "rules.yaml"))
    m = mapper.mapping("robot/State", STATE_1)
    assert m.ros2_type == "robot_interfaces/msg/RobotState"
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    twin = get_typestore(Stores.ROS2_JAZZY)
    twin.register(get_types_from_msg(STATE_2, "robot_interfaces/msg/RobotState"))
    assert m.type_hash == twin.hash_rihs01("robot_interfaces/msg/RobotState")
    body = struct.pack("<fB", 0.5, 2)
    assert bytes(mapper.to_ros1(m.ros2_type, mapper.to_cdr(m.ros2_type, body))) == body


def test_without_a_rule_a_field_with_capitals_names_the_field_and_the_rule_to_add() -> None:
    with pytest.raises(UnmappableTypeError, match=r"batteryLevel.*field mapping rule"):
        TypeMapper().mapping("robot/State", STATE_1)


def test_a_field_rule_that_moves_a_field_is_refused_naming_the_rule() -> None:
    rules = parse_mapping_rules(
        "- {ros1_package_name: robot, ros2_package_name: r2, ros1_message_name: S, ros2_message_name: S,"
        " fields_1_to_2: {'header.stamp': stamp}}",
        "move.yaml",
    )
    with pytest.raises(UnmappableTypeError, match=r"move.yaml: rule 0.*header.stamp"):
        TypeMapper(rules).mapping("robot/S", "time stamp\n")


def _share(root: Path) -> Path:
    (root / "fleet_msgs" / "msg").mkdir(parents=True)
    (root / "fleet_msgs" / "msg" / "Waypoint.msg").write_text(
        "# a ROS 2 definition: bounds, defaults, builtin_interfaces\n"
        "uint8 KIND_GOAL=1\nstring<=32 name\nfloat64 x 0.0\nbuiltin_interfaces/Duration wait\n"
    )
    (root / "fleet_msgs" / "msg" / "Route.msg").write_text(
        "std_msgs/Header header\nWaypoint[<=100] points\nint32[3] tags\nbool done\n"
    )
    return root


ROUTE_1 = """std_msgs/Header header
fleet_msgs/Waypoint[] points
int32[3] tags
bool done
================================================================================
MSG: fleet_msgs/Waypoint
uint8 KIND_GOAL=1
string name
float64 x
duration wait
"""


def test_a_ros2_type_from_a_share_tree_gets_a_ros1_form_with_genmsgs_md5(tmp_path: Path) -> None:
    mapper = TypeMapper(ros2_share=[str(_share(tmp_path))])
    back = mapper.ros1_for("fleet_msgs/msg/Route")
    assert back.ros1_type == "fleet_msgs/Route"
    # the md5 of the same type written by hand in ROS 1's syntax (genmsg's rules, through mrosd.msg)
    assert back.md5sum == load_type("fleet_msgs/Route", ROUTE_1)._md5sum
    assert back.definition.startswith("std_msgs/Header header\nfleet_msgs/Waypoint[] points\n")
    header = back.definition.split("MSG: std_msgs/Header\n")[1]  # ROS 1's own Header, as genpy sends it
    assert "\nuint32 seq\n" in header.split("MSG:")[0]
    # ROS 2 bytes -> ROS 1 bytes -> ROS 2 bytes
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ros2 = get_typestore(Stores.ROS2_JAZZY)
    ros2.register(get_types_from_msg((tmp_path / "fleet_msgs/msg/Waypoint.msg").read_text(), "fleet_msgs/msg/Waypoint"))
    ros2.register(get_types_from_msg((tmp_path / "fleet_msgs/msg/Route.msg").read_text(), "fleet_msgs/msg/Route"))
    assert back.mapping.type_hash == ros2.hash_rihs01("fleet_msgs/msg/Route")
    route, wp = ros2.types["fleet_msgs/msg/Route"], ros2.types["fleet_msgs/msg/Waypoint"]
    header = ros2.types["std_msgs/msg/Header"](ros2.types["builtin_interfaces/msg/Time"](3, 4), "map")
    dur = ros2.types["builtin_interfaces/msg/Duration"]
    import numpy as np

    msg = route(header, [wp("a", 1.5, dur(1, 2)), wp("b", 2.5, dur(3, 4))], np.array([1, 2, 3], dtype=np.int32), True)
    cdr = ros2.serialize_cdr(msg, "fleet_msgs/msg/Route")
    ros1 = bytes(mapper.to_ros1("fleet_msgs/msg/Route", cdr))
    decoded = load_type("fleet_msgs/Route", back.definition)().deserialize(ros1)
    assert [p.name for p in decoded.points] == ["a", "b"] and decoded.points[1].wait.secs == 3
    assert decoded.header.frame_id == "map" and decoded.header.seq == 0 and list(decoded.tags) == [1, 2, 3]
    assert bytes(mapper.to_cdr("fleet_msgs/msg/Route", ros1)) == bytes(cdr)


def test_a_ros2_type_nobody_defines_says_where_to_put_its_definition(tmp_path: Path) -> None:
    with pytest.raises(UnmappableTypeError, match=r"fleet_msgs/msg/Nope.*ROS_PACKAGE_PATH.*ros2_share"):
        TypeMapper(ros2_share=[str(tmp_path)]).ros1_for("fleet_msgs/msg/Nope")


def test_a_wstring_field_is_named(tmp_path: Path) -> None:
    (tmp_path / "w_msgs" / "msg").mkdir(parents=True)
    (tmp_path / "w_msgs" / "msg" / "W.msg").write_text("wstring text\n")
    with pytest.raises(UnmappableTypeError, match=r"'text' is a wstring"):
        TypeMapper(ros2_share=[str(tmp_path)]).ros1_for("w_msgs/msg/W")


def test_standard_types_keep_mrosds_ros1_definitions() -> None:
    back = TypeMapper().ros1_for("sensor_msgs/msg/Image")
    from mrosd.msg import get_message_class

    assert back.md5sum == get_message_class("sensor_msgs/Image")._md5sum


def test_a_share_tree_is_read_only_under_its_roots_and_within_bounds(tmp_path: Path) -> None:
    from mrosd.ros2.ros1defs import MAX_MSG_FILE_SIZE, Ros2Share

    share = tmp_path / "share"
    (share / "big_msgs" / "msg").mkdir(parents=True)
    (share / "big_msgs" / "msg" / "Big.msg").write_text("# " + "x" * MAX_MSG_FILE_SIZE + "\nint32 a\n")
    (tmp_path / "secret" / "msg").mkdir(parents=True)
    (tmp_path / "secret" / "msg" / "Key.msg").write_text("int32 a\n")
    assert Ros2Share([str(share)]).find("../secret/msg/Key") is None
    assert Ros2Share([str(share)]).find("..%2Fsecret/msg/Key") is None
    with pytest.raises(UnmappableTypeError, match=r"Big\.msg: over"):
        TypeMapper(ros2_share=[str(share)]).ros1_for("big_msgs/msg/Big")
    # a type that nests itself through a chain of files stops at the bound, with a line
    (share / "loop_msgs" / "msg").mkdir(parents=True)
    for i in range(300):
        (share / "loop_msgs" / "msg" / f"T{i}.msg").write_text(f"T{i + 1} next\n" if i < 299 else "int32 end\n")
    with pytest.raises(UnmappableTypeError, match="nested types"):
        TypeMapper(ros2_share=[str(share)]).ros1_for("loop_msgs/msg/T0")


def test_a_ros2_type_whose_ros1_msg_is_on_ros_package_path_takes_that_definition(tmp_path: Path) -> None:
    import os
    import subprocess
    import sys

    pkg = tmp_path / "ws" / "rpp_msgs"
    (pkg / "msg").mkdir(parents=True)
    (pkg / "package.xml").write_text("<package><name>rpp_msgs</name></package>\n")
    (pkg / "msg" / "Pose2.msg").write_text("# a ROS 1 comment\nfloat64 x\nfloat64 y\nchar flag\n")
    code = (
        "from mrosd.ros2.types import TypeMapper\n"
        "back = TypeMapper().ros1_for('rpp_msgs/msg/Pose2')\n"
        "print(back.ros1_type, back.md5sum, back.mapping.type_hash)\n"
        "print(repr(back.definition))\n"
    )
    env = {**os.environ, "ROS_PACKAGE_PATH": str(tmp_path / "ws")}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr.decode()
    first, definition = done.stdout.decode().splitlines()
    name, md5, type_hash = first.split()
    assert name == "rpp_msgs/Pose2" and md5 == load_type("rpp_msgs/Pose2", "float64 x\nfloat64 y\nchar flag\n")._md5sum
    assert "a ROS 1 comment" in definition  # the file as written, as genpy sends it
    # its ROS 2 twin (char is uint8 in ROS 2) has the same hash
    assert type_hash == TypeMapper().mapping("rpp_msgs/Pose2", "float64 x\nfloat64 y\nchar flag\n").type_hash


def test_a_ros1_definition_that_differs_from_the_share_trees_type_is_refused_not_converted(tmp_path: Path) -> None:
    share = _share(tmp_path)
    mapper = TypeMapper(ros2_share=[str(share)])
    # field-identical to the share tree's Waypoint (bounds and defaults aside): crosses
    same = "uint8 KIND_GOAL=1\nstring name\nfloat64 x\nduration wait\n"
    assert mapper.mapping("fleet_msgs/Waypoint", same).ros2_type == "fleet_msgs/msg/Waypoint"
    # x as float32: the bytes would be read with the wrong layout
    other = TypeMapper(ros2_share=[str(share)])
    with pytest.raises(UnmappableTypeError, match=r"fleet_msgs/Waypoint.*share tree.*'x': float32 here, float64"):
        other.mapping("fleet_msgs/Waypoint", "uint8 KIND_GOAL=1\nstring name\nfloat32 x\nduration wait\n")
