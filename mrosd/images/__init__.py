"""Compressed camera topics as image_transport's ``compressed`` plugin makes them (docs/images.md).

``encoding`` (the pure core: Image fields -> CompressedImage ``format``, the checks), ``compress``
(``encode_image``: the whole conversion), ``jpeg`` (the optional
libjpeg-turbo encoders), ``png`` (the one PNG writer), ``part`` (the daemon's ``[images]`` node, which
publishes ``T/compressed`` into the ROS graph while someone subscribes).
"""

from mrosd.images.compress import encode_image
from mrosd.images.encoding import (
    CompressedFrame,
    EncodeSettings,
    ImageError,
    RawImage,
    compressed_format,
)

__all__ = ["CompressedFrame", "EncodeSettings", "ImageError", "RawImage", "compressed_format", "encode_image"]
