"""The one PNG writer: chunks, a whole file from rows, with zlib and struct only (no imaging library).

Used for 16-bit depth and mono16 images on ``<camera>/compressed`` (``mrosd.images.encoding``) and by the
rosbridge codec for its ``png`` op (``mrosd.web.rosbridge`` imports ``png_chunk`` and ``PNG_SIGNATURE``).
Knows nothing of ROS messages.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterable

__all__ = ["COLOR_GRAY", "COLOR_RGB", "PNG_SIGNATURE", "encode_png", "png_chunk"]

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: IHDR colour types (PNG spec 11.2.2)
COLOR_GRAY = 0
COLOR_RGB = 2


def png_chunk(kind: bytes, data: bytes) -> bytes:
    """One chunk: length, type, data, CRC over type and data."""
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(data, zlib.crc32(kind)))


def encode_png(
    width: int, height: int, rows: Iterable[bytes | memoryview], *, bit_depth: int, color_type: int, level: int
) -> bytes:
    """A PNG file of ``rows`` (each exactly one row of samples, big-endian when 16-bit), filter type 0.

    Depth images gain little from PNG's predictors at the levels a live stream can afford, and filter 0
    costs nothing to write; the IDAT is one chunk (decoders accept any split).
    """
    deflate = zlib.compressobj(level)
    out = [PNG_SIGNATURE, png_chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, bit_depth, color_type, 0, 0, 0))]
    body: list[bytes] = []
    for row in rows:
        body.append(deflate.compress(b"\0"))
        body.append(deflate.compress(row))
    body.append(deflate.flush())
    out.append(png_chunk(b"IDAT", b"".join(body)))
    out.append(png_chunk(b"IEND", b""))
    return b"".join(out)
