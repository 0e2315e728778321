"""The drive tabs' computations under node (static/tf.js, actions.js, reconfigure.js, teleop.js): TF composition,
actionlib's goal id and the goal bytes, the edit_method literal parser (hostile texts refused), the description
as groups, the teleop command and its bytes; the bytes checked against mrosd's own serializer."""

from __future__ import annotations

import base64
import json
import math
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

from mrosd.msg import get_message_class
from mrosd.reconfigure import Description, EnumConstant, GroupSpec, Param

HERE = Path(__file__).resolve().parent
NODE = shutil.which("node")
pytestmark = pytest.mark.skipif(NODE is None, reason="node is missing (scripts/install-system-deps.sh)")

#: dynamic_reconfigure's TestConfig edit_method for int_enum_, as its generator writes it
EDIT_METHOD = (
    "{'enum': [{'name': 'Small', 'type': 'int', 'value': 0, 'srcline': 44, 'srcfile': 'Test.cfg', "
    "'description': 'A small constant', 'ctype': 'int', 'cconsttype': 'const int'}, {'name': 'Medium', "
    "'type': 'int', 'value': 1, 'srcline': 45, 'srcfile': 'Test.cfg', 'description': 'A medium value', "
    "'ctype': 'int', 'cconsttype': 'const int'}], 'enum_description': 'An enum to set the size.'}"
)
GOAL_ID = "/mrosd_web/page_x-1-1700000000.123"
GOAL_MS = 1700000000123


@pytest.fixture(scope="module")
def units() -> dict[str, Any]:
    goal = get_message_class("actionlib/TestActionGoal")
    config_desc = get_message_class("dynamic_reconfigure/ConfigDescription")
    config = get_message_class("dynamic_reconfigure/Config")
    description = Description(
        [
            GroupSpec(
                "Default",
                0,
                params=[
                    Param("exposure", "int", 10, min=1, max=1000, description="Exposure"),
                    Param(
                        "mode",
                        "int",
                        0,
                        min=0,
                        max=1,
                        enum=(EnumConstant("Full", 0, "<b>all</b>"), EnumConstant("Roi", 1)),
                    ),
                ],
            ),
            GroupSpec("Info", 1, parent=0, params=[Param("name", "str", "cam"), Param("gain", "double", 1.0)]),
        ]
    )
    payload = {
        "actionGoal": {"type": goal._type, "definition": goal._full_text, "id": GOAL_ID, "ms": GOAL_MS},
        "configDescription": {
            "type": config_desc._type,
            "definition": config_desc._full_text,
            "body": base64.b64encode(description.to_msg().serialize()).decode(),
        },
        "config": {"type": config._type, "definition": config._full_text},
        "editMethod": EDIT_METHOD,
    }
    assert NODE is not None
    done = subprocess.run(
        [NODE, str(HERE / "page_drive_units.mjs")],
        input=json.dumps(payload).encode(),
        capture_output=True,
        timeout=30,
        check=False,
    )
    assert done.returncode == 0, done.stderr.decode()
    result: dict[str, Any] = json.loads(done.stdout)
    return result


def close(a: list[float], b: list[float], tol: float = 1e-12) -> bool:
    return len(a) == len(b) and all(math.isclose(x, y, abs_tol=tol) for x, y in zip(a, b, strict=True))


def test_tf_composes_inverts_and_walks_the_tree(units: dict[str, Any]) -> None:
    tf = units["tf"]
    # base at (1, 2) turned 90 degrees: laser 0.5 ahead of base is at (1, 2.5), 0.2 up.
    assert close(tf["laserInWorld"], [1.0, 2.5, 0.2]) and math.isclose(tf["laserYaw"], math.pi / 2)
    assert close(tf["roundTrip"], [0, 0, 0, 0, 0, 0, 1])
    assert close(tf["invertTwice"], [0, 0.3, 1, math.sin(0.4), 0, 0, math.cos(0.4)])
    # cam: (0, 0.3, 1) in base, rolled 0.8 rad about x; its x axis stays base's x, which is world's y.
    assert close(tf["point"], [1 - 0.3, 2 + 1, 1])
    assert close(tf["camInLaser"][:3], [-0.5, 0.3, 0.8])
    assert tf["otherTree"] is None and tf["loop"] is None
    assert tf["rows"] == ["0:sea", "1:island", "0:world", "1:base", "2:cam", "2:laser"]
    assert tf["slash"] == "base_link"
    store = tf["store"]
    assert math.isclose(store["rate"], 10.0) and store["staticRate"] is None
    assert store["parent"] == "world" and close(store["q"], [0, 0, 0, 1])
    assert store["frames"] == 2000 and not store["self"]  # bounded; a frame that is its own parent is dropped


