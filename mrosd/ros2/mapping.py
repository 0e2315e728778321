"""ros1_bridge's mapping-rule YAML: renamed packages, messages, fields and services (pure, no I/O but the read).

A rules file is a YAML list of rules, each a mapping with the keys ros1_bridge documents (``doc/index.rst``):

- a **package rule**: ``ros1_package_name`` and ``ros2_package_name``: every message and service of the one
  package is the same-named one of the other;
- a **message rule**: a package rule plus ``ros1_message_name`` and ``ros2_message_name``, optionally with
  ``fields_1_to_2`` (ROS 1 field selection -> ROS 2 field selection);
- a **service rule**: a package rule plus ``ros1_service_name`` and ``ros2_service_name``, optionally with
  ``request_fields_1_to_2`` / ``response_fields_1_to_2``.

mrosd converts bodies byte for byte (CDR and ROS 1 lay fields out in declaration order), so a field rule may
rename fields but not move them: a selection with a ``.`` (``header.stamp``) or a mapping that changes the
order is refused when the type is mapped, with a line naming the rule. A file that does not parse, or a rule
with a missing, unknown or ill-typed key, is one ``MappingRuleError`` naming the file and the rule's index.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import msgspec

from mrosd.errors import ConfigError

__all__ = [
    "MAX_RULES",
    "MAX_RULES_FILE_SIZE",
    "MappingRuleError",
    "MappingRules",
    "MessageRule",
    "PackageRule",
    "ServiceRule",
    "load_mapping_rules",
    "parse_mapping_rules",
]

#: a rules file larger than this is refused before it is parsed (ros1_bridge's own files are a few kB)
MAX_RULES_FILE_SIZE = 1 << 20
#: rules in all files together
MAX_RULES = 10_000
#: a ROS package, message, service or field name (ROS 1 allows capitals in field names, ROS 2 does not)
_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
_SELECTION = re.compile(r"^[A-Za-z][A-Za-z0-9_]*(\.[A-Za-z][A-Za-z0-9_]*)*$")

_PACKAGE_KEYS = {"ros1_package_name", "ros2_package_name"}


class _Shape(msgspec.Struct, frozen=True):
    """The keys of a typed rule beyond the package pair: its two names, then its field-pair mappings."""

    names: tuple[str, str]
    fields: tuple[str, ...]

    @property
    def keys(self) -> set[str]:
        return {*self.names, *self.fields}


_MESSAGE = _Shape(("ros1_message_name", "ros2_message_name"), ("fields_1_to_2",))
_SERVICE = _Shape(("ros1_service_name", "ros2_service_name"), ("request_fields_1_to_2", "response_fields_1_to_2"))


class MappingRuleError(ConfigError):
    """A rules file or one of its rules is wrong; the message names the file and the rule."""


class PackageRule(msgspec.Struct, frozen=True):
    """Every type of ``ros1_package`` is the same-named type of ``ros2_package``."""

    ros1_package: str
    ros2_package: str


class MessageRule(msgspec.Struct, frozen=True):
    """``ros1_package/ros1_message`` is ``ros2_package/msg/ros2_message``; ``fields`` as (ROS 1, ROS 2) pairs."""

    ros1_package: str
    ros1_message: str
    ros2_package: str
    ros2_message: str
    fields: tuple[tuple[str, str], ...] = ()
    #: where the rule came from, for the messages that name it
    origin: str = ""

    def field_renames(self) -> dict[str, str]:
        """ROS 1 field name -> ROS 2 field name.

        Raises:
            MappingRuleError: a selection goes through a nested field (mrosd renames, it never moves).
        """
        renames = {}
        for one, two in self.fields:
            if "." in one or "." in two:
                raise MappingRuleError(
                    f"{self.origin}: field selection {one!r} -> {two!r} moves a field between messages; mrosd "
                    "converts byte for byte and supports renaming a field in place only"
                )
            renames[one] = two
        return renames


class ServiceRule(msgspec.Struct, frozen=True):
    """``ros1_package/ros1_service`` is ``ros2_package/srv/ros2_service``."""

    ros1_package: str
    ros1_service: str
    ros2_package: str
    ros2_service: str
    request_fields: tuple[tuple[str, str], ...] = ()
    response_fields: tuple[tuple[str, str], ...] = ()
    origin: str = ""


class MappingRules:
    """The rules of every file, looked up by either side's type name; the first rule for a name wins."""

    def __init__(
        self,
        packages: list[PackageRule] | None = None,
        messages: list[MessageRule] | None = None,
        services: list[ServiceRule] | None = None,
    ) -> None:
        self.packages = packages or []
        self.messages = messages or []
        self.services = services or []
        self._pkg_1to2: dict[str, str] = {}
        self._pkg_2to1: dict[str, str] = {}
        for p in self.packages:
            self._pkg_1to2.setdefault(p.ros1_package, p.ros2_package)
            self._pkg_2to1.setdefault(p.ros2_package, p.ros1_package)
        self._msg_1to2: dict[str, MessageRule] = {}
        self._msg_2to1: dict[str, MessageRule] = {}
        for m in self.messages:
            self._msg_1to2.setdefault(f"{m.ros1_package}/{m.ros1_message}", m)
            self._msg_2to1.setdefault(f"{m.ros2_package}/msg/{m.ros2_message}", m)
        self._srv_1to2: dict[str, ServiceRule] = {}
        self._srv_2to1: dict[str, ServiceRule] = {}
        #: a service rule's request and response as message rules (``pkg/XRequest`` -> ``pkg/srv/Y_Request``)
        self._srv_msg_1to2: dict[str, MessageRule] = {}
        for s in self.services:
            self._srv_1to2.setdefault(f"{s.ros1_package}/{s.ros1_service}", s)
            self._srv_2to1.setdefault(f"{s.ros2_package}/srv/{s.ros2_service}", s)
            for part, fields in (("Request", s.request_fields), ("Response", s.response_fields)):
                self._srv_msg_1to2.setdefault(
                    f"{s.ros1_package}/{s.ros1_service}{part}",
                    MessageRule(
                        s.ros1_package,
                        s.ros1_service + part,
                        s.ros2_package,
                        f"{s.ros2_service}_{part}",
                        fields,
                        s.origin,
                    ),
                )

    def __bool__(self) -> bool:
        return bool(self.packages or self.messages or self.services)

    def message_rule(self, ros1_type: str) -> MessageRule | None:
        """The message rule for a ROS 1 ``pkg/Type``, if any; a service rule's ``pkg/XRequest`` and
        ``pkg/XResponse`` have one made of its ``request_fields_1_to_2`` / ``response_fields_1_to_2``."""
        return self._msg_1to2.get(ros1_type) or self._srv_msg_1to2.get(ros1_type)

    def message_rule_2to1(self, ros2_type: str) -> MessageRule | None:
        """The message rule for a ROS 2 ``pkg/msg/Type``, if any."""
        return self._msg_2to1.get(ros2_type)

    def ros2_message(self, ros1_type: str) -> str | None:
        """ROS 1 ``pkg/Type`` -> ROS 2 ``pkg/msg/Type`` by a message or package rule, or None."""
        rule = self._msg_1to2.get(ros1_type)
        if rule is not None:
            return f"{rule.ros2_package}/msg/{rule.ros2_message}"
        pkg, _, name = ros1_type.partition("/")
        if pkg in self._pkg_1to2 and name:
            return f"{self._pkg_1to2[pkg]}/msg/{name}"
        return None

    def ros1_message(self, ros2_type: str) -> str | None:
        """ROS 2 ``pkg/msg/Type`` -> ROS 1 ``pkg/Type`` by a message or package rule, or None."""
        rule = self._msg_2to1.get(ros2_type)
        if rule is not None:
            return f"{rule.ros1_package}/{rule.ros1_message}"
        parts = ros2_type.split("/")
        if len(parts) == 3 and parts[0] in self._pkg_2to1:
            return f"{self._pkg_2to1[parts[0]]}/{parts[2]}"
        return None

    def ros2_service(self, ros1_type: str) -> str | None:
        """ROS 1 ``pkg/Srv`` -> ROS 2 ``pkg/srv/Srv`` by a service or package rule, or None."""
        rule = self._srv_1to2.get(ros1_type)
        if rule is not None:
            return f"{rule.ros2_package}/srv/{rule.ros2_service}"
        pkg, _, name = ros1_type.partition("/")
        if pkg in self._pkg_1to2 and name:
            return f"{self._pkg_1to2[pkg]}/srv/{name}"
        return None

    def ros1_service(self, ros2_type: str) -> str | None:
        """ROS 2 ``pkg/srv/Srv`` -> ROS 1 ``pkg/Srv`` by a service or package rule, or None."""
        rule = self._srv_2to1.get(ros2_type)
        if rule is not None:
            return f"{rule.ros1_package}/{rule.ros1_service}"
        parts = ros2_type.split("/")
        if len(parts) == 3 and parts[0] in self._pkg_2to1:
            return f"{self._pkg_2to1[parts[0]]}/{parts[2]}"
        return None


