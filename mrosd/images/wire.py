"""A serialized sensor_msgs/Image read in place: its fields, and ``data`` as a view of the received body.

Why not the generated class's ``deserialize``: it copies ``data`` into a new ``bytes``, and the web encoder
also had to make the body ``bytes`` first; for a 100 MB frame that was 200 MB more per frame being encoded
(two worker threads: 400 MB) on top of the frame TCPROS received. Here nothing is copied; every length is
checked against the bytes actually present before it is used, and the body must end exactly where ``data``
does (as the generated decoder requires).
"""

from __future__ import annotations

import struct

from mrosd.errors import MsgError
from mrosd.images.encoding import RawImage

__all__ = ["ImageView", "read_image"]

_U32 = struct.Struct("<I")
#: an encoding name longer than this is no encoding (the longest known is 6 characters)
_MAX_ENCODING = 256


class ImageView:
    """What the encoder needs of one serialized Image: the header's bytes (copied into the CompressedImage
    as they are) and the image, its ``data`` a view of the body."""

    __slots__ = ("header", "image")

    def __init__(self, header: memoryview, image: RawImage) -> None:
        self.header = header
        self.image = image


def _u32(view: memoryview, at: int) -> int:
    if at + 4 > len(view):
        raise MsgError(f"sensor_msgs/Image cut short at byte {at} of {len(view)}")
    return int(_U32.unpack_from(view, at)[0])


def _string(view: memoryview, at: int, limit: int) -> tuple[int, int]:
    """(start, end) of the length-prefixed string at ``at``."""
    size = _u32(view, at)
    if size > limit or at + 4 + size > len(view):
        raise MsgError(f"sensor_msgs/Image: a string of {size} bytes at byte {at} of {len(view)}")
    return at + 4, at + 4 + size


def read_image(body: bytes | bytearray | memoryview) -> ImageView:
    """The Image in ``body``, without copying its pixels.

    Raises:
        MsgError: a length that runs past the body, bytes left after ``data``, or an encoding that is no name.
    """
    view = memoryview(body).cast("B")
    _, end = _string(view, 12, len(view))  # seq, stamp (secs, nsecs), frame_id
    header = view[:end]
    height, width = _u32(view, end), _u32(view, end + 4)
    start, stop = _string(view, end + 8, _MAX_ENCODING)
    try:
        encoding = bytes(view[start:stop]).decode()
    except UnicodeDecodeError as exc:
        raise MsgError("sensor_msgs/Image: the encoding is not UTF-8") from exc
    if stop + 1 > len(view):
        raise MsgError("sensor_msgs/Image cut short before is_bigendian")
    is_bigendian = view[stop]
    step = _u32(view, stop + 1)
    data_start, data_end = _string(view, stop + 5, len(view))
    if data_end != len(view):
        raise MsgError(f"sensor_msgs/Image: {len(view) - data_end} bytes after its data")
    return ImageView(header, RawImage(height, width, encoding, is_bigendian, step, view[data_start:data_end]))
