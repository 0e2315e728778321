"""mrosd as roscore: a rospy node's log lines reach /rosout_agg through the daemon's built-in aggregator."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from tests.rosenv import Processes, free_port, iter_lines_until, needs_ros, ros_env, wait_for_xmlrpc

pytestmark = [needs_ros, pytest.mark.interop]

LOGGER = """
import rospy
rospy.init_node("chatty")
rate = rospy.Rate(10)
while not rospy.is_shutdown():
    rospy.loginfo("hello aggregator")
    rate.sleep()
"""


def test_rospy_log_lines_appear_on_rosout_agg_for_rostopic_and_mros(procs: Processes, tmp_path: Path) -> None:
    port = free_port()
    uri = f"http://127.0.0.1:{port}/"
    env = ros_env(uri, tmp_path, MROSD_IXM_SOCKET=str(tmp_path / "ixm.sock"))
    procs.our_python(["-m", "mrosd.daemon", "--port", str(port)], env, stderr=subprocess.DEVNULL)
    wait_for_xmlrpc(uri)
    procs.python(LOGGER, env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    theirs = procs.start(["rostopic", "echo", "-n", "1", "/rosout_agg/msg"], env)
    assert list(iter_lines_until(theirs, 2, timeout=40)) == ['"hello aggregator"', "---"]
    ours = procs.our_python(["-m", "mros_cli.main", "topic", "echo", "-n", "1", "/rosout_agg/name"], env)
    assert list(iter_lines_until(ours, 2, timeout=40)) == ['"/chatty"', "---"]
    nodes = subprocess.run(["rosnode", "list"], env=env, capture_output=True, text=True, timeout=60, check=False)
    assert "/rosout" in nodes.stdout.split()
