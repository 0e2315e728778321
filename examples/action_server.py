"""Serve ``actionlib/TestAction`` at ``/test_action``: one feedback a step counting up to the goal, result 2 x goal.

    python examples/action_server.py [__name:=test_action_server]

A newer goal preempts the running one (SimpleActionServer's policy); a cancel ends it PREEMPTED.
"""

from __future__ import annotations

import asyncio

import mrosd
from mrosd.actions import ActionServer, ServerGoal
from mrosd.msg import get_message_class

TestFeedback = get_message_class("actionlib/TestFeedback")
TestResult = get_message_class("actionlib/TestResult")

#: Seconds between steps.
STEP = 0.2


async def execute(goal: ServerGoal) -> object:
    for step in range(1, goal.goal.goal + 1):
        goal.publish_feedback(TestFeedback(feedback=step))
        await asyncio.sleep(STEP)
    return TestResult(result=2 * goal.goal.goal)


async def main() -> None:
    async with (
        mrosd.Node("test_action_server") as node,
        ActionServer(node, "/test_action", "actionlib/TestAction", execute),
    ):
        await node.spin()


if __name__ == "__main__":
    mrosd.run(main)