def load_mapping_rules(paths: list[str] | tuple[str, ...]) -> MappingRules:
    """Every rule of the files at ``paths``, in order.

    Raises:
        MappingRuleError: a file is missing, too big, not YAML, or has a bad rule (file and rule named).
    """
    rules = MappingRules()
    for path in paths:
        try:
            with Path(path).open("rb") as f:
                data = f.read(MAX_RULES_FILE_SIZE + 1)
        except OSError as exc:
            raise MappingRuleError(f"mapping rules {path}: cannot read: {exc.strerror or exc}") from exc
        if len(data) > MAX_RULES_FILE_SIZE:
            raise MappingRuleError(f"mapping rules {path}: over {MAX_RULES_FILE_SIZE} bytes")
        more = parse_mapping_rules(data.decode("utf-8", "replace"), path)
        rules = MappingRules(
            [*rules.packages, *more.packages], [*rules.messages, *more.messages], [*rules.services, *more.services]
        )
    if len(rules.packages) + len(rules.messages) + len(rules.services) > MAX_RULES:
        raise MappingRuleError(f"mapping rules: over {MAX_RULES} rules in all")
    return rules


def parse_mapping_rules(text: str, origin: str = "<rules>") -> MappingRules:
    """The rules of one file's text.

    Raises:
        MappingRuleError: not YAML, not a list of mappings, or a rule with a missing, unknown or ill-typed key.
    """
    import yaml

    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        where = getattr(exc, "problem_mark", None)
        line = f" line {where.line + 1}" if where is not None else ""
        raise MappingRuleError(f"mapping rules {origin}:{line}: not YAML: {getattr(exc, 'problem', exc)}") from None
    if doc is None:
        return MappingRules()
    if not isinstance(doc, list):
        raise MappingRuleError(f"mapping rules {origin}: a list of rules is expected, not {type(doc).__name__}")
    if len(doc) > MAX_RULES:
        raise MappingRuleError(f"mapping rules {origin}: over {MAX_RULES} rules")
    rules = MappingRules()
    for index, item in enumerate(doc):
        _parse_rule(item, f"mapping rules {origin}: rule {index}", rules)
    return MappingRules(rules.packages, rules.messages, rules.services)


