"""SIGTERM, and a second SIGINT, stop a long-running ``mros`` command as the first SIGINT does.

``kill %1``, ``timeout``, systemd and roslaunch send SIGTERM. Before the fix ``mros topic pub`` died of it at
once (status 143) without unregistering, and rosmaster kept the stale publisher for good; a second Ctrl-C
also skipped the unregistering and printed aiohttp's "Unclosed client session". Against Debian's real
rosmaster: the registration is gone from getSystemState within 1 s of the signal, rosmaster's master.log
shows the ``-PUB``/``-SUB`` line, and the command says nothing on stderr.
"""

from __future__ import annotations

import os
import signal
import time
import xmlrpc.client
from pathlib import Path

import pytest

from tests.interop.cli.cliutil import mros_process, start_rospy
from tests.rosenv import Processes, needs_ros

pytestmark = [needs_ros, pytest.mark.interop]

#: The bar of issue 33: gone from the master this soon after the signal.
GONE_WITHIN = 1.0


def _state(uri: str) -> tuple[dict[str, list[str]], dict[str, list[str]]]:
    with xmlrpc.client.ServerProxy(uri) as proxy:
        code, _, (pubs, subs, _srvs) = proxy.getSystemState("/test")
    assert code == 1
    return {t: n for t, n in pubs}, {t: n for t, n in subs}


def _wait_registered(uri: str, topic: str, role: int, timeout: float = 20.0) -> str:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        nodes = _state(uri)[role].get(topic, [])
        mine = [n for n in nodes if n.startswith("/mros_")]
        if mine:
            return mine[0]
        time.sleep(0.02)
    raise AssertionError(f"no mros node registered on {topic} within {timeout} s")


def _wait_gone(uri: str, topic: str, role: int, node: str, timeout: float) -> float:
    start = time.monotonic()
    while time.monotonic() - start < timeout:
        if node not in _state(uri)[role].get(topic, []):
            return time.monotonic() - start
        time.sleep(0.01)
    raise AssertionError(f"{node} still registered on {topic} {timeout} s after the signal")


def _master_log(procs: Processes) -> str:
    logs = list(Path(procs.tmp / "ros_log").rglob("master.log"))
    assert logs, "rosmaster wrote no master.log"
    return "".join(p.read_text(errors="replace") for p in logs)


#: A publisher for the subscribing commands (echo and hz wait for a topic's type, as rostopic does).
TALKER = """
import rospy
from std_msgs.msg import String
rospy.init_node("talker")
pubs = [rospy.Publisher(t, String, queue_size=1, latch=True) for t in ("/edges_echo", "/edges_hz", "/edges_bag")]
for p in pubs:
    p.publish(String(data="hello"))
print("up", flush=True)
rospy.spin()
"""

#: (argv, topic, 0 for a publisher / 1 for a subscriber, master.log mark)
COMMANDS = {
    "topic pub": (["topic", "pub", "/edges_pub", "std_msgs/String", "hi"], "/edges_pub", 0, "-PUB [/edges_pub]"),
    "topic pub -r": (
        ["topic", "pub", "-r", "5", "/edges_rate", "std_msgs/String", "hi"],
        "/edges_rate",
        0,
        "-PUB [/edges_rate]",
    ),
    "topic echo": (["topic", "echo", "/edges_echo"], "/edges_echo", 1, "-SUB [/edges_echo]"),
    "topic hz": (["topic", "hz", "/edges_hz"], "/edges_hz", 1, "-SUB [/edges_hz]"),
    "bag record": (["bag", "record", "-q", "/edges_bag", "-O", "{tmp}/run.bag"], "/edges_bag", 1, "-SUB [/edges_bag]"),
}


#: Commands whose normal end is Ctrl-C: exit status 0 after a stop signal (the others: 128 + the signal).
ENDS_NORMALLY = {"topic hz", "bag record"}


@pytest.mark.parametrize("signals", [(signal.SIGTERM,), (signal.SIGINT, signal.SIGINT)], ids=["SIGTERM", "SIGINTx2"])
@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_a_stop_signal_unregisters_within_one_second_and_exits_quietly(
    rosmaster: str, procs: Processes, command: str, signals: tuple[int, ...]
) -> None:
    argv, topic, role, mark = COMMANDS[command]
    if role == 1:
        start_rospy(procs, TALKER, rosmaster)
    proc = mros_process(procs, rosmaster, *(a.format(tmp=procs.tmp) for a in argv))
    node = _wait_registered(rosmaster, topic, role)
    for signum in signals:
        os.kill(proc.pid, signum)
    took = _wait_gone(rosmaster, topic, role, node, GONE_WITHIN * 5)
    _, err = proc.communicate(timeout=10)
    assert took < GONE_WITHIN, f"unregistered {took:.2f} s after the signal"
    assert err.decode() == ""
    # hz and bag record end normally on Ctrl-C (as rostopic's and rosbag's), and so on SIGTERM too
    assert proc.returncode == (0 if command in ENDS_NORMALLY else 128 + signals[0])
    deadline = time.monotonic() + 5
    while mark not in _master_log(procs) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert mark in _master_log(procs)


@pytest.mark.parametrize("signals", [(signal.SIGTERM,), (signal.SIGINT, signal.SIGINT)], ids=["SIGTERM", "SIGINTx2"])
def test_a_stop_signal_ends_mros_bridge_quietly(rosmaster: str, procs: Processes, signals: tuple[int, ...]) -> None:
    """The bridge registers nothing until a browser asks; it still closes its node and sessions quietly."""
    proc = mros_process(procs, rosmaster, "bridge", "--port", "0", "--rosbridge-port", "-1")
    assert proc.stderr is not None
    assert proc.stderr.readline().startswith(b"serving ")
    for signum in signals:
        os.kill(proc.pid, signum)
    _, err = proc.communicate(timeout=10)
    assert (proc.returncode, err.decode()) == (128 + signals[0], "")
