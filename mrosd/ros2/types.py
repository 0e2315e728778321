"""ROS 1 type -> ROS 2 type, its RIHS01 hash and the body conversion to CDR (pure but for rosbags' tables).

Standard types are mapped by name (``pkg/Type`` -> ``pkg/msg/Type``, ``tf/tfMessage`` ->
``tf2_msgs/msg/TFMessage``) onto rosbags' Jazzy type store, whose byte-level converter drops ``Header.seq`` and
carries ``time``/``duration`` as ``builtin_interfaces/Time``/``Duration`` (the same 8 bytes). A type the store
does not know is derived from the ``message_definition`` of the TCPROS connection: its ROS 1 text is parsed by
rosbags, standard nested types keep their ROS 2 definitions, ``char`` becomes ``uint8`` and ``byte`` ``int8`` (the
ROS 1 meanings), and the RIHS01 hash is computed over the result, so a ROS 2 package with a field-identical
``.msg`` matches. What ROS 2 cannot express is refused with one line naming the type and the field.

Bodies are converted by rosbags at the byte level: arrays of primitives are copied as whole slices, never walked
element by element in Python.
"""

from __future__ import annotations

import re
from typing import Any

import msgspec

from mrosd.errors import MsgError

__all__ = ["TypeMapper", "TypeMapping", "UnmappableTypeError", "ros2_type_name"]

#: ROS 1 names whose ROS 2 name is not ``pkg/msg/Type``
RENAMED = {"tf/tfMessage": "tf2_msgs/msg/TFMessage"}
#: ROS 1 primitive -> the ROS 2 primitive of the same bytes and meaning
_PRIMITIVES = {"char": "uint8", "byte": "int8"}
#: rosidl's rule for field names
_FIELD_NAME = re.compile(r"^(?!.*__)(?!.*_$)[a-z][a-z0-9_]*$")
#: a message_definition longer than this is refused before it is parsed (the largest standard ones, with every
#: nested definition, are a few tens of kB)
MAX_DEFINITION_SIZE = 1 << 20


class UnmappableTypeError(MsgError):
    """A ROS 1 type has no ROS 2 form; the message is the one log line (type, field, what to add)."""


class TypeMapping(msgspec.Struct, frozen=True):
    """How one ROS 1 type crosses: its ROS 2 name and RIHS01 hash."""

    ros1_type: str
    ros2_type: str
    type_hash: str


def ros2_type_name(ros1_type: str) -> str:
    """``pkg/Type`` -> ``pkg/msg/Type`` (and the renamed ones).

    Raises:
        UnmappableTypeError: not a ``pkg/Type`` name.
    """
    if ros1_type in RENAMED:
        return RENAMED[ros1_type]
    parts = ros1_type.split("/")
    if len(parts) != 2 or not all(parts):
        raise UnmappableTypeError(f"ros2: {ros1_type!r} is not a ROS 1 type name (pkg/Type)")
    return f"{parts[0]}/msg/{parts[1]}"


