"""Big replies in the dispatch layer (no sockets): built once per state, shared by callers, within budgets."""

from __future__ import annotations

import asyncio
from typing import Any, cast

import pytest

import mrosd.master.dispatch as dispatch
from mrosd.master.api import READ_ONLY_METHODS, MasterApi
from mrosd.master.dispatch import (
    BIG_REPLY,
    BIG_REPLY_ITEMS,
    FAULT_REPLY_BUDGET,
    LargeReply,
    XmlRpcHttpHandler,
    estimate_size,
)
from mrosd.xmlrpc import Fault, XmlRpcServer, decode_response, encode_call

MIB = 1 << 20


@pytest.fixture
def handler() -> Any:
    api = MasterApi(None, cleanup_interval=0)
    h = XmlRpcHttpHandler(
        api.sync_methods, XmlRpcServer(api.methods), cacheable=READ_ONLY_METHODS, state_version=api.state_version
    )
    yield h
    h.close()


async def call(handler: XmlRpcHttpHandler, method: str, *params: Any) -> bytes | LargeReply:
    out = handler.handle(encode_call(method, params))
    return out if isinstance(out, bytes) else await out


async def test_concurrent_callers_share_one_encoded_value(handler: XmlRpcHttpHandler) -> None:
    assert await call(handler, "setParam", "/c", "/big", {"a": "x" * (2 * MIB), "b": [1, 2.5, None]})
    first = await call(handler, "getParam", "/one", "/big")
    second = await call(handler, "getParam", "/two", "big")  # another caller, another body: the same value
    assert isinstance(first, LargeReply) and isinstance(second, LargeReply)
    assert first.body is second.body
    assert decode_response(first.to_bytes()) == [1, "Parameter [/big]", {"a": "x" * (2 * MIB), "b": [1, 2.5, None]}]
    size = first.body.size
    assert handler.budget.held == size  # counted once: cached and written twice
    first.release()
    second.release()
    assert handler.budget.held == size  # the cache still holds it
    assert await call(handler, "setParam", "/c", "/other", 1)
    await call(handler, "getPid", "/c")  # the next call sees the change: the cached body goes
    assert handler.budget.held == 0
    third = await call(handler, "getParam", "/three", "/big")
    assert isinstance(third, LargeReply) and third.body is not first.body
    third.release()


async def test_a_small_value_is_plain_bytes(handler: XmlRpcHttpHandler) -> None:
    await call(handler, "setParam", "/c", "/small", "x" * 1000)
    assert isinstance(await call(handler, "getParam", "/c", "/small"), bytes)


async def test_getsystemstate_of_long_names_is_shared(handler: XmlRpcHttpHandler) -> None:
    for i in range(3):
        topic = f"/t{i}" + "n" * MIB
        await call(handler, "registerPublisher", "/n", topic, "std_msgs/String", "http://127.0.0.1:1/")
    a = await call(handler, "getSystemState", "/a")
    b = await call(handler, "getSystemState", "/b")
    assert isinstance(a, LargeReply) and isinstance(b, LargeReply) and a.body is b.body
    pubs, _, _ = decode_response(a.to_bytes())[2]
    assert len(pubs) == 3
    a.release()
    b.release()


async def test_over_the_reply_budget_the_caller_gets_a_fault(handler: XmlRpcHttpHandler) -> None:
    for key in ("/a", "/b"):
        await call(handler, "setParam", "/c", key, "v" * (2 * MIB))
    held = await call(handler, "getParam", "/c", "/a")
    assert isinstance(held, LargeReply)
    handler.budget.limit = held.body.size + BIG_REPLY  # no room for another
    refused = await call(handler, "getParam", "/c", "/b")
    assert isinstance(refused, bytes)
    with pytest.raises(Fault) as info:
        decode_response(refused)
    assert info.value.code == FAULT_REPLY_BUDGET and "REPLY_BUDGET" in info.value.message
    again = await call(handler, "getParam", "/d", "/a")  # the value already held is still served
    assert isinstance(again, LargeReply)
    held.release()
    again.release()


async def test_a_reply_over_max_reply_size_is_a_fault(handler: XmlRpcHttpHandler, monkeypatch: Any) -> None:
    monkeypatch.setattr(dispatch, "MAX_REPLY_SIZE", 3 * MIB)
    await call(handler, "setParam", "/c", "/huge", ["w" * MIB] * 5)
    refused = await call(handler, "getParam", "/c", "/huge")
    with pytest.raises(Fault) as info:
        decode_response(refused)  # type: ignore[arg-type]
    assert info.value.code == FAULT_REPLY_BUDGET and "MAX_REPLY_SIZE" in info.value.message
    assert handler.budget.held == 0


