"""Rate limits, the bounded queue and the presence table (pure; the clock is passed in)."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from mrosd.fleet.keys import Item, ItemKind
from mrosd.fleet.limits import DropOldestQueue, RateLimit
from mrosd.fleet.presence import Presence


def test_rate_limit_holds_30hz_to_5hz() -> None:
    limit = RateLimit(max_hz=5.0)
    sent = sum(limit.admit(i / 30.0, 1_000_000) for i in range(30 * 10))
    assert 49 <= sent <= 51  # 10 s at 5 Hz (one message of burst)
    assert limit.limited == 300 - sent


def test_bandwidth_limit() -> None:
    limit = RateLimit(max_bytes_per_s=1_000_000)
    sent = sum(limit.admit(i / 100.0, 100_000) for i in range(100 * 5))
    assert 50 <= sent <= 60  # 5 s at 10 messages/s, plus the first second's bucket


@given(st.lists(st.floats(min_value=0, max_value=0.5), max_size=300), st.floats(min_value=0.5, max_value=50))
def test_rate_limit_never_exceeds_its_rate(gaps: list[float], hz: float) -> None:
    limit = RateLimit(max_hz=hz)
    now = 0.0
    for gap in gaps:
        now += gap
        limit.admit(now, 10)
    assert limit.passed <= max(1.0, hz) + now * hz + 1e-6
    assert limit.passed + limit.limited == len(gaps)


@given(st.integers(min_value=1, max_value=20), st.lists(st.integers(), max_size=100))
def test_drop_oldest_queue(maxlen: int, values: list[int]) -> None:
    q: DropOldestQueue[int] = DropOldestQueue(maxlen)
    for v in values:
        q.put(v)
    assert list(q.items) == values[-maxlen:]
    assert q.dropped == max(0, len(values) - maxlen)


def test_presence_forgets_after_three_seconds() -> None:
    p = Presence()
    a = Item(ItemKind.PUBLISHER, "std_msgs/String", "0" * 32, "r1", "/chatter")
    assert p.heard(a, 0.0)
    assert not p.heard(a, 1.0)
    assert p.expire(3.9) == []
    assert p.expire(4.0) == [a]
    assert a not in p


def test_presence_is_bounded() -> None:
    p = Presence(max_items=2)
    items = [Item(ItemKind.PUBLISHER, "a/B", "0" * 32, "r1", f"/t{i}") for i in range(3)]
    assert [p.heard(i, 0.0) for i in items] == [True, True, False]
    assert p.refused == 1


def test_rate_meter_follows_the_recent_rate() -> None:
    from mrosd.fleet.limits import RateMeter

    meter = RateMeter()
    for i in range(200):  # 10 Hz for 20 s
        meter.tick(i / 10)
    assert 9.0 <= meter.rate(19.9) <= 11.0
    assert meter.rate(19.9 + 20) < 0.1  # then silence
    assert RateMeter().rate(5.0) == 0.0
