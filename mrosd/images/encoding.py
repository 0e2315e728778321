"""sensor_msgs/Image -> sensor_msgs/CompressedImage ``format`` and ``data``, as image_transport's ``compressed``
plugin (compressed_image_transport, noetic) writes them. Pure: bytes in, bytes out, no asyncio, no threads.

What the plugin writes, and so what its subscriber (rqt_image_view, ``image_transport republish``) parses:
``format`` is the raw ``encoding``, then ``"; jpeg compressed "`` (or ``"; png compressed "``), then, for colour
encodings only, the layout the pixels were converted to (``bgr8``). So ``rgb8`` gives
``"rgb8; jpeg compressed bgr8"`` and ``mono8`` gives ``"mono8; jpeg compressed "`` (trailing space kept).
Its defaults: JPEG quality 80, PNG level 9. We encode 8-bit images as JPEG (colour as the plugin's bgr8
conversion does, mono kept grey) and 16-bit mono/depth as 16-bit grey PNG (the plugin's ``format=png``
output, ``"mono16; png compressed "``), because JPEG would cut them to 8 bits.

The image comes from a peer and is untrusted: ``step``, ``height`` and ``width`` are checked against the bytes
actually received before anything is allocated, and each side is bounded (``MAX_SIDE``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mrosd.errors import RemoteProtocolError

__all__ = [
    "DEFAULT_PNG_LEVEL",
    "DEFAULT_QUALITY",
    "MAX_SIDE",
    "CompressedFrame",
    "EncodeSettings",
    "ImageError",
    "PixelLayout",
    "RawImage",
    "compressed_format",
    "pixel_layout",
]

#: compressed_image_transport's default ``jpeg_quality`` (cfg/CompressedPublisher.cfg)
DEFAULT_QUALITY = 80
#: The plugin's default ``png_level`` is 9, which costs tens of milliseconds a depth frame; a live stream
#: wants 1 (the format string does not carry the level, so any level decodes the same).
DEFAULT_PNG_LEVEL = 1
#: Largest width or height accepted: JPEG's own limit is 65535, libjpeg-turbo's buffers grow with it, and
#: no camera we know of exceeds 16k on a side.
MAX_SIDE = 16384


class ImageError(RemoteProtocolError):
    """An image that cannot be encoded: bad layout, unsupported encoding, or no encoder installed."""


@dataclass(frozen=True, slots=True)
class PixelLayout:
    """How the pixels of one raw encoding are laid out and what the plugin would make of them."""

    channels: int
    #: bytes per channel: 1 or 2
    depth: int
    #: the channel order the JPEG encoders are told: "RGB", "BGR", "RGBA", "BGRA" or "GRAY"
    order: str
    #: the plugin's ``enc::isColor``: the format then ends with the converted layout, ``bgr8``
    color: bool


_LAYOUTS: dict[str, PixelLayout] = {
    "rgb8": PixelLayout(3, 1, "RGB", True),
    "bgr8": PixelLayout(3, 1, "BGR", True),
    "rgba8": PixelLayout(4, 1, "RGBA", True),
    "bgra8": PixelLayout(4, 1, "BGRA", True),
    "mono8": PixelLayout(1, 1, "GRAY", False),
    "8UC1": PixelLayout(1, 1, "GRAY", False),
    # OpenCV reads a 3-channel Mat as BGR, and the plugin hands 8UC3 to it unconverted
    "8UC3": PixelLayout(3, 1, "BGR", False),
    "mono16": PixelLayout(1, 2, "GRAY", False),
    "16UC1": PixelLayout(1, 2, "GRAY", False),
}


@dataclass(frozen=True, slots=True)
class EncodeSettings:
    """Per topic: JPEG ``quality`` 1..100, ``max_width`` in pixels (0: keep; wider images are scaled down by
    a whole factor), PNG ``png_level`` 0..9."""

    quality: int = DEFAULT_QUALITY
    max_width: int = 0
    png_level: int = DEFAULT_PNG_LEVEL

    def __post_init__(self) -> None:
        if not 1 <= self.quality <= 100:
            raise ValueError(f"JPEG quality must be 1..100, got {self.quality}")
        if self.max_width < 0:
            raise ValueError(f"max_width must be >= 0 (0: no limit), got {self.max_width}")
        if not 0 <= self.png_level <= 9:
            raise ValueError(f"PNG level must be 0..9, got {self.png_level}")


@dataclass(frozen=True, slots=True)
class RawImage:
    """The fields of a sensor_msgs/Image that the encoders read (``header`` stays with the caller)."""

    height: int
    width: int
    encoding: str
    is_bigendian: int
    step: int
    data: bytes | bytearray | memoryview

    @classmethod
    def of(cls, msg: Any) -> RawImage:
        """From a sensor_msgs/Image message (or anything with its fields)."""
        return cls(msg.height, msg.width, msg.encoding, msg.is_bigendian, msg.step, msg.data)


@dataclass(frozen=True, slots=True)
class CompressedFrame:
    """A CompressedImage's ``format`` and ``data``, and the size the picture was encoded at."""

    format: str
    data: bytes
    width: int
    height: int


def pixel_layout(encoding: str) -> PixelLayout:
    """The layout of ``encoding``.

    Raises:
        ImageError: the encoding is not one we encode (bayer, yuv422, float and signed depth, 16-bit colour).
    """
    layout = _LAYOUTS.get(encoding)
    if layout is None:
        known = ", ".join(_LAYOUTS)
        raise ImageError(f"image encoding {encoding[:40]!r} is not supported for compression (supported: {known})")
    return layout


def compressed_format(encoding: str) -> str:
    """``format`` exactly as compressed_image_transport writes it for ``encoding`` (JPEG 8-bit, PNG 16-bit).

    Raises:
        ImageError: the encoding is not supported.
    """
    layout = pixel_layout(encoding)
    if layout.depth == 2:
        return f"{encoding}; png compressed "
    return f"{encoding}; jpeg compressed " + ("bgr8" if layout.color else "")


def scale_factor(width: int, max_width: int) -> int:
    """The whole factor a ``width`` wide image is divided by to fit ``max_width`` (1 when it fits)."""
    if max_width <= 0 or width <= max_width:
        return 1
    return -(-width // max_width)


def check_image(height: int, width: int, encoding: str, step: int, size: int) -> PixelLayout:
    """Check a peer's image header against the ``size`` bytes actually received, before any allocation.

    Raises:
        ImageError: the sizes disagree, a side is 0 or above ``MAX_SIDE``, or the encoding is unsupported.
    """
    layout = pixel_layout(encoding)
    if not (0 < width <= MAX_SIDE and 0 < height <= MAX_SIDE):
        raise ImageError(f"image size {width}x{height} is outside 1..{MAX_SIDE} on a side")
    row = width * layout.channels * layout.depth
    if step < row:
        raise ImageError(f"image step {step} is shorter than a {width}-pixel {encoding} row ({row} bytes)")
    if step * height > size:
        raise ImageError(f"image claims {height} rows of {step} bytes but carries {size} bytes of data")
    return layout
