"""The Wi-Fi lab's robot: a 1280x720 rgb8 camera at 30 Hz, /odom at 50 Hz and a 100 Hz std_msgs/Float64.

Run as a script (``python tests/netns/scene.py MASTER_URI [--camera-hz 30] ...``) inside the robot's namespace;
one mrosd node publishes the three topics on absolute schedules (late ticks are sent at once: the rate holds) and
prints ``ready`` once they are advertised. Every message carries ``header.stamp`` = the wall clock when it was
published (the Float64, which has no header, carries that time as its value), so a client can measure the age of
what it receives; the camera's pixels change each frame (tests/web/stamped_camera.py's moving textured
gradient, 8 frames cycled), so deflate and JPEG see a camera's picture, not a constant.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import time
from pathlib import Path
from typing import Any

#: topic names of the scene (the camera's ``/compressed`` sibling is the web part's, not ours)
CAMERA = "/camera/image_raw"
ODOM = "/odom"
FLOAT = "/rate100"
WIDTH, HEIGHT = 1280, 720


def _frames(count: int) -> list[bytes]:
    """``count`` rgb8 frames of tests/web/stamped_camera.py's textured scene (what a camera could see: JPEG
    compresses it as a camera's picture, not as a flat one); each frame the scene moved by 4 pixels."""
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "web"))
    from stamped_camera import frames  # a script beside the web tests, not a package

    return frames(WIDTH, HEIGHT, count)


async def _every(hz: float, publish: Any) -> None:
    period = 1.0 / hz
    due = time.monotonic()
    while True:
        await publish()
        due += period
        now = time.monotonic()
        if due < now - 1.0:
            due = now  # more than a second late (a stopped process): start over rather than burst
        # late by less: the missed ticks go at once, so that the topic keeps its nominal rate on a loaded
        # machine (what the tests count against), as a driver's buffered samples would
        await asyncio.sleep(max(0.0, due - now))


async def main(argv: list[str]) -> None:
    import mrosd
    from mrosd.msg import Time, get_message_class

    parser = argparse.ArgumentParser()
    parser.add_argument("master_uri")
    parser.add_argument("--camera-hz", type=float, default=30.0)
    parser.add_argument("--odom-hz", type=float, default=50.0)
    parser.add_argument("--float-hz", type=float, default=100.0)
    parser.add_argument("--host", default="127.0.0.1")
    args = parser.parse_args(argv)
    image_cls = get_message_class("sensor_msgs/Image")
    header_cls = get_message_class("std_msgs/Header")
    odom_cls = get_message_class("nav_msgs/Odometry")
    float_cls = get_message_class("std_msgs/Float64")
    frames = _frames(8)  # 8 of them cycled: 0.2 s to make (30: over 1 s of every lab's setup)
    async with mrosd.Node("wifi_scene", master_uri=args.master_uri, argv=[], host=args.host) as node:
        cam = await node.advertise(CAMERA, image_cls, queue_size=2)
        # deep queues: a daemon busy for a moment must not make the scene drop what the tests count
        odom = await node.advertise(ODOM, odom_cls, queue_size=200)
        flt = await node.advertise(FLOAT, float_cls, queue_size=400)
        counter = {"camera": 0}

        async def camera() -> None:
            i = counter["camera"] = counter["camera"] + 1
            header = header_cls(stamp=Time.from_sec(time.time()), frame_id="camera")
            await cam.publish(
                image_cls(
                    header=header,
                    height=HEIGHT,
                    width=WIDTH,
                    encoding="rgb8",
                    step=WIDTH * 3,
                    data=frames[i % len(frames)],
                )
            )

        async def odometry() -> None:
            msg = odom_cls(header=header_cls(stamp=Time.from_sec(time.time()), frame_id="odom"))
            msg.child_frame_id = "base_link"
            await odom.publish(msg)

        async def value() -> None:
            await flt.publish(float_cls(data=time.time()))

        print("ready", flush=True)
        await asyncio.gather(
            _every(args.camera_hz, camera), _every(args.odom_hz, odometry), _every(args.float_hz, value)
        )


if __name__ == "__main__":
    try:
        asyncio.run(main(sys.argv[1:]))
    except KeyboardInterrupt:
        pass
