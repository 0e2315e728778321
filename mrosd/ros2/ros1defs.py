"""ROS 2 type definitions -> ROS 1 ``message_definition`` text, and ROS 2 ``share/<pkg>/msg/*.msg`` trees.

A ROS 2 type that mrosd's ROS 1 search path does not know (a custom type a ROS 2 node publishes) becomes a
ROS 1 type by writing its fields in ROS 1's syntax: ``builtin_interfaces/Time``/``Duration`` are ``time`` and
``duration`` (the same 8 bytes), bounded strings and sequences lose their bound (the bytes are the same),
nested types take their ROS 1 names (by mapping rule, else ``pkg/Type``), and a type ROS 1 has no form for
(``wstring``) is refused with the field named. The md5 of the result is then computed as genmsg does, by
``mrosd.msg``, so ``rostopic echo`` and rospy subscribers match it.

Knows rosbags' field descriptions (``(Nodetype, argument)`` pairs) and nothing of Zenoh or TCPROS.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mrosd.errors import MsgError

if TYPE_CHECKING:
    from collections.abc import Callable

    from mrosd.ros2.mapping import MappingRules

__all__ = ["MAX_MSG_FILE_SIZE", "Ros2Share", "ros1_definition", "ros1_type_name"]

#: a ``.msg`` file of a ROS 2 share tree larger than this is refused (the largest standard ones are a few kB)
MAX_MSG_FILE_SIZE = 256 * 1024
#: nested types followed at most when loading one type from a share tree (a cycle or a hostile tree stops here)
MAX_NESTED_TYPES = 256
_PART = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")

#: ROS 2 names whose ROS 1 name is not ``pkg/Type``
RENAMED_BACK = {"tf2_msgs/msg/TFMessage": "tf2_msgs/TFMessage"}
#: ROS 2 types that are ROS 1 primitives
_BUILTIN_TIME = {"builtin_interfaces/msg/Time": "time", "builtin_interfaces/msg/Duration": "duration"}


def ros1_type_name(ros2_type: str, rules: MappingRules | None = None) -> str:
    """``pkg/msg/Type`` -> ``pkg/Type`` (by mapping rule first).

    Raises:
        MsgError: not a ``pkg/msg/Type`` name.
    """
    if rules is not None:
        ruled = rules.ros1_message(ros2_type)
        if ruled is not None:
            return ruled
    if ros2_type in RENAMED_BACK:
        return RENAMED_BACK[ros2_type]
    parts = ros2_type.split("/")
    if len(parts) != 3 or parts[1] != "msg" or not parts[0] or not parts[2]:
        raise MsgError(f"ros2: {ros2_type!r} is not a ROS 2 message type (pkg/msg/Type)")
    return f"{parts[0]}/{parts[2]}"


def ros1_definition(
    fielddefs: dict[str, Any],
    ros2_type: str,
    rules: MappingRules | None,
    ros1_knows: Callable[[str], bool],
) -> str:
    """The ROS 1 ``message_definition`` of ``ros2_type``: its text, then a ``MSG:`` section per nested type
    that ``ros1_knows`` does not (standard ROS 1 types come from mrosd's own definitions).

    Raises:
        MsgError: a field ROS 1 cannot express (named), or a nested type missing from ``fielddefs``.
    """
    sections: list[str] = []
    done: set[str] = set()
    todo = [ros2_type]
    while todo:
        name = todo.pop(0)
        if name in done:
            continue
        done.add(name)
        if name not in fielddefs:
            raise MsgError(f"ros2: {ros2_type}: no definition of the nested type {name}")
        text, nested = _one(fielddefs[name], name, ros2_type, rules)
        ros1_name = ros1_type_name(name, rules)
        if name == ros2_type:
            sections.insert(0, text)
        elif not ros1_knows(ros1_name):
            sections.append(f"{'=' * 80}\nMSG: {ros1_name}\n{text}")
        todo.extend(n for n in nested if n not in done and (n == ros2_type or not ros1_knows(ros1_type_name(n, rules))))
    return "\n".join(sections)


def _one(fdef: Any, name: str, top: str, rules: MappingRules | None) -> tuple[str, list[str]]:
    consts, fields = fdef
    rule = rules.message_rule_2to1(name) if rules is not None else None
    back = {two: one for one, two in rule.fields} if rule is not None else {}
    lines = [f"{typ} {cname}={value}" for cname, typ, value in consts]
    nested: list[str] = []
    for fname, desc in fields:
        if fname == "structure_needs_at_least_one_member":
            continue
        lines.append(f"{_type_text(desc, name, fname, top, rules=rules, nested=nested)} {back.get(fname, fname)}")
    return "\n".join(lines) + "\n", nested


def _type_text(desc: Any, owner: str, fname: str, top: str, *, rules: MappingRules | None, nested: list[str]) -> str:
    kind, arg = desc
    if kind.name == "BASE":
        base, _bound = arg
        if base == "wstring":
            raise MsgError(f"ros2: {top}: type {owner} field {fname!r} is a wstring, which ROS 1 has no form for")
        return str(base)
    if kind.name == "NAME":
        if arg in _BUILTIN_TIME:
            return _BUILTIN_TIME[arg]
        nested.append(arg)
        return ros1_type_name(arg, rules)
    inner, count = arg
    item = _type_text(inner, owner, fname, top, rules=rules, nested=nested)
    return f"{item}[{count}]" if kind.name == "ARRAY" else f"{item}[]"


class Ros2Share:
    """ROS 2 ``share`` trees (``<root>/<pkg>/msg/<Type>.msg``) read on demand into rosbags field definitions."""

    def __init__(self, roots: list[str] | tuple[str, ...]) -> None:
        self.roots = [Path(r) for r in roots]

    def find(self, ros2_type: str) -> Path | None:
        """The ``.msg`` file of ``pkg/msg/Type``, or None (names are checked: no path tricks)."""
        parts = ros2_type.split("/")
        if len(parts) != 3 or parts[1] != "msg" or not all(_PART.match(p) for p in (parts[0], parts[2])):
            return None
        for root in self.roots:
            path = root / parts[0] / "msg" / f"{parts[2]}.msg"
            if path.is_file():
                return path
        return None

    def load(self, ros2_type: str, known: Callable[[str], bool]) -> dict[str, Any]:
        """The field definitions of ``ros2_type`` and of every nested type ``known`` does not have.

        Raises:
            MsgError: a file is missing, too big or does not parse (the file named).
        """
        from rosbags.typesys import get_types_from_msg

        found: dict[str, Any] = {}
        todo = [ros2_type]
        while todo:
            name = todo.pop()
            if name in found or known(name):
                continue
            if len(found) >= MAX_NESTED_TYPES:
                raise MsgError(f"ros2: {ros2_type}: over {MAX_NESTED_TYPES} nested types in the share tree")
            path = self.find(name)
            if path is None:
                raise MsgError(f"ros2: no definition of {name} (add its .msg to ros2_share or ROS_PACKAGE_PATH)")
            try:
                with path.open("rb") as f:
                    data = f.read(MAX_MSG_FILE_SIZE + 1)
            except OSError as exc:
                raise MsgError(f"ros2: {path}: cannot read: {exc.strerror or exc}") from exc
            if len(data) > MAX_MSG_FILE_SIZE:
                raise MsgError(f"ros2: {path}: over {MAX_MSG_FILE_SIZE} bytes")
            try:
                parsed = get_types_from_msg(data.decode("utf-8", "replace"), name)
            except Exception as exc:  # rosbags' parser errors
                raise MsgError(f"ros2: {path}: does not parse: {exc}") from exc
            for tname, fdef in parsed.items():
                found[tname] = fdef
                for fname, desc in fdef[1]:
                    nested = _names(desc)
                    if any(n.endswith("/wstring") for n in nested):  # rosbags reads wstring as a type name
                        raise MsgError(f"ros2: {tname}: field {fname!r} is a wstring, which ROS 1 has no form for")
                    todo.extend(nested)
        return found


def _names(desc: Any) -> list[str]:
    kind, arg = desc
    if kind.name == "NAME":
        return [arg]
    if kind.name in ("ARRAY", "SEQUENCE"):
        return _names(arg[0])
    return []
