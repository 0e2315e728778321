"""`mros topic echo` prints byte-for-byte what `rostopic echo` prints, for a corpus of latched messages.

A rospy node latches one message on each topic; both tools echo it with the same options and the outputs
are compared exactly. mros decodes every type from the publisher's message_definition.
"""

from __future__ import annotations

import json
import subprocess
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from tests.interop.cli.cliutil import mask_seq, mros, ros_tool, start_rospy
from tests.rosenv import Processes, needs_ros, start_rosmaster

pytestmark = [needs_ros, pytest.mark.interop]

CORPUS = r"""
import rospy, genpy
from std_msgs.msg import String, Bool, Float32, Int8, Header, UInt8MultiArray, MultiArrayDimension, Empty
from geometry_msgs.msg import PoseStamped, Twist, Point
from sensor_msgs.msg import JointState, Image, NavSatFix
from std_msgs.msg import Duration
from nav_msgs.msg import Path
from actionlib_msgs.msg import GoalStatusArray, GoalStatus, GoalID
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
    "/path": Path(header=h, poses=[PoseStamped(header=h), PoseStamped()]),
    "/goals": GoalStatusArray(header=h, status_list=[GoalStatus(goal_id=GoalID(id="g1"), status=1, text="t")]),
    "/dur": Duration(data=genpy.Duration(-1, 500000000)),
    "/u8": UInt8MultiArray(data=bytes(range(0, 256, 15))),
}
pubs = [rospy.Publisher(t, type(m), queue_size=1, latch=True) for t, m in msgs.items()]
for p, m in zip(pubs, msgs.values()):
    p.publish(m)
print("up", flush=True)
rospy.spin()
"""

TOPICS = [
    "/s/plain", "/s/empty", "/s/quote", "/s/unicode", "/s/long", "/s/multiline", "/b", "/f", "/i", "/e",
    "/pose", "/twist", "/joints", "/image", "/gps", "/path", "/goals", "/dur", "/u8",
]  # fmt: skip


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """One rosmaster and one latching rospy node for the whole module (they only answer reads)."""
    procs = Processes(tmp_path_factory.mktemp("corpus"))
    try:
        master = start_rosmaster(procs)
        start_rospy(procs, CORPUS, master, stderr=subprocess.DEVNULL)
        yield master
    finally:
        procs.close()


FIELD_CASES = [
    ["--noarr", "/joints"],
    ["--noarr", "/gps"],
    ["--noarr", "/path"],
    ["/pose/header"],
    ["/pose/header/stamp"],
    ["/pose/pose/position/x"],
    ["/joints/name"],
    ["/path/poses"],
    ["/goals/status_list"],
]


def _both(corpus: str, tmp: Path, argv: list[str]) -> tuple[list[str], str, str, int]:
    ours = mros(corpus, tmp, "topic", "echo", "-n", "1", *argv)
    theirs = ros_tool(corpus, tmp, "rostopic", "echo", "-n", "1", *argv)
    return argv, mask_seq(ours.stdout), mask_seq(theirs.stdout), ours.returncode


def test_echo_of_every_corpus_message_and_option_matches_rostopic_exactly(corpus: str, tmp_path: Path) -> None:
    cases = [[t] for t in TOPICS] + FIELD_CASES
    # Both tools start in ~1 s each; run the cases side by side to keep the test short.
    with ThreadPoolExecutor(max_workers=6) as pool:
        results = list(pool.map(lambda argv: _both(corpus, tmp_path, argv), cases))
    failed = [argv for argv, ours, _theirs, code in results if code != 0 or not ours]
    assert not failed, f"mros echo failed for {failed}"
    mismatched = {" ".join(argv): (ours, theirs) for argv, ours, theirs, _code in results if ours != theirs}
    assert not mismatched, mismatched


def test_echo_of_a_uint8_array_field_prints_the_numbers(corpus: str, tmp_path: Path) -> None:
    # rostopic echo /image/data crashes under Python 3 (ord() of an int) and prints nothing; genpy's rule for a
    # uint8[] field is a list of numbers, which is what mros prints.
    ours = mros(corpus, tmp_path, "topic", "echo", "-n", "1", "/image/data")
    assert ours.returncode == 0, ours.stderr
    assert ours.stdout == "[0, 9, 10, 255]\n---\n"


def test_echo_json_prints_one_object_per_line(corpus: str, tmp_path: Path) -> None:
    out = mros(corpus, tmp_path, "topic", "echo", "-n", "1", "--json", "/joints")
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert len(lines) == 1
    obj = json.loads(lines[0])
    assert obj["name"] == ["a", "b c"]
    assert obj["header"]["stamp"] == {"secs": 1700000000, "nsecs": 5}
