"""dynamic_reconfigure's description and config rules without a network."""

from __future__ import annotations

import math
import re

import pytest

from mrosd.reconfigure import Description, EnumConstant, GroupSpec, Param, ReconfigureError
from mrosd.reconfigure.description import MAX_EDIT_METHOD, config_values, encode_config, parse_edit_method

DESCRIPTION = Description(
    [
        GroupSpec(
            "Default",
            0,
            params=[
                Param("n", "int", 1, min=0, max=10, level=1),
                Param("x", "double", 0.5, level=2),
                Param("on", "bool", False, level=4),
                Param("mode", "int", 0, enum=(EnumConstant("A", 0), EnumConstant("B", 3))),
            ],
        )
    ]
)


def test_values_convert_as_the_python_client_converts_them() -> None:
    assert DESCRIPTION.check("n", "7") == 7
    assert DESCRIPTION.check("x", 2) == 2.0 and isinstance(DESCRIPTION.check("x", 2), float)
    assert DESCRIPTION.check("on", "yes") is True
    assert DESCRIPTION.check("mode", "b") == 3  # enum names, any case


@pytest.mark.parametrize(
    ("name", "value", "text"),
    [
        ("nope", 1, "don't know parameter: nope"),
        ("n", 11, "out of its range [0, 10]"),
        ("n", 1.5, "is not an integer"),
        ("n", "many", "can't set parameter 'n'"),
        ("mode", 1, "not one of its constants"),
        ("x", math.nan, "cannot be NaN"),
    ],
)
def test_values_that_do_not_fit_are_refused_with_what_to_fix(name: str, value: object, text: str) -> None:
    with pytest.raises(ReconfigureError, match=re.escape(text)):
        DESCRIPTION.check(name, value)


def test_a_description_survives_its_message_with_enums_and_unbounded_numbers() -> None:
    back = Description.from_msg(DESCRIPTION.to_msg())
    x = back.param("x")
    assert x is not None and (x.min, x.max, x.default) == (-math.inf, math.inf, 0.5)
    mode = back.param("mode")
    assert mode is not None and [(c.name, c.value) for c in mode.enum] == [("A", 0), ("B", 3)]


def test_config_arrays_follow_the_value_types_and_clamp_and_level_follow_the_server() -> None:
    msg = encode_config({"n": 3, "x": 1.0, "on": True, "s": "t"})
    assert ([p.name for p in msg.ints], [p.name for p in msg.doubles], [p.name for p in msg.bools]) == (
        ["n"],
        ["x"],
        ["on"],
    )
    assert config_values(msg) == {"n": 3, "x": 1.0, "on": True, "s": "t"}
    config = {"n": 50, "x": 0.5, "on": True, "mode": 0}
    DESCRIPTION.clamp(config)
    assert config["n"] == 10
    assert DESCRIPTION.level(config, DESCRIPTION.defaults()) == 1 | 4


def test_a_peers_edit_method_is_parsed_as_a_literal_never_run_and_bounded() -> None:
    assert parse_edit_method("__import__('os').system('true')") == ((), "")
    assert parse_edit_method("{'enum': [" + "{'name': 'a', 'value': 1}, " * (MAX_EDIT_METHOD // 20) + "]}") == ((), "")
    consts, text = parse_edit_method(
        "{'enum': [{'name': 'Small', 'value': 0, 'description': 's'}], 'enum_description': 'd'}"
    )
    assert consts == (EnumConstant("Small", 0, "s"),) and text == "d"
