"""ActionServer: actionlib's server on the five topics, each goal a coroutine.

``simple=True`` (the default) is SimpleActionServer's policy: one goal runs at a time; a newer goal preempts it
(the running coroutine is cancelled, its goal ends PREEMPTED) and waits as the next goal; a goal displaced from
that slot, or older than the one running, ends RECALLED. ``simple=False`` runs every goal at once, as a plain
actionlib ActionServer whose goal callback accepts every goal.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any

from mrosd.actions.spec import ActionSpec
from mrosd.actions.status import (
    MAX_STATUS_ENTRIES,
    PREEMPTED_BY_NEW_GOAL,
    STATUS_FREQUENCY,
    STATUS_LIST_TIMEOUT,
    Entry,
    Status,
    StatusList,
    Transition,
    time_key,
)
from mrosd.lograte import RateLimitedLog
from mrosd.msg import Time, get_message_class

if TYPE_CHECKING:
    from mrosd.tcpros import Node, Publisher, Subscriber

log = logging.getLogger(__name__)
_peer_log = RateLimitedLog(log)

GoalID = get_message_class("actionlib_msgs/GoalID")
GoalStatus = get_message_class("actionlib_msgs/GoalStatus")
GoalStatusArray = get_message_class("actionlib_msgs/GoalStatusArray")
Header = get_message_class("std_msgs/Header")

#: actionlib's ``actionlib_server_pub_queue_size`` default.
PUB_QUEUE_SIZE = 50
#: Goals and cancels waiting for the server's task; beyond, the subscriber's own drop-oldest applies.
SUB_QUEUE_SIZE = 100


class ServerGoal:
    """One goal as its coroutine sees it: the goal message, its id and stamp, and feedback."""

    def __init__(self, server: ActionServer, entry: Entry, goal: Any) -> None:
        self._server = server
        self._entry = entry
        self.goal = goal
        self.id = entry.goal_id
        self.stamp = entry.stamp

    @property
    def status(self) -> Status:
        return self._entry.status

    @property
    def cancel_requested(self) -> bool:
        return self._entry.status in (Status.PREEMPTING, Status.RECALLING)

    def publish_feedback(self, feedback: Any) -> None:
        """Send one feedback message for this goal (never waits; a slow subscriber loses the oldest)."""
        self._server.publish_feedback(self._entry, feedback)


Execute = Callable[[ServerGoal], Awaitable[Any]]


class ActionServer:
    """Serve ``action_type`` under ``name``: ``execute(goal)`` returns the result message (or None for an empty
    one); raising ends the goal ABORTED with the exception's text; a cancel (or preemption) cancels it and the
    goal ends PREEMPTED, or SUCCEEDED if the coroutine catches the cancellation and returns a result."""

    def __init__(
        self,
        node: Node,
        name: str,
        action_type: str | ActionSpec,
        execute: Execute,
        *,
        simple: bool = True,
        status_frequency: float = STATUS_FREQUENCY,
        status_list_timeout: float = STATUS_LIST_TIMEOUT,
        max_goals: int = MAX_STATUS_ENTRIES,
    ) -> None:
        self.node = node
        self.ns = node.resolve_name(name)
        self.spec = action_type if isinstance(action_type, ActionSpec) else ActionSpec.load(action_type)
        self.execute = execute
        self.simple = simple
        self.status_frequency = status_frequency
        self.status = StatusList(timeout=status_list_timeout, max_entries=max_goals)
        self.tasks: dict[str, asyncio.Task[None]] = {}
        self._current: Entry | None = None
        self._next: tuple[Entry, Any] | None = None
        self._pubs: dict[str, Publisher] = {}
        self._subs: list[Subscriber] = []
        self._timer: asyncio.Task[None] | None = None
        self._closed = False

    async def start(self) -> ActionServer:
        node, ns = self.node, self.ns
        self._pubs["status"] = await node.advertise(
            f"{ns}/status", GoalStatusArray, latch=True, queue_size=PUB_QUEUE_SIZE
        )
        self._pubs["result"] = await node.advertise(f"{ns}/result", self.spec.action_result, queue_size=PUB_QUEUE_SIZE)
        self._pubs["feedback"] = await node.advertise(
            f"{ns}/feedback", self.spec.action_feedback, queue_size=PUB_QUEUE_SIZE
        )
        self._subs.append(
            await node.subscribe(f"{ns}/goal", self.spec.action_goal, self._goal_cb, queue_size=SUB_QUEUE_SIZE)
        )
        self._subs.append(await node.subscribe(f"{ns}/cancel", GoalID, self._cancel_cb, queue_size=SUB_QUEUE_SIZE))
        self.publish_status()
        if self.status_frequency > 0:
            self._timer = asyncio.create_task(self._status_loop(), name=f"action status {ns}")
        return self

    async def aclose(self) -> None:
        self._closed = True
        tasks = [t for t in (self._timer, *self.tasks.values()) if t is not None]
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        for sub in self._subs:
            await sub.aclose()
        for pub in self._pubs.values():
            await pub.aclose()

    async def __aenter__(self) -> ActionServer:
        return await self.start()

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()

    # --- publishing ------------------------------------------------------------------------------

    def _status_msg(self, entry: Entry) -> Any:
        return GoalStatus(
            goal_id=GoalID(stamp=entry.stamp, id=entry.goal_id), status=int(entry.status), text=entry.text
        )

    def publish_status(self) -> None:
        self.status.prune(asyncio.get_running_loop().time())
        msg = GoalStatusArray(header=Header(stamp=Time.now()), status_list=[self._status_msg(e) for e in self.status])
        self._pubs["status"].publish_nowait(msg)

    def publish_feedback(self, entry: Entry, feedback: Any) -> None:
        msg = self.spec.action_feedback(
            header=Header(stamp=Time.now()), status=self._status_msg(entry), feedback=feedback
        )
        self._pubs["feedback"].publish_nowait(msg)

    def _publish_result(self, entry: Entry, result: Any = None) -> None:
        msg = self.spec.action_result(
            header=Header(stamp=Time.now()),
            status=self._status_msg(entry),
            result=self.spec.result() if result is None else result,
        )
        self._pubs["result"].publish_nowait(msg)
        self.publish_status()

    async def _status_loop(self) -> None:
        period = 1.0 / self.status_frequency
        while True:
            await asyncio.sleep(period)
            self.publish_status()

    def _finish(self, entry: Entry, status: Status, text: str = "", result: Any = None) -> None:
        if self.status.finish(entry, status, text, asyncio.get_running_loop().time()):
            self._publish_result(entry, result)

    # --- goals and cancels -----------------------------------------------------------------------

    def _goal_cb(self, msg: Any) -> None:
        if self._closed:
            return
        entry, transition = self.status.goal_received(msg.goal_id.id, msg.goal_id.stamp, Time.now())
        if transition is not None:
            self._publish_result(transition.entry)
        if entry is None:
            return
        if not self.simple:
            self._run(entry, msg.goal)
            return
        key = time_key(entry.stamp)
        current, pending = self._current, self._next
        if (current is not None and key < time_key(current.stamp)) or (
            pending is not None and key < time_key(pending[0].stamp)
        ):
            self._finish(entry, Status.RECALLED, PREEMPTED_BY_NEW_GOAL)
            return
        if pending is not None:
            self._finish(pending[0], Status.RECALLED, PREEMPTED_BY_NEW_GOAL)
        self._next = (entry, msg.goal)
        if current is not None:
            task = self.tasks.get(current.goal_id)
            if task is not None:
                task.cancel(PREEMPTED_BY_NEW_GOAL)
        else:
            self._start_next()
        self.publish_status()

    def _start_next(self) -> None:
        if self._next is None or self._closed:
            return
        entry, goal = self._next
        self._next = None
        if entry.status not in (Status.PENDING, Status.RECALLING):
            return
        self._current = entry
        self._run(entry, goal)

    def _cancel_cb(self, msg: Any) -> None:
        if self._closed:
            return
        transitions: list[Transition] = self.status.cancel_received(
            msg.id, msg.stamp, asyncio.get_running_loop().time()
        )
        for transition in transitions:
            entry = transition.entry
            task = self.tasks.get(entry.goal_id)
            if task is not None:
                task.cancel()
            elif self._next is not None and self._next[0] is entry:
                self._next = None
                self._finish(entry, Status.RECALLED)
        if transitions:
            self.publish_status()

    def _run(self, entry: Entry, goal: Any) -> None:
        self.status.accept(entry)
        handle = ServerGoal(self, entry, goal)
        task = asyncio.create_task(self._execute(entry, handle), name=f"action goal {entry.goal_id}")
        self.tasks[entry.goal_id] = task
        self.publish_status()
        if entry.status is Status.PREEMPTING:  # its cancel came before the goal
            task.cancel()

    async def _execute(self, entry: Entry, handle: ServerGoal) -> None:
        try:
            try:
                result = await self.execute(handle)
            except asyncio.CancelledError as exc:
                if self._closed:
                    raise
                self._finish(entry, Status.PREEMPTED, exc.args[0] if exc.args else "")
            except Exception as exc:  # the user's code failed: the goal ends ABORTED, the server lives on
                _peer_log.warning(f"execute {self.ns}", "%s: goal %s aborted: %r", self.ns, entry.goal_id, exc)
                self._finish(entry, Status.ABORTED, str(exc) or type(exc).__name__)
            else:
                self._finish(entry, Status.SUCCEEDED, "", result)
        finally:
            self.tasks.pop(entry.goal_id, None)
            if self._current is entry:
                self._current = None
                if not self._closed:
                    self._start_next()
