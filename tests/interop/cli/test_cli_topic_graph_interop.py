"""`mros topic list/info/type` against real rosmaster and rospy nodes print what rostopic prints."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from tests.interop.cli.cliutil import mros, ros_tool
from tests.rosenv import Processes, needs_ros, ros_env

pytestmark = [needs_ros, pytest.mark.interop]

GRAPH = """
import rospy
from std_msgs.msg import String
from geometry_msgs.msg import PoseStamped
rospy.init_node("graph")
a = rospy.Publisher("/chatter", String, queue_size=10)
b = rospy.Publisher("/robot/pose", PoseStamped, queue_size=10)
c = rospy.Subscriber("/chatter", String, lambda m: None)
d = rospy.Subscriber("/robot/cmd", String, lambda m: None)
print("up", flush=True)
rospy.spin()
"""


def test_topic_list_info_and_type_match_rostopic(procs: Processes, rosmaster: str, tmp_path: Path) -> None:
    node = procs.python(GRAPH, ros_env(rosmaster, tmp_path))
    assert node.stdout is not None
    assert node.stdout.readline().strip() == b"up"
    cases = [
        ["list"],
        ["list", "-v"],
        ["list", "-p"],
        ["list", "-s"],
        ["list", "/robot"],
        ["info", "/chatter"],
        ["info", "/robot/cmd"],
        ["type", "/chatter"],
        ["type", "/robot/pose"],
        ["type", "/robot/pose/pose"],
        ["type", "/robot/pose/header/stamp"],
    ]
    with ThreadPoolExecutor(max_workers=4) as pool:
        ours = list(pool.map(lambda argv: mros(rosmaster, tmp_path, "topic", *argv), cases))
        theirs = list(pool.map(lambda argv: ros_tool(rosmaster, tmp_path, "rostopic", *argv), cases))
    for argv, o, t in zip(cases, ours, theirs, strict=True):
        assert o.stdout == t.stdout, argv
        assert o.returncode == t.returncode == 0, argv


def test_unknown_topics_fail_with_exit_code_1(rosmaster: str, tmp_path: Path) -> None:
    ours = mros(rosmaster, tmp_path, "topic", "type", "/nothing")
    theirs = ros_tool(rosmaster, tmp_path, "rostopic", "type", "/nothing")
    assert ours.returncode == theirs.returncode == 1
    assert ours.stderr == theirs.stderr == "unknown topic type [/nothing]\n"
    info = mros(rosmaster, tmp_path, "topic", "info", "/nothing")
    assert info.returncode == 1
    assert info.stderr == "ERROR: Unknown topic /nothing\n"
