"""The web clients' dead-man switch: a client whose connection ends while it was driving gets its robot stopped.

A browser's teleop (the page's joystick, a roslibjs pad) publishes ``geometry_msgs/Twist`` or ``TwistStamped``
at 10 Hz and sends a zero when it lets go. When its connection drops instead (Wi-Fi gone, laptop shut, the
browser killed), nothing sends that zero and a robot without its own command timeout keeps going. So each web
session keeps a :class:`DeadMan`: every message it publishes is noted (type check first: other types cost a
set lookup), and as the session ends, :meth:`DeadMan.stop` publishes one zero of the same type on each topic
whose last command from that client was not zero and is at most :data:`WINDOW_S` old. A client that stopped
(its last command a zero) or went quiet long ago is left alone: it was not driving.

The policy is pure (:func:`zero_body`, :func:`is_moving`, :class:`DeadMan` over an injected clock); the hooks in
the Foxglove and rosbridge servers are one call on publish and one as the session ends.
"""

from __future__ import annotations

import asyncio
import logging
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

log = logging.getLogger(__name__)

#: the types a teleop drives with
TWIST = "geometry_msgs/Twist"
TWIST_STAMPED = "geometry_msgs/TwistStamped"
DRIVE_TYPES = frozenset((TWIST, TWIST_STAMPED))
#: a client counts as driving when its last non-zero command is at most this old as it disconnects
WINDOW_S = 1.0
#: how long a session's end waits for the zeros to leave (a subscriber that was behind reads them first)
SETTLE_S = 2.0
#: a Twist is six float64: linear xyz, angular xyz (it ends a TwistStamped too)
_TWIST_BYTES = 48
_SIX = struct.Struct("<6d")
_STAMP = struct.Struct("<II")
#: a Header starts with seq (uint32), then the stamp
_STAMP_OFFSET = 4


def _twist_part(type_name: str, body: bytes) -> bytes | None:
    """The Twist's 48 bytes of a serialized Twist/TwistStamped (None: too short to be one)."""
    if type_name == TWIST:
        return body if len(body) == _TWIST_BYTES else None
    if len(body) < _STAMP_OFFSET + _STAMP.size + 4 + _TWIST_BYTES:
        return None
    return body[-_TWIST_BYTES:]


def is_moving(type_name: str, body: bytes) -> bool:
    """Whether the command asks for any motion (NaN counts as motion: it is not a stop)."""
    twist = _twist_part(type_name, body)
    return twist is not None and any(v != 0.0 for v in _SIX.unpack(twist))


def zero_body(type_name: str, last: bytes, now_ns: int) -> bytes:
    """The stop command after ``last``: all zeros; a TwistStamped keeps the header's seq and frame_id and is
    stamped ``now_ns`` (a consumer that drops stale commands must not drop the stop)."""
    zeros = bytes(_TWIST_BYTES)
    if type_name == TWIST:
        return zeros
    header = bytearray(last[:-_TWIST_BYTES])
    _STAMP.pack_into(header, _STAMP_OFFSET, now_ns // 1_000_000_000, now_ns % 1_000_000_000)
    return bytes(header) + zeros


@dataclass(slots=True)
class _Command:
    publisher: Any
    type_name: str
    body: bytes
    at: float
    moving: bool


class DeadMan:
    """One web client's last drive command per topic, and the zero that follows it when the client is gone."""

    def __init__(
        self,
        client: str,
        *,
        window: float = WINDOW_S,
        clock: Callable[[], float] = time.monotonic,
        wall_ns: Callable[[], int] = time.time_ns,
    ) -> None:
        self.client = client
        self.window = window
        self._clock = clock
        self._wall_ns = wall_ns
        self._last: dict[str, _Command] = {}

    def published(self, publisher: Any, type_name: str, body: bytes) -> None:
        """Note a serialized message the client published through ``publisher`` (any type; most are ignored)."""
        if type_name not in DRIVE_TYPES:
            return
        self._last[publisher.topic] = _Command(publisher, type_name, body, self._clock(), is_moving(type_name, body))

    def published_message(self, publisher: Any, msg: Any) -> None:
        """:meth:`published` for a message object (rosbridge decodes JSON into one); serialized only if it drives."""
        type_name = getattr(msg, "_type", "")
        if type_name in DRIVE_TYPES:
            self.published(publisher, type_name, msg.serialize())

    def due(self) -> list[tuple[Any, bytes]]:
        """The (publisher, zero body) pairs owed now: topics driven within the window whose last command moved."""
        now = self._clock()
        out = []
        for cmd in self._last.values():
            if cmd.moving and now - cmd.at <= self.window:
                out.append((cmd.publisher, zero_body(cmd.type_name, cmd.body, self._wall_ns())))
        return out

    async def stop(self, settle: float = SETTLE_S) -> int:
        """The client is gone: publish the zeros owed (once; what cannot be sent is logged), then wait (at most
        ``settle`` s) until they have left for the kernel: the client's publisher is released next, and a
        publisher's close drops what a slow subscriber has not taken yet. Returns how many zeros were sent."""
        sent = []
        for publisher, body in self.due():
            try:
                publisher.publish_serialized(body)
            except Exception as exc:  # a closed publisher: nothing left to stop through
                log.warning("web: dead-man: could not stop %s for %s: %s", publisher.topic, self.client, exc)
                continue
            sent.append(publisher)
            log.warning(
                "web: dead-man: %s disconnected while driving %s: published a zero", self.client, publisher.topic
            )
        self._last.clear()
        if sent:
            await _settle(sent, settle)
        return len(sent)


def _backlog(publisher: Any) -> bool:
    """Whether a subscriber connection of ``publisher`` still holds frames not handed to the kernel."""
    for link in getattr(publisher, "links", ()):
        proto = getattr(link, "proto", None)
        transport = getattr(proto, "transport", None)
        if getattr(link, "queue", None) or (transport is not None and transport.get_write_buffer_size()):
            return True
    return False


async def _settle(publishers: list[Any], timeout: float) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    # a publisher offers no event for "flushed": poll
    while any(_backlog(p) for p in publishers) and loop.time() < deadline:  # noqa: ASYNC110
        await asyncio.sleep(0.01)
