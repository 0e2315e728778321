"""An action type's seven message classes, found by actionlib's naming (genaction's ``<Action>ActionGoal`` ...)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mrosd.errors import MsgNotFoundError
from mrosd.msg import TypeStore, get_message_class

#: Suffixes genaction gives the types it generates from ``<Name>.action``.
ACTION_SUFFIXES = ("ActionGoal", "ActionResult", "ActionFeedback", "Goal", "Result", "Feedback")


@dataclass(frozen=True)
class ActionSpec:
    """The classes an action's five topics carry (``/goal``, ``/result``, ``/feedback``; ``/cancel`` and
    ``/status`` are always ``actionlib_msgs``)."""

    name: str
    action_goal: Any
    action_result: Any
    action_feedback: Any
    goal: Any
    result: Any
    feedback: Any

    @classmethod
    def load(cls, action_type: str, store: TypeStore | None = None) -> ActionSpec:
        """``pkg/Name`` or ``pkg/NameAction`` -> its classes (shipped, ``-I``, ROS_PACKAGE_PATH or system).

        Raises:
            MsgNotFoundError: a generated type of the action is not found.
        """
        base = action_type.removesuffix("Action")
        try:
            classes = [get_message_class(base + suffix, store) for suffix in ACTION_SUFFIXES]
        except MsgNotFoundError as exc:
            raise MsgNotFoundError(f"action type {action_type!r}: {exc}") from exc
        return cls(base + "Action", *classes)


def action_type_of_goal(goal_type: str) -> str | None:
    """``actionlib/TestActionGoal`` (a ``/goal`` topic's type) -> ``actionlib/TestAction``."""
    return goal_type.removesuffix("Goal") if goal_type.endswith("ActionGoal") else None
