"""zenoh-bridge-ros1's key expressions, per-robot renaming and topic globs: pure, no Zenoh import.

The facts come from the bridge's source (zenoh-plugin-ros1, ``topic_utilities.rs`` and ``discovery.rs``), so a
robot running mrosd and one running ROS + zenoh-bridge-ros1 see each other without a change on either side:

- data: ``hex(type)/md5/NS/topic``, the type as lower-case hex of the UTF-8 ``pkg/Name``, the topic without its
  leading and trailing ``/``, NS the bridge namespace (``*`` unless ``BRIDGE_NAMESPACE`` is set). A service
  uses the same form, with the service's type and md5, for the queryable its provider declares.
- discovery: ``ros1_discovery_info/DNS/CLASS/hex(type)/md5/NS/topic``, DNS the discovery namespace (the bridge
  always uses ``*``), CLASS one of ``pub``, ``sub``, ``srv``, ``cl``; the sample carries no payload. Each
  announced item is put again every second; a listener forgets it after three seconds of silence.
- payload: the ROS 1 message body as TCPROS carries it, without the frame's 4-byte length.

mrosd uses NS for the robot's name: a remote robot's topics appear locally under ``/<robot>/...``
(``RenameRule``). A plain bridge announces NS ``*``, which matches every name; its items are kept under the
name configured for it (``RenameRule.wildcard_robot``), and left out without one.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache

from mrosd.backports import StrEnum
from mrosd.errors import RemoteProtocolError
from mrosd.names import canonicalize, is_valid_name

#: The first chunk of every discovery key.
DISCOVERY_PREFIX = "ros1_discovery_info"
#: The bridge's default namespaces (``BRIDGE_NAMESPACE`` unset; the discovery namespace is never configurable).
WILDCARD_NS = "*"
#: The attachment mrosd puts on the samples of a latched topic (a zenoh-bridge-ros1 ignores attachments): the
#: receiving robot then latches them too, so later local subscribers get the last one.
LATCHED_ATTACHMENT = b"mrosd:latched"
#: Seconds between two announcements of one item, and of silence after which a listener forgets it.
ANNOUNCE_PERIOD = 1.0
FORGET_AFTER = 3.0 * ANNOUNCE_PERIOD

_MD5 = re.compile(r"^([0-9a-f]{32}|\*)$")
_HEX = re.compile(r"^([0-9a-f]{2})+$")
#: A message or service type: ``pkg/Name`` (genmsg's rules; the bridge may also announce ``*``).
_TYPE = re.compile(r"^[A-Za-z][A-Za-z0-9_]*/[A-Za-z][A-Za-z0-9_]*$")
#: A namespace chunk we put into keys: one Zenoh chunk, no wildcard or special characters.
_NS = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")


class FleetKeyError(RemoteProtocolError):
    """A key expression from the Zenoh side does not have the bridge's form; the item is ignored."""


class ItemKind(StrEnum):
    """What a discovery key announces (the bridge's resource classes)."""

    PUBLISHER = "pub"
    SUBSCRIBER = "sub"
    SERVICE = "srv"
    CLIENT = "cl"


@dataclass(frozen=True, slots=True)
class Item:
    """One topic or service as the bridge describes it: ``topic`` global (``/chatter``), ``namespace`` the
    bridge namespace it was announced under (a robot's name, or ``*``)."""

    kind: ItemKind
    type: str
    md5sum: str
    namespace: str
    topic: str

    @property
    def data_key(self) -> str:
        """Where the data (or the service queryable) of this item lives."""
        return data_key(self.type, self.md5sum, self.namespace, self.topic)

    @property
    def discovery_key(self) -> str:
        """The key this item is announced on."""
        return discovery_key(self.kind, self.type, self.md5sum, self.namespace, self.topic)


def topic_chunks(topic: str) -> str:
    """A ROS name as the key's tail: no leading or trailing ``/`` (``/a/b/`` -> ``a/b``)."""
    return topic.strip("/")


def type_hex(msg_type: str) -> str:
    """The type chunk: lower-case hex of the UTF-8 type name (``std_msgs/String`` -> ``7374...``)."""
    return msg_type.encode().hex()


def _check_namespace(namespace: str) -> None:
    if namespace != WILDCARD_NS and not _NS.match(namespace):
        raise ValueError(f"bridge namespace {namespace!r} must be '*' or one key chunk of letters, digits, _ . -")


def data_key(msg_type: str, md5sum: str, namespace: str, topic: str) -> str:
    """The data key of a topic or service (``hex(type)/md5/NS/topic``).

    Raises:
        ValueError: the namespace is not one plain chunk or ``*``, or the topic is not a legal ROS name.
    """
    _check_namespace(namespace)
    tail = topic_chunks(topic)
    if not tail or not is_valid_name("/" + tail):
        raise ValueError(f"{topic!r} is not a legal global ROS name")
    return f"{type_hex(msg_type)}/{md5sum}/{namespace}/{tail}"


def discovery_key(kind: ItemKind, msg_type: str, md5sum: str, namespace: str, topic: str) -> str:
    """The announcement key (``ros1_discovery_info/*/CLASS/hex(type)/md5/NS/topic``).

    Raises:
        ValueError: as ``data_key``.
    """
    return f"{DISCOVERY_PREFIX}/{WILDCARD_NS}/{kind.value}/{data_key(msg_type, md5sum, namespace, topic)}"


def discovery_subscription(namespace: str = WILDCARD_NS) -> str:
    """What a listener subscribes to for announcements in ``namespace`` (``*``: from every robot)."""
    _check_namespace(namespace)
    return f"{DISCOVERY_PREFIX}/*/*/*/*/{namespace}/*/**"


