"""genaction's rules reproduce actionlib's generated TestAction types: same texts, same md5s."""

from __future__ import annotations

import pytest

from mrosd.actions import ActionSpec
from mrosd.errors import MsgParseError
from mrosd.msg import TypeStore, get_message_class
from mrosd.msg.action import generate_action
from mrosd.msg.typestore import BUILTIN_DIR

TEST_ACTION = "int32 goal\n---\nint32 result\n---\nint32 feedback\n"


def test_generated_texts_are_the_shipped_generated_files() -> None:
    generated = generate_action("actionlib/Test", TEST_ACTION)
    assert len(generated) == 7
    for name, text in generated.items():
        shipped = (BUILTIN_DIR / "actionlib" / "msg" / f"{name.split('/')[1]}.msg").read_text()
        assert text.strip() == shipped.strip(), name


def test_classes_from_the_action_text_have_actionlibs_md5s() -> None:
    spec = ActionSpec.from_action("actionlib/TestAction", TEST_ACTION)
    store = TypeStore(ros_package_path="", system_dirs=())
    for cls in (spec.action_goal, spec.action_result, spec.action_feedback, spec.goal, spec.result, spec.feedback):
        assert cls._md5sum == get_message_class(cls._type, store)._md5sum, cls._type


def test_an_action_without_three_sections_is_refused() -> None:
    with pytest.raises(MsgParseError, match="has 2 sections"):
        generate_action("pkg/Bad", "int32 a\n---\nint32 b\n")


def test_an_action_nobody_generated_gets_its_classes_from_its_text() -> None:
    spec = ActionSpec.from_action("mypkg/Dock", "float64 x\n---\nbool ok\n---\nfloat64 distance\n")
    goal = spec.action_goal(goal=spec.goal(x=1.5))
    back = spec.action_goal.deserialize(goal.serialize())
    assert (spec.action_goal._type, back.goal.x) == ("mypkg/DockActionGoal", 1.5)
    assert spec.action_feedback.__struct_fields__ == ("header", "status", "feedback")
