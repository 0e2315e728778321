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