def test_estimate_size() -> None:
    assert estimate_size(["a", "b", {"k": 1}]) < 300
    assert estimate_size("x" * (2 * BIG_REPLY)) > BIG_REPLY
    assert estimate_size(list(range(BIG_REPLY_ITEMS + 1))) > BIG_REPLY  # many items: big too
    assert estimate_size([["t" * 100, ["/n"]]] * 100) < BIG_REPLY


def multicall_of(*calls: tuple[str, tuple[Any, ...]]) -> list[dict[str, Any]]:
    return [{"methodName": m, "params": list(p)} for m, p in calls]


async def test_a_multicall_of_big_values_goes_through_the_same_limits(
    handler: XmlRpcHttpHandler, monkeypatch: Any
) -> None:
    await call(handler, "setParam", "/c", "/big", "m" * (2 * MIB))
    calls = multicall_of(*[("getParam", ("/c", "/big"))] * 3)
    out = await call(handler, "system.multicall", calls)
    assert isinstance(out, LargeReply)
    results = decode_response(out.to_bytes())
    assert [r[0][2] for r in results] == ["m" * (2 * MIB)] * 3
    out.release()
    assert handler.budget.held == 0  # built for this call alone: not kept
    monkeypatch.setattr(dispatch, "MAX_REPLY_SIZE", 5 * MIB)  # 3 x 2 MiB: one request amplified past it
    with pytest.raises(Fault) as info:
        decode_response(await call(handler, "system.multicall", calls))  # type: ignore[arg-type]
    assert info.value.code == FAULT_REPLY_BUDGET and "MAX_REPLY_SIZE" in info.value.message


async def test_wait_system_state_change_shares_one_snapshot(handler: XmlRpcHttpHandler) -> None:
    for i in range(2):
        await call(handler, "registerPublisher", "/n", f"/t{i}" + "w" * MIB, "std_msgs/String", "http://127.0.0.1:1/")
    a = await call(handler, "waitSystemStateChange", "/a", -1, 1)
    b = await call(handler, "waitSystemStateChange", "/b", -1, 1)
    assert isinstance(a, LargeReply) and isinstance(b, LargeReply) and a.body is b.body
    code, _, (_, (pubs, _, _), types) = decode_response(a.to_bytes())
    assert code == 1 and len(pubs) == 2 and len(types) == 2
    a.release()
    b.release()


async def test_a_namespace_edited_while_it_is_encoded_is_answered_whole(handler: XmlRpcHttpHandler) -> None:
    """setParam edits a namespace in place between two chunks: the reply is the new namespace, never a mix."""
    await call(handler, "setParam", "/c", "/ns", {"a": "a" * (2 * MIB), "b": "b" * (2 * MIB)})
    pending = handler.handle(encode_call("getParam", ("/r", "/ns")))
    assert not isinstance(pending, bytes)
    task = asyncio.ensure_future(pending)
    for _ in range(3):  # a few chunks in
        await asyncio.sleep(0)
    assert not task.done()
    await call(handler, "setParam", "/c", "/ns/c", "new")
    await call(handler, "setParam", "/c", "/ns/a", "A")
    out = await task
    assert isinstance(out, LargeReply)
    assert decode_response(out.to_bytes()) == [1, "Parameter [/ns]", {"a": "A", "b": "b" * (2 * MIB), "c": "new"}]
    out.release()


async def test_a_graph_snapshot_is_not_encoded_again_when_the_graph_changes(handler: XmlRpcHttpHandler) -> None:
    """The registry's values are never edited: registrations during the encoding do not restart it."""
    for i in range(3):
        await call(handler, "registerPublisher", "/n", f"/t{i}" + "g" * MIB, "std_msgs/String", "http://127.0.0.1:1/")
    task = asyncio.ensure_future(cast(Any, handler.handle(encode_call("getSystemState", ("/r",)))))
    for i in range(20):  # registrations all along
        await asyncio.sleep(0)
        await call(handler, "registerSubscriber", f"/s{i}", "/other", "std_msgs/String", "http://127.0.0.1:2/")
    out = await task
    assert isinstance(out, LargeReply)
    pubs, subs, _ = decode_response(out.to_bytes())[2]
    assert len(pubs) == 3 and subs == []  # the state as it was asked for, whole
    out.release()
