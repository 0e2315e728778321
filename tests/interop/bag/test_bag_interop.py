"""mros bag against Debian's rosbag and rostopic on a real rosmaster with a rospy publisher.

- a bag from `mros bag record` is read by `rosbag info` (every message counted, the same text as
  `mros bag info`, compressed or not) and by `rostopic echo -b`;
- `mros bag play` is received by `rostopic echo`;
- a bag from `rosbag record` played by `mros bag play` delivers the same messages, byte for byte.
"""

from __future__ import annotations

import asyncio
import re
import subprocess
import sys
from pathlib import Path

import pytest

from mrosd.bag.files import open_bag
from mrosd.tcpros import AnyMsg, Node
from tests.rosenv import Processes, iter_lines_until, needs_ros, ros_env

pytestmark = [needs_ros, pytest.mark.interop]

TALKER = r"""
import rospy
from std_msgs.msg import String
rospy.init_node("talker")
pub = rospy.Publisher("/chatter", String, queue_size=1000)
rate = rospy.Rate(200)
i = 0
print("up", flush=True)
while not rospy.is_shutdown():
    pub.publish(String(data="hello %d" % i))
    i += 1
    rate.sleep()
"""


def run(master: str, tmp: Path, argv: list[str], **env: str) -> subprocess.CompletedProcess[str]:
    """A command (``mros`` under our python, or a Debian ROS tool) on ``master``, bounded to 60 s."""
    return subprocess.run(
        argv, env=ros_env(master, tmp, **env), capture_output=True, text=True, timeout=60, check=False
    )


def mros(master: str, tmp: Path, *args: str, **env: str) -> subprocess.CompletedProcess[str]:
    return run(master, tmp, [sys.executable, "-m", "mros_cli.main", *args], **env)


def ros_tool(master: str, tmp: Path, *argv: str, **env: str) -> subprocess.CompletedProcess[str]:
    return run(master, tmp, list(argv), **env)


def start_talker(procs: Processes, master: str) -> None:
    talker = procs.python(TALKER, ros_env(master, procs.tmp), stderr=subprocess.DEVNULL)
    assert talker.stdout is not None
    assert talker.stdout.readline().strip() == b"up"


@pytest.mark.parametrize("compression", [[], ["-j"]], ids=["none", "bz2"])
def test_rosbag_info_reads_every_message_mros_recorded_and_prints_what_mros_bag_info_prints(
    procs: Processes, rosmaster: str, tmp_path: Path, compression: list[str]
) -> None:
    start_talker(procs, rosmaster)
    out = tmp_path / "mine.bag"
    rec = mros(rosmaster, tmp_path, "bag", "record", "/chatter", "-l", "100", "-O", str(out), *compression)
    assert rec.returncode == 0, rec.stderr
    theirs = ros_tool(rosmaster, tmp_path, "rosbag", "info", str(out), TZ="UTC")
    assert theirs.returncode == 0, theirs.stderr
    assert re.search(r"^messages: +100$", theirs.stdout, re.M)
    assert re.search(r"^topics: +/chatter   100 msgs    : std_msgs/String$", theirs.stdout, re.M)
    ours = mros(rosmaster, tmp_path, "bag", "info", str(out), TZ="UTC")
    assert ours.stdout == theirs.stdout
    echoed = ros_tool(rosmaster, tmp_path, "rostopic", "echo", "-b", str(out), "/chatter")
    lines = [line for line in echoed.stdout.splitlines() if line.startswith("data:")]
    assert len(lines) == 100
    first = int(lines[0].split()[-1].rstrip('"'))
    assert lines == [f'data: "hello {first + i}"' for i in range(100)]
    assert mros(rosmaster, tmp_path, "topic", "echo", "-b", str(out), "/chatter").stdout == echoed.stdout


def test_rostopic_echo_receives_what_mros_bag_play_publishes(procs: Processes, rosmaster: str, tmp_path: Path) -> None:
    start_talker(procs, rosmaster)
    bag = tmp_path / "src.bag"
    assert mros(rosmaster, tmp_path, "bag", "record", "/chatter", "-l", "20", "-O", str(bag)).returncode == 0
    reader = open_bag(str(bag))
    stored = [data for _c, _t, data in reader.messages()]
    reader.close()
    expected = [f'data: "{data[4:].decode()}"' for data in stored]
    echo = procs.start(["rostopic", "echo", "-n", "20", "/replay"], ros_env(rosmaster, tmp_path))
    # rostopic registers its subscription before play advertises; --wait-for-subscribers covers the rest.
    play = mros(rosmaster, tmp_path, "bag", "play", str(bag), "/chatter:=/replay", "--wait-for-subscribers", "-q")
    assert play.returncode == 0, play.stderr
    lines = [line for line in iter_lines_until(echo, 40, timeout=20) if line.startswith("data:")]
    assert lines == expected


async def test_mros_bag_play_replays_a_rosbag_record_bag_with_the_same_count_and_bytes(
    procs: Processes, rosmaster: str, tmp_path: Path
) -> None:
    start_talker(procs, rosmaster)
    bag = tmp_path / "theirs.bag"
    rec = await asyncio.to_thread(
        ros_tool, rosmaster, tmp_path, "rosbag", "record", "/chatter", "-l", "50", "-O", str(bag)
    )
    assert rec.returncode == 0, rec.stderr
    reader = open_bag(str(bag))
    stored = [data for _c, _t, data in reader.messages()]
    reader.close()
    assert len(stored) == 50
    ours = await asyncio.to_thread(mros, rosmaster, tmp_path, "bag", "info", str(bag), TZ="UTC")
    theirs = await asyncio.to_thread(ros_tool, rosmaster, tmp_path, "rosbag", "info", str(bag), TZ="UTC")
    assert ours.stdout == theirs.stdout
    async with Node("listener", master_uri=rosmaster, argv=[]) as node:
        sub = await node.subscribe("/again", AnyMsg, queue_size=1000)
        play = await asyncio.to_thread(
            mros, rosmaster, tmp_path, "bag", "play", str(bag), "/chatter:=/again", "--wait-for-subscribers", "-q"
        )
        assert play.returncode == 0, play.stderr
        got = [await sub.next(timeout=10) for _ in range(50)]
    assert [m.data for m in got] == stored
    assert {m.header.type for m in got} == {"std_msgs/String"}


async def test_rosbag_play_replays_an_mros_bag_with_the_same_bytes_and_latching(
    procs: Processes, rosmaster: str, tmp_path: Path
) -> None:
    start_talker(procs, rosmaster)
    bag = tmp_path / "mine.bag"
    rec = await asyncio.to_thread(mros, rosmaster, tmp_path, "bag", "record", "/chatter", "-l", "30", "-O", str(bag))
    assert rec.returncode == 0, rec.stderr
    reader = open_bag(str(bag))
    stored = [data for _c, _t, data in reader.messages()]
    reader.close()
    async with Node("listener", master_uri=rosmaster, argv=[]) as node:
        sub = await node.subscribe("/chatter2", AnyMsg, queue_size=1000)
        play = procs.start(
            ["rosbag", "play", "--wait-for-subscribers", str(bag), "/chatter:=/chatter2"], ros_env(rosmaster, tmp_path)
        )
        got = [await sub.next(timeout=20) for _ in range(30)]
        await asyncio.to_thread(play.wait, 20)
    assert [m.data for m in got] == stored
