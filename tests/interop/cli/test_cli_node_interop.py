"""`mros node` and `mros service list` against real rosmaster and a real rospy node match rosnode/rosservice."""

from __future__ import annotations

import subprocess
import time
import xmlrpc.client
from pathlib import Path

import pytest

from tests.interop.cli.cliutil import mros, ros_tool, start_rospy
from tests.rosenv import Processes, needs_ros

pytestmark = [needs_ros, pytest.mark.interop]

TALKER = """
import rospy
from std_msgs.msg import String
rospy.init_node("talker")
pub = rospy.Publisher("/chatter", String, queue_size=10)
listener = rospy.Subscriber("/other", String, lambda m: None)
print("up", flush=True)
rospy.spin()
"""


def _start_talker(procs: Processes, master: str) -> subprocess.Popen[bytes]:
    return start_rospy(procs, TALKER, master)


def test_node_list_info_and_service_list_match_the_ros_tools(procs: Processes, rosmaster: str, tmp_path: Path) -> None:
    _start_talker(procs, rosmaster)
    for argv in (["list"], ["list", "-a"], ["info", "/talker"], ["info", "-q", "/talker"]):
        ours = mros(rosmaster, tmp_path, "node", *argv)
        theirs = ros_tool(rosmaster, tmp_path, "rosnode", *argv)
        assert ours.stdout == theirs.stdout, argv
        assert ours.returncode == theirs.returncode == 0
    ours = mros(rosmaster, tmp_path, "service", "list")
    theirs = ros_tool(rosmaster, tmp_path, "rosservice", "list")
    assert ours.stdout == theirs.stdout
    assert "/talker/get_loggers" in ours.stdout


def test_node_ping_succeeds_for_a_live_node_and_reports_an_unknown_one_as_rosnode(
    procs: Processes, rosmaster: str, tmp_path: Path
) -> None:
    _start_talker(procs, rosmaster)
    ok = mros(rosmaster, tmp_path, "node", "ping", "-c", "1", "/talker")
    assert ok.returncode == 0
    assert "xmlrpc reply from" in ok.stdout
    missing = mros(rosmaster, tmp_path, "node", "ping", "-c", "1", "/nobody")
    theirs = ros_tool(rosmaster, tmp_path, "rosnode", "ping", "-c", "1", "/nobody")
    # rosnode exits 0 even here (the verdict is the stderr line); mros does the same for scripts.
    assert (
        (missing.returncode, missing.stdout)
        == (theirs.returncode, theirs.stdout)
        == (0, "rosnode: node is [/nobody]\n")
    )
    assert missing.stderr.strip() == theirs.stderr.strip() == "cannot ping [/nobody]: unknown node"


def test_node_kill_shuts_a_rospy_node_down_and_cleanup_purges_a_dead_one(
    procs: Processes, rosmaster: str, tmp_path: Path
) -> None:
    talker = _start_talker(procs, rosmaster)
    out = mros(rosmaster, tmp_path, "node", "kill", "/talker")
    assert out.returncode == 0
    assert out.stdout == "killing /talker\nkilled\n"
    talker.wait(timeout=20)
    # rospy unregisters on shutdown; a node killed with SIGKILL stays registered until cleanup.
    second = _start_talker(procs, rosmaster)
    second.kill()
    second.wait(timeout=10)
    assert "/talker" in mros(rosmaster, tmp_path, "node", "list").stdout
    cleaned = mros(rosmaster, tmp_path, "node", "cleanup", "-y")
    assert cleaned.returncode == 0, cleaned.stderr
    deadline = time.monotonic() + 10
    while "/talker" in mros(rosmaster, tmp_path, "node", "list").stdout:
        assert time.monotonic() < deadline
    assert ros_tool(rosmaster, tmp_path, "rosnode", "list").stdout.strip() == ""


def test_node_list_u_and_a_follow_rosnodes_order_and_an_empty_graph_prints_its_empty_line(
    rosmaster: str, tmp_path: Path
) -> None:
    """rosnode list -u prints one URI per node in the order of the names (not sorted by URI, not merged)."""
    for argv in (["list"], ["list", "-u"]):  # nothing registered: rosnode prints one empty line
        assert mros(rosmaster, tmp_path, "node", *argv).stdout == ros_tool(rosmaster, tmp_path, "rosnode", *argv).stdout
    # Registrations only (rosnode list never calls the nodes): names in one order, URIs in the opposite one,
    # and two names on one URI.
    nodes = {"/a_node": "http://127.0.0.1:3/", "/b_node": "http://127.0.0.1:2/", "/c_node": "http://127.0.0.1:2/"}
    with xmlrpc.client.ServerProxy(rosmaster) as master:
        for name, api in nodes.items():
            assert master.registerPublisher(name, f"{name}/out", "std_msgs/String", api)[0] == 1
    for argv in (["list", "-u"], ["list", "-a"], ["list", "-u", "/b_node"]):
        ours = mros(rosmaster, tmp_path, "node", *argv)
        theirs = ros_tool(rosmaster, tmp_path, "rosnode", *argv)
        assert (ours.returncode, ours.stdout) == (theirs.returncode, theirs.stdout), argv
    assert mros(rosmaster, tmp_path, "node", "list", "-u").stdout.split() == [nodes[n] for n in sorted(nodes)]
