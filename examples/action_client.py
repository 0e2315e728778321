"""Send one ``actionlib/TestAction`` goal to ``/test_action``; print its feedback and result.

    python examples/action_client.py [GOAL]

Ctrl-C cancels the goal on the server before exiting.
"""

from __future__ import annotations

import sys

import mrosd
from mrosd.actions import ActionClient
from mrosd.msg import get_message_class

TestGoal = get_message_class("actionlib/TestGoal")


async def main() -> None:
    target = int(sys.argv[1]) if len(sys.argv) > 1 and sys.argv[1].lstrip("-").isdigit() else 5
    async with (
        mrosd.Node("test_action_client") as node,
        ActionClient(node, "/test_action", "actionlib/TestAction") as client,
    ):
        await client.wait_for_server(timeout=10.0)
        goal = await client.send_goal(TestGoal(goal=target))
        try:
            async for feedback in goal.feedback():
                print(f"feedback: {feedback.feedback}", flush=True)
            result = await goal
        finally:
            if not goal.done.is_set():
                await goal.cancel()
        print(f"{goal.status.name}: result {None if result is None else result.result}", flush=True)


if __name__ == "__main__":
    mrosd.run(main)
