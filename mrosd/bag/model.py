"""The pure parts of ``mros bag``: connection records, command-line values, file naming, split and replay timing.

Nothing here touches a file, a socket or the event loop, so every rule (how rosbag names split files, what
``5m`` means, when a file is full, when a replayed message is due) is tested on its own.
"""

from __future__ import annotations

import re
import time
from collections.abc import Sequence

import msgspec

from mrosd.errors import MrosError

#: rosbag record's default in-memory buffer (``-b/--buffsize``, MB) between the receiving loop and the writer.
DEFAULT_BUFFER_MB = 256
#: rosbag play's default rate of /clock messages (``--hz``).
DEFAULT_CLOCK_HZ = 100.0

_DURATION = re.compile(r"^\s*(\d+(?:\.\d*)?|\.\d+)\s*([smh]?)\s*$")
_UNIT = {"": 1.0, "s": 1.0, "m": 60.0, "h": 3600.0}


class BagError(MrosError):
    """A bag file cannot be read or written, or a bag option is wrong; the message says which and why."""


class ConnectionInfo(msgspec.Struct, frozen=True, gc=False):
    """One connection of a bag: what the publisher's connection header said about the topic.

    Recorded exactly as the publisher sent it (type, md5sum, message_definition, callerid, latching), which is
    what rosbag stores, so a player can advertise the same type and latch the same topics.
    """

    topic: str
    type: str
    md5sum: str
    message_definition: str
    callerid: str = ""
    latching: bool = False


def parse_duration(text: str) -> float:
    """rosbag's duration syntax: seconds, or a number with ``s``, ``m`` or ``h`` (``30``, ``1.5m``, ``2h``).

    Raises:
        BagError: not a positive duration.
    """
    match = _DURATION.match(text)
    if match is None or float(match.group(1)) <= 0:
        raise BagError(f"duration {text!r} is not a positive number of seconds (e.g. 30, 30s, 5m, 2h)")
    return float(match.group(1)) * _UNIT[match.group(2)]


def timestamped_name(now: float | None = None) -> str:
    """rosbag record's default name stem: local time as ``YYYY-MM-DD-HH-MM-SS``."""
    return time.strftime("%Y-%m-%d-%H-%M-%S", time.localtime(time.time() if now is None else now))


def output_stem(name: str | None, prefix: str | None, extension: str, now: float | None = None) -> str:
    """The file name without its extension, as rosbag record chooses it.

    ``-O NAME`` is used as given (its extension dropped); ``-o PREFIX`` gets ``_`` and the time appended (no
    ``_`` when the prefix is a directory); neither gives the time alone.
    """
    if name:
        return name[: -len(extension)] if name.endswith(extension) else name
    stamp = timestamped_name(now)
    if prefix:
        prefix = prefix[: -len(extension)] if prefix.endswith(extension) else prefix
        return prefix + stamp if prefix.endswith("/") else f"{prefix}_{stamp}"
    return stamp


def split_path(stem: str, extension: str, index: int | None) -> str:
    """The path of file ``index`` of a recording (``NAME_0.bag``, ``NAME_1.bag``...), or ``NAME.bag`` unsplit."""
    return f"{stem}{extension}" if index is None else f"{stem}_{index}{extension}"


class SplitPolicy(msgspec.Struct, frozen=True):
    """When a file is full: ``max_bytes`` written or ``max_seconds`` of bag time since its first message."""

    max_bytes: int | None = None
    max_seconds: float | None = None

    def full(self, written: int, first_ns: int | None, now_ns: int) -> bool:
        """True once the current file reached a limit."""
        if self.max_bytes is not None and written >= self.max_bytes:
            return True
        return self.max_seconds is not None and first_ns is not None and now_ns - first_ns >= self.max_seconds * 1e9


def parse_play_args(args: Sequence[str]) -> tuple[list[str], dict[str, str]]:
    """Split rosbag play's positional arguments into bag files and ``/from:=/to`` topic remappings.

    Raises:
        BagError: a remapping has an empty side.
    """
    files: list[str] = []
    remaps: dict[str, str] = {}
    for arg in args:
        if ":=" in arg:
            src, dst = arg.split(":=", 1)
            if not src or not dst:
                raise BagError(f"remapping {arg!r} must be FROM:=TO with both names given")
            if src.startswith("__"):
                continue  # __name:=, __ns:= and friends are node arguments, not topic remappings
            remaps[_absolute(src)] = _absolute(dst)
        else:
            files.append(arg)
    return files, remaps


def _absolute(name: str) -> str:
    return name if name.startswith("/") else "/" + name


class ReplaySchedule:
    """When each stored message is due on the wall clock, for a rate, a start offset and loops.

    Bag time ``t`` (ns) is due at ``wall_start + (t - bag_start) / rate`` seconds; ``bag_start`` is the bag's
    first message plus the start offset. ``restart`` begins another loop from the current wall time.
    """

    def __init__(self, bag_start_ns: int, rate: float, wall_start: float) -> None:
        if rate <= 0:
            raise BagError(f"rate {rate} must be positive")
        self.bag_start_ns = bag_start_ns
        self.rate = rate
        self.wall_start = wall_start

    def due(self, t_ns: int) -> float:
        """Wall time (same clock as ``wall_start``) at which the message stamped ``t_ns`` is published."""
        return self.wall_start + (t_ns - self.bag_start_ns) / 1e9 / self.rate

    def bag_time(self, wall: float) -> int:
        """The bag time (ns) that corresponds to wall time ``wall`` (for /clock between messages)."""
        return self.bag_start_ns + int(max(0.0, wall - self.wall_start) * self.rate * 1e9)

    def restart(self, wall_start: float) -> None:
        self.wall_start = wall_start
