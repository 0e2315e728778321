"""Image encoders for ``T/compressed``: each installed JPEG encoder at quality 50 and 80, 640x480 and 1280x720
rgb8, in one run, as ms per frame and bytes per frame, with each encoder's time as a ratio of Pillow's (the
fallback); then the 1280 -> 640 downscale and 16-bit PNG depth frames. ``python -m bench images [--rounds N]``.

The picture is a camera-like scene (smooth gradients, edges and sensor noise of a few levels) made with a
fixed seed, so that sizes compare across runs. Rounds alternate between encoders, each round one frame per
encoder, and the median is reported: load from other processes hits every encoder alike.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from functools import partial
from typing import Any

from mrosd.images import EncodeSettings, RawImage, encode_image
from mrosd.images.jpeg import available_encoders, encoder

SIZES = [(640, 480), (1280, 720)]
QUALITIES = [50, 80]
REFERENCE = "pillow"


def scene(width: int, height: int, channels: int = 3) -> bytes:
    """A deterministic camera-like rgb8 picture (numpy only here, not in the encoders' path)."""
    import numpy as np

    rng = np.random.default_rng(32)
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    r = 128 + 100 * np.sin(x / 97.0) * np.cos(y / 61.0)
    g = 255 * (y / height)
    b = np.where(((x // 80) + (y // 80)) % 2 == 0, 60.0, 190.0)  # a checkerboard: hard edges
    img = np.stack([r, g, b][:channels], axis=-1) + rng.normal(0, 3, (height, width, channels))
    return bytes(np.clip(img, 0, 255).astype(np.uint8).tobytes())


def depth_scene(width: int, height: int) -> bytes:
    """A deterministic 16-bit depth frame: a floor ramp, a box, millimetre noise, some invalid zeros."""
    import numpy as np

    rng = np.random.default_rng(33)
    y = np.mgrid[0:height, 0:width][0]
    depth = 800 + 4000 * (1 - y / height) + rng.normal(0, 4, (height, width))
    depth[height // 3 : height // 2, width // 3 : width // 2] = 1200
    depth[rng.random((height, width)) < 0.02] = 0
    return bytes(depth.astype("<u2").tobytes())


def measure(calls: dict[str, Callable[[], Any]], rounds: int) -> dict[str, tuple[float, float, int]]:
    """Median and best ms per call and the output's bytes, rounds alternating between the calls."""
    times: dict[str, list[float]] = {name: [] for name in calls}
    sizes: dict[str, int] = {}
    for name, call in calls.items():  # warm-up: first calls load libraries and fault in buffers
        sizes[name] = len(call().data)
    for _ in range(rounds):
        for name, call in calls.items():
            start = time.perf_counter()
            call()
            times[name].append((time.perf_counter() - start) * 1e3)
    return {name: (statistics.median(times[name]), min(times[name]), sizes[name]) for name in calls}


def main(argv: list[str]) -> int:
    rounds = int(argv[argv.index("--rounds") + 1]) if "--rounds" in argv else 30
    names = available_encoders()
    if not names:
        print("no JPEG encoder installed: pip install 'mrosd[images]'")
        return 0
    print(f"JPEG encoders here: {', '.join(names)} (ratio: the encoder's ms / {REFERENCE}'s ms; lower is faster)")
    print(f"{'case':28} {'encoder':12} {'median ms':>9} {'best ms':>8} {'bytes':>9} {'ratio':>6}")
    for width, height in SIZES:
        data = scene(width, height)
        image = RawImage(height, width, "rgb8", 0, width * 3, data)
        for quality in QUALITIES:
            settings = EncodeSettings(quality=quality)
            calls = {name: partial(encode_image, image, settings, encoder(name)) for name in names}
            results = measure(calls, rounds)
            reference = results.get(REFERENCE, next(iter(results.values())))[0]
            for name, (ms, best, size) in results.items():
                case = f"rgb8 {width}x{height} q{quality}"
                print(f"{case:28} {name:12} {ms:9.2f} {best:8.2f} {size:9d} {ms / reference:6.2f}")
    # What the web part and [images] do for a slow link: scale down before encoding.
    data = scene(1280, 720)
    image = RawImage(720, 1280, "rgb8", 0, 1280 * 3, data)
    settings = EncodeSettings(quality=80, max_width=640)
    calls = {name: partial(encode_image, image, settings, encoder(name)) for name in names}
    results = measure(calls, rounds)
    reference = results.get(REFERENCE, next(iter(results.values())))[0]
    for name, (ms, best, size) in results.items():
        print(f"{'rgb8 1280x720->640 q80':28} {name:12} {ms:9.2f} {best:8.2f} {size:9d} {ms / reference:6.2f}")
    depth = RawImage(480, 640, "16UC1", 0, 640 * 2, depth_scene(640, 480))
    png = {f"level {level}": partial(encode_image, depth, EncodeSettings(png_level=level)) for level in (1, 6, 9)}
    for label, (ms, best, size) in measure(png, max(3, rounds // 3)).items():
        print(f"{'16UC1 640x480 png':28} {label:12} {ms:9.2f} {best:8.2f} {size:9d} {'':>6}")
    return 0
