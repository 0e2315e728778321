"""Two robots, each an mrosd daemon with [fleet] in its own network namespace, linked over Zenoh (root only).

The link of robot1 is cut (``ip link set down``) for 10 s and restored: data reaches rospy on robot2 again
within 5 s, with no action from anyone.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest

from tests.netns.nsutil import NetnsLab
from tests.rosenv import ROS_PYTHON, Processes, needs_ros, ros_env

pytest.importorskip("zenoh", reason="the fleet tests need eclipse-zenoh (pip install 'mrosd[fleet]')")
pytestmark = [pytest.mark.root, pytest.mark.interop, needs_ros]

ZENOH_PORT = 7447
MASTER_PORT = 11311

TALKER = textwrap.dedent(
    """
    import rospy
    from std_msgs.msg import String
    rospy.init_node("talker", disable_signals=True)
    pub = rospy.Publisher("/chatter", String, queue_size=10)
    rate = rospy.Rate(20)
    i = 0
    while not rospy.is_shutdown():
        pub.publish(String(data="hello %d" % i))
        i += 1
        rate.sleep()
    """
)
LISTENER = textwrap.dedent(
    """
    import sys, rospy
    from std_msgs.msg import String
    rospy.init_node("listener", disable_signals=True)
    rospy.Subscriber("/robot1/chatter", String, lambda m: (sys.stdout.write(m.data + "\\n"), sys.stdout.flush()))
    rospy.spin()
    """
)


def daemon_config(tmp: Path, robot: str, listen: str, connect: str, extra: str) -> Path:
    path = tmp / f"{robot}.toml"
    path.write_text(
        textwrap.dedent(
            f"""
            [master]
            host = "127.0.0.1"
            port = {MASTER_PORT}
            [ixm]
            enabled = false
            [rosout]
            enabled = false
            [fleet]
            enabled = true
            robot = "{robot}"
            listen = ["tcp/{listen}:{ZENOH_PORT}"]
            connect = [{f'"tcp/{connect}:{ZENOH_PORT}"' if connect else ""}]
            """
        )
        + extra
    )
    return path


class Arrivals:
    """Lines of a process's stdout with the monotonic time each one arrived (a reader thread)."""

    def __init__(self, proc: subprocess.Popen[bytes]) -> None:
        self.times: list[float] = []
        self._thread = threading.Thread(target=self._read, args=(proc,), daemon=True)
        self._thread.start()

    def _read(self, proc: subprocess.Popen[bytes]) -> None:
        assert proc.stdout is not None
        for _line in proc.stdout:
            self.times.append(time.monotonic())

    def wait_after(self, since: float, timeout: float) -> float:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            later = [t for t in self.times if t > since]
            if later:
                return later[0]
            time.sleep(0.02)
        raise TimeoutError(f"no message within {timeout} s after {since}")


def test_link_cut_for_10s_then_data_resumes_within_5s(netns_lab: NetnsLab, procs: Processes, tmp_path: Path) -> None:
    lab = netns_lab
    env = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "MROSD_"))}
    env["ROS_HOSTNAME"] = "127.0.0.1"  # each robot's nodes talk to their own master only
    env["PYTHONPATH"] = os.pathsep.join([str(Path.cwd()), str(Path.cwd() / "cli")])
    for i, (robot, connect, extra) in enumerate(
        [
            ("robot1", "", 'send_topics = ["/chatter"]\n'),
            ("robot2", lab.addrs[0], 'receive_topics = ["/robot1/**"]\n'),
        ]
    ):
        cfg = daemon_config(tmp_path, robot, lab.addrs[i], connect, extra)
        with open(tmp_path / f"{robot}.log", "wb") as log:  # the daemon keeps its own copy of the descriptor
            procs.start(
                lab.argv(i, [sys.executable, "-m", "mrosd.daemon", "--config", str(cfg)]), env, stderr=log.fileno()
            )
    master = f"http://127.0.0.1:{MASTER_PORT}/"
    for i in range(2):
        lab.exec_ok(
            lab.hosts[i],
            [sys.executable, "-c", f"from tests.rosenv import wait_for_xmlrpc; wait_for_xmlrpc({master!r}, 30)"],
            timeout=40,
        )
    procs.start(lab.argv(0, [ROS_PYTHON, "-c", TALKER]), ros_env(master, tmp_path / "h1"))
    listener = procs.start(lab.argv(1, [ROS_PYTHON, "-c", LISTENER]), ros_env(master, tmp_path / "h2"))
    arrivals = Arrivals(listener)
    arrivals.wait_after(0.0, 40)

    link = f"{lab.tag}i1"[-15:]
    lab.exec_ok(lab.hosts[0], ["ip", "link", "set", link, "down"])
    cut = time.monotonic()
    time.sleep(10)
    lab.exec_ok(lab.hosts[0], ["ip", "link", "set", link, "up"])
    restored = time.monotonic()
    assert not [t for t in arrivals.times if cut + 0.5 < t < restored], "data crossed a cut link"
    resumed = arrivals.wait_after(restored, 15)
    print(f"data resumed {resumed - restored:.2f} s after the link came back")
    assert resumed - restored <= 5.0
