"""Who may read and write which key: the ``[ixm.rules]`` part of the daemon's configuration.

This module owns the access-rule data and its parsing from the TOML table (``parse_rules``, which the
daemon calls for ``[ixm.rules]``); it is pure and knows nothing of sockets. Example::

    [ixm.rules]
    default = "creator"          # for keys without a rule: "creator" (default), "allow" or "deny"

    [ixm.rules.keys."/arm/joints"]
    read_uids = [1000, "robot"]  # numeric uids or user names
    read_gids = ["video"]        # numeric gids or group names (primary or supplementary)
    read_names = ["viewer"]      # process names (/proc/PID/comm or argv[0]/argv[1] basename)
    write_uids = ["robot"]

    [ixm.rules.keys."/camera/*"]  # fnmatch patterns are tried after exact keys, in file order
    read_gids = ["video"]

Rules: the daemon's own uid and root may always read and write. A write right implies the read right.
``default = "creator"`` lets any local user read a key without a rule, and only processes of the uid that
created it (and root) write it; ``"allow"`` lets everyone read and write; ``"deny"`` refuses everyone
else. uids and gids come from SO_PEERCRED and /proc, never from the client. Process names are a
convenience for grouping, not a security boundary (a process chooses its own name).
"""

from __future__ import annotations

import fnmatch
import grp
import pwd
from collections.abc import Iterable, Mapping
from typing import Any, Literal

import msgspec

from mrosd.errors import ConfigError

__all__ = ["AccessRules", "KeyRule", "Peer", "parse_rules"]

DefaultPolicy = Literal["creator", "allow", "deny"]


class Peer(msgspec.Struct, frozen=True, kw_only=True):
    """What the daemon knows of a client process (from the kernel, not from the client)."""

    pid: int
    uid: int
    gid: int
    groups: frozenset[int] = frozenset()
    names: frozenset[str] = frozenset()


class KeyRule(msgspec.Struct, frozen=True, kw_only=True):
    """The read and write grants of one key or key pattern."""

    read_uids: frozenset[int] = frozenset()
    read_gids: frozenset[int] = frozenset()
    read_names: frozenset[str] = frozenset()
    write_uids: frozenset[int] = frozenset()
    write_gids: frozenset[int] = frozenset()
    write_names: frozenset[str] = frozenset()

    def allows(self, peer: Peer, write: bool) -> bool:
        if _matches(peer, self.write_uids, self.write_gids, self.write_names):
            return True
        return not write and _matches(peer, self.read_uids, self.read_gids, self.read_names)


def _matches(peer: Peer, uids: frozenset[int], gids: frozenset[int], names: frozenset[str]) -> bool:
    if peer.uid in uids:
        return True
    if gids and (peer.gid in gids or not gids.isdisjoint(peer.groups)):
        return True
    return bool(names) and not names.isdisjoint(peer.names)


class AccessRules(msgspec.Struct, frozen=True, kw_only=True):
    """The default policy, exact-key rules and pattern rules (in file order)."""

    default: DefaultPolicy = "creator"
    keys: dict[str, KeyRule] = msgspec.field(default_factory=dict)
    patterns: tuple[tuple[str, KeyRule], ...] = ()
    #: uids that may always do everything: root and the daemon's own uid (filled in by the server).
    superusers: frozenset[int] = frozenset({0})

    def rule_for(self, key: str) -> KeyRule | None:
        rule = self.keys.get(key)
        if rule is not None:
            return rule
        for pattern, prule in self.patterns:
            if fnmatch.fnmatchcase(key, pattern):
                return prule
        return None

    def allows(self, key: str, peer: Peer, write: bool, creator_uid: int | None) -> bool:
        """Whether ``peer`` may open ``key`` for reading (``write`` False) or writing.

        ``creator_uid`` is the uid that created the key's segment, or None when it does not exist yet.
        """
        if peer.uid in self.superusers:
            return True
        rule = self.rule_for(key)
        if rule is not None:
            return rule.allows(peer, write)
        if self.default == "allow":
            return True
        if self.default == "deny":
            return False
        return not write or creator_uid is None or creator_uid == peer.uid

    def with_superuser(self, uid: int) -> AccessRules:
        return msgspec.structs.replace(self, superusers=self.superusers | {uid})


