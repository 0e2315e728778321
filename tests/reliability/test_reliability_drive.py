"""Hostile peers against mrosd's action server, action client, TF buffer and reconfigure server (real sockets,
our master): every bound holds and each keeps serving the honest peer afterwards."""

from __future__ import annotations

import asyncio
import math
from collections.abc import AsyncIterator
from typing import Any

import pytest

from mrosd import backports
from mrosd.actions import ActionClient, ActionServer, ServerGoal, Status
from mrosd.master import Master
from mrosd.msg import Time, get_message_class
from mrosd.tf import Buffer, transform_stamped
from tests.web.inloop import node

ActionGoal = get_message_class("actionlib/TestActionGoal")
ActionResult = get_message_class("actionlib/TestActionResult")
GoalMsg = get_message_class("actionlib/TestGoal")
ResultMsg = get_message_class("actionlib/TestResult")
GoalID = get_message_class("actionlib_msgs/GoalID")
TFMessage = get_message_class("tf2_msgs/TFMessage")


@pytest.fixture
async def master() -> AsyncIterator[str]:
    async with Master(host="127.0.0.1", port=0) as m:
        yield m.uri


async def ended(results: Any, goal_id: str, status: Status) -> None:
    """Until the result of ``goal_id`` arrives with ``status`` (bounded; the server's result queue drops the
    oldest of a burst, never the newest)."""
    async with backports.timeout(15):
        async for msg in results:
            if msg.status.goal_id.id == goal_id:
                assert msg.status.status == status
                return


async def test_a_goal_id_flood_is_bounded_and_the_honest_client_is_still_served(master: str) -> None:
    forever = asyncio.Event()

    async def execute(goal: ServerGoal) -> Any:
        if goal.goal.goal < 0:
            await forever.wait()  # the flood's goals never finish on their own
        return ResultMsg(result=2 * goal.goal.goal)

    async with (
        node("server", master) as srv_node,
        ActionServer(srv_node, "/act", "actionlib/TestAction", execute, simple=False, max_goals=50) as server,
        node("rogue", master) as rogue,
    ):
        results = await rogue.subscribe("/act/result", ActionResult, queue_size=1000)
        goals = await rogue.advertise("/act/goal", ActionGoal, queue_size=1000)
        cancels = await rogue.advertise("/act/cancel", GoalID, queue_size=1000)
        await goals.wait_for_subscribers(1, 10)
        await cancels.wait_for_subscribers(1, 10)
        await results.wait_for_publishers(1, 10)
        for i in range(400):
            await goals.publish(ActionGoal(goal_id=GoalID(id=f"flood-{i}", stamp=Time(1, i)), goal=GoalMsg(goal=-1)))
            await cancels.publish(GoalID(id=f"never-{i}"))  # stored cancels for ids that never come
        await ended(results, "flood-399", Status.REJECTED)  # the goals beyond the bound
        assert len(server.status.entries) <= 50 and len(server.tasks) <= 50
        # the flood is cancelled by stamp; the honest client then gets its goal served
        await cancels.publish(GoalID(stamp=Time(1, 10**6)))
        last = max(server.tasks, key=lambda goal_id: int(goal_id.split("-")[1]))
        await ended(results, last, Status.PREEMPTED)
        assert not server.tasks
        server.status.prune(math.inf)
        async with node("client", master) as cli_node, ActionClient(cli_node, "/act", "actionlib/TestAction") as cli:
            await cli.wait_for_server(10)
            goal = await cli.send_goal(GoalMsg(goal=4))
            assert (await goal.wait(10)).result == 8 and goal.status is Status.SUCCEEDED


async def test_a_tf_publisher_sending_nan_self_loops_and_endless_frames_is_bounded(master: str) -> None:
    async with node("listener", master) as lst, Buffer(lst) as buffer, node("rogue_tf", master) as rogue:
        buffer.core.frames.clear()
        pub = await rogue.advertise("/tf", TFMessage, queue_size=1000)
        await pub.wait_for_subscribers(1, 10)
        ok = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
        bad = [
            transform_stamped("a", "a", 1, ok),
            transform_stamped("a", "b", 1, (math.nan, *ok[1:])),
            transform_stamped("", "c", 1, ok),
        ]
        await pub.publish(TFMessage(transforms=bad))
        await pub.publish(TFMessage(transforms=[transform_stamped("world", "robot", 5, ok)]))
        t = await buffer.wait_for_transform("world", "robot", timeout=10)
        assert t.header.stamp == Time(0, 5)
        assert set(buffer.core.frames) == {"robot"} and buffer.core.rejected == 3
