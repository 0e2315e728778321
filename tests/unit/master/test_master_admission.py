"""The master's admission policy (pure): caps per who, one pass of identification, shedding the biggest holder."""

from __future__ import annotations

from dataclasses import dataclass, field

from hypothesis import given, settings
from hypothesis import strategies as st

from mrosd.master.admission import Admission


@dataclass(eq=False)
class Conn:
    name: str
    sheddable: bool = True
    uid: int | None = field(default=None)


def test_a_flooding_uid_on_loopback_does_not_spend_another_uids_share() -> None:
    adm: Admission[Conn] = Admission(total=100, per_who=10)
    flood = [Conn(f"f{i}", uid=1000) for i in range(10)]
    for c in flood:
        assert not adm.needs_identity(local=True)
        assert adm.admit(c, "127.0.0.1", True, None).admitted  # no lookup needed below the cap
    assert adm.needs_identity(local=True)
    assert not adm.needs_identity(local=False)
    pending = adm.unidentified()
    assert pending == flood
    for c in pending:
        adm.identify(c, c.uid)
    assert adm.unidentified() == []
    refused = adm.admit(Conn("f10"), "127.0.0.1", True, 1000)
    assert not refused.admitted and "uid 1000" in refused.reason
    assert adm.admit(Conn("node"), "127.0.0.1", True, 0).admitted  # root's node still gets in
    # another loopback address is the same uid: no fresh share per address
    assert not adm.admit(Conn("f11"), "127.0.0.9", True, 1000).admitted
    assert adm.count(("uid", 1000)) == 10 and adm.count(("uid", 0)) == 1


def test_at_the_global_cap_the_biggest_holder_gives_up_its_oldest_idle_connection() -> None:
    adm: Admission[Conn] = Admission(total=6, per_who=5)
    busy = Conn("busy", sheddable=False)
    adm.admit(busy, "127.0.0.1", True, 1000)
    idle = [Conn(f"idle{i}") for i in range(4)]
    for c in idle:
        adm.admit(c, "127.0.0.1", True, 1000)
    adm.admit(Conn("other"), "10.0.0.1", False, None)
    assert len(adm) == 6
    decision = adm.admit(Conn("node"), "127.0.0.1", True, 0)
    assert decision.admitted and decision.shed is idle[0] and decision.shed_from == "uid 1000"
    assert adm.count(("uid", 1000)) == 4 and len(adm) == 6
    # the flooder's own newcomer is never admitted by shedding its own connections
    assert not adm.admit(Conn("more"), "127.0.0.1", True, 1000).admitted
    adm.forget(decision.shed)  # its connection_lost later: already forgotten, no effect
    assert len(adm) == 6


def test_nobody_is_shed_for_a_newcomer_holding_as_many() -> None:
    adm: Admission[Conn] = Admission(total=4, per_who=4)
    for i in range(2):
        adm.admit(Conn(f"a{i}"), "10.0.0.1", False, None)
        adm.admit(Conn(f"b{i}"), "10.0.0.2", False, None)
    assert not adm.admit(Conn("b2"), "10.0.0.2", False, None).admitted


def test_an_unidentifiable_local_peer_is_counted_by_address() -> None:
    adm: Admission[Conn] = Admission(total=10, per_who=2)
    a, b = Conn("a"), Conn("b")
    adm.admit(a, "127.0.0.1", True, None)
    adm.admit(b, "127.0.0.1", True, None)
    adm.identify(a, None)
    adm.identify(b, 7)
    assert adm.count(("addr", "127.0.0.1")) == 1 and adm.count(("uid", 7)) == 1
    assert adm.admit(Conn("c"), "127.0.0.1", True, 7).admitted  # uid 7 held 1 of 2
    assert not adm.admit(Conn("d"), "127.0.0.1", True, 7).admitted


events = st.lists(
    st.one_of(
        st.tuples(
            st.just("open"),
            st.sampled_from(["127.0.0.1", "127.0.0.2", "10.0.0.1", "10.0.0.2"]),
            st.sampled_from([None, 0, 1000, 1001]),  # the uid the kernel reports (None: cannot be told)
            st.booleans(),
        ),
        st.tuples(st.just("close"), st.integers(0, 50)),
    ),
    max_size=120,
)


@settings(max_examples=300, deadline=None)
@given(total=st.integers(1, 12), per_who=st.integers(1, 12), script=events)
def test_caps_hold_and_shedding_only_takes_from_the_biggest_holder(total: int, per_who: int, script: list) -> None:
    """Driven as the HTTP server drives it: uids are looked up only when ``needs_identity`` says so."""
    adm: Admission[Conn] = Admission(total, per_who)
    live: list[Conn] = []
    for event in script:
        if event[0] == "open":
            _, host, kernel_uid, sheddable = event
            local = host.startswith("127.")
            conn = Conn(f"c{len(live)}", sheddable=sheddable, uid=kernel_uid)
            uid = None
            if adm.needs_identity(local):
                for other in adm.unidentified():
                    adm.identify(other, other.uid)
                uid = kernel_uid if local else None
            counts_before = {w: len(g) for w, g in adm._by_who.items()}
            who_before = dict(adm._who)
            decision = adm.admit(conn, host, local, uid)
            if decision.admitted:
                live.append(conn)
                if decision.shed is not None:
                    victim = decision.shed
                    assert victim.sheddable and victim in live
                    assert counts_before[who_before[victim]] == max(counts_before.values())
                    live.remove(victim)
        elif live:
            adm.forget(live.pop(event[1] % len(live)))
        assert len(adm) == len(live) <= total
        assert all(len(g) <= per_who for g in adm._by_who.values())
        assert sum(len(g) for g in adm._by_who.values()) == len(live)
