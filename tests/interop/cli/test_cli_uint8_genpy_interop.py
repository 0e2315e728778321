"""Our fast uint8[] text is byte-identical to genpy's strify_message (what rostopic echo prints).

genpy runs under Debian's python (``ROS_PYTHON``) on the same serialized sensor_msgs/Image bytes that our
renderer decodes with ``mrosd.msg``: odd, even and empty data, every byte value, and a megabyte.
"""

from __future__ import annotations

import os
import subprocess

import pytest
from mros_cli.output import TextRenderer

from mrosd.msg import get_message_class
from tests.rosenv import ROS_PYTHON, needs_ros

GENPY_RENDER = r"""
import sys
from genpy.message import strify_message
from sensor_msgs.msg import Image
msg = Image()
msg.deserialize(sys.stdin.buffer.read())
sys.stdout.write(strify_message(msg))
"""


@needs_ros
@pytest.mark.parametrize(
    "data",
    [b"", b"\x00", b"\x09\x0a\x63\x64\xff", bytes(range(256)) * 3 + b"\x07", os.urandom((1 << 20) + 1)],
    ids=["empty", "one-zero", "odd-boundaries", "all-values-odd", "megabyte-odd"],
)
def test_an_image_renders_byte_identical_to_genpy(data: bytes) -> None:
    image_cls = get_message_class("sensor_msgs/Image")
    raw = image_cls(height=1, width=len(data), encoding="mono8", step=len(data), data=data).serialize()
    theirs = subprocess.run([ROS_PYTHON, "-c", GENPY_RENDER], input=raw, capture_output=True, timeout=60, check=True)
    ours = b"".join(TextRenderer().render_chunks(image_cls.deserialize(memoryview(raw))))
    assert ours == theirs.stdout
