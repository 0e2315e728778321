"""Print the transform of TARGET in SOURCE's frame once a second (tf_echo's argument order).

    python examples/tf_listener.py SOURCE TARGET

One ``mrosd.tf.Buffer`` holds /tf and /tf_static; a lookup that fails prints tf2's error text.
"""

from __future__ import annotations

import asyncio
import sys

import mrosd
from mrosd.tf import Buffer, TransformError


async def main() -> None:
    args = [a for a in sys.argv[1:] if ":=" not in a]
    if len(args) != 2:
        sys.exit("usage: tf_listener.py SOURCE TARGET")
    source, target = args
    async with mrosd.Node("tf_listener") as node, Buffer(node) as buffer:
        while not node.shutdown_event.is_set():
            try:
                t = await buffer.wait_for_transform(source, target, timeout=1.0)
            except TransformError as exc:
                print(f"error: {exc}", flush=True)
            else:
                v, q = t.transform.translation, t.transform.rotation
                stamp = t.header.stamp
                print(
                    f"{stamp.secs}.{stamp.nsecs:09d} translation [{v.x:.9f}, {v.y:.9f}, {v.z:.9f}] "
                    f"rotation [{q.x:.9f}, {q.y:.9f}, {q.z:.9f}, {q.w:.9f}]",
                    flush=True,
                )
            await asyncio.sleep(1.0)


if __name__ == "__main__":
    mrosd.run(main)
