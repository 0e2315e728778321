"""The type search walks ``ROS_PACKAGE_PATH`` only when it must: with Debian's ``/usr/share`` on it, a walk reads
thousands of directories, and every ``mros`` command that names a standard type paid for it at start-up."""

from __future__ import annotations

from pathlib import Path

from mrosd.msg.typestore import TypeStore


def package(where: Path, name: str, *types: str) -> Path:
    (where / "msg").mkdir(parents=True)
    (where / "package.xml").write_text(f"<package><name>{name}</name></package>")
    for short in types:
        (where / "msg" / f"{short}.msg").write_text("string data\n")
    return where


def test_a_builtin_type_and_a_package_right_under_a_root_are_found_without_a_walk(tmp_path: Path) -> None:
    share = tmp_path / "share"
    direct = package(share / "robot_msgs", "robot_msgs", "Pose")
    package(share / "deep" / "er" / "other_msgs", "other_msgs", "Other")
    store = TypeStore(ros_package_path=str(share), system_dirs=[])
    assert store.find("std_msgs/String", "msg").parent.parent.parent.name == "definitions"
    assert store.find("robot_msgs/Pose", "msg") == direct / "msg" / "Pose.msg"
    assert store.msg_spec("robot_msgs/Pose").full_name == "robot_msgs/Pose"
    assert store._packages is None  # nothing walked ROS_PACKAGE_PATH


def test_a_nested_package_is_still_found_and_the_roots_keep_their_order(tmp_path: Path) -> None:
    ws, share = tmp_path / "ws", tmp_path / "share"
    nested = package(ws / "src" / "group" / "robot_msgs", "robot_msgs", "Pose")
    package(share / "robot_msgs", "robot_msgs", "Pose", "Twist")
    renamed = package(share / "dir_name", "named_msgs", "Thing")
    store = TypeStore(ros_package_path=f"{ws}:{share}", system_dirs=[], builtin=False)
    assert store.find("robot_msgs/Pose", "msg") == nested / "msg" / "Pose.msg"  # the first root wins
    assert store.find("robot_msgs/Twist", "msg") == share / "robot_msgs" / "msg" / "Twist.msg"
    assert store.find("named_msgs/Thing", "msg") == renamed / "msg" / "Thing.msg"  # by package.xml's name
    assert store.package_dirs("robot_msgs", "msg") == [nested / "msg", share / "robot_msgs" / "msg"]


def test_a_directory_that_names_another_package_does_not_stand_for_the_one_asked(tmp_path: Path) -> None:
    share = tmp_path / "share"
    package(share / "robot_msgs", "not_robot_msgs", "Pose")
    real = package(share / "x" / "robot_msgs", "robot_msgs", "Pose")
    store = TypeStore(ros_package_path=str(share), system_dirs=[], builtin=False)
    assert store.find("robot_msgs/Pose", "msg") == real / "msg" / "Pose.msg"
