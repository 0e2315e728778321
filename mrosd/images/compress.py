"""One sensor_msgs/Image -> the CompressedImage image_transport's ``compressed`` plugin would publish: the
format rules and checks of ``mrosd.images.encoding``, then a JPEG encoder (``mrosd.images.jpeg``) for 8-bit
images or the PNG writer (``mrosd.images.png``) for 16-bit ones. Pure: bytes in, bytes out.
"""

from __future__ import annotations

from array import array
from typing import Any

from mrosd.images.encoding import (
    CompressedFrame,
    EncodeSettings,
    RawImage,
    check_image,
    compressed_format,
    scale_factor,
)
from mrosd.images.jpeg import best_encoder
from mrosd.images.png import COLOR_GRAY, encode_png

__all__ = ["encode_image"]


def encode_image(image: RawImage, settings: EncodeSettings | None = None, jpeg: Any = None) -> CompressedFrame:
    """One sensor_msgs/Image -> the CompressedImage the plugin would publish.

    Rows may be padded (``step`` above the row's length); 16-bit samples may be either byte order.
    ``jpeg`` is a JPEG encoder (``mrosd.images.jpeg``); default: the best one installed.

    Raises:
        ImageError: a bad or unsupported image, or a JPEG image with no JPEG encoder installed.
    """
    settings = settings or EncodeSettings()
    layout = check_image(image.height, image.width, image.encoding, image.step, memoryview(image.data).nbytes)
    factor = scale_factor(image.width, settings.max_width)
    if layout.depth == 2:
        png, out_w, out_h = _encode_png16(image, factor, settings.png_level)
        return CompressedFrame(compressed_format(image.encoding), png, out_w, out_h)
    if jpeg is None:
        jpeg = best_encoder()
    out, out_w, out_h = jpeg.encode(image, layout, factor, settings.quality)
    return CompressedFrame(compressed_format(image.encoding), out, out_w, out_h)


def _encode_png16(image: RawImage, factor: int, level: int) -> tuple[bytes, int, int]:
    """16-bit grey PNG, big-endian samples as PNG stores them. Scaling keeps every ``factor``-th sample:
    averaging depth across an edge would invent distances that are in neither surface."""
    view = memoryview(image.data).cast("B")
    width, step = image.width, image.step
    out_w, out_h = width // factor or 1, image.height // factor or 1
    swap = not image.is_bigendian  # PNG stores samples big-endian: swap each byte pair of little-endian data

    def rows() -> Any:
        for y in range(0, out_h * factor, factor):
            start = y * step
            row = view[start : start + width * 2]
            if factor == 1 and not swap:
                yield row
                continue
            samples = array("H")
            samples.frombytes(row)
            if factor != 1:
                samples = samples[: out_w * factor : factor]
            if swap:
                samples.byteswap()
            yield samples.tobytes()

    return encode_png(out_w, out_h, rows(), bit_depth=16, color_type=COLOR_GRAY, level=level), out_w, out_h
