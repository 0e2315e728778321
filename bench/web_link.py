"""The browser bridges behind a shaped link: ``python -m bench web --link 20mbit`` (root; network namespaces).

The Wi-Fi lab of the tests (``tests/netns/wifi.py``): the daemon and the scene (1280x720 rgb8 camera at 30 Hz,
/odom at 50 Hz, a 100 Hz Float64) in one namespace, one @foxglove/ws-protocol client in another, the link
between them shaped with ``tc`` tbf to the given rate. One row per way of receiving the camera:

- ``raw``: the raw camera, the client offering no permessage-deflate;
- ``deflate``: the raw camera, the client offering permessage-deflate (small topics deflated; the camera is
  not: frames from ``DEFLATE_MAX_BYTES`` on never are);
- ``jpeg q80``, ``jpeg q50``: ``<camera>/compressed`` (made by the daemon's web part) at JPEG quality 80 (the
  default) and 50, set as the page sets it (``x-mrosd.imageSettings``, sent from the robot's loopback).

Per row: the camera's frames per second and median/p90 age (arrival minus ``header.stamp``), the small topics'
rates, the bytes that crossed the link per second, and the daemon's CPU (one client, so per client: the JPEG
rows include the encoder's). Then the JPEG encoders on the scene's own frame (simplejpeg, PyTurboJPEG and
Pillow, as many as are installed: ``bench.images.measure``) and the deflate levels measured on this machine on
the payloads the bridges send (what ``DEFLATE_LEVEL`` rests on). One run takes about a minute.
"""

from __future__ import annotations

import json
import math
import random
import struct
import subprocess
import sys
import tempfile
import time
import zlib
from functools import partial
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
SECONDS = 5.0
WARMUP = 2.0


