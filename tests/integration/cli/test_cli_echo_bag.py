"""`mros topic echo -b BAG` renders stored messages with the live echo's options (-n, -p, --filter, --nostr)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from mrosd.bag.files import open_writer
from mrosd.bag.model import ConnectionInfo
from mrosd.msg import get_message_class
from tests.rosenv import free_port, needs_ros, ros_env


def _bag(path: Path) -> None:
    string = get_message_class("std_msgs/String")
    writer = open_writer(str(path), "bag")
    conn = writer.add_connection(ConnectionInfo("/a", "std_msgs/String", string._md5sum, string._full_text, "/rec"))
    for i in range(5):
        writer.write(conn, 1_700_000_000_000_000_000 + i, string(data=f"stored {i}").serialize())
    writer.close()


def _echo(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mros_cli.main", "topic", "echo", *args],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def test_echo_from_a_bag_takes_the_echo_options(tmp_path: Path) -> None:
    bag = tmp_path / "s.bag"
    _bag(bag)
    out = _echo("-b", str(bag), "-n", "2", "/a")
    assert (out.returncode, out.stdout) == (0, 'data: "stored 0"\n---\ndata: "stored 1"\n---\n'), out.stderr
    out = _echo("-b", str(bag), "--filter", "m.data.endswith(('3', '4'))", "--nostr", "/a")
    assert (out.returncode, out.stdout) == (0, 'data: "<string length: 8>"\n---\n' * 2), out.stderr
    out = _echo("-b", str(bag), "-p", "-n", "1", "/a")
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines()[0] == "%time,field.data"
    assert out.stdout.splitlines()[1].endswith(",stored 0")


#: Record times of the stamped bag: a message's header.stamp differs from when it was recorded.
RECORDED = [1_700_000_000_000_000_000 + i * 250_000_000 for i in range(3)]


def _stamped_bag(path: Path) -> None:
    point = get_message_class("geometry_msgs/PointStamped")
    string = get_message_class("std_msgs/String")
    writer = open_writer(str(path), "bag")
    pts = writer.add_connection(ConnectionInfo("/p", point._type, point._md5sum, point._full_text, "/rec"))
    txt = writer.add_connection(ConnectionInfo("/s", string._type, string._md5sum, string._full_text, "/rec"))
    for i, t_ns in enumerate(RECORDED):
        msg = point()
        msg.header.stamp.secs, msg.header.stamp.nsecs = 42 + i, 7
        msg.header.frame_id = "map"
        msg.point.x = float(i)
        writer.write(pts, t_ns, msg.serialize())
        writer.write(txt, t_ns + 1, string(data=f"s{i}").serialize())
    writer.close()


def test_echo_p_from_a_bag_prints_the_record_time(tmp_path: Path) -> None:
    """rostopic echo -p -b prints when each message was recorded, even for a message with a Header."""
    bag = tmp_path / "t.bag"
    _stamped_bag(bag)
    out = _echo("-b", str(bag), "-p", "/p")
    assert out.returncode == 0, out.stderr
    assert [line.split(",", 1)[0] for line in out.stdout.splitlines()[1:]] == [str(t) for t in RECORDED]
    out = _echo("-b", str(bag), "-p", "/s")
    assert [line.split(",", 1)[0] for line in out.stdout.splitlines()[1:]] == [str(t + 1) for t in RECORDED]
    out = _echo("-b", str(bag), "-p", "/p/point")
    assert [line.split(",", 1)[0] for line in out.stdout.splitlines()[1:]] == [str(t) for t in RECORDED]


@needs_ros
@pytest.mark.interop
@pytest.mark.parametrize("topic", ["/p", "/s", "/p/point", "/p/header"])
def test_echo_p_from_a_bag_prints_what_rostopic_prints(tmp_path: Path, topic: str) -> None:
    bag = tmp_path / "t.bag"
    _stamped_bag(bag)
    env = ros_env(f"http://127.0.0.1:{free_port()}/", tmp_path)  # no master: rostopic -b reads the file only
    theirs = subprocess.run(
        ["/usr/bin/rostopic", "echo", "-p", "-b", str(bag), topic],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert theirs.returncode == 0, theirs.stderr
    ours = _echo("-b", str(bag), "-p", topic)
    assert ours.returncode == 0, ours.stderr
    assert ours.stdout == theirs.stdout
