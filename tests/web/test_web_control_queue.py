"""``ControlQueue``: the frames a session sends ahead of subscription data, bounded in bytes (pure)."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from mrosd.web.queue import ControlQueue


def test_push_reports_a_client_past_the_budget() -> None:
    q = ControlQueue(max_bytes=10)
    assert q.push(True, b"12345")
    assert q.push(False, b"12345")
    assert not q.push(True, b"x")
    assert q.size == 11


def test_frames_come_out_in_order_and_give_their_bytes_back() -> None:
    q = ControlQueue(max_bytes=100)
    q.push(True, b"a")
    q.push(False, b"bb")
    assert q.pop() == (True, b"a")
    assert q.pop() == (False, b"bb")
    assert not q
    assert q.size == 0


def test_pieces_put_in_front_come_first_and_are_not_counted() -> None:
    """A message's later fragments go first in the next turns; they are that message's bytes, bounded by its
    queue, not the client's control budget, and popping them gives nothing back (the count never goes
    negative: a negative count would let a client that reads nothing queue more than the budget)."""
    q = ControlQueue(max_bytes=10)
    q.push(True, b"reply")
    q.push_front([(False, b"piece2"), (False, b"piece3")])
    assert [q.pop(), q.pop(), q.pop()] == [(False, b"piece2"), (False, b"piece3"), (True, b"reply")]
    assert q.size == 0
    assert q.push(True, b"0123456789")
    assert not q.push(True, b"x")


@given(st.lists(st.tuples(st.booleans(), st.binary(max_size=20), st.booleans()), max_size=50))
def test_the_count_is_the_bytes_pushed_and_not_yet_popped(ops: list[tuple[bool, bytes, bool]]) -> None:
    q = ControlQueue(max_bytes=1 << 20)
    for flag, data, pop in ops:
        if pop and q:
            q.pop()
        elif flag:
            q.push(flag, data)
        else:
            q.push_front([(flag, data)])
        assert q.size >= 0
    while q:
        q.pop()
    assert q.size == 0
