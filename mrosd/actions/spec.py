"""An action type's seven message classes, found by actionlib's naming (genaction's ``<Action>ActionGoal`` ...)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mrosd.errors import MsgNotFoundError
from mrosd.msg import TypeStore, get_message_class, load_type
from mrosd.msg.action import action_definition, generate_action

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
    def from_action(cls, action_type: str, text: str) -> ActionSpec:
        """Classes from a ``.action`` file's text by genaction's rules (no generated .msg files needed).

        Raises:
            MsgParseError: the text is not an action definition.
        """
        base = action_type.removesuffix("Action")
        generated = generate_action(base, text)
        classes = [load_type(base + s, action_definition(generated, base + s)) for s in ACTION_SUFFIXES]
        return cls(base + "Action", *classes)

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
