"""The byte budgets of what a peer's samples fill (``Inbox`` with ``max_bytes``): a real loop, no network."""

from __future__ import annotations

import asyncio

from mrosd.fleet.handoff import Inbox


async def test_the_inbox_drops_by_bytes_its_own_oldest_first_then_the_fullest_names_and_refuses_a_giant() -> None:
    delivered: dict[str, list[bytes]] = {}
    done = asyncio.Event()

    def deliver(name: str, items: list[bytes]) -> None:
        delivered.setdefault(name, []).extend(items)
        done.set()

    inbox = Inbox(asyncio.get_running_loop(), deliver, 1000, max_bytes=100, max_bytes_each=60)
    a1, a2, a3, b1 = b"1" * 30, b"2" * 30, b"3" * 30, b"b" * 50
    assert not inbox.put("a", a1) and not inbox.put("a", a2)
    assert inbox.put("a", a3)  # over a's 60 bytes: its oldest goes
    assert inbox.put("b", b1)  # over 100 in all: the oldest of the name holding most (a) goes
    assert inbox.held_bytes == 80
    assert inbox.put("c", b"c" * 61)  # bigger than a name's share: refused
    # a's share takes one body of 60 (its 30 go), but a would then hold more than b: a's body is refused
    assert inbox.put("a", b"4" * 60) and inbox.held_bytes == 50
    assert not inbox.put("d", b"d" * 40) and inbox.held_bytes == 90
    await asyncio.wait_for(done.wait(), 5)
    assert delivered == {"b": [b1], "d": [b"d" * 40]}
    assert (inbox.dropped("a"), inbox.dropped("b"), inbox.dropped("c")) == (4, 0, 1)
    assert inbox.held_bytes == 0


async def test_the_inbox_without_a_byte_budget_counts_only_items() -> None:
    got: list[object] = []
    done = asyncio.Event()
    inbox = Inbox(asyncio.get_running_loop(), lambda _n, items: (got.extend(items), done.set()), 2)
    for item in (b"x" * 10_000, ("token", True), b"y"):
        inbox.put("t", item)
    await asyncio.wait_for(done.wait(), 5)
    assert got == [("token", True), b"y"] and inbox.dropped("t") == 1


def test_token_lanes_take_each_session_in_turn_and_drop_from_the_longest() -> None:
    from mrosd.ros2.tokens import TokenLanes

    lanes = TokenLanes(max_waiting=6)
    assert lanes.put("flood", ("f0", True)) == (True, False)
    for i in range(1, 5):
        lanes.put("flood", (f"f{i}", True))
    lanes.put("honest", ("h0", True))
    assert lanes.put("flood", ("f5", True)) == (False, True)  # full: the flood's oldest goes
    assert lanes.put("honest", ("h0", False)) == (False, True)  # and again the flood's, never the honest one
    assert lanes.take(3) == [("f2", True), ("h0", True), ("f3", True)]
    assert lanes.take(10) == [("h0", False), ("f4", True), ("f5", True)]
    assert lanes.waiting == 0 and lanes.dropped == 2 and lanes.take(1) == []


def test_the_token_filter_keeps_only_what_can_matter_from_the_key_alone() -> None:
    from mrosd.fleet.keys import NameFilter
    from mrosd.ros2.tokens import TokenFilter

    def key(zid: str, kind: str, topic: str, domain: int = 0) -> str:
        return f"@ros2_lv/{domain}/{zid}/0/1/{kind}/%/%/n/{topic.replace('/', '%')}/t/h/::,:,:,:,,"

    wanted = TokenFilter(0, "me", NameFilter(include=("/in/**",)), None)
    assert wanted.session_of(key("z1", "MP", "/in/a")) == "z1"
    assert wanted.session_of(key("z1", "SS", "/in/a")) == "z1"
    assert wanted.session_of(key("z1", "MP", "/out")) is None
    assert wanted.session_of(key("me", "MP", "/in/a")) is None
    assert wanted.session_of(key("z1", "MP", "/in/a", domain=3)) is None
    assert wanted.session_of(key("z1", "MS", "/in/a")) is None  # subscribers only matter in mode "demand"
    assert wanted.session_of("@ros2_lv/0/z1/0/0/NN/%/%/node") is None
    demand = TokenFilter(0, "me", NameFilter(), NameFilter(include=("/**",)))
    assert demand.session_of(key("z2", "MS", "/cam")) == "z2"
    assert demand.session_of(key("z2", "MP", "/cam")) is None
