"""ROS 1 type -> ROS 2 type, its RIHS01 hash and the body conversion to CDR (pure but for rosbags' tables).

Standard types are mapped by name (``pkg/Type`` -> ``pkg/msg/Type``, ``tf/tfMessage`` ->
``tf2_msgs/msg/TFMessage``) onto rosbags' Jazzy type store, whose byte-level converter drops ``Header.seq`` and
carries ``time``/``duration`` as ``builtin_interfaces/Time``/``Duration`` (the same 8 bytes). A type the store
does not know is derived from the ``message_definition`` of the TCPROS connection: its ROS 1 text is parsed by
rosbags, standard nested types keep their ROS 2 definitions, ``char`` becomes ``uint8`` and ``byte`` ``int8`` (the
ROS 1 meanings), and the RIHS01 hash is computed over the result, so a ROS 2 package with a field-identical
``.msg`` matches. What ROS 2 cannot express is refused with one line naming the type and the field.

ros1_bridge's mapping rules (``mrosd.ros2.mapping``) rename packages, types and fields on the way; ROS 2 types
found in a ``share`` tree (``ros2_share``) are used as they are written there. The other way, ``ros1_for`` gives a
ROS 2 type its ROS 1 form: the one on mrosd's ROS 1 search path (``ROS_PACKAGE_PATH`` included) if there is one,
else one written from the ROS 2 definition (``mrosd.ros2.ros1defs``), with its md5 computed as genmsg does.

Bodies are converted by rosbags at the byte level: arrays of primitives are copied as whole slices, never walked
element by element in Python.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING, Any

import msgspec

from mrosd.errors import MrosError, MsgError
from mrosd.ros2.ros1defs import Ros2Share, ros1_definition, ros1_type_name

if TYPE_CHECKING:
    from mrosd.ros2.mapping import MappingRules

__all__ = ["Ros1Type", "TypeMapper", "TypeMapping", "UnmappableTypeError", "ros2_type_name"]

#: ROS 1 names whose ROS 2 name is not ``pkg/msg/Type``
RENAMED = {"tf/tfMessage": "tf2_msgs/msg/TFMessage"}
#: ROS 1 primitive -> the ROS 2 primitive of the same bytes and meaning
_PRIMITIVES = {"char": "uint8", "byte": "int8"}
#: rosidl's rule for field names
_FIELD_NAME = re.compile(r"^(?!.*__)(?!.*_$)[a-z][a-z0-9_]*$")
#: a message_definition longer than this is refused before it is parsed (the largest standard ones, with every
#: nested definition, are a few tens of kB)
MAX_DEFINITION_SIZE = 1 << 20
#: ROS 1 type names whose presence on the search path is remembered (a ROS 2 peer can announce any number of
#: made-up types; the table is emptied when full)
MAX_KNOWN_NAMES = 1024


class UnmappableTypeError(MsgError):
    """A ROS 1 type has no ROS 2 form; the message is the one log line (type, field, what to add)."""


class TypeMapping(msgspec.Struct, frozen=True):
    """How one ROS 1 type crosses: its ROS 2 name and RIHS01 hash."""

    ros1_type: str
    ros2_type: str
    type_hash: str


class Ros1Type(msgspec.Struct, frozen=True):
    """How one ROS 2 type crosses to ROS 1: its ROS 1 name, md5 and ``message_definition``, and its mapping."""

    ros1_type: str
    md5sum: str
    definition: str
    mapping: TypeMapping


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

    def __init__(self, rules: MappingRules | None = None, ros2_share: list[str] | tuple[str, ...] = ()) -> None:
        from rosbags.typesys import Stores, get_typestore

        self._store: Any = get_typestore(Stores.ROS2_JAZZY)
        #: the types rosbags' Jazzy store has before anything is added (the standard ones)
        self._standard = frozenset(self._store.types)
        self._mappings: dict[str, TypeMapping] = {}
        self._back: dict[str, Ros1Type] = {}
        self._ros1_known: dict[str, bool] = {}
        self.rules = rules
        self.share = Ros2Share(ros2_share) if ros2_share else None

    @property
    def store(self) -> Any:
        """The rosbags type store every mapped type is registered in (``mrosd.ros2.bagconvert`` writes with it;
        services add their wrapper types to it: ``mrosd.ros2.srvtypes``)."""
        return self._store

    def ros2_name(self, ros1_type: str) -> str:
        """The ROS 2 name of a ROS 1 type: by mapping rule, else by name.

        Raises:
            UnmappableTypeError: not a ``pkg/Type`` name.
        """
        ruled = self.rules.ros2_message(ros1_type) if self.rules else None
        return ruled or ros2_type_name(ros1_type)

    def mapping(self, ros1_type: str, message_definition: str = "", *, ros2_type: str = "") -> TypeMapping:
        """The ROS 2 name and hash of ``ros1_type``; custom types are derived from ``message_definition``;
        ``ros2_type`` names the ROS 2 type when it is not ``pkg/msg/Type`` (a service's ``pkg/srv/X_Request``).

        Raises:
            UnmappableTypeError: no standard ROS 2 type and no usable definition, or a field ROS 2 cannot have.
        """
        known = self._mappings.get(ros1_type)
        if known is not None:
            return known
        ros2_type = ros2_type or self.ros2_name(ros1_type)
        standard = ros2_type in self._standard
        if ros2_type not in self._store.types:
            self._from_share(ros2_type)
        if ros2_type not in self._store.types:
            self._register(ros1_type, ros2_type, message_definition)
        try:
            type_hash = self._store.hash_rihs01(ros2_type)
        except Exception as exc:  # rosbags' own errors: a nested type it cannot hash
            raise UnmappableTypeError(f"ros2: {ros1_type}: no RIHS01 hash: {exc}") from exc
        if self.share is not None and message_definition and not standard:
            # bodies are converted byte for byte with the share tree's layout: it must be the publisher's
            scratch = TypeMapper(self.rules)
            scratch.mapping(ros1_type, message_definition, ros2_type=ros2_type)
            where = _layout_difference(scratch.store.fielddefs, self._store.fielddefs, ros2_type)
            if where:
                raise UnmappableTypeError(
                    f"ros2: {ros1_type}: its message_definition is not {ros2_type} as the ROS 2 share tree defines "
                    f"it ({where}); make the two .msg agree"
                )
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

    def ros1_for(self, ros2_type: str) -> Ros1Type:
        """The ROS 1 form of a ROS 2 type: from mrosd's ROS 1 search path if it has the type, else written from
        the ROS 2 definition (rosbags' Jazzy store, then ``ros2_share``), md5 computed as genmsg does.

        Raises:
            UnmappableTypeError: no definition anywhere, or a field one side cannot express (named).
        """
        known = self._back.get(ros2_type)
        if known is not None:
            return known
        from mrosd.msg import get_message_class, load_type

        try:
            ros1_type = ros1_type_name(ros2_type, self.rules)
        except MsgError as exc:
            raise UnmappableTypeError(str(exc)) from None
        if self._knows_ros1(ros1_type):
            cls = get_message_class(ros1_type)
            mapping = self.mapping(ros1_type, str(cls._full_text))
            if mapping.ros2_type != ros2_type:
                raise UnmappableTypeError(
                    f"ros2: {ros2_type}: ROS 1's {ros1_type} maps to {mapping.ros2_type}; add a message mapping rule"
                )
            back = Ros1Type(ros1_type, str(cls._md5sum), str(cls._full_text), mapping)
        else:
            if ros2_type not in self._store.types:
                try:
                    self._from_share(ros2_type, required=True)
                except MsgError as exc:
                    raise UnmappableTypeError(str(exc)) from None
            try:
                text = _full_text(
                    ros1_type, ros1_definition(self._store.fielddefs, ros2_type, self.rules, self._knows_ros1)
                )
                cls = load_type(ros1_type, text)
                type_hash = self._store.hash_rihs01(ros2_type)
            except UnmappableTypeError:
                raise
            except MrosError as exc:
                raise UnmappableTypeError(f"ros2: {ros2_type}: no ROS 1 form: {exc}") from None
            except Exception as exc:  # rosbags' own errors
                raise UnmappableTypeError(f"ros2: {ros2_type}: no RIHS01 hash: {exc}") from exc
            mapping = TypeMapping(ros1_type, ros2_type, type_hash)
            self._mappings[ros1_type] = mapping
            back = Ros1Type(ros1_type, str(cls._md5sum), text, mapping)
        self._back[ros2_type] = back
        return back

    def _knows_ros1(self, ros1_type: str) -> bool:
        hit = self._ros1_known.get(ros1_type)
        if hit is None:
            from mrosd.msg import get_message_class

            try:
                get_message_class(ros1_type)
                hit = True
            except MsgError:
                hit = False
            if len(self._ros1_known) >= MAX_KNOWN_NAMES:  # names come from peers' announcements: never unbounded
                self._ros1_known.clear()
            self._ros1_known[ros1_type] = hit
        return hit

    def _from_share(self, ros2_type: str, *, required: bool = False) -> None:
        """Register ``ros2_type`` (and what it nests) from the ROS 2 share trees, if they have it."""
        if self.share is None or self.share.find(ros2_type) is None:
            if required:
                raise MsgError(
                    f"ros2: no definition of {ros2_type}: add its ROS 1 .msg to ROS_PACKAGE_PATH or a ROS 2 "
                    "share tree holding it to ros2_share"
                )
            return
        defs = self.share.load(ros2_type, lambda name: name in self._store.types)
        try:
            self._store.register(defs)
        except Exception as exc:
            raise UnmappableTypeError(f"ros2: {ros2_type}: rosbags refused the share tree's definition: {exc}") from exc

    def _field_renames(self, ros1_type: str) -> dict[str, str]:
        rule = self.rules.message_rule(ros1_type) if self.rules else None
        if rule is None:
            return {}
        try:
            return rule.field_renames()
        except MrosError as exc:
            raise UnmappableTypeError(str(exc)) from None

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
        # rosbags names the nested types ``pkg/msg/Type`` after their ROS 1 package: rename them by rule
        names = {name: name if name == ros2_type else self.ros2_name(_ros1_of(name)) for name in parsed}
        fresh: dict[str, Any] = {}
        for name, (consts, fields) in parsed.items():
            target = names[name]
            if target not in self._store.types:
                self._from_share(target)
            if target in self._store.types:
                continue  # a standard type keeps its ROS 2 definition (Header without seq, ...)
            renames = self._field_renames(ros1_type if name == ros2_type else _ros1_of(name))
            new_fields = []
            for ros1_field, desc in fields:
                fname = renames.get(ros1_field, ros1_field)
                if not _FIELD_NAME.match(fname):
                    raise UnmappableTypeError(
                        f"ros2: {ros1_type}: type {name} field {fname!r} is not a ROS 2 field name "
                        "(lower case, digits, single underscores); add a field mapping rule for it"
                    )
                new_fields.append((fname, _rewrite(desc, names)))
            new_consts = [(c, _PRIMITIVES.get(t, t), v) for c, t, v in consts]
            fresh[target] = (new_consts, new_fields)
        try:
            self._store.register(fresh)
        except Exception as exc:
            raise UnmappableTypeError(f"ros2: {ros1_type}: rosbags refused the derived types: {exc}") from exc


def _full_text(ros1_type: str, custom: str) -> str:
    """The whole ``message_definition`` genpy would send: ``custom`` (the type and its custom nested types) with
    the standard nested types' ROS 1 sections added (``std_msgs/Header`` with ``seq``), which rosbag and genpy
    need to decode it.

    Raises:
        MsgError: the text does not parse or uses a type nobody defines.
    """
    from mrosd.msg import TypeStore
    from mrosd.msg.parser import parse_definition

    store = TypeStore()
    for spec in parse_definition(ros1_type, custom).values():
        store.add(spec)
    return store.full_text(ros1_type)


def _layout_difference(ours: Any, theirs: Any, name: str, depth: int = 0) -> str:
    """Where two definitions of ``name`` lay their bytes out differently ("" if they do not): the field types in
    order, nested types followed; names, bounds and defaults do not change the bytes and are ignored."""
    a, b = ours[name][1], theirs[name][1]
    if len(a) != len(b):
        return f"{name}: {len(a)} fields, not {len(b)}"
    for (fname, da), (_, db) in zip(a, b, strict=True):
        if depth > 32:
            return f"{name}: nested too deep"
        why = _desc_difference(ours, theirs, da, db, depth)
        if why:
            return f"{name} field {fname!r}: {why}"
    return ""


def _desc_difference(ours: Any, theirs: Any, da: Any, db: Any, depth: int) -> str:
    (ka, aa), (kb, ab) = da, db
    if ka.name != kb.name:
        return f"{ka.name.lower()} here, {kb.name.lower()} there"
    if ka.name == "BASE":
        return "" if aa[0] == ab[0] else f"{aa[0]} here, {ab[0]} there"
    if ka.name == "NAME":
        return _layout_difference(ours, theirs, aa, depth + 1) if aa in ours and ab in theirs else ""
    if ka.name == "ARRAY" and aa[1] != ab[1]:
        return f"{aa[1]} items here, {ab[1]} there"
    return _desc_difference(ours, theirs, aa[0], ab[0], depth)


def _ros1_of(rosbags_name: str) -> str:
    """rosbags' ``pkg/msg/Type`` for a type parsed from a ROS 1 definition -> its ROS 1 ``pkg/Type``."""
    pkg, _, name = rosbags_name.rpartition("/")
    return f"{pkg.split('/')[0]}/{name}"


def _rewrite(desc: Any, names: dict[str, str]) -> Any:
    """A rosbags field description with ``char``/``byte`` replaced by their ROS 2 primitives and nested types
    renamed (``names``: parsed name -> ROS 2 name)."""
    kind, arg = desc
    if kind.name == "BASE":
        base, bound = arg
        return (kind, (_PRIMITIVES.get(base, base), bound))
    if kind.name == "NAME":
        return (kind, names.get(arg, arg))
    if kind.name in ("ARRAY", "SEQUENCE"):
        inner, count = arg
        return (kind, (_rewrite(inner, names), count))
    return desc