def parse_discovery_key(key: str) -> Item:
    """The item a discovery key announces.

    Raises:
        FleetKeyError: not seven or more chunks, an unknown class, a type that is not hex of ``pkg/Name``,
            an md5 that is not 32 hex digits (or ``*``), a namespace or topic that is not legal.
    """
    parts = key.split("/")
    if len(parts) < 7 or parts[0] != DISCOVERY_PREFIX:
        raise FleetKeyError(f"not a discovery key: {key[:200]!r}")
    _dns, cls, hex_type, md5sum, namespace = parts[1:6]
    try:
        kind = ItemKind(cls)
    except ValueError:
        raise FleetKeyError(f"unknown resource class {cls[:20]!r} in {key[:200]!r}") from None
    msg_type = _parse_type(hex_type, key)
    if not _MD5.match(md5sum):
        raise FleetKeyError(f"md5 {md5sum[:40]!r} is not 32 lower-case hex digits in {key[:200]!r}")
    if namespace != WILDCARD_NS and not _NS.match(namespace):
        raise FleetKeyError(f"namespace {namespace[:40]!r} is not one plain chunk in {key[:200]!r}")
    topic = "/" + "/".join(parts[6:])
    if not is_valid_name(topic) or topic.endswith("/"):
        raise FleetKeyError(f"topic {topic[:200]!r} is not a legal ROS name")
    return Item(kind, msg_type, md5sum, namespace, topic)


def parse_data_key(key: str) -> tuple[str, str, str, str]:
    """``(type, md5, namespace, topic)`` of a data key.

    Raises:
        FleetKeyError: as ``parse_discovery_key``.
    """
    item = parse_discovery_key(f"{DISCOVERY_PREFIX}/{WILDCARD_NS}/{ItemKind.PUBLISHER.value}/{key}")
    return item.type, item.md5sum, item.namespace, item.topic


def _parse_type(hex_type: str, key: str) -> str:
    if not _HEX.match(hex_type):
        raise FleetKeyError(f"type chunk {hex_type[:40]!r} is not hex in {key[:200]!r}")
    try:
        msg_type = bytes.fromhex(hex_type).decode()
    except UnicodeDecodeError:
        raise FleetKeyError(f"type chunk {hex_type[:40]!r} is not UTF-8 in {key[:200]!r}") from None
    if not _TYPE.match(msg_type):
        raise FleetKeyError(f"type {msg_type[:80]!r} is not pkg/Name in {key[:200]!r}")
    return msg_type


# --- per-robot names ------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class RenameRule:
    """How remote names map to local ones and back.

    ``prefix`` is a template with ``{robot}`` (default ``/{robot}``; ``""`` keeps remote names as they are,
    as the bridge does: an explicit choice in the configuration). ``wildcard_robot`` is the robot name given to
    items announced under ``*`` (a plain zenoh-bridge-ros1, or anyone claiming to be one); ``""`` leaves them
    out, unless ``prefix`` is ``""``: an item never keeps its remote name by default, so a peer cannot
    announce ``/cmd_vel`` into this robot's own names (issue 31).
    """

    prefix: str = "/{robot}"
    wildcard_robot: str = ""

    def local_name(self, namespace: str, topic: str) -> str | None:
        """Where a remote robot's ``topic`` appears here (``robot1``, ``/chatter`` -> ``/robot1/chatter``), or
        None: an item announced under ``*`` with no ``wildcard_robot`` to put it under is not bridged."""
        if not self.prefix:
            return canonicalize(topic)
        robot = self.wildcard_robot if namespace == WILDCARD_NS else namespace
        if not robot:
            return None
        return canonicalize(self.prefix.format(robot=robot) + "/" + topic_chunks(topic))

    def remote_name(self, local: str, robots: frozenset[str] | set[str]) -> tuple[str, str] | None:
        """``(namespace, topic)`` if ``local`` is a renamed name of one of ``robots``, else None."""
        if not self.prefix:
            return None
        for robot in robots:
            head = canonicalize(self.prefix.format(robot=robot))
            if local.startswith(head + "/") and len(local) > len(head) + 1:
                return robot, local[len(head) :]
        return None


# --- globs ----------------------------------------------------------------------------------------


@lru_cache(maxsize=256)
def _glob_regex(pattern: str) -> re.Pattern[str]:
    out = []
    i = 0
    while i < len(pattern):
        if pattern.startswith("**", i):
            out.append(".*")
            i += 2
        elif pattern[i] == "*":
            out.append("[^/]*")
            i += 1
        elif pattern[i] == "?":
            out.append("[^/]")
            i += 1
        else:
            out.append(re.escape(pattern[i]))
            i += 1
    return re.compile("^" + "".join(out) + "$")


def glob_match(pattern: str, name: str) -> bool:
    """True if ``name`` matches ``pattern`` (``*`` within a segment, ``**`` across, ``?`` one character)."""
    return _glob_regex(pattern).match(name) is not None


@dataclass(frozen=True, slots=True)
class NameFilter:
    """Which names cross in one direction: ``include`` globs minus ``exclude`` globs.

    ``*`` matches within one name segment, ``**`` across segments, ``?`` one character; patterns are global
    names (``/tf``, ``/camera/**``). The default crosses nothing: a fleet link carries only what was chosen.
    """

    include: tuple[str, ...] = ()
    exclude: tuple[str, ...] = ()

    def __contains__(self, name: object) -> bool:
        if not isinstance(name, str):
            return False
        return any(_glob_regex(p).match(name) for p in self.include) and not any(
            _glob_regex(p).match(name) for p in self.exclude
        )
