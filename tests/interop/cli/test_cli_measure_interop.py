"""`mros topic delay`, `hz --filter` and `service call --wait` against rostopic/rosservice on a rospy graph."""

from __future__ import annotations

import concurrent.futures
import re
import sys
import time
from pathlib import Path

import pytest

from tests.interop.cli.cliutil import mros, ros_tool, start_rospy
from tests.rosenv import Processes, iter_lines_until, needs_ros, ros_env

pytestmark = [needs_ros, pytest.mark.interop]

#: Stamps 0.25 s in the past at 20 Hz; every fourth message says "keep".
STAMPED = """
import rospy
from geometry_msgs.msg import PointStamped
rospy.init_node("stamped")
pub = rospy.Publisher("/stamped", PointStamped, queue_size=10)
rate = rospy.Rate(20)
print("up", flush=True)
i = 0
while not rospy.is_shutdown():
    msg = PointStamped()
    msg.header.stamp = rospy.Time.now() - rospy.Duration(0.25)
    msg.header.frame_id = "keep" if i % 4 == 0 else "drop"
    pub.publish(msg)
    i += 1
    rate.sleep()
"""

LATE_SERVER = """
import rospy
from std_srvs.srv import SetBool, SetBoolResponse
rospy.init_node("late")
rospy.Service("/late", SetBool, lambda r: SetBoolResponse(success=r.data, message="late"))
print("up", flush=True)
rospy.spin()
"""


def _report(procs: Processes, argv: list[str], env: dict[str, str], pattern: str) -> list[str]:
    """The first two statistics reports (each a line matching ``pattern`` and the line after it)."""
    proc = procs.start(argv, env)
    lines = iter_lines_until(proc, 200, timeout=60)
    found: list[str] = []
    for line in lines:
        if re.match(pattern, line):
            found += [line, next(lines)]
            if len(found) == 4:
                break
    Processes.stop(proc)
    return found


def test_delay_and_filtered_hz_report_what_rostopic_reports(procs: Processes, rosmaster: str, tmp_path: Path) -> None:
    start_rospy(procs, STAMPED, rosmaster)
    env = ros_env(rosmaster, tmp_path)
    mros_argv = [sys.executable, "-m", "mros_cli.main", "topic"]
    keep = ["--filter", "m.header.frame_id == 'keep'"]
    jobs = {
        ("ours", "delay"): ([*mros_argv, "delay", "/stamped"], r"average delay: ([0-9.]+)$"),
        ("theirs", "delay"): (["rostopic", "delay", "/stamped"], r"average delay: ([0-9.]+)$"),
        ("ours", "hz"): ([*mros_argv, "hz", *keep, "/stamped"], r"average rate: ([0-9.]+)$"),
        ("theirs", "hz"): (["rostopic", "hz", *keep, "/stamped"], r"average rate: ([0-9.]+)$"),
    }
    with concurrent.futures.ThreadPoolExecutor(4) as pool:
        futures = {key: pool.submit(_report, procs, argv, env, pattern) for key, (argv, pattern) in jobs.items()}
        reports = {key: future.result() for key, future in futures.items()}
    for (_who, what), lines in reports.items():
        value = float(lines[2].split(": ")[1])
        if what == "delay":
            assert 0.2 < value < 0.5, lines
            assert re.match(r"\tmin: [0-9.]+s max: [0-9.]+s std dev: [0-9.]+s window: \d+$", lines[3]), lines
        else:
            assert 2.0 < value < 8.0, lines  # 20 Hz, one message in four kept
            assert re.match(r"\tmin: [0-9.]+s max: [0-9.]+s std dev: [0-9.]+s window: \d+$", lines[3]), lines


def test_call_wait_waits_for_the_service_like_rosservice(procs: Processes, rosmaster: str, tmp_path: Path) -> None:
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        ours = pool.submit(mros, rosmaster, tmp_path, "service", "call", "--wait", "/late", "{data: true}")
        theirs = pool.submit(ros_tool, rosmaster, tmp_path, "rosservice", "call", "--wait", "/late", "{data: true}")
        time.sleep(1.5)  # both are waiting now: the service does not exist yet
        assert not ours.done() and not theirs.done()
        start_rospy(procs, LATE_SERVER, rosmaster)
        a, b = ours.result(timeout=60), theirs.result(timeout=60)
    assert (a.returncode, a.stdout) == (b.returncode, b.stdout) == (0, 'success: True\nmessage: "late"\n')
