"""The fair scheduler of a client's subscriptions (``mrosd.web.delivery``), as pure data: every message goes
once and in order, backlogged subscriptions share bytes within DRR's bound, and a small topic's backlog goes
out before a big topic sends its next frame."""

from __future__ import annotations

import collections

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mrosd.web.delivery import DeficitRoundRobin
from mrosd.web.queue import ByteQueue

QUANTUM = 1000

lanes_st = st.dictionaries(
    st.integers(0, 20), st.lists(st.integers(0, 5000), min_size=0, max_size=30), min_size=1, max_size=6
)


def _drain(drr: DeficitRoundRobin[int], queues: dict[int, collections.deque[int]]) -> list[tuple[int, int]]:
    sent: list[tuple[int, int]] = []
    keys = list(queues)
    total = sum(len(q) for q in queues.values())
    for _ in range(total + 1):
        key = drr.pick(keys, lambda k: queues[k][0] if queues[k] else None)
        if key is None:
            break
        assert queues[key], "picked a subscription with nothing to send"
        sent.append((key, queues[key].popleft()))
    return sent


@given(lanes_st)
def test_every_message_goes_once_in_its_subscriptions_order(lanes: dict[int, list[int]]) -> None:
    queues = {k: collections.deque(v) for k, v in lanes.items()}
    sent = _drain(DeficitRoundRobin(QUANTUM), queues)
    assert all(not q for q in queues.values())
    for key, sizes in lanes.items():
        assert [s for k, s in sent if k == key] == sizes


@given(lanes_st)
@settings(max_examples=200)
def test_backlogged_subscriptions_share_bytes_within_a_quantum_and_a_message(lanes: dict[int, list[int]]) -> None:
    queues = {k: collections.deque(v) for k, v in lanes.items()}
    biggest = max((s for v in lanes.values() for s in v), default=0)
    drr: DeficitRoundRobin[int] = DeficitRoundRobin(QUANTUM)
    sent = dict.fromkeys(queues, 0)
    keys = list(queues)
    busy = [k for k in keys if queues[k]]
    # while every subscription that had messages still has some, none is ahead of another by more than
    # DRR's bound (a round's quantum and the messages that straddle its ends)
    while busy and all(queues[k] for k in busy):
        key = drr.pick(keys, lambda k: queues[k][0] if queues[k] else None)
        assert key is not None
        sent[key] += queues[key].popleft()
        assert max(sent[k] for k in busy) - min(sent[k] for k in busy) <= 2 * (QUANTUM + biggest)


@given(st.lists(st.integers(1, 300), min_size=1, max_size=3), st.integers(2, 8))
def test_a_small_topics_backlog_goes_before_the_big_topics_next_frame(small: list[int], frames: int) -> None:
    """A big topic of frames 40x the quantum beside small topics whose backlog fits a quantum: no small
    message waits for more than one frame."""
    queues = {0: collections.deque([40 * QUANTUM] * frames)}
    queues.update((i + 1, collections.deque([s])) for i, s in enumerate(small))
    drr: DeficitRoundRobin[int] = DeficitRoundRobin(QUANTUM)
    sent = _drain(drr, queues)
    first_frame_again = [i for i, (k, _) in enumerate(sent) if k == 0][1]
    assert all(k == 0 for k, _ in sent[first_frame_again:])


def test_a_subscription_that_has_nothing_now_banks_no_credit() -> None:
    drr: DeficitRoundRobin[str] = DeficitRoundRobin(QUANTUM)
    assert drr.pick(["a", "b"], lambda k: 5 * QUANTUM if k == "a" else None) == "a"
    assert drr.credit("b") == 0
    assert drr.pick([], lambda k: 0) is None
    with pytest.raises(ValueError):
        DeficitRoundRobin(0)


def test_a_big_queue_keeps_its_newest_when_told_and_counts_the_rest() -> None:
    q: ByteQueue[int] = ByteQueue(1 << 20)
    q.big = True
    for i in range(5):
        q.put(i, 100 + i)
    assert q.backlog() == 104 and q.size == 510
    q.keep_newest()
    assert len(q) == 1 and q.peek_size() == 104 and q.get() == 4
    assert q.dropped == 4 and q.peek_size() is None and q.backlog() == 0
