"""Watching the graph: the long-poll handler (in memory) and the pure snapshot diff used by ``mros graph watch``."""

from __future__ import annotations

import asyncio
from typing import Any

import pytest

from mrosd import backports
from mrosd.errors import MasterError
from mrosd.master.api import WATCH_MAX_PER_CALLER, MasterApi
from mrosd.master.client import GraphChange, GraphSnapshot, graph_changes

API = "http://127.0.0.1:1001/"


async def wait(m: MasterApi, *args: Any) -> Any:
    return await m.methods["waitSystemStateChange"](*args)


async def test_the_long_poll_answers_at_once_when_the_version_differs_and_on_the_next_change() -> None:
    m = MasterApi(None)
    code, _, (version, state, types) = await wait(m, "/w", -1, 10)
    assert code == 1 and state == [[], [], []] and types == []
    waiter = asyncio.ensure_future(wait(m, "/w", version, 10))
    await asyncio.sleep(0)
    assert not waiter.done()
    m.sync_methods["registerPublisher"]("/talker", "/chatter", "std_msgs/String", API)
    code, _, (new_version, state, types) = await backports.wait_for(waiter, 5)
    assert new_version != version
    assert state[0] == [["/chatter", ["/talker"]]] and types == [["/chatter", "std_msgs/String"]]


async def test_the_long_poll_returns_the_unchanged_state_after_its_timeout() -> None:
    m = MasterApi(None)
    version = (await wait(m, "/w", -1, 0))[2][0]
    assert (await wait(m, "/w", version, 0.01))[2][0] == version


async def test_waiters_are_bounded_per_caller_and_bad_arguments_answer_minus_one() -> None:
    m = MasterApi(None)
    version = (await wait(m, "/w", -1, 0))[2][0]
    waiters = [asyncio.ensure_future(wait(m, "/w", version, 10)) for _ in range(WATCH_MAX_PER_CALLER)]
    await asyncio.sleep(0)
    assert (await wait(m, "/w", version, 10))[0] == -1
    m.sync_methods["registerSubscriber"]("/l", "/t", "std_msgs/String", API)
    assert all(r[0] == 1 for r in await backports.wait_for(asyncio.gather(*waiters), 5))
    assert m._watchers == {}
    for bad in [(), ("/w", 1), ("/w", "1", 1), ("/w", 1, "x"), ("/w", 1, -1), (5, 1, 1), ("", 1, 1)]:
        assert (await wait(m, *bad))[0] == -1, bad


def snapshot(state: Any, types: Any) -> GraphSnapshot:
    return GraphSnapshot.from_master(state, types)


def test_graph_changes_list_appearances_then_disappearances() -> None:
    old = snapshot([[["/a", ["/n1"]]], [], [["/s", ["/n1"]]]], [["/a", "pkg/A"]])
    new = snapshot([[["/b", ["/n2"]]], [["/a", ["/n2"]]], []], [["/a", "pkg/A"], ["/b", "pkg/B"]])
    assert graph_changes(old, new) == [
        GraphChange(True, "node", "/n2"),
        GraphChange(True, "topic", "/b", "pkg/B"),
        GraphChange(False, "service", "/s", "/n1"),
        GraphChange(False, "node", "/n1"),
    ]
    assert graph_changes(new, new) == []
    assert snapshot([[["/x", ["/n"]]], [], []], []).topics == {"/x": "*"}  # type unknown


@pytest.mark.parametrize("state", [None, [1, 2], [[["/a"]], [], []], [[], [], [["/s"]]]])
def test_a_malformed_graph_is_a_master_error(state: Any) -> None:
    with pytest.raises(MasterError):
        snapshot(state, [])
