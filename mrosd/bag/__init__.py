"""Bags: record topics to rosbag v2 or MCAP files, play them back, summarize them, with no ROS install.

``model`` and ``info`` are pure (names, durations, split and replay timing, ``rosbag info`` text); ``files``
wraps the ``rosbags`` and ``mcap`` libraries (no codec of our own); ``recorder`` and ``player`` are the
asyncio parts built on ``mrosd.tcpros.Node``. Re-exports are lazy so ``import mrosd.bag`` loads nothing else.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mrosd.bag.files import BagReader, open_bag, open_writer
    from mrosd.bag.info import BagSummary, format_info
    from mrosd.bag.model import BagError, ConnectionInfo
    from mrosd.bag.player import Player
    from mrosd.bag.recorder import Recorder, RecordSink

__all__ = [
    "BagError",
    "BagReader",
    "BagSummary",
    "ConnectionInfo",
    "Player",
    "RecordSink",
    "Recorder",
    "format_info",
    "open_bag",
    "open_writer",
]

_EXPORTS = {
    "BagError": "mrosd.bag.model",
    "BagReader": "mrosd.bag.files",
    "BagSummary": "mrosd.bag.info",
    "ConnectionInfo": "mrosd.bag.model",
    "Player": "mrosd.bag.player",
    "RecordSink": "mrosd.bag.recorder",
    "Recorder": "mrosd.bag.recorder",
    "format_info": "mrosd.bag.info",
    "open_bag": "mrosd.bag.files",
    "open_writer": "mrosd.bag.files",
}


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