class TypeMapper:
    """One rosbags Jazzy type store, grown by the custom types met; ``mapping`` then ``to_cdr`` per body."""

    def __init__(self) -> None:
        from rosbags.typesys import Stores, get_typestore

        self._store: Any = get_typestore(Stores.ROS2_JAZZY)
        self._mappings: dict[str, TypeMapping] = {}

    @property
    def store(self) -> Any:
        """The rosbags type store (services add their wrapper types to it: ``mrosd.ros2.srvtypes``)."""
        return self._store

    def mapping(self, ros1_type: str, message_definition: str = "", *, ros2_type: str = "") -> TypeMapping:
        """The ROS 2 name and hash of ``ros1_type``; custom types are derived from ``message_definition``;
        ``ros2_type`` names the ROS 2 type when it is not ``pkg/msg/Type`` (a service's ``pkg/srv/X_Request``).

        Raises:
            UnmappableTypeError: no standard ROS 2 type and no usable definition, or a field ROS 2 cannot have.
        """
        known = self._mappings.get(ros1_type)
        if known is not None:
            return known
        ros2_type = ros2_type or ros2_type_name(ros1_type)
        if ros2_type not in self._store.types:
            self._register(ros1_type, ros2_type, message_definition)
        try:
            type_hash = self._store.hash_rihs01(ros2_type)
        except Exception as exc:  # rosbags' own errors: a nested type it cannot hash
            raise UnmappableTypeError(f"ros2: {ros1_type}: no RIHS01 hash: {exc}") from exc
        mapping = TypeMapping(ros1_type, ros2_type, type_hash)
        self._mappings[ros1_type] = mapping
        return mapping

    def to_cdr(self, ros2_type: str, body: bytes | bytearray | memoryview) -> memoryview:
        """A ROS 1 body of ``ros2_type`` (from ``mapping``) as CDR with its 4-byte encapsulation header.

        Raises:
            MsgError: the body does not match the type (a peer's bad bytes).
        """
        try:
            # a memoryview: rosbags slices its input, and a slice of ``bytes`` is a copy (6 MB per 1080p image)
            raw = body if isinstance(body, memoryview) else memoryview(body)
            out: memoryview = self._store.ros1_to_cdr(raw, ros2_type)
        except Exception as exc:
            raise MsgError(f"ros2: a {ros2_type} body does not convert: {exc}") from exc
        return out

    def to_ros1(self, ros2_type: str, cdr: bytes | memoryview) -> memoryview:
        """A CDR body as ROS 1 bytes (``Header.seq`` is 0).

        Raises:
            MsgError: the body does not match the type.
        """
        try:
            out: memoryview = self._store.cdr_to_ros1(
                cdr if isinstance(cdr, memoryview) else memoryview(cdr), ros2_type
            )
        except Exception as exc:
            raise MsgError(f"ros2: a {ros2_type} CDR body does not convert: {exc}") from exc
        return out

    def _register(self, ros1_type: str, ros2_type: str, definition: str) -> None:
        from rosbags.typesys import get_types_from_msg

        if not definition:
            raise UnmappableTypeError(
                f"ros2: {ros1_type}: not a standard type and its publisher sent no message_definition"
            )
        if len(definition) > MAX_DEFINITION_SIZE:
            raise UnmappableTypeError(f"ros2: {ros1_type}: message_definition over {MAX_DEFINITION_SIZE} bytes")
        try:
            # rosbags reads ``pkg/srv/X_Request`` as ``pkg/srv/msg/X_Request``: parse as a msg, then rename
            pkg, _, name = ros2_type.rpartition("/")
            as_msg = f"{pkg.partition('/')[0]}/msg/{name}"
            parsed = get_types_from_msg(definition, as_msg)
            if as_msg != ros2_type and as_msg in parsed:
                parsed[ros2_type] = parsed.pop(as_msg)
        except Exception as exc:
            raise UnmappableTypeError(f"ros2: {ros1_type}: message_definition does not parse: {exc}") from exc
        fresh: dict[str, Any] = {}
        for name, (consts, fields) in parsed.items():
            if name in self._store.types:
                continue  # a standard type keeps its ROS 2 definition (Header without seq, ...)
            new_fields = []
            for fname, desc in fields:
                if not _FIELD_NAME.match(fname):
                    raise UnmappableTypeError(
                        f"ros2: {ros1_type}: type {name} field {fname!r} is not a ROS 2 field name "
                        "(lower case, digits, single underscores); add a field mapping rule for it"
                    )
                new_fields.append((fname, _rewrite(desc)))
            new_consts = [(c, _PRIMITIVES.get(t, t), v) for c, t, v in consts]
            fresh[name] = (new_consts, new_fields)
        try:
            self._store.register(fresh)
        except Exception as exc:
            raise UnmappableTypeError(f"ros2: {ros1_type}: rosbags refused the derived types: {exc}") from exc


def _rewrite(desc: Any) -> Any:
    """A rosbags field description with ``char``/``byte`` replaced by their ROS 2 primitives."""
    kind, arg = desc
    if kind.name == "BASE":
        base, bound = arg
        return (kind, (_PRIMITIVES.get(base, base), bound))
    if kind.name in ("ARRAY", "SEQUENCE"):
        inner, count = arg
        return (kind, (_rewrite(inner), count))
    return desc
