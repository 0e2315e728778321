"""A real camera frame of tens of megabytes on a topic a browser client watches as ``T/compressed``: the web
encoder reads its pixels where TCPROS received them. Before: the body was copied to ``bytes`` and the generated
decoder copied ``data`` again, two frames more per frame being encoded (a 100 MB camera: +497 MiB of daemon RSS
against +286 MiB for the raw topic)."""

from __future__ import annotations

import tracemalloc

from mrosd.images.encoding import EncodeSettings
from mrosd.msg import get_message_class
from mrosd.msg.runtime import FrameBuffer
from mrosd.web.compressed import compress_image_body

Image = get_message_class("sensor_msgs/Image")
CompressedImage = get_message_class("sensor_msgs/CompressedImage")
SIDE = 4096  # 16 MiB of mono8


def test_encoding_a_16_mib_frame_allocates_no_copy_of_it() -> None:
    image = Image(height=SIDE, width=SIDE, encoding="mono8", step=SIDE, data=bytes(SIDE * SIDE))
    image.header.frame_id = "cam"
    body = FrameBuffer(image.serialize())  # as TCPROS delivers a large frame
    compress_image_body(body, EncodeSettings())  # the encoder's libraries loaded, outside the measure
    tracemalloc.start()
    try:
        out = compress_image_body(body, EncodeSettings())
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    msg = CompressedImage.deserialize(out)
    assert msg.header.frame_id == "cam" and msg.format == "mono8; jpeg compressed " and msg.data[:2] == b"\xff\xd8"
    assert peak < len(body) // 4, f"{peak / 2**20:.1f} MiB allocated to encode a {len(body) / 2**20:.0f} MiB frame"


def test_a_body_that_is_no_image_is_refused_without_reading_past_it() -> None:
    import pytest

    from mrosd.errors import MrosError

    good = Image(height=2, width=2, encoding="mono8", step=2, data=b"abcd").serialize()
    for bad in (good[:-1], good + b"x", good[:20], b"", (2**31).to_bytes(4, "little") * 8):
        with pytest.raises(MrosError):
            compress_image_body(bad, EncodeSettings())
