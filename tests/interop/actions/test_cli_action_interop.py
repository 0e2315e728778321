"""``mros action`` against Debian's SimpleActionServer: list, info, send (feedback and result), Ctrl-C cancels."""

from __future__ import annotations

import asyncio
import signal
import sys

from mrosd import backports
from mrosd.actions import Status
from mrosd.msg import get_message_class
from tests.interop.actions.test_actionlib_interop import lines, needs_actionlib, our_node, rospy_action
from tests.interop.cli.cliutil import mros, mros_env
from tests.rosenv import Processes, iter_lines_until, needs_ros

pytestmark = [needs_ros, needs_actionlib]


async def test_mros_action_send_prints_feedback_and_result_from_debian_server(procs: Processes, rosmaster: str) -> None:
    server = rospy_action(procs, rosmaster, "server")
    assert await lines(server, 1) == ["up"]

    listed = await asyncio.to_thread(mros, rosmaster, procs.tmp, "action", "list")
    assert listed.stdout.split() == ["/test_action"], listed
    info = await asyncio.to_thread(mros, rosmaster, procs.tmp, "action", "info", "/test_action")
    assert "Type: actionlib/TestAction" in info.stdout and "/rospy_action" in info.stdout, info

    sent = await asyncio.to_thread(mros, rosmaster, procs.tmp, "action", "send", "/test_action", "goal: 5")
    assert sent.returncode == 0, sent
    out = sent.stdout
    assert [line.strip() for line in out.splitlines() if line.strip().startswith("feedback: ")] == [
        f"feedback: {i}" for i in range(1, 6)
    ], out
    assert out.rstrip().endswith("status: SUCCEEDED\nresult: 10"), out

    typed = await asyncio.to_thread(
        mros, rosmaster, procs.tmp, "action", "send", "/test_action", "actionlib/TestAction", "{goal: 1}"
    )
    assert typed.stdout.rstrip().endswith("result: 2"), typed


async def test_ctrl_c_on_mros_action_send_cancels_the_goal(procs: Processes, rosmaster: str) -> None:
    server = rospy_action(procs, rosmaster, "server")
    assert await lines(server, 1) == ["up"]
    env = mros_env(rosmaster, procs.tmp)
    sender = procs.start([sys.executable, "-m", "mros_cli.main", "action", "send", "/test_action", "goal: 100"], env)
    got = await asyncio.to_thread(lambda: list(iter_lines_until(sender, 2, 30.0)))
    # the goal runs: its feedback arrives (the first may be lost to rospy's publisher, which answers a new
    # subscriber's header before it adds the connection to those it sends to)
    assert got[0] == "feedback:" and got[1].startswith("  feedback: "), got
    sender.send_signal(signal.SIGINT)
    code = await asyncio.to_thread(sender.wait, 15)
    assert code == 130
    # the server ends the goal PREEMPTED: its status array says so
    status_array = get_message_class("actionlib_msgs/GoalStatusArray")
    async with our_node("watch", rosmaster) as node:
        sub = await node.subscribe("/test_action/status", status_array, queue_size=10)
        async with backports.timeout(15):
            async for msg in sub:
                if [st.status for st in msg.status_list] == [Status.PREEMPTED]:
                    break


async def test_mros_action_cancel_ends_a_debian_clients_goal(procs: Processes, rosmaster: str) -> None:
    server = rospy_action(procs, rosmaster, "server")
    assert await lines(server, 1) == ["up"]
    client = rospy_action(procs, rosmaster, "client", "100")
    assert await lines(client, 2) == ["up", "feedback 1"]
    done = await asyncio.to_thread(mros, rosmaster, procs.tmp, "action", "cancel", "/test_action")
    assert done.returncode == 0, done
    rest = await lines(client, 1)
    while not rest[-1].startswith("done"):
        rest += await lines(client, 1)
    assert rest[-1].startswith("done PREEMPTED"), rest
