"""Sans-IO parts of the slave API and of /rosout: argument checks under any input, level mappings."""

from __future__ import annotations

import asyncio
import logging
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mrosd.tcpros.rosout import get_loggers, level_name, log_level_byte, set_logger_level
from mrosd.tcpros.slave import SlaveApi


class Owner:
    """The smallest SlaveOwner: no topics, records what the slave API reports."""

    name = "/n"
    master_uri = "http://m:11311/"
    host = "127.0.0.1"
    tcpros_port = 1
    uri = "http://127.0.0.1:2/"

    def __init__(self) -> None:
        self.publishers: dict[str, Any] = {}
        self.subscribers: dict[str, Any] = {}
        self.services: dict[str, Any] = {}
        self.params: list[tuple[str, Any]] = []
        self.shutdowns: list[str] = []

    def shutdown_requested(self, reason: str) -> None:
        self.shutdowns.append(reason)

    def param_update(self, key: str, value: Any) -> bool:
        self.params.append((key, value))
        return key == "/subscribed"


xmlrpc_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**31), 2**31 - 1) | st.text(max_size=20) | st.floats(allow_nan=False),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=5), inner, max_size=3),
    max_leaves=8,
)


@settings(max_examples=200, deadline=None)
@given(method=st.sampled_from(sorted(SlaveApi(Owner()).methods())), args=st.lists(xmlrpc_values, max_size=5))
def test_any_arguments_get_a_status_triple_never_an_exception(method: str, args: list[Any]) -> None:
    handler = SlaveApi(Owner()).methods()[method]
    reply = asyncio.run(handler(*args))
    assert isinstance(reply, list) and len(reply) == 3 and reply[0] in (-1, 0, 1)
    if not args or not isinstance(args[0], str):
        assert reply[0] == -1


async def test_param_update_answers_minus_one_unless_the_owner_subscribes_the_key() -> None:
    owner = Owner()
    update = SlaveApi(owner).methods()["paramUpdate"]
    assert (await update("/m", "/subscribed", 1))[0] == 1
    assert (await update("/m", "/other", 1))[0] == -1
    assert (await update("/m", "relative", 1))[0] == -1  # never reaches the owner
    assert owner.params == [("/subscribed", 1), ("/other", 1)]


def test_log_levels_map_as_rospys() -> None:
    assert [log_level_byte(lv) for lv in (10, 20, 30, 40, 50)] == [1, 2, 4, 8, 16]
    assert [log_level_byte(lv) for lv in (5, 25, 45, 60)] == [1, 2, 8, 16]  # in between: round down
    assert [level_name(lv) for lv in (10, 20, 30, 40, 50)] == ["debug", "info", "warn", "error", "fatal"]


def test_set_logger_level_takes_roscpp_names_and_refuses_others() -> None:
    logger = logging.getLogger("mrosd.test.levels")
    set_logger_level("mrosd.test.levels", "WARN")
    assert logger.level == logging.WARNING
    assert ("mrosd.test.levels", "warn") in get_loggers()
    with pytest.raises(ValueError, match="unknown logger level"):
        set_logger_level("mrosd.test.levels", "loud")
