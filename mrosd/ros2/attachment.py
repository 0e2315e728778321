"""The attachment rmw_zenoh puts beside every sample and service message, and the GIDs in it (pure).

rmw_zenoh (``attachment_helpers.cpp``, zenoh 1.x) serializes three values with zenoh's ``ext`` serializer, with
no keys between them: the sequence number (int64), the source timestamp in nanoseconds (int64) and the
source GID (16 bytes, as a sequence: a LEB128 count, here always the single byte 16, then the bytes). That is
33 bytes, little-endian.

rmw_zenoh's GID is the XXH3-128 (seed 0) of the entity's liveliness key, stored as ``memcpy(gid, &low64, 8)``
then ``&high64`` (``liveliness_utils.cpp``, ``Entity``'s constructor; ``simplified_xxhash3.cpp`` is stock
XXH3-128 reduced to its portable code): the 128-bit value in little-endian, which is what ours is.
"""

from __future__ import annotations

import struct

import msgspec
import xxhash

from mrosd.errors import RemoteProtocolError

__all__ = ["ATTACHMENT_SIZE", "GID_SIZE", "Attachment", "decode_attachment", "encode_attachment", "gid_of"]

#: rmw's RMW_GID_STORAGE_SIZE
GID_SIZE = 16
ATTACHMENT_SIZE = 8 + 8 + 1 + GID_SIZE
_HEAD = struct.Struct("<qqB")


class Attachment(msgspec.Struct, frozen=True, gc=False):
    """Sequence number, source timestamp (ns since the epoch) and the sender's GID."""

    sequence_number: int
    source_timestamp: int
    gid: bytes


def gid_of(token_key: str) -> bytes:
    """The 16-byte GID of the entity whose liveliness key is ``token_key``."""
    return int(xxhash.xxh3_128_intdigest(token_key.encode())).to_bytes(GID_SIZE, "little")


def encode_attachment(sequence_number: int, source_timestamp: int, gid: bytes) -> bytes:
    """The 33 attachment bytes rmw_zenoh reads.

    Raises:
        ValueError: ``gid`` is not 16 bytes.
    """
    if len(gid) != GID_SIZE:
        raise ValueError(f"a GID is {GID_SIZE} bytes, not {len(gid)}")
    return _HEAD.pack(sequence_number, source_timestamp, GID_SIZE) + gid


def decode_attachment(data: bytes | bytearray | memoryview) -> Attachment:
    """Parse an attachment.

    Raises:
        RemoteProtocolError: not 33 bytes, or a GID count other than 16.
    """
    if len(data) != ATTACHMENT_SIZE:
        raise RemoteProtocolError(f"rmw_zenoh attachment of {len(data)} bytes, not {ATTACHMENT_SIZE}")
    seq, stamp, count = _HEAD.unpack_from(data, 0)
    if count != GID_SIZE:
        raise RemoteProtocolError(f"rmw_zenoh attachment with a GID of {count} bytes")
    return Attachment(seq, stamp, bytes(data[_HEAD.size :]))
