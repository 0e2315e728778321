"""Handlers without sockets: rosmaster's return codes, argument validation and name resolution."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mrosd.master.api import MasterApi
from mrosd.names import lenient_resolve

API = "http://127.0.0.1:1001/"


async def call(m: MasterApi, method: str, *args: Any) -> Any:
    return await m.methods[method](*args)


def test_names_resolve_as_rosgraph_does() -> None:
    assert lenient_resolve("chatter", "/ns/node") == "/ns/chatter"
    assert lenient_resolve("~x", "/ns/node") == "/ns/node/x"
    assert lenient_resolve("/a//b/", "/ns/node") == "/a/b"
    assert lenient_resolve("x", "relative_node") == "/x"


async def test_wrong_arity_and_types_answer_error_code_minus_one() -> None:
    m = MasterApi(None)
    assert (await call(m, "lookupNode"))[0] == -1
    assert (await call(m, "lookupNode", "/c"))[:2] == (-1, "Error: bad call arity")
    assert (await call(m, "lookupNode", 5, "/x"))[:2] == (-1, "caller_id must be a string")
    assert (await call(m, "registerPublisher", "/c", "/t", "notatype", API))[0] == -1
    assert (await call(m, "registerPublisher", "/c", "/t", "a/B", "ftp://x"))[0] == -1
    assert (await call(m, "registerPublisher", "/c", "/", "a/B", API))[0] == -1
    assert (await call(m, "registerPublisher", "/c", "bad name", "a/B", API))[0] == -1
    assert (await call(m, "setParam", "/c", "/k", None))[0] == -1
    assert (await call(m, "getParam", "/c", ""))[0] == -1
    assert (await call(m, "setParam", "/c", "/", 3))[0] == -1


async def test_private_and_relative_names_resolve_against_the_caller() -> None:
    m = MasterApi(None)
    assert (await call(m, "setParam", "/ns/node", "~p", 1))[0] == 1
    assert (await call(m, "getParam", "/x", "/ns/node/p"))[2] == 1
    assert (await call(m, "registerPublisher", "/ns/node", "chatter", "std_msgs/String", API))[0] == 1
    assert (await call(m, "getPublishedTopics", "/ns/other", ""))[2] == [["/ns/chatter", "std_msgs/String"]]
    assert (await call(m, "getPublishedTopics", "/other", "ns"))[2] == [["/ns/chatter", "std_msgs/String"]]
    assert (await call(m, "getPublishedTopics", "/other", "/n"))[2] == []


async def test_failures_use_rosmaster_codes() -> None:
    m = MasterApi(None)
    assert (await call(m, "lookupNode", "/c", "/nobody"))[0] == -1
    assert (await call(m, "lookupService", "/c", "/nothing"))[0] == -1
    assert (await call(m, "getParam", "/c", "/unset"))[0] == -1
    assert (await call(m, "deleteParam", "/c", "/unset"))[0] == -1
    assert await call(m, "searchParam", "/c", "unset") == (-1, "Cannot find parameter [unset] in an upwards search", "")
    assert await call(m, "hasParam", "/c", "/unset") == (1, "/unset", False)
    assert (await call(m, "unregisterPublisher", "/c", "/t", API))[::2] == (1, 0)


async def test_subscribe_param_returns_the_value_or_empty_dict_and_updates_go_to_the_outbox() -> None:
    m = MasterApi(None)
    assert (await call(m, "subscribeParam", "/n", API, "/gains"))[2] == {}
    await call(m, "setParam", "/other", "/gains", {"p": 1})
    assert [(n.api, n.method, n.args) for n in m.outbox] == [(API, "paramUpdate", ("/gains/", {"p": 1}))]
    assert (await call(m, "subscribeParam", "/n", API, "/gains"))[2] == {"p": 1}
    assert (await call(m, "unsubscribeParam", "/n", API, "/gains"))[0] == 1


async def test_a_param_update_rejected_with_minus_one_drops_the_subscription() -> None:
    m = MasterApi(None)
    await call(m, "subscribeParam", "/n", API, "/k")
    await call(m, "setParam", "/other", "/k", 2)
    m.on_notification_result(m.outbox[0], [-1, "not subscribed", 0])
    assert "/k/" not in m.registry.param_subscribers


@settings(max_examples=200)
@given(
    st.sampled_from(sorted(MasterApi(None).methods)),
    st.lists(
        st.one_of(
            st.none(),
            st.integers(),
            st.text(max_size=8),
            st.sampled_from(["/a", "~b", "c/d", "/", "http://h:1/", "pkg/T", "*"]),
            st.lists(st.integers(), max_size=2),
            st.dictionaries(st.text(max_size=3), st.integers(), max_size=2),
        ),
        max_size=5,
    ),
)
async def test_no_argument_list_crashes_a_handler(method: str, args: list[Any]) -> None:
    m = MasterApi(None)
    code, status, _ = await call(m, method, *args)
    assert code in (-1, 0, 1) and isinstance(status, str)
    if code == 0:
        pytest.fail(f"internal failure: {status}")
