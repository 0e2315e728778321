"""rmw_zenoh's names on Zenoh: data keys, liveliness tokens, name mangling and the QoS string (pure).

What a ROS 2 node running ``rmw_zenoh_cpp`` (the Jazzy line, zenoh 1.x) puts on Zenoh, as read in its source
(``rmw_zenoh_cpp/src/detail/liveliness_utils.cpp`` and ``qos.cpp``):

- a topic's data key is ``<domain>/<name without leading or trailing '/'>/<dds type>/<type hash>``, e.g.
  ``0/chatter/std_msgs::msg::dds_::String_/RIHS01_df66...``;
- every node and endpoint holds a liveliness token
  ``@ros2_lv/<domain>/<zid>/<nid>/<id>/<NN|MP|MS|SS|SC>/<enclave>/<namespace>/<node>``, followed for endpoints
  by ``/<topic>/<dds type>/<type hash>/<qos>``; each ``/`` inside a component is mangled to ``%`` (so the root
  namespace ``/`` is ``%`` and ``/chatter`` is ``%chatter``);
- the QoS string is ``<reliability>:<durability>:<history>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:
  <liveliness>,<lease s>,<ns>`` with rmw's enum numbers, and a value equal to rmw_zenoh's default left empty.

No sockets, no asyncio, no zenoh import here: the shells in this package put and declare what this module names.
"""

from __future__ import annotations

import enum

import msgspec

from mrosd.errors import RemoteProtocolError

__all__ = [
    "ADMIN_SPACE",
    "DEFAULT_QOS",
    "MAX_TOKEN_LENGTH",
    "EntityKind",
    "LivelinessToken",
    "Qos",
    "data_key",
    "dds_type_name",
    "decode_qos",
    "demangle_name",
    "encode_qos",
    "mangle_name",
    "parse_token",
    "ros2_type_of_dds",
]

#: the first chunk of every liveliness token
ADMIN_SPACE = "@ros2_lv"
#: rmw_zenoh's component separators inside the QoS chunk
_QOS_DELIMITER = ":"
_QOS_COMPONENT_DELIMITER = ","
#: a token is never longer than this (a peer's token is parsed before anything else looks at it); the longest
#: real ones are a few hundred characters: deep namespaces, long type names and a 71-character hash
MAX_TOKEN_LENGTH = 4096

#: rmw's RMW_DURATION_INFINITE as (sec, nsec): rmw_zenoh's default deadline, lifespan and lease
_INFINITE = (9223372036, 854775807)

# rmw/types.h enum values
RELIABILITY_RELIABLE = 1
RELIABILITY_BEST_EFFORT = 2
DURABILITY_TRANSIENT_LOCAL = 1
DURABILITY_VOLATILE = 2
HISTORY_KEEP_LAST = 1
HISTORY_KEEP_ALL = 2
LIVELINESS_AUTOMATIC = 1


class EntityKind(enum.Enum):
    """The entity chunk of a liveliness token."""

    NODE = "NN"
    PUBLISHER = "MP"
    SUBSCRIPTION = "MS"
    SERVICE = "SS"
    CLIENT = "SC"


class Qos(msgspec.Struct, frozen=True, kw_only=True):
    """The QoS a token carries, with rmw's enum numbers; the defaults are rmw_zenoh's (``qos.cpp``)."""

    reliability: int = RELIABILITY_RELIABLE
    durability: int = DURABILITY_VOLATILE
    history: int = HISTORY_KEEP_LAST
    depth: int = 42
    deadline: tuple[int, int] = _INFINITE
    lifespan: tuple[int, int] = _INFINITE
    liveliness: int = LIVELINESS_AUTOMATIC
    lease: tuple[int, int] = _INFINITE


DEFAULT_QOS = Qos()


