"""Access rules: parsing [ixm.rules], defaults, uid/gid/name grants, errors naming the key."""

from __future__ import annotations

import pytest

from mrosd.errors import ConfigError
from mrosd.ixm.rules import AccessRules, Peer, names_of, parse_rules


def peer(uid: int, gid: int = 100, groups: tuple[int, ...] = (), names: tuple[str, ...] = ()) -> Peer:
    return Peer(pid=1, uid=uid, gid=gid, groups=frozenset(groups), names=frozenset(names))


def test_the_default_policy_lets_anyone_read_and_only_the_creator_write() -> None:
    rules = AccessRules()
    assert rules.allows("/k", peer(1000), write=True, creator_uid=None)
    assert rules.allows("/k", peer(1001), write=False, creator_uid=1000)
    assert not rules.allows("/k", peer(1001), write=True, creator_uid=1000)
    assert rules.allows("/k", peer(0), write=True, creator_uid=1000)


def test_a_key_rule_grants_by_uid_gid_and_name_and_write_implies_read() -> None:
    rules = parse_rules(
        {"keys": {"/arm": {"read_uids": [1001], "read_gids": [50], "read_names": ["viewer"], "write_uids": [1002]}}}
    )
    assert rules.allows("/arm", peer(1001), False, None)
    assert not rules.allows("/arm", peer(1001), True, None)
    assert rules.allows("/arm", peer(1003, groups=(50,)), False, None)
    assert rules.allows("/arm", peer(1004, names=("viewer",)), False, None)
    assert not rules.allows("/arm", peer(1005), False, None)
    assert rules.allows("/arm", peer(1002), False, None)


def test_patterns_apply_after_exact_keys_and_deny_refuses_the_rest() -> None:
    rules = parse_rules({"default": "deny", "keys": {"/cam/*": {"read_uids": [7]}, "/cam/x": {"read_uids": [8]}}})
    assert rules.allows("/cam/y", peer(7), False, None)
    assert not rules.allows("/cam/x", peer(7), False, None)
    assert not rules.allows("/other", peer(7), False, None)
    assert parse_rules({"default": "allow"}).allows("/k", peer(9), True, 1)


def test_user_and_group_names_are_resolved() -> None:
    rules = parse_rules({"keys": {"/k": {"write_uids": ["root"], "read_gids": ["root"]}}})
    assert rules.keys["/k"].write_uids == frozenset({0})
    assert rules.keys["/k"].read_gids == frozenset({0})


@pytest.mark.parametrize(
    ("raw", "match"),
    [
        ({"bogus": 1}, "unknown setting"),
        ({"default": "maybe"}, "default"),
        ({"keys": {"/k": {"x": []}}}, "unknown field"),
        ({"keys": {"/k": {"read_uids": ["no-such-user-xyz"]}}}, "no such user"),
        ({"keys": {"/k": {"read_uids": 3}}}, "list"),
        ({"keys": {"/k": {"read_names": [""]}}}, "process names"),
        ({"keys": {"/k": {"read_uids": [-1]}}}, "non-negative"),
    ],
)
def test_bad_rules_name_the_offending_key(raw: dict, match: str) -> None:  # type: ignore[type-arg]
    with pytest.raises(ConfigError, match=match):
        parse_rules(raw)


def test_process_names_come_from_comm_and_argv() -> None:
    assert names_of("python3", ["/usr/bin/python3", "/opt/robot/viewer.py", "x"]) == {"python3", "viewer.py"}


def test_the_standalone_registry_reads_the_rules_table_of_a_daemon_config(tmp_path: object) -> None:
    from pathlib import Path

    from mrosd.ixm.__main__ import load_rules_file

    path = Path(str(tmp_path)) / "mrosd.toml"
    path.write_text('[master]\nport = 1\n[ixm.rules]\ndefault = "deny"\n[ixm.rules.keys."/k"]\nread_uids = [5]\n')
    rules = load_rules_file(str(path))
    assert rules.default == "deny" and rules.keys["/k"].read_uids == frozenset({5})
    path.write_text('[ixm.rules]\ndefault = "maybe"\n')
    with pytest.raises(ConfigError, match="default must be"):
        load_rules_file(str(path))
    assert load_rules_file(None) == AccessRules()
