"""examples/camera.py and examples/viewer.py against each other (issue 25): loaned frames, zero-copy views."""

from __future__ import annotations

import asyncio
import importlib.util
from pathlib import Path
from types import ModuleType

from mrosd import backports
from mrosd.master import Master

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"


def example(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


async def test_the_viewer_computes_on_the_cameras_loaned_frames() -> None:
    camera, viewer = example("camera"), example("viewer")
    async with Master(host="127.0.0.1", port=0) as master:
        watching = asyncio.ensure_future(viewer.main(master.uri, count=5))
        await asyncio.sleep(0.3)  # the viewer subscribes first: it sees the camera's first frames
        in_place = await camera.main(master.uri, rate=30.0, count=20)
        seen = await backports.wait_for(watching, 20)
    assert in_place >= 15  # frames written into the pool itself (the rest were copied: no slot free yet)
    assert len(seen) == 5 and all(0 <= b <= 255 for b in seen)