class LivelinessToken(msgspec.Struct, frozen=True, kw_only=True):
    """One rmw_zenoh liveliness token, parsed; ``topic``, ``type_name``, ``type_hash`` and ``qos`` are set for
    every entity but a node. Names are demangled (``/chatter``, namespace ``/``)."""

    domain_id: int
    zid: str
    nid: str
    id: str
    kind: EntityKind
    enclave: str
    namespace: str
    node: str
    topic: str = ""
    type_name: str = ""
    type_hash: str = ""
    qos: Qos | None = None

    def key(self) -> str:
        """The token's key expression, as rmw_zenoh builds it."""
        parts = [
            ADMIN_SPACE,
            str(self.domain_id),
            self.zid,
            self.nid,
            self.id,
            self.kind.value,
            mangle_name(self.enclave),
            mangle_name(self.namespace),
            mangle_name(self.node),
        ]
        if self.kind is not EntityKind.NODE:
            parts += [
                mangle_name(self.topic),
                mangle_name(self.type_name),
                mangle_name(self.type_hash),
                encode_qos(self.qos or DEFAULT_QOS),
            ]
        return "/".join(parts)


def mangle_name(name: str) -> str:
    """``/`` -> ``%``: a ROS name as one key chunk."""
    return name.replace("/", "%")


def demangle_name(chunk: str) -> str:
    """``%`` -> ``/``: the inverse of ``mangle_name``."""
    return chunk.replace("%", "/")


def dds_type_name(ros2_type: str) -> str:
    """``std_msgs/msg/String`` -> ``std_msgs::msg::dds_::String_`` (the name in keys and tokens).

    Raises:
        ValueError: not a ``pkg/msg/Type`` (or ``srv``) name.
    """
    parts = ros2_type.split("/")
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"not a ROS 2 type name (pkg/msg/Type): {ros2_type!r}")
    pkg, kind, name = parts
    return f"{pkg}::{kind}::dds_::{name}_"


def ros2_type_of_dds(dds_name: str) -> str:
    """``std_msgs::msg::dds_::String_`` -> ``std_msgs/msg/String`` (as ``ros2 topic list -t`` shows it).

    Raises:
        RemoteProtocolError: not a DDS type name of that shape.
    """
    parts = dds_name.split("::")
    if len(parts) != 4 or parts[2] != "dds_" or not parts[3].endswith("_") or len(parts[3]) < 2:
        raise RemoteProtocolError(f"not an rmw_zenoh type name: {dds_name[:200]!r}")
    return f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"


def data_key(domain_id: int, topic: str, ros2_type: str, type_hash: str) -> str:
    """The key a topic's samples are put on: ``<domain>/<topic>/<dds type>/<hash>`` (the topic's slashes at
    either end stripped, inner ones kept)."""
    return f"{domain_id}/{topic.strip('/')}/{dds_type_name(ros2_type)}/{type_hash}"


def _pair(sec_ns: tuple[int, int], default: tuple[int, int]) -> str:
    return _QOS_COMPONENT_DELIMITER.join("" if v == d else str(v) for v, d in zip(sec_ns, default, strict=True))


def encode_qos(qos: Qos) -> str:
    """The QoS chunk of a token; a value equal to rmw_zenoh's default is left out (empty)."""
    d = DEFAULT_QOS

    def one(v: int, dv: int) -> str:
        return "" if v == dv else str(v)

    return _QOS_DELIMITER.join(
        [
            one(qos.reliability, d.reliability),
            one(qos.durability, d.durability),
            one(qos.history, d.history) + _QOS_COMPONENT_DELIMITER + one(qos.depth, d.depth),
            _pair(qos.deadline, d.deadline),
            _pair(qos.lifespan, d.lifespan),
            one(qos.liveliness, d.liveliness) + _QOS_COMPONENT_DELIMITER + _pair(qos.lease, d.lease),
        ]
    )


def _number(text: str, default: int, what: str) -> int:
    if text == "":
        return default
    if not text.isdigit() or len(text) > 20:
        raise RemoteProtocolError(f"liveliness QoS: {what} is not a number: {text[:30]!r}")
    return int(text)


