"""actionlib's bookkeeping as plain data: goal ids, the server's status list, cancel matching, client states.

No I/O and no asyncio here: the server and client shells feed messages in and publish what these return. The
rules are actionlib's (Debian's python3-actionlib ``action_server.py``, ``server_goal_handle.py``,
``goal_id_generator.py``, ``action_client.py``), restated, so that a rospy or roscpp peer sees exactly what
its own counterpart would send.
"""

from __future__ import annotations

import enum
from collections.abc import Iterator
from dataclasses import dataclass, field

from mrosd.msg import Time


class Status(enum.IntEnum):
    """``actionlib_msgs/GoalStatus`` values."""

    PENDING = 0
    ACTIVE = 1
    PREEMPTED = 2
    SUCCEEDED = 3
    ABORTED = 4
    REJECTED = 5
    PREEMPTING = 6
    RECALLING = 7
    RECALLED = 8
    LOST = 9


#: States after which nothing changes (the goal's result has been, or will never be, published).
TERMINAL = frozenset(
    {Status.PREEMPTED, Status.SUCCEEDED, Status.ABORTED, Status.REJECTED, Status.RECALLED, Status.LOST}
)

#: actionlib's defaults: ``actionlib_status_frequency`` (Hz) and ``~status_list_timeout`` (s, how long a
#: finished goal stays in the status array after its handle is gone).
STATUS_FREQUENCY = 5.0
STATUS_LIST_TIMEOUT = 5.0
#: A goal (or a stored cancel) is held at most this many entries; beyond, the oldest finished ones go first and
#: new goals are rejected (a peer cannot grow the list without bound by sending ids).
MAX_STATUS_ENTRIES = 10_000

#: The text SimpleActionServer gives a goal displaced by a newer one.
PREEMPTED_BY_NEW_GOAL = "This goal was canceled because another goal was received by the simple action server"
#: The text ActionServer gives a goal whose stamp is at or before the last cancel-by-stamp.
CANCELED_BY_STAMP = (
    "This goal handle was canceled by the action server because its timestamp is before the timestamp of the "
    "last cancel request"
)


class GoalIdGenerator:
    """Goal ids as actionlib makes them: ``<node name>-<count>-<secs>.<nsecs>``, stamped with the same time.

    The count is per generator here; actionlib's is per process. Both make ids unique per node, which is all
    a server relies on.
    """

    def __init__(self, name: str) -> None:
        self.name = name
        self.count = 0

    def next(self, now: Time) -> tuple[str, Time]:
        self.count += 1
        return f"{self.name}-{self.count}-{now.secs}.{now.nsecs}", now


def time_key(stamp: Time) -> int:
    return stamp.secs * 1_000_000_000 + stamp.nsecs


def cancel_matches(cancel_id: str, cancel_stamp: Time, goal_id: str, goal_stamp: Time) -> bool:
    """Whether a ``cancel`` GoalID applies to a goal: empty id and zero stamp cancel everything, an id cancels
    that goal, a non-zero stamp cancels every goal stamped at or before it."""
    if not cancel_id and cancel_stamp.is_zero():
        return True
    if cancel_id == goal_id:
        return True
    return not cancel_stamp.is_zero() and time_key(goal_stamp) <= time_key(cancel_stamp)


@dataclass
class Entry:
    """One line of the server's status array.

    ``removed_at``: when the goal finished (or a stored cancel was made); the line leaves the array
    ``STATUS_LIST_TIMEOUT`` later, as actionlib's ``handle_destruction_time``.
    """

    goal_id: str
    stamp: Time
    status: Status
    text: str = ""
    removed_at: float | None = None


@dataclass
class Transition:
    """What a status change asks of the shell: ``cancel`` the goal's coroutine, ``result`` publish one."""

    entry: Entry
    cancel: bool = False
    result: bool = False


