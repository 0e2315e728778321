"""A camera driver that writes each 1920x1080 rgb8 frame straight into shared memory (docs/shm.md).

``pub.loan(data=...)`` lends a slot of the topic's pool; numpy writes the frame into it; ``publish`` sends it
without serializing or copying the pixels, to same-host mrosd subscribers (``examples/viewer.py``) and, from
the same slot, to TCPROS ones (rviz, rospy, roscpp). Run a master (``mrosd``), then
``python examples/camera.py`` and ``python examples/viewer.py``. numpy is needed (``pip install numpy``).
"""

from __future__ import annotations

import argparse
import asyncio

import numpy as np

import mrosd
from mrosd.msg import get_message_class

Image = get_message_class("sensor_msgs/Image")
WIDTH, HEIGHT = 1920, 1080


async def main(master_uri: str | None = None, *, rate: float = 30.0, count: int | None = None) -> int:
    """Publish ``count`` frames (forever when None) at ``rate`` Hz; returns how many went in place."""
    frame_bytes = WIDTH * HEIGHT * 3
    in_place = 0
    async with mrosd.Node("camera", master_uri=master_uri, argv=[]) as node:
        # the pool is made now, its pages touched once: no frame pays for fresh memory
        pub = await node.advertise("/camera/image", Image, queue_size=2, max_message_size=frame_bytes + 4096)
        ramp = np.arange(WIDTH, dtype=np.uint8)  # a pattern that moves: one column per frame
        n = 0
        while count is None or n < count:
            msg = pub.loan(data=frame_bytes)
            frame = np.frombuffer(msg.data, np.uint8).reshape(HEIGHT, WIDTH, 3)
            frame[:, :, 0] = np.roll(ramp, n)  # red: a moving ramp; written into the pool itself
            frame[:, :, 1] = n % 256
            frame[:, :, 2] = 255 - n % 256
            del frame  # the slot is published next: nothing may write it afterwards
            in_place += msg._shm_loan.in_place
            msg.header.stamp = mrosd.Time.now()
            msg.header.frame_id = "camera"
            msg.height, msg.width, msg.encoding, msg.step = HEIGHT, WIDTH, "rgb8", WIDTH * 3
            await pub.publish(msg)
            n += 1
            await asyncio.sleep(1.0 / rate)
    return in_place


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--count", type=int, default=None)
    args = parser.parse_args()
    mrosd.run(main(rate=args.rate, count=args.count))
