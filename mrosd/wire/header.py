"""TCPROS connection headers: the pure codec and the typed header record.

A header is a 4-byte little-endian total length followed by fields, each a 4-byte little-endian length and
``key=value`` bytes. This module owns that codec and nothing else: no sockets, no asyncio. Every header
role (subscriber, publisher, service client/server, error reply) is a ``ConnectionHeader`` with the keys
that role uses; keys we do not know are kept in ``extra`` and sent back unchanged when re-encoded.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping

import msgspec

from mrosd.errors import LocalProtocolError, RemoteProtocolError

#: Largest connection header we accept. The biggest message_definition shipped by Debian's ROS
#: (visualization_msgs/MarkerArray with all its dependencies) is about 10 KB; 4 MiB leaves room for huge
#: user types while keeping a hostile peer from making us buffer without bound before the handshake.
MAX_HEADER_SIZE = 4 * 1024 * 1024

_U32 = struct.Struct("<I")

#: Keys with a dedicated attribute, in the order we write them.
KNOWN_KEYS = (
    "callerid",
    "topic",
    "service",
    "md5sum",
    "type",
    "request_type",
    "response_type",
    "message_definition",
    "latching",
    "tcp_nodelay",
    "persistent",
    "probe",
    "error",
)


class ConnectionHeader(msgspec.Struct, kw_only=True, gc=False):
    """One decoded connection header; ``None`` means the key was absent.

    Roles: a subscriber sends callerid, topic, md5sum, type, message_definition, tcp_nodelay; a publisher
    answers callerid, md5sum, type, latching, message_definition (or only ``error``); a service client sends
    callerid, service, md5sum, persistent (or probe); a service server answers callerid, md5sum, type,
    request_type, response_type (or ``error``).
    """

    callerid: str | None = None
    topic: str | None = None
    service: str | None = None
    md5sum: str | None = None
    type: str | None = None
    request_type: str | None = None
    response_type: str | None = None
    message_definition: str | None = None
    latching: str | None = None
    tcp_nodelay: str | None = None
    persistent: str | None = None
    probe: str | None = None
    error: str | None = None
    extra: dict[str, str] = msgspec.field(default_factory=dict)

    @classmethod
    def from_fields(cls, fields: Mapping[str, str]) -> ConnectionHeader:
        """Build from a decoded key -> value mapping; unknown keys go to ``extra``."""
        known = {k: v for k, v in fields.items() if k in KNOWN_KEYS}
        extra = {k: v for k, v in fields.items() if k not in KNOWN_KEYS}
        return cls(**known, extra=extra)

    def to_fields(self) -> dict[str, str]:
        """The key -> value mapping to send: present known keys in a fixed order, then ``extra``."""
        fields = {k: v for k in KNOWN_KEYS if (v := getattr(self, k)) is not None}
        fields.update(self.extra)
        return fields

    def flag(self, key: str) -> bool:
        """A boolean header value ("1"/"true") such as latching, tcp_nodelay, persistent, probe."""
        value = getattr(self, key, None) if key in KNOWN_KEYS else self.extra.get(key)
        return value is not None and value.strip().lower() in ("1", "true")


def encode_header(fields: Mapping[str, str] | ConnectionHeader) -> bytes:
    """Encode a header, 4-byte total length prefix included.

    Raises:
        LocalProtocolError: a key is empty or contains '=', or the header exceeds MAX_HEADER_SIZE.
    """
    if isinstance(fields, ConnectionHeader):
        fields = fields.to_fields()
    parts: list[bytes] = []
    for key, value in fields.items():
        if not key or "=" in key:
            raise LocalProtocolError(f"connection header key {key!r} must be non-empty and contain no '='")
        item = f"{key}={value}".encode()
        parts.append(_U32.pack(len(item)))
        parts.append(item)
    body = b"".join(parts)
    if len(body) > MAX_HEADER_SIZE:
        raise LocalProtocolError(f"connection header of {len(body)} bytes exceeds MAX_HEADER_SIZE={MAX_HEADER_SIZE}")
    return _U32.pack(len(body)) + body


def decode_header(body: bytes | bytearray | memoryview) -> dict[str, str]:
    """Decode a header body (without its 4-byte total length); a repeated key keeps its last value.

    Raises:
        RemoteProtocolError: a field runs past the end, lacks '=', has an empty key or is not UTF-8, or the
            header exceeds MAX_HEADER_SIZE.
    """
    view = memoryview(body)
    size = len(view)
    if size > MAX_HEADER_SIZE:
        raise RemoteProtocolError(f"connection header of {size} bytes exceeds MAX_HEADER_SIZE={MAX_HEADER_SIZE}")
    fields: dict[str, str] = {}
    pos = 0
    while pos < size:
        if size - pos < 4:
            raise RemoteProtocolError(f"connection header truncated: {size - pos} stray bytes at offset {pos}")
        (length,) = _U32.unpack_from(view, pos)
        pos += 4
        if length > size - pos:
            raise RemoteProtocolError(
                f"connection header field at offset {pos - 4} claims {length} bytes, only {size - pos} remain"
            )
        raw = bytes(view[pos : pos + length])
        pos += length
        eq = raw.find(b"=")
        if eq <= 0:
            raise RemoteProtocolError(f"connection header field {raw[:40]!r} is not key=value")
        try:
            key = raw[:eq].decode()
            value = raw[eq + 1 :].decode()
        except UnicodeDecodeError as exc:
            raise RemoteProtocolError(f"connection header field {raw[:40]!r} is not UTF-8") from exc
        fields[key] = value
    return fields


def decode_connection_header(body: bytes | bytearray | memoryview) -> ConnectionHeader:
    """``decode_header`` into a typed ``ConnectionHeader``."""
    return ConnectionHeader.from_fields(decode_header(body))
