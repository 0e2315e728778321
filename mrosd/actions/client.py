"""ActionClient: send goals to an actionlib server; each goal is a handle to await, iterate and cancel.

A goal the server stops reporting ends LOST, as actionlib's client decides it: the goal vanished from a status
array after the server had listed it, or (the server died, so no array comes at all) no status array arrived
for ``lost_after`` seconds while the goal was unfinished.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections import deque
from collections.abc import AsyncIterator, Generator
from typing import TYPE_CHECKING, Any

from mrosd import backports
from mrosd.actions.spec import ActionSpec
from mrosd.actions.status import TERMINAL, GoalIdGenerator, Status
from mrosd.msg import Time, get_message_class

if TYPE_CHECKING:
    from mrosd.tcpros import Node, Publisher, Subscriber

GoalID = get_message_class("actionlib_msgs/GoalID")
GoalStatusArray = get_message_class("actionlib_msgs/GoalStatusArray")
Header = get_message_class("std_msgs/Header")

#: Feedback messages a handle keeps for its iterator; beyond, the oldest are dropped (counted).
FEEDBACK_QUEUE = 100
#: Silence on /status after which unfinished goals are LOST: ten periods at actionlib's default 5 Hz.
LOST_AFTER = 2.0
#: Goals a client tracks at once (finished ones are forgotten when their result is taken).
MAX_GOALS = 10_000


class ClientGoal:
    """A goal sent: ``await handle`` gives the result message (None when LOST), ``async for fb in
    handle.feedback()`` its feedback until it ends, ``await handle.cancel()`` asks the server to cancel it."""

    def __init__(self, client: ActionClient, goal_id: str, stamp: Time) -> None:
        self._client = client
        self.id = goal_id
        self.stamp = stamp
        self.status: Status = Status.PENDING
        self.text = ""
        self.result: Any = None
        self.acknowledged = False
        self.feedback_dropped = 0
        self._feedback: deque[Any] = deque(maxlen=FEEDBACK_QUEUE)
        self._wake = asyncio.Event()
        self.done = asyncio.Event()

    def _push_feedback(self, fb: Any) -> None:
        if len(self._feedback) == FEEDBACK_QUEUE:
            self.feedback_dropped += 1
        self._feedback.append(fb)
        self._wake.set()

    def _end(self, status: Status, text: str, result: Any) -> None:
        if self.done.is_set():
            return
        self.status, self.text, self.result = status, text, result
        self.done.set()
        self._wake.set()
        self._client.goals.pop(self.id, None)

    async def feedback(self) -> AsyncIterator[Any]:
        """Each feedback message (``<Action>Feedback``) as it comes, until the goal ends."""
        while True:
            while self._feedback:
                yield self._feedback.popleft()
            if self.done.is_set():
                return
            self._wake.clear()
            await self._wake.wait()

    async def wait(self, timeout: float | None = None) -> Any:
        """The result message once the goal ends (None when LOST).

        Raises:
            TimeoutError: not ended within ``timeout`` seconds.
        """
        async with backports.timeout(timeout):
            await self.done.wait()
        return self.result

    def __await__(self) -> Generator[Any, None, Any]:
        return self.wait().__await__()

    async def cancel(self) -> None:
        """Ask the server to cancel this goal (the handle ends when the server reports it, PREEMPTED or RECALLED)."""
        await self._client.cancel(goal_id=self.id)


class ActionClient:
    """A client of the action server at ``name`` (its five topics ``name/goal`` ... ``name/status``)."""

    def __init__(self, node: Node, name: str, action_type: str | ActionSpec, *, lost_after: float = LOST_AFTER) -> None:
        self.node = node
        self.ns = node.resolve_name(name)
        self.spec = action_type if isinstance(action_type, ActionSpec) else ActionSpec.load(action_type)
        self.lost_after = lost_after
        self.ids = GoalIdGenerator(node.name)
        self.goals: dict[str, ClientGoal] = {}
        self._pubs: dict[str, Publisher] = {}
        self._subs: dict[str, Subscriber] = {}
        self._status_seen = asyncio.Event()
        self._last_status = 0.0
        self._watchdog: asyncio.Task[None] | None = None

    async def start(self) -> ActionClient:
        node, ns = self.node, self.ns
        self._pubs["goal"] = await node.advertise(f"{ns}/goal", self.spec.action_goal, queue_size=10)
        self._pubs["cancel"] = await node.advertise(f"{ns}/cancel", GoalID, queue_size=10)
        self._subs["status"] = await node.subscribe(f"{ns}/status", GoalStatusArray, self._status_cb)
        self._subs["result"] = await node.subscribe(f"{ns}/result", self.spec.action_result, self._result_cb)
        self._subs["feedback"] = await node.subscribe(f"{ns}/feedback", self.spec.action_feedback, self._feedback_cb)
        self._watchdog = asyncio.create_task(self._watch(), name=f"action client {ns}")
        return self

    async def aclose(self) -> None:
        if self._watchdog is not None:
            self._watchdog.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._watchdog
        for sub in self._subs.values():
            await sub.aclose()
        for pub in self._pubs.values():
            await pub.aclose()

    async def __aenter__(self) -> ActionClient:
        return await self.start()

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()

    async def wait_for_server(self, timeout: float = 10.0) -> None:
        """Wait until the server is connected both ways and has sent a status array.

        Raises:
            TimeoutError: the server did not appear within ``timeout`` seconds.
        """
        async with backports.timeout(timeout):
            await self._pubs["goal"].wait_for_subscribers(1, timeout)
            await self._pubs["cancel"].wait_for_subscribers(1, timeout)
            for sub in self._subs.values():
                await sub.wait_for_publishers(1, timeout)
            await self._status_seen.wait()

    async def send_goal(self, goal: Any) -> ClientGoal:
        """Publish ``goal`` (an ``<Action>Goal``) with a fresh id; the handle follows it to its end."""
        if len(self.goals) >= MAX_GOALS:
            raise RuntimeError(f"{self.ns}: {MAX_GOALS} goals unfinished; await or cancel some first")
        goal_id, stamp = self.ids.next(Time.now())
        handle = ClientGoal(self, goal_id, stamp)
        self.goals[goal_id] = handle
        msg = self.spec.action_goal(header=Header(stamp=stamp), goal_id=GoalID(stamp=stamp, id=goal_id), goal=goal)
        self._last_status = max(self._last_status, asyncio.get_running_loop().time())
        await self._pubs["goal"].publish(msg)
        return handle

    async def cancel(self, goal_id: str = "", stamp: Time | None = None) -> None:
        """Cancel one goal by id, every goal stamped at or before ``stamp``, or (neither given) every goal."""
        await self._pubs["cancel"].publish(GoalID(stamp=stamp or Time(), id=goal_id))

    async def cancel_all(self) -> None:
        await self.cancel()

    # --- topics ----------------------------------------------------------------------------------

    def _status_cb(self, msg: Any) -> None:
        self._last_status = asyncio.get_running_loop().time()
        self._status_seen.set()
        listed = {st.goal_id.id: st for st in msg.status_list}
        for handle in list(self.goals.values()):
            st = listed.get(handle.id)
            if st is None:
                if handle.acknowledged and handle.status not in TERMINAL:
                    handle._end(Status.LOST, "the server no longer lists this goal", None)
                continue
            handle.acknowledged = True
            if handle.status not in TERMINAL:
                handle.status, handle.text = Status(st.status) if 0 <= st.status <= 9 else handle.status, st.text

    def _result_cb(self, msg: Any) -> None:
        handle = self.goals.get(msg.status.goal_id.id)
        if handle is None:
            return
        code = msg.status.status
        status = Status(code) if 0 <= code <= 9 else Status.LOST
        handle._end(status, msg.status.text, msg.result)

    def _feedback_cb(self, msg: Any) -> None:
        handle = self.goals.get(msg.status.goal_id.id)
        if handle is not None and not handle.done.is_set():
            handle._push_feedback(msg.feedback)

    async def _watch(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            await asyncio.sleep(self.lost_after / 4)
            if self.goals and loop.time() - self._last_status > self.lost_after:
                for handle in list(self.goals.values()):
                    handle._end(Status.LOST, f"no status from the server for {self.lost_after:g} s", None)
