"""``mros topic echo -n 1`` prints the message and nothing else as it exits, as ``rostopic echo -n 1`` does.

Against real roscore's parts (rosmaster and the roscpp rosout node): rosout connects to every new node's
/rosout publication, so the connection of a short-lived echo often arrives while the echo closes. Before
the fix, about one run in ten printed ``/mros_echo_...: refusing TCPROS connection from ...: no topic with
name [/rosout] ...`` on stderr (the closing node treated rosout's late connection as a stray peer).
"""

from __future__ import annotations

import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

import pytest

from tests.interop.cli.cliutil import mros_env, start_rospy
from tests.rosenv import Processes, needs_ros, ros_env

pytestmark = [needs_ros, pytest.mark.interop]

ROSOUT_NODE = "/usr/lib/rosout/rosout"

TALKER = """
import rospy
from std_msgs.msg import String
rospy.init_node("talker")
pub = rospy.Publisher("/chatter", String, queue_size=1, latch=True)
pub.publish(String(data="hello"))
print("up", flush=True)
rospy.spin()
"""

RUNS = 30
#: Runs at once: enough to finish 30 in seconds on 2 cores, few enough that each run stays short.
PARALLEL = 5


def test_thirty_runs_of_echo_n_1_print_only_the_message(rosmaster: str, procs: Processes) -> None:
    procs.start([ROSOUT_NODE], ros_env(rosmaster, procs.tmp), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    start_rospy(procs, TALKER, rosmaster)
    env = mros_env(rosmaster, procs.tmp)
    argv = [sys.executable, "-m", "mros_cli.main", "topic", "echo", "-n", "1", "/chatter"]

    def once(_: int) -> subprocess.CompletedProcess[str]:
        return subprocess.run(argv, env=env, capture_output=True, text=True, timeout=60, check=False)

    real = subprocess.run(
        ["rostopic", "echo", "-n", "1", "/chatter"],
        env=ros_env(rosmaster, procs.tmp),
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    with ThreadPoolExecutor(PARALLEL) as pool:
        runs = list(pool.map(once, range(RUNS)))
    assert [(r.returncode, r.stdout, r.stderr) for r in runs] == [(0, real.stdout, real.stderr)] * RUNS
    assert real.stdout == 'data: "hello"\n---\n'
