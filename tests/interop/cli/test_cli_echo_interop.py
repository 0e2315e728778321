"""`mros topic echo` prints byte-for-byte what `rostopic echo` prints, for a corpus of latched messages.

A rospy node latches one message on each topic; both tools echo it with the same options and the outputs
are compared exactly. mros decodes every type from the publisher's message_definition.
"""

from __future__ import annotations

import importlib
import json
import subprocess
from pathlib import Path

import pytest

from tests.interop.cli.cliutil import mros, ros_tool
from tests.rosenv import Processes, needs_ros, ros_env


def _node_available() -> bool:
    try:
        return hasattr(importlib.import_module("mrosd"), "Node")
    except ImportError:
        return False


pytestmark = [
    needs_ros,
    pytest.mark.interop,
    pytest.mark.skipif(not _node_available(), reason="mrosd.Node is not built yet"),
]

CORPUS = r'''
import rospy, genpy
from std_msgs.msg import String, Bool, Float32, Int8, Header, UInt8MultiArray, MultiArrayDimension, Empty
from geometry_msgs.msg import PoseStamped, Twist, Point
from sensor_msgs.msg import JointState, Image, NavSatFix
from visualization_msgs.msg import Marker
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
rospy.init_node("corpus")
h = Header(seq=3, stamp=genpy.Time(1700000000, 5), frame_id="base_link")
msgs = {
    "/s/plain": String(data="hello world"),
    "/s/empty": String(data=""),
    "/s/quote": String(data='say "hi" \\ back\ttab'),
    "/s/unicode": String(data=u"caf\u00e9 \u65e5\u672c"),
    "/s/long": String(data="word " * 40),
    "/s/multiline": String(data="line one\nline two"),
    "/b": Bool(data=True),
    "/f": Float32(data=0.1),
    "/i": Int8(data=-5),
    "/e": Empty(),
    "/pose": PoseStamped(header=h),
    "/twist": Twist(),
    "/joints": JointState(header=h, name=["a", "b c"], position=[0.5, -1.25], velocity=[], effort=[1e-9]),
    "/image": Image(header=h, height=2, width=2, encoding="mono8", step=2, data=bytes([0, 9, 10, 255])),
    "/gps": NavSatFix(header=h, latitude=35.6, position_covariance=[0.0] * 9),
    "/marker": Marker(header=h, ns="n", points=[Point(1, 2, 3), Point()], lifetime=genpy.Duration(2, 5)),
    "/diag": DiagnosticArray(header=h, status=[DiagnosticStatus(level=1, name="x", values=[KeyValue("k", "v")])]),
    "/u8": UInt8MultiArray(data=bytes(range(0, 256, 15))),
}
pubs = [rospy.Publisher(t, type(m), queue_size=1, latch=True) for t, m in msgs.items()]
for p, m in zip(pubs, msgs.values()):
    p.publish(m)
print("up", flush=True)
rospy.spin()
'''

TOPICS = [
    "/s/plain", "/s/empty", "/s/quote", "/s/unicode", "/s/long", "/s/multiline", "/b", "/f", "/i", "/e",
    "/pose", "/twist", "/joints", "/image", "/gps", "/marker", "/diag", "/u8",
]  # fmt: skip


@pytest.fixture
def corpus(procs: Processes, rosmaster: str) -> str:
    node = procs.python(CORPUS, ros_env(rosmaster, procs.tmp), stderr=subprocess.DEVNULL)
    assert node.stdout is not None
    assert node.stdout.readline().strip() == b"up"
    return rosmaster


@pytest.mark.parametrize("topic", TOPICS)
def test_echo_of_one_latched_message_matches_rostopic(corpus: str, tmp_path: Path, topic: str) -> None:
    ours = mros(corpus, tmp_path, "topic", "echo", "-n", "1", topic)
    theirs = ros_tool(corpus, tmp_path, "rostopic", "echo", "-n", "1", topic)
    assert ours.returncode == 0, ours.stderr
    assert ours.stdout == theirs.stdout


@pytest.mark.parametrize(
    "argv",
    [
        ["--noarr", "/joints"],
        ["--noarr", "/gps"],
        ["--noarr", "/marker"],
        ["/pose/header"],
        ["/pose/header/stamp"],
        ["/pose/pose/position/x"],
        ["/joints/name"],
        ["/image/data"],
        ["/marker/points"],
    ],
    ids=" ".join,
)
def test_echo_options_and_field_paths_match_rostopic(corpus: str, tmp_path: Path, argv: list[str]) -> None:
    ours = mros(corpus, tmp_path, "topic", "echo", "-n", "1", *argv)
    theirs = ros_tool(corpus, tmp_path, "rostopic", "echo", "-n", "1", *argv)
    assert ours.returncode == 0, ours.stderr
    assert ours.stdout == theirs.stdout


def test_echo_json_prints_one_object_per_line(corpus: str, tmp_path: Path) -> None:
    out = mros(corpus, tmp_path, "topic", "echo", "-n", "1", "--json", "/joints")
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert len(lines) == 1
    obj = json.loads(lines[0])
    assert obj["name"] == ["a", "b c"]
    assert obj["header"]["stamp"] == {"secs": 1700000000, "nsecs": 5}
