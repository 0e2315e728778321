"""Registry: the paper's IxmInit/IxmFree rules and a process's death, as pure data and effects."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.errors import IxmError, IxmPermissionError
from mrosd.ixm.registry import CreateSegment, ReadersChanged, Registry, UnlinkSegment
from mrosd.ixm.rules import AccessRules, Peer


def make() -> Registry:
    names = iter(range(1, 10**6))
    reg = Registry(AccessRules(), lambda key: f"/seg-{next(names)}")
    reg.connect(1, Peer(pid=11, uid=1000, gid=1000), "writer")
    reg.connect(2, Peer(pid=22, uid=1001, gid=1001), "reader")
    return reg


def test_the_first_open_creates_the_segment_and_the_last_close_unlinks_it() -> None:
    reg = make()
    seg, effects = reg.open(1, "/k", "float64", None, None, "w")
    assert isinstance(effects[0], CreateSegment) and seg.type.capacity == 8
    _, effects = reg.open(2, "/k", None, None, None, "r")
    assert effects == [ReadersChanged("/k")]
    assert reg.close(1, "/k") == []
    assert reg.close(2, "/k") == [UnlinkSegment("/k", "/seg-1")]
    assert reg.segments == {}


def test_a_dead_process_releases_every_key_it_held() -> None:
    reg = make()
    reg.open(1, "/a", "int32", None, None, "w")
    reg.open(1, "/b", "int32", None, None, "rw")
    effects = reg.disconnect(1)
    assert {e.key for e in effects if isinstance(e, UnlinkSegment)} == {"/a", "/b"}
    assert 1 not in reg.processes and reg.disconnect(1) == []


def test_another_uid_may_read_but_not_write_a_key_it_did_not_create() -> None:
    reg = make()
    reg.open(1, "/k", "float64", None, None, "w")
    with pytest.raises(IxmPermissionError, match="may not write /k"):
        reg.open(2, "/k", "float64", None, None, "rw")
    reg.open(2, "/k", "float64", None, None, "r")


def test_a_type_or_size_mismatch_is_refused_with_both_types_named() -> None:
    reg = make()
    reg.open(1, "/k", "float64", 3, None, "w")
    with pytest.raises(IxmError, match=r"holds float64\[3\].*asked for int32"):
        reg.open(2, "/k", "int32", None, None, "r")
    with pytest.raises(IxmError, match="asked for float64"):
        reg.open(2, "/k", "float64", 4, None, "r")


def test_opening_a_missing_key_without_a_type_or_twice_is_an_error() -> None:
    reg = make()
    with pytest.raises(IxmError, match="does not exist"):
        reg.open(2, "/k", None, None, None, "r")
    reg.open(1, "/k", "bool", None, None, "w")
    with pytest.raises(IxmError, match="already open"):
        reg.open(1, "/k", "bool", None, None, "w")
    with pytest.raises(IxmError, match="not open"):
        reg.close(2, "/k")
    with pytest.raises(IxmError, match="mode"):
        reg.open(2, "/k", "bool", None, None, "x")
    with pytest.raises(IxmError, match="key"):
        reg.open(2, "", "bool", None, None, "r")


@given(st.lists(st.tuples(st.sampled_from([1, 2]), st.sampled_from(["/a", "/b"]), st.sampled_from(["open", "close"]))))
def test_segments_exist_exactly_while_someone_holds_them(ops: list[tuple[int, str, str]]) -> None:
    reg = make()
    reg.rules = AccessRules(default="allow")
    live: set[str] = set()
    for conn, key, op in ops:
        try:
            effects = reg.open(conn, key, "int8", None, None, "rw")[1] if op == "open" else reg.close(conn, key)
        except IxmError:
            continue
        for e in effects:
            if isinstance(e, CreateSegment):
                live.add(key)
            elif isinstance(e, UnlinkSegment):
                live.discard(key)
    held = {k for p in reg.processes.values() for k in p.keys}
    assert live == held == set(reg.segments)


def test_keys_held_are_capped_per_uid_and_overall_and_released_on_close_and_death() -> None:
    reg = make()
    reg.max_keys_per_uid = 2
    reg.max_keys = 3
    reg.open(1, "/a", "int32", None, None, "w")
    reg.open(1, "/b", "int32", None, None, "w")
    with pytest.raises(IxmError, match="uid 1000 already holds 2 IXM keys, the per-user limit"):
        reg.open(1, "/c", "int32", None, None, "w")
    reg.open(2, "/a", None, None, None, "r")
    with pytest.raises(IxmError, match="holds 3 keys, its limit"):
        reg.open(2, "/b", None, None, None, "r")
    reg.close(1, "/a")
    assert reg.keys_by_uid == {1000: 1, 1001: 1} and reg.keys_held == 2
    reg.disconnect(1)
    reg.disconnect(2)
    assert reg.keys_by_uid == {} and reg.keys_held == 0


@given(st.lists(st.tuples(st.sampled_from([1, 2]), st.sampled_from(["/a", "/b", "/c"]), st.booleans()), max_size=40))
def test_the_key_counts_always_match_what_processes_hold(ops: list[tuple[int, str, bool]]) -> None:
    reg = make()
    reg.rules = AccessRules(default="allow")
    for conn, key, opening in ops:
        try:
            if opening:
                reg.open(conn, key, "int32", None, None, "rw")
            else:
                reg.close(conn, key)
        except IxmError:
            pass
        by_uid: dict[int, int] = {}
        for proc in reg.processes.values():
            if proc.keys:
                by_uid[proc.peer.uid] = by_uid.get(proc.peer.uid, 0) + len(proc.keys)
        assert reg.keys_by_uid == by_uid and reg.keys_held == sum(by_uid.values())


def test_a_key_is_visible_to_whoever_may_open_it_in_some_mode() -> None:
    reg = make()
    reg.rules = AccessRules(default="deny")
    reg.connect(3, Peer(pid=33, uid=0, gid=0), "root")
    info, _ = reg.open(3, "/a", "int32", None, None, "w")
    assert not reg.visible(reg.processes[2].peer, info)
    assert not reg.visible(reg.processes[1].peer, info)  # "deny": only root and the daemon's uid
    assert reg.visible(Peer(pid=1, uid=0, gid=0), info)