def _parse_rule(item: Any, where: str, rules: MappingRules) -> None:
    if not isinstance(item, dict):
        raise MappingRuleError(f"{where}: a rule is a mapping of keys, not {type(item).__name__}")
    keys = set(item)
    unknown = keys - _PACKAGE_KEYS - _MESSAGE.keys - _SERVICE.keys
    if unknown:
        raise MappingRuleError(f"{where}: unknown key {sorted(map(str, unknown))[0]!r}")
    missing = _PACKAGE_KEYS - keys
    if missing:
        raise MappingRuleError(f"{where}: {sorted(missing)[0]!r} is missing")
    pkg1 = _name(item, "ros1_package_name", where)
    pkg2 = _name(item, "ros2_package_name", where)
    is_msg, is_srv = bool(keys & _MESSAGE.keys), bool(keys & _SERVICE.keys)
    if is_msg and is_srv:
        raise MappingRuleError(f"{where}: a rule is for a message or a service, not both")
    if is_msg:
        one, two, (fields,) = _typed(item, _MESSAGE, where)
        rules.messages.append(MessageRule(pkg1, one, pkg2, two, fields, where))
    elif is_srv:
        one, two, (request, response) = _typed(item, _SERVICE, where)
        rules.services.append(ServiceRule(pkg1, one, pkg2, two, request, response, where))
    else:
        rules.packages.append(PackageRule(pkg1, pkg2))


def _typed(item: dict[str, Any], shape: _Shape, where: str) -> tuple[str, str, list[tuple[tuple[str, str], ...]]]:
    """A message or service rule's ROS 1 and ROS 2 names and its field pairs, one tuple per ``shape.fields``.

    Raises:
        MappingRuleError: a name is missing or not a name, or a field mapping is not pairs of selections.
    """
    for key in shape.names:
        if key not in item:
            raise MappingRuleError(f"{where}: {key!r} is missing")
    one, two = (_name(item, key, where) for key in shape.names)
    return one, two, [_fields(item, key, where) for key in shape.fields]


def _name(item: dict[str, Any], key: str, where: str) -> str:
    value = item[key]
    if not isinstance(value, str) or not _NAME.match(value):
        raise MappingRuleError(f"{where}: {key} {value!r} is not a name (letters, digits, underscores)")
    return value


def _fields(item: dict[str, Any], key: str, where: str) -> tuple[tuple[str, str], ...]:
    value = item.get(key)
    if value is None:
        return ()
    if not isinstance(value, dict):
        raise MappingRuleError(f"{where}: {key} is a mapping of ROS 1 field -> ROS 2 field")
    pairs = []
    for one, two in value.items():
        if not (isinstance(one, str) and isinstance(two, str) and _SELECTION.match(one) and _SELECTION.match(two)):
            raise MappingRuleError(f"{where}: {key}: {one!r}: {two!r} is not a pair of field selections")
        pairs.append((one, two))
    return tuple(pairs)