def deflate_levels() -> list[tuple[str, int, float, float]]:
    """(payload, level, compressed/raw, CPU ms per MB) for the payloads a bridge deflates."""
    from mrosd.msg import Time, get_message_class
    from mrosd.web import rosbridge as rb

    odom_cls = get_message_class("nav_msgs/Odometry")
    header_cls = get_message_class("std_msgs/Header")
    cloud_cls = get_message_class("sensor_msgs/PointCloud2")
    field_cls = get_message_class("sensor_msgs/PointField")

    def odom(i: int) -> object:
        m = odom_cls(header=header_cls(seq=i, stamp=Time.from_sec(1.7e9 + i * 0.02), frame_id="odom"))
        m.child_frame_id = "base_link"
        m.pose.pose.position.x = math.sin(i / 50)
        m.twist.twist.linear.x = 0.5 + random.random() * 0.01
        return m

    points = bytearray()
    for i in range(16384):  # a floor seen by a lidar: a plane with noise, x y z intensity
        points += struct.pack("<ffff", (i % 128) * 0.05, (i // 128) * 0.05, random.gauss(0, 0.01), random.random())
    fields = [field_cls(name=n, offset=o, datatype=7, count=1) for n, o in (("x", 0), ("y", 4), ("z", 8), ("i", 12))]
    cloud = cloud_cls(height=1, width=16384, fields=fields, point_step=16, row_step=len(points), data=bytes(points))
    payloads = {
        "odom (ros1) x200": [odom(i).serialize() for i in range(200)],  # type: ignore[attr-defined]
        "rosbridge JSON odom x200": [rb.publish_json("/odom", odom(i)) for i in range(200)],
        "pointcloud 256 KiB x4": [cloud.serialize()] * 4,
        "noise 1 MiB (JPEG-like)": [random.randbytes(1 << 20)],
    }
    rows = []
    for name, msgs in payloads.items():
        raw = sum(len(m) for m in msgs)
        for level in (1, 6, 9):
            start = time.process_time()
            out = 0
            comp = zlib.compressobj(level, zlib.DEFLATED, -15)  # one stream: context takeover, as negotiated
            for m in msgs:
                out += len(comp.compress(m) + comp.flush(zlib.Z_SYNC_FLUSH)) - 4
            took = time.process_time() - start
            rows.append((name, level, out / raw, took * 1e3 / (raw / 1e6)))
    return rows


#: ``python -c`` in the robot's namespace: set a ``T/compressed`` topic's JPEG quality as the page does, print
#: the daemon's answer (argv: url, topic, quality)
_SET_QUALITY = """
import asyncio, json, sys
import aiohttp
async def main():
    url, topic, quality = sys.argv[1], sys.argv[2], int(sys.argv[3])
    async with aiohttp.ClientSession() as http:
        async with http.ws_connect(url, protocols=["foxglove.websocket.v1"]) as ws:
            await ws.send_str(json.dumps({"op": "x-mrosd.imageSettings", "topic": topic, "quality": quality}))
            async for msg in ws:
                if msg.type == aiohttp.WSMsgType.TEXT and json.loads(msg.data).get("op") == "x-mrosd.imageSettings":
                    print(msg.data)
                    return
asyncio.run(asyncio.wait_for(main(), 10))
"""


def set_quality(scene: Any, topic: str, quality: int) -> dict[str, Any]:
    """Set ``topic``'s JPEG quality (shared by every client), from the robot's loopback; the daemon's answer."""
    argv = scene.link.argv(
        scene.link.robot, [sys.executable, "-c", _SET_QUALITY, scene.url(scene.foxglove_port, False)]
    )
    done = subprocess.run([*argv, topic, str(quality)], capture_output=True, check=False, timeout=20)
    if done.returncode != 0:
        raise RuntimeError(f"x-mrosd.imageSettings failed: {done.stderr.decode()[-500:]}")
    answer: dict[str, Any] = json.loads(done.stdout)
    return answer


def encoder_rows(rounds: int = 15) -> list[tuple[str, float, int, float]]:
    """(encoder, median ms, bytes, ms / Pillow's) per installed JPEG encoder, on one 1280x720 frame of the lab's
    camera (tests/web/stamped_camera.py's picture) at quality 80 and 50."""
    from bench.images import REFERENCE, measure
    from mrosd.images import EncodeSettings, RawImage, encode_image
    from mrosd.images.jpeg import available_encoders, encoder

    sys.path.insert(0, str(ROOT / "tests" / "web"))
    from stamped_camera import frames

    picture = RawImage(720, 1280, "rgb8", 0, 1280 * 3, frames(1280, 720, 1)[0])
    rows = []
    for quality in (80, 50):
        settings = EncodeSettings(quality=quality)
        calls = {name: partial(encode_image, picture, settings, encoder(name)) for name in available_encoders()}
        results = measure(calls, rounds)
        reference = results.get(REFERENCE, next(iter(results.values())))[0]
        rows += [(f"{name} q{quality}", ms, size, ms / reference) for name, (ms, _, size) in results.items()]
    return rows


def run(rate: str) -> int:
    sys.path.insert(0, str(ROOT))
    from tests.netns.wifi import CAMERA, FLOAT, ODOM, WifiScene, lab_unavailable

    why = lab_unavailable()
    if why is not None:
        print(f"web --link: skipped: {why}")
        return 0
    print(f"web --link {rate}: one Foxglove client behind tbf {rate}; {SECONDS:g} s per row after {WARMUP:g} s")
    header = f"{'row':8} {'cam fps':>8} {'age med':>8} {'age p90':>8} {'odom Hz':>8} {'100Hz':>7}"
    header += f" {'link KB/s':>10} {'CPU %':>6}"
    with tempfile.TemporaryDirectory() as tmp, WifiScene(Path(tmp), rate) as scene:
        print(header)
        jpeg = f"{CAMERA}/compressed"
        cases = [("raw", CAMERA, False, 0), ("deflate", CAMERA, True, 0), ("jpeg q80", jpeg, True, 80)]
        cases.append(("jpeg q50", jpeg, True, 50))
        for row, camera, deflate, quality in cases:
            fox = scene.foxglove(shaped=True, deflate=deflate)
            try:
                try:
                    fox.wait(lambda ev, c=camera: ev.get("event") == "channel" and ev.get("topic") == c, 3.0)
                except TimeoutError:
                    print(f"{row:8} skipped: the daemon offers no {camera}")
                    continue
                if quality:
                    set_quality(scene, camera, quality)
                fox.subscribe(camera, ODOM, FLOAT)
                time.sleep(WARMUP)
                cpu0, wire0, t0 = scene.daemon_cpu(), scene.link.sent_bytes(), time.monotonic()
                got = fox.collect(SECONDS, warmup=0.0)
                cpu1, wire1, t1 = scene.daemon_cpu(), scene.link.sent_bytes(), time.monotonic()
            finally:
                fox.close()
            cam = got.get(camera)
            fps, med, p90 = (cam.rate, cam.median_age, cam.p90_age) if cam else (0.0, math.nan, math.nan)
            odom = got[ODOM].rate if ODOM in got else 0.0
            flt = got[FLOAT].rate if FLOAT in got else 0.0
            print(
                f"{row:8} {fps:8.1f} {med * 1e3:6.0f}ms {p90 * 1e3:6.0f}ms {odom:8.1f} {flt:7.1f} "
                f"{(wire1 - wire0) / (t1 - t0) / 1e3:10.0f} {100 * (cpu1 - cpu0) / (t1 - t0):6.1f}"
            )
    print("JPEG encoders on one frame of the lab's camera, 1280x720 rgb8 (ratio: ms / Pillow's ms):")
    print(f"{'encoder':20} {'ms':>6} {'bytes':>8} {'ratio':>6}")
    for name, ms, size, ratio in encoder_rows():
        print(f"{name:20} {ms:6.2f} {size:8d} {ratio:6.2f}")
    print("deflate levels on this machine (one stream per payload, sync flush per message):")
    print(f"{'payload':28} {'level':>5} {'ratio':>6} {'ms/MB':>6}")
    for name, level, ratio, ms in deflate_levels():
        print(f"{name:28} {level:5} {ratio:6.3f} {ms:6.1f}")
    return 0
