"""HeaderAdmission: the pure bookkeeping of connections that still owe their connection header."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mrosd.tcpros.admission import AdmissionLimits, HeaderAdmission


def test_beyond_the_waiting_cap_the_oldest_is_shed() -> None:
    adm: HeaderAdmission[int] = HeaderAdmission(AdmissionLimits(max_pending=3, max_pending_per_address=10))
    for key in range(3):
        assert adm.admit(key, "10.0.0.1", 0.0).shed == []
    verdict = adm.admit(3, "10.0.0.2", 0.0)
    assert verdict.admitted and verdict.shed == [0]
    assert adm.pending == 3


def test_the_per_address_cap_sheds_that_address_oldest_only() -> None:
    adm: HeaderAdmission[str] = HeaderAdmission(AdmissionLimits(max_pending=10, max_pending_per_address=2))
    adm.admit("other", "10.0.0.9", 0.0)
    adm.admit("a1", "10.0.0.1", 0.0)
    adm.admit("a2", "10.0.0.1", 0.0)
    assert adm.admit("a3", "10.0.0.1", 0.0).shed == ["a1"]
    assert adm.is_pending("other")


def test_a_finished_header_is_never_shed() -> None:
    adm: HeaderAdmission[int] = HeaderAdmission(AdmissionLimits(max_pending=1))
    adm.admit(1, "h", 0.0)
    adm.header_done(1)
    assert adm.admit(2, "h", 0.0).shed == []
    assert adm.expired(100.0) == [2]
    assert adm.connections == 2


def test_deadlines_expire_in_arrival_order() -> None:
    adm: HeaderAdmission[int] = HeaderAdmission(AdmissionLimits(header_timeout=2.0))
    adm.admit(1, "h", 0.0)
    adm.admit(2, "h", 1.0)
    assert adm.next_deadline() == 2.0
    assert adm.expired(1.9) == []
    assert adm.expired(2.0) == [1]
    assert adm.next_deadline() == 3.0
    adm.header_done(2)
    assert adm.next_deadline() is None


def test_the_byte_budget_sheds_the_oldest_header_first() -> None:
    adm: HeaderAdmission[int] = HeaderAdmission(AdmissionLimits(max_pending_bytes=100))
    adm.admit(1, "h", 0.0)
    adm.admit(2, "h", 0.0)
    assert adm.received(1, 60) == []
    assert adm.received(2, 50) == [1]
    assert adm.pending_bytes == 50
    assert adm.received(2, 101) == [2]
    assert adm.pending_bytes == 0


def test_at_the_connection_cap_a_waiting_one_makes_room_else_the_new_one_is_refused() -> None:
    adm: HeaderAdmission[int] = HeaderAdmission(AdmissionLimits(max_connections=2))
    adm.admit(1, "h", 0.0)
    adm.admit(2, "h", 0.0)
    adm.header_done(2)
    verdict = adm.admit(3, "h", 0.0)
    assert verdict.admitted and verdict.shed == [1]
    adm.closed(1)
    adm.header_done(3)
    assert not adm.admit(4, "h", 0.0).admitted


def test_shedding_for_descriptors_takes_the_oldest_quarter() -> None:
    adm: HeaderAdmission[int] = HeaderAdmission()
    for key in range(10):
        adm.admit(key, "h", 0.0)
    assert adm.shed_oldest() == [0, 1]
    assert HeaderAdmission[int]().shed_oldest() == []


def test_limits_are_checked() -> None:
    with pytest.raises(ValueError):
        AdmissionLimits(header_timeout=0)
    with pytest.raises(ValueError):
        AdmissionLimits(max_pending=0)


_OPS = st.lists(
    st.tuples(
        st.sampled_from(["admit", "done", "close", "bytes", "expire", "shed"]),
        st.integers(0, 30),
        st.sampled_from(["a", "b", "c"]),
        st.integers(0, 300),
    ),
    max_size=200,
)


@settings(deadline=None, max_examples=200)
@given(_OPS)
def test_caps_hold_whatever_peers_do(ops: list[tuple[str, int, str, int]]) -> None:
    limits = AdmissionLimits(max_pending=8, max_pending_per_address=4, max_pending_bytes=500, max_connections=12)
    adm: HeaderAdmission[int] = HeaderAdmission(limits)
    now = 0.0
    open_keys: set[int] = set()
    for op, key, address, n in ops:
        now += 0.5
        if op == "admit" and key not in open_keys:
            verdict = adm.admit(key, address, now)
            if verdict.admitted:
                open_keys.add(key)
        elif op == "done":
            adm.header_done(key)
        elif op == "close":
            adm.closed(key)
            open_keys.discard(key)
        elif op == "bytes":
            adm.received(key, n)
        elif op == "expire":
            adm.expired(now)
        else:
            adm.shed_oldest()
        assert adm.pending <= limits.max_pending
        assert adm.pending_bytes <= limits.max_pending_bytes
        assert adm.connections <= limits.max_connections
        assert adm.connections == len(open_keys)
        for addr in "abc":
            assert sum(1 for k in open_keys if adm.is_pending(k) and adm._pending[k].address == addr) <= 4