def test_actions_find_servers_make_actionlibs_goal_id_and_the_goal_bytes(units: dict[str, Any]) -> None:
    actions = units["actions"]
    assert actions["servers"] == [["/test_action", "actionlib/TestAction", True, False]]
    assert actions["goalId"] == "%s-%i-%.3f" % ("/mrosd_web/page_x", 3, 1700000000.1234)  # noqa: UP031 - actionlib writes it so
    assert actions["stamp"] == {"secs": 1700000000, "nsecs": 123000000}
    assert actions["fields"] == [["goal", "int32", None]]
    cls = get_message_class("actionlib/TestActionGoal")
    want = cls()
    want.header.stamp.secs, want.header.stamp.nsecs = 1700000000, 123000000
    want.goal_id.stamp = want.header.stamp
    want.goal_id.id = GOAL_ID
    want.goal.goal = 5
    assert base64.b64decode(actions["bytes"]) == want.serialize()
    assert [e.get("error") for e in actions["errors"]] == [
        "goal: not an integer",
        "goal: not a number",
        "v: a JSON array expected",
    ]


def test_reconfigure_reads_descriptions_and_refuses_hostile_literals(units: dict[str, Any]) -> None:
    rc = units["reconfigure"]
    groups = rc["groups"]
    assert [(g["name"], g["id"], g["parent"]) for g in groups] == [("Default", 0, 0), ("Info", 1, 0)]
    exposure, mode = groups[0]["params"]
    assert (exposure["type"], exposure["min"], exposure["max"], exposure["dflt"], exposure["enum"]) == (
        "int",
        1,
        1000,
        10,
        None,
    )
    assert mode["enum"] == [
        {"name": "Full", "value": 0, "description": "<b>all</b>"},
        {"name": "Roi", "value": 1, "description": ""},
    ]
    assert [p["name"] for p in groups[1]["params"]] == ["name", "gain"]
    literal = rc["literal"]["value"]
    assert [c["name"] for c in literal["enum"]] == ["Small", "Medium"] and literal["enum_description"].startswith(
        "An enum"
    )
    assert all(r != "parsed" for r in rc["hostile"]), rc["hostile"]
    assert rc["plainLiterals"] == {"s": "it's", "t": [1, -2500, True, None, "inf"], "u": "Aé"}
    assert rc["protoKey"]
    config = get_message_class("dynamic_reconfigure/Config").deserialize(base64.b64decode(rc["config"]))
    assert [(p.name, p.value) for p in config.ints] == [("i", 7)] and config.bools[0].value is True
    assert (config.doubles[0].value, config.strs[0].value) == (0.5, "x")
    assert rc["values"] == [["b", False], ["a", 1]]
    assert rc["ranges"] == [True, False, False, False]


def test_teleop_commands_are_clamped_to_the_limits(units: dict[str, Any]) -> None:
    t = units["teleop"]
    assert (t["upLeft"]["linear"]["x"], t["upLeft"]["angular"]["z"]) == (0.5, 0.5)
    assert (t["clamped"]["linear"]["x"], t["clamped"]["angular"]["z"]) == (-0.5, -1.0)
    assert (t["nan"]["linear"]["x"], t["nan"]["angular"]["z"]) in ((0, 0), (-0.0, -0.0))
    assert t["keys"] == [[0, -1], [-1, 0]]
    assert t["limits"] == [0.8, 0.5, 10, 0.5]
    twist = get_message_class("geometry_msgs/Twist")()
    twist.linear.x, twist.angular.z = 0.5, 0.5
    assert base64.b64decode(t["bytes"]) == twist.serialize()