_RULE_FIELDS = ("read_uids", "read_gids", "read_names", "write_uids", "write_gids", "write_names")


def _resolve_ids(values: Any, where: str, group: bool) -> frozenset[int]:
    if not isinstance(values, list):
        raise ConfigError(f"{where} must be a list, got {values!r}")
    out: set[int] = set()
    for value in values:
        if isinstance(value, bool):
            raise ConfigError(f"{where}: {value!r} is not a {'gid' if group else 'uid'} or name")
        if isinstance(value, int):
            if value < 0:
                raise ConfigError(f"{where}: ids are non-negative, got {value}")
            out.add(value)
        elif isinstance(value, str):
            try:
                out.add(grp.getgrnam(value).gr_gid if group else pwd.getpwnam(value).pw_uid)
            except KeyError as exc:
                raise ConfigError(f"{where}: no such {'group' if group else 'user'} {value!r}") from exc
        else:
            raise ConfigError(f"{where}: {value!r} is not a {'gid' if group else 'uid'} or name")
    return frozenset(out)


def _names(values: Any, where: str) -> frozenset[str]:
    if not isinstance(values, list) or not all(isinstance(v, str) and v for v in values):
        raise ConfigError(f"{where} must be a list of process names, got {values!r}")
    return frozenset(values)


def parse_rules(raw: Mapping[str, Any] | None, source: str = "ixm.rules") -> AccessRules:
    """Turn the ``[ixm.rules]`` table into AccessRules; user and group names are resolved now.

    Raises:
        ConfigError: an unknown key, a bad policy, an unknown user or group, or a value of the wrong type.
    """
    if not raw:
        return AccessRules()
    if not isinstance(raw, Mapping):
        raise ConfigError(f"{source} must be a table")
    extra = set(raw) - {"default", "keys", "bridges"}
    if extra:
        raise ConfigError(f"{source}: unknown setting(s) {', '.join(sorted(extra))} (expected default, keys, bridges)")
    default = raw.get("default", "creator")
    if default not in ("creator", "allow", "deny"):
        raise ConfigError(f"{source}.default must be 'creator', 'allow' or 'deny', got {default!r}")
    keys: dict[str, KeyRule] = {}
    patterns: list[tuple[str, KeyRule]] = []
    table = raw.get("keys", {})
    if not isinstance(table, Mapping):
        raise ConfigError(f"{source}.keys must be a table of key -> rule")
    for key, spec in table.items():
        where = f'{source}.keys."{key}"'
        if not isinstance(spec, Mapping):
            raise ConfigError(f"{where} must be a table")
        unknown = set(spec) - set(_RULE_FIELDS)
        if unknown:
            known = ", ".join(_RULE_FIELDS)
            raise ConfigError(f"{where}: unknown field(s) {', '.join(sorted(unknown))}; known: {known}")
        fields: dict[str, Any] = {}
        for name in _RULE_FIELDS:
            if name in spec:
                value = spec[name]
                sub = f"{where}.{name}"
                if name.endswith("_names"):
                    fields[name] = _names(value, sub)
                else:
                    fields[name] = _resolve_ids(value, sub, group=name.endswith("_gids"))
        rule = KeyRule(**fields)
        if any(c in key for c in "*?["):
            patterns.append((key, rule))
        else:
            keys[key] = rule
    return AccessRules(default=default, keys=keys, patterns=tuple(patterns))


def names_of(comm: str, argv: Iterable[str]) -> frozenset[str]:
    """The names a process answers to: its comm and the basenames of argv[0] and argv[1]."""
    out = {comm} if comm else set()
    for arg in list(argv)[:2]:
        base = arg.rsplit("/", 1)[-1]
        if base:
            out.add(base)
    return frozenset(out)