def decode_qos(text: str) -> Qos:
    """Parse a token's QoS chunk (empty values are rmw_zenoh's defaults).

    Raises:
        RemoteProtocolError: fewer components than rmw_zenoh writes, or a value that is not a number.
    """
    parts = text.split(_QOS_DELIMITER)
    if len(parts) < 6:
        raise RemoteProtocolError(f"liveliness QoS has {len(parts)} of 6 components: {text[:100]!r}")
    history = parts[2].split(_QOS_COMPONENT_DELIMITER)
    deadline = parts[3].split(_QOS_COMPONENT_DELIMITER)
    lifespan = parts[4].split(_QOS_COMPONENT_DELIMITER)
    live = parts[5].split(_QOS_COMPONENT_DELIMITER)
    if len(history) < 2 or len(deadline) < 2 or len(lifespan) < 2 or len(live) < 3:
        raise RemoteProtocolError(f"liveliness QoS has a short component: {text[:100]!r}")
    d = DEFAULT_QOS
    return Qos(
        reliability=_number(parts[0], d.reliability, "reliability"),
        durability=_number(parts[1], d.durability, "durability"),
        history=_number(history[0], d.history, "history"),
        depth=_number(history[1], d.depth, "depth"),
        deadline=(_number(deadline[0], d.deadline[0], "deadline"), _number(deadline[1], d.deadline[1], "deadline")),
        lifespan=(_number(lifespan[0], d.lifespan[0], "lifespan"), _number(lifespan[1], d.lifespan[1], "lifespan")),
        liveliness=_number(live[0], d.liveliness, "liveliness"),
        lease=(_number(live[1], d.lease[0], "lease"), _number(live[2], d.lease[1], "lease")),
    )


def parse_token(key: str) -> LivelinessToken:
    """Parse a liveliness token's key expression (as rmw_zenoh's ``Entity::make(keyexpr)`` does).

    Raises:
        RemoteProtocolError: too long, too few chunks, an empty chunk, another admin space, an unknown entity,
            a domain that is not a number, or a bad QoS chunk.
    """
    if len(key) > MAX_TOKEN_LENGTH:
        raise RemoteProtocolError(f"liveliness token longer than {MAX_TOKEN_LENGTH} characters")
    parts = key.split("/")
    if len(parts) < 9 or any(p == "" for p in parts):
        raise RemoteProtocolError(f"liveliness token with {len(parts)} chunks or an empty one: {key[:200]!r}")
    if parts[0] != ADMIN_SPACE:
        raise RemoteProtocolError(f"liveliness token outside {ADMIN_SPACE}: {key[:200]!r}")
    try:
        kind = EntityKind(parts[5])
    except ValueError:
        raise RemoteProtocolError(f"liveliness token with unknown entity {parts[5][:10]!r}") from None
    if not parts[1].isdigit() or len(parts[1]) > 10:
        raise RemoteProtocolError(f"liveliness token with a bad domain id {parts[1][:20]!r}")
    common = {
        "domain_id": int(parts[1]),
        "zid": parts[2],
        "nid": parts[3],
        "id": parts[4],
        "kind": kind,
        "enclave": demangle_name(parts[6]),
        "namespace": demangle_name(parts[7]),
        "node": demangle_name(parts[8]),
    }
    if kind is EntityKind.NODE:
        return LivelinessToken(**common)  # type: ignore[arg-type]
    if len(parts) < 13:
        raise RemoteProtocolError(f"liveliness token of an endpoint without topic, type, hash or QoS: {key[:200]!r}")
    return LivelinessToken(
        **common,  # type: ignore[arg-type]
        topic=demangle_name(parts[9]),
        type_name=demangle_name(parts[10]),
        type_hash=demangle_name(parts[11]),
        qos=decode_qos(parts[12]),
    )
