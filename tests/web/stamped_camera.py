"""A camera for the compressed-image tests, as an mrosd node in its own process: ``/camera/image`` rgb8 of
W x H at HZ, every frame stamped with the time it is published, and, when FAST_HZ > 0, a std_msgs/Float64
``/fast`` at FAST_HZ (the small topic that must not be starved).

The scene is one a camera could see and JPEG compresses as it would a camera's: a diagonal colour gradient
that moves 4 pixels a frame, with a checker texture of 16-pixel squares and a little fixed grain (not noise,
which no codec compresses). 30 frames are made once and cycled.

Usage: python stamped_camera.py W H HZ FAST_HZ
"""

import asyncio
import sys
import time

import numpy as np

import mrosd
from mrosd.msg import Time, get_message_class

Image = get_message_class("sensor_msgs/Image")
Float64 = get_message_class("std_msgs/Float64")


def frames(w: int, h: int, count: int = 30) -> list[bytes]:
    y, x = np.mgrid[0:h, 0:w]
    checker = (((x // 16) + (y // 16)) % 2) * 24
    grain = np.random.default_rng(1).integers(0, 6, size=(h, w))
    out = []
    for k in range(count):
        r = ((x + 4 * k) * 255 // max(1, w)) % 256
        g = (y * 255 // max(1, h) + checker) % 256
        b = ((x + y + 8 * k) // 4 + grain) % 256
        out.append(np.stack([r, g, b], axis=-1).astype(np.uint8).tobytes())
    return out


async def main(w: int, h: int, hz: float, fast_hz: float) -> None:
    pictures = frames(w, h)
    async with mrosd.Node("stamped_camera", argv=[]) as node:
        cam = await node.advertise("/camera/image", Image, queue_size=1)
        fast = await node.advertise("/fast", Float64, queue_size=100) if fast_hz > 0 else None

        async def images() -> None:
            n, start = 0, time.monotonic()
            while True:
                img = Image(height=h, width=w, encoding="rgb8", step=3 * w, data=pictures[n % len(pictures)])
                img.header.stamp = Time.from_sec(time.time())
                await cam.publish(img)
                n += 1
                await asyncio.sleep(max(0.0, start + n / hz - time.monotonic()))

        async def numbers() -> None:
            assert fast is not None
            n, start = 0, time.monotonic()
            while True:
                await fast.publish(Float64(data=float(n)))
                n += 1
                await asyncio.sleep(max(0.0, start + n / fast_hz - time.monotonic()))

        await asyncio.gather(images(), *([numbers()] if fast is not None else []))


if __name__ == "__main__":
    w, h, hz, fast_hz = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
    asyncio.run(main(w, h, hz, fast_hz))
