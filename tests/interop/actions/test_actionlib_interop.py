"""mrosd.actions against Debian's actionlib (rospy) both ways: goal, feedback, result, cancel, preemption, LOST."""

from __future__ import annotations

import asyncio
import subprocess
import sys
from pathlib import Path

import pytest

import mrosd
from mrosd.actions import ActionClient, ActionServer, ServerGoal, Status
from mrosd.msg import get_message_class
from tests.rosenv import PROJECT_ROOT, ROS_PYTHON, Processes, iter_lines_until, needs_ros, ros_env

pytestmark = needs_ros

SCRIPT = str(Path(__file__).resolve().parents[2] / "data" / "actions" / "rospy_action.py")
EXAMPLE = str(PROJECT_ROOT / "examples" / "action_server.py")
GoalMsg = get_message_class("actionlib/TestGoal")
FeedbackMsg = get_message_class("actionlib/TestFeedback")
ResultMsg = get_message_class("actionlib/TestResult")


def has_actionlib() -> bool:
    probe = subprocess.run([ROS_PYTHON, "-c", "import actionlib"], capture_output=True, timeout=60, check=False)
    return probe.returncode == 0


needs_actionlib = pytest.mark.skipif(not has_actionlib(), reason="python3-actionlib is not installed")


def rospy_action(procs: Processes, master: str, *args: str) -> subprocess.Popen[bytes]:
    return procs.start([ROS_PYTHON, SCRIPT, *args], ros_env(master, procs.tmp), stderr=subprocess.DEVNULL)


async def lines(proc: subprocess.Popen[bytes], count: int, timeout: float = 30.0) -> list[str]:
    return await asyncio.to_thread(lambda: list(iter_lines_until(proc, count, timeout)))


def our_node(name: str, master: str) -> mrosd.Node:
    return mrosd.Node(name, master_uri=master, argv=[], host="127.0.0.1")


@needs_actionlib
async def test_debian_simple_action_client_drives_the_example_server(procs: Processes, rosmaster: str) -> None:
    env = ros_env(rosmaster, procs.tmp)
    procs.start([sys.executable, EXAMPLE], env, stderr=subprocess.DEVNULL)
    client = rospy_action(procs, rosmaster, "client", "5")
    out, _ = await asyncio.to_thread(client.communicate, None, 40.0)  # it prints 7 lines and ends
    got = out.decode().splitlines()
    # every feedback from the first the client takes: SimpleActionClient drops a feedback that comes before
    # send_goal has returned its goal handle (``self.gh``, set after the goal is published), and our server
    # answers at once: CI saw feedback 2..5 (actionlib's race, not the link's: the client waits for our header)
    assert got[0] == "up" and got[-1] == "done SUCCEEDED 10", got
    assert got[1:-1] and got[1:-1] == [f"feedback {i}" for i in range(6 - len(got[1:-1]), 6)], got

    canceller = rospy_action(procs, rosmaster, "cancel", "50", "2")
    got = await lines(canceller, 4, timeout=40.0)
    # feedback arrives (which numbers: a rospy client may miss the first while its subscription connects)
    assert got[0] == "up" and all(line.startswith("feedback ") for line in got[1:3]), got
    assert got[3].startswith("done PREEMPTED"), got


@needs_actionlib
async def test_our_client_against_debian_simple_action_server(procs: Processes, rosmaster: str) -> None:
    server = rospy_action(procs, rosmaster, "server")
    assert await lines(server, 1) == ["up"]
    async with (
        our_node("action_client", rosmaster) as node,
        ActionClient(node, "/test_action", "actionlib/TestAction") as client,
    ):
        await client.wait_for_server(timeout=20.0)
        goal = await client.send_goal(GoalMsg(goal=5))
        assert goal.id.startswith("/action_client-1-")
        feedback = [fb.feedback async for fb in goal.feedback()]
        result = await goal.wait(timeout=20.0)
        assert (goal.status, result.result, feedback) == (Status.SUCCEEDED, 10, [1, 2, 3, 4, 5])

        # cancel by id
        goal = await client.send_goal(GoalMsg(goal=50))
        async for _ in goal.feedback():
            await goal.cancel()
            break
        await goal.wait(timeout=20.0)
        assert goal.status is Status.PREEMPTED

        # preemption: a newer goal ends the running one PREEMPTED and runs itself
        first = await client.send_goal(GoalMsg(goal=50))
        async for _ in first.feedback():
            break
        second = await client.send_goal(GoalMsg(goal=2))
        await first.wait(timeout=20.0)
        result = await second.wait(timeout=20.0)
        assert (first.status, second.status, result.result) == (Status.PREEMPTED, Status.SUCCEEDED, 4)

        # cancel all
        goal = await client.send_goal(GoalMsg(goal=50))
        async for _ in goal.feedback():
            break
        await client.cancel_all()
        await goal.wait(timeout=20.0)
        assert goal.status is Status.PREEMPTED

        # the server dies mid-goal: the goal ends LOST
        goal = await client.send_goal(GoalMsg(goal=50))
        async for _ in goal.feedback():
            break
        server.kill()
        assert await goal.wait(timeout=20.0) is None
        assert goal.status is Status.LOST


async def _count(goal: ServerGoal) -> object:
    for step in range(1, goal.goal.goal + 1):
        goal.publish_feedback(FeedbackMsg(feedback=step))
        await asyncio.sleep(0.1)
    return ResultMsg(result=2 * goal.goal.goal)


@needs_actionlib
async def test_debian_client_cancel_cancels_our_goal_coroutine(procs: Processes, rosmaster: str) -> None:
    cancelled = asyncio.Event()

    async def execute(goal: ServerGoal) -> object:
        try:
            return await _count(goal)
        except asyncio.CancelledError:
            cancelled.set()
            raise

    async with (
        our_node("action_server", rosmaster) as node,
        ActionServer(node, "/test_action", "actionlib/TestAction", execute),
    ):
        canceller = rospy_action(procs, rosmaster, "cancel", "50", "3")
        got = await lines(canceller, 5, timeout=40.0)
        assert got[-1].startswith("done PREEMPTED"), got
        assert cancelled.is_set()
