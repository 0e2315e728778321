"""A viewer that computes on camera frames where the publisher wrote them: no copy (docs/shm.md).

``subscribe(..., zero_copy=True)`` delivers each ``sensor_msgs/Image`` with ``data`` a read-only view of the
publisher's shared memory; ``np.frombuffer`` makes an array over it without copying. The frame is leased
until released (``with msg:``) or dropped: keep at most ``max_leased`` frames at once (a worker thread may
hold one), or later frames are dropped. Run ``python examples/camera.py`` beside it.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np

import mrosd
from mrosd.msg import get_message_class

Image = get_message_class("sensor_msgs/Image")


def brightness(msg: Any) -> float:
    """Mean of the green channel, computed on the publisher's pages (subsampled: every 8th pixel)."""
    img = np.frombuffer(msg.data, np.uint8).reshape(msg.height, msg.width, 3)
    return float(img[::8, ::8, 1].mean())


async def main(master_uri: str | None = None, *, count: int | None = None) -> list[float]:
    """Print the frame rate and brightness once a second; returns the brightness of ``count`` frames."""
    seen: list[float] = []
    async with mrosd.Node("viewer", master_uri=master_uri, argv=[]) as node:
        sub = await node.subscribe("/camera/image", Image, zero_copy=True, max_leased=2)
        t0, frames = time.monotonic(), 0
        async for msg in sub:
            with msg:  # the lease ends here: the camera may reuse the slot
                seen.append(brightness(msg))
            frames += 1
            if time.monotonic() - t0 >= 1.0:
                print(f"{frames} frames/s, brightness {seen[-1]:.0f}", flush=True)
                t0, frames = time.monotonic(), 0
            if count is not None and len(seen) >= count:
                break
    return seen


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--count", type=int, default=None)
    args = parser.parse_args()
    mrosd.run(main(count=args.count))