@dataclass
class StatusList:
    """The server's goals by id, in arrival order, with actionlib's transitions."""

    timeout: float = STATUS_LIST_TIMEOUT
    max_entries: int = MAX_STATUS_ENTRIES
    entries: dict[str, Entry] = field(default_factory=dict)
    last_cancel: Time = field(default_factory=Time)

    def __iter__(self) -> Iterator[Entry]:
        return iter(self.entries.values())

    def goal_received(self, goal_id: str, stamp: Time, now: Time) -> tuple[Entry | None, Transition | None]:
        """A goal arrived. Returns (new entry to run, or None; a transition to publish, or None).

        A goal already listed is never run twice; one listed as RECALLING (its cancel came first) becomes
        RECALLED with a result. A goal stamped at or before the last cancel-by-stamp is RECALLED at once.
        """
        known = self.entries.get(goal_id)
        if known is not None:
            if known.status is Status.RECALLING:
                known.status = Status.RECALLED
                return None, Transition(known, result=True)
            return None, None
        if len(self.entries) >= self.max_entries:
            self.prune(float("inf"))
        if stamp.is_zero():
            stamp = now
        entry = Entry(goal_id, stamp, Status.PENDING)
        if len(self.entries) >= self.max_entries:
            entry.status, entry.text = Status.REJECTED, "the action server holds too many goals"
            return None, Transition(entry, result=True)
        self.entries[goal_id] = entry
        if not self.last_cancel.is_zero() and time_key(stamp) <= time_key(self.last_cancel):
            entry.status, entry.text = Status.RECALLED, CANCELED_BY_STAMP
            return None, Transition(entry, result=True)
        return entry, None

    def cancel_received(self, cancel_id: str, cancel_stamp: Time, clock: float) -> list[Transition]:
        """A cancel arrived: every matching unfinished goal moves to RECALLING or PREEMPTING (its coroutine is to
        be cancelled); an id not seen yet is stored as RECALLING, so its goal is recalled when it comes."""
        found = False
        out: list[Transition] = []
        for entry in self.entries.values():
            if not cancel_matches(cancel_id, cancel_stamp, entry.goal_id, entry.stamp):
                continue
            found = found or entry.goal_id == cancel_id
            if entry.status is Status.PENDING:
                entry.status = Status.RECALLING
                out.append(Transition(entry, cancel=True))
            elif entry.status is Status.ACTIVE:
                entry.status = Status.PREEMPTING
                out.append(Transition(entry, cancel=True))
        if cancel_id and not found and len(self.entries) < self.max_entries:
            self.entries[cancel_id] = Entry(cancel_id, cancel_stamp, Status.RECALLING, removed_at=clock)
        if time_key(cancel_stamp) > time_key(self.last_cancel):
            self.last_cancel = cancel_stamp
        return out

    def finish(self, entry: Entry, status: Status, text: str, clock: float) -> bool:
        """Move a goal to a terminal state if actionlib allows that transition; True when it moved."""
        current = entry.status
        if status in (Status.SUCCEEDED, Status.ABORTED):
            allowed = current in (Status.ACTIVE, Status.PREEMPTING)
        elif status is Status.REJECTED:
            allowed = current in (Status.PENDING, Status.RECALLING)
        else:  # canceled: RECALLED before it ran, PREEMPTED once it had
            allowed = current in (Status.PENDING, Status.RECALLING, Status.ACTIVE, Status.PREEMPTING)
            if current in (Status.PENDING, Status.RECALLING):
                status = Status.RECALLED
            elif allowed:
                status = Status.PREEMPTED
        if not allowed:
            return False
        entry.status, entry.text, entry.removed_at = status, text, clock
        return True

    def accept(self, entry: Entry) -> None:
        """The server starts the goal: PENDING -> ACTIVE, RECALLING -> PREEMPTING."""
        if entry.status is Status.PENDING:
            entry.status = Status.ACTIVE
        elif entry.status is Status.RECALLING:
            entry.status = Status.PREEMPTING

    def prune(self, clock: float) -> None:
        """Drop lines whose goal finished more than ``timeout`` ago (``clock``: monotonic seconds)."""
        gone = [k for k, e in self.entries.items() if e.removed_at is not None and e.removed_at + self.timeout < clock]
        for key in gone:
            del self.entries[key]
