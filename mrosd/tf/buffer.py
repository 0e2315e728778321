"""The asyncio shell of tf2: a Buffer fed by /tf and /tf_static, and the two broadcasters.

One Buffer holds one subscription to each topic, whatever number of lookups it serves. Messages are decoded
raw (``AnyMsg``) so that each transform keeps its broadcaster (the publisher's caller id), as tf2_ros does.

The Buffer runs on the daemon's loop, which is the master's: a /tf publisher must not be able to hold it.
Received messages wait in an inbox bounded in bytes (the oldest /tf message dropped first, counted in
``dropped``) and a task stores them, giving the loop back every ``SLICE_S`` seconds; a message claiming more
than ``MAX_TRANSFORMS`` transforms is refused before it is decoded. Before: a publisher of 1,000-transform
messages kept the loop in the Buffer for seconds at a time (getPid 5 s, the daemon's own nodes lost the master).
"""

from __future__ import annotations

import asyncio
import logging
import time as _time
from collections import deque
from typing import TYPE_CHECKING, Any

from mrosd import backports
from mrosd.errors import MrosError
from mrosd.lograte import RateLimitedLog
from mrosd.msg import Time, get_message_class
from mrosd.msg.runtime import FrameBuffer
from mrosd.tf.core import DEFAULT_CACHE_TIME, BufferCore, Pose, TransformError

if TYPE_CHECKING:
    from mrosd.tcpros import Node, Publisher, RawMessage, Subscriber

log = logging.getLogger(__name__)
_peer_log = RateLimitedLog(log)

TFMessage = get_message_class("tf2_msgs/TFMessage")
TransformStamped = get_message_class("geometry_msgs/TransformStamped")
Transform = get_message_class("geometry_msgs/Transform")
Vector3 = get_message_class("geometry_msgs/Vector3")
Quaternion = get_message_class("geometry_msgs/Quaternion")
Header = get_message_class("std_msgs/Header")


#: Transforms one message may carry (tf2 has no bound; a robot's broadcasters send tens, a big one hundreds).
MAX_TRANSFORMS = 10_000
#: Bytes of received messages waiting to be stored (always at least the newest message).
INBOX_BYTES = 8 * 1024 * 1024
#: Longest the storing task holds the loop before it yields.
SLICE_S = 0.005


def stamp_ns(stamp: Any) -> int:
    return int(stamp.secs) * 1_000_000_000 + int(stamp.nsecs)


def pose_of(transform: Any) -> Pose:
    t, r = transform.translation, transform.rotation
    return (t.x, t.y, t.z, r.x, r.y, r.z, r.w)


def transform_stamped(target: str, source: str, ns: int, pose: Pose) -> Any:
    return TransformStamped(
        header=Header(stamp=Time.from_nsec(ns), frame_id=target),
        child_frame_id=source,
        transform=Transform(
            translation=Vector3(x=pose[0], y=pose[1], z=pose[2]),
            rotation=Quaternion(x=pose[3], y=pose[4], z=pose[5], w=pose[6]),
        ),
    )


class Buffer:
    """Transforms from /tf and /tf_static, ``cache_time`` seconds per frame (tf2's default 10 s).

    ``lookup_transform(target, source, time)`` returns a ``geometry_msgs/TransformStamped`` (target <- source;
    ``time`` None or zero: the latest common time) or raises tf2's errors (``mrosd.tf.ExtrapolationError``
    ...) with tf2's texts.
    """

    def __init__(self, node: Node | None = None, *, cache_time: float = DEFAULT_CACHE_TIME) -> None:
        self.node = node
        self.core = BufferCore(cache_time=cache_time)
        self._subs: list[Subscriber] = []
        self._changed = asyncio.Event()
        #: received (message body, caller id, static), waiting for ``_store``
        self._inbox: deque[tuple[bytes | bytearray | memoryview, str, bool]] = deque()
        self._inbox_bytes = 0
        self._inbox_ready = asyncio.Event()
        self._storer: asyncio.Task[None] | None = None
        #: /tf messages dropped from the inbox (the Buffer stored slower than they came)
        self.dropped = 0

    async def start(self) -> Buffer:
        from mrosd.tcpros import AnyMsg

        if self.node is not None:
            self._storer = asyncio.get_running_loop().create_task(self._store(), name="tf buffer")
            self._subs.append(await self.node.subscribe("/tf", AnyMsg, self._on_tf, queue_size=1000))
            self._subs.append(await self.node.subscribe("/tf_static", AnyMsg, self._on_tf_static, queue_size=1000))
        return self

    async def aclose(self) -> None:
        for sub in self._subs:
            await sub.aclose()
        self._subs.clear()
        storer, self._storer = self._storer, None
        if storer is not None:
            storer.cancel()
            await asyncio.gather(storer, return_exceptions=True)
        self._inbox.clear()
        self._inbox_bytes = 0

    async def __aenter__(self) -> Buffer:
        return await self.start()

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()

    # --- feeding ---------------------------------------------------------------------------------

    def set_transform(self, msg: Any, authority: str = "default_authority", static: bool = False) -> bool:
        """Store one ``geometry_msgs/TransformStamped``; False when tf2 would ignore it."""
        ok = self.core.set_transform(
            msg.header.frame_id,
            msg.child_frame_id,
            stamp_ns(msg.header.stamp),
            pose_of(msg.transform),
            authority=authority,
            static=static,
        )
        self._changed.set()
        return ok

    def _feed(self, raw: RawMessage, static: bool) -> None:
        """Queue a received message for ``_store`` (bounded: the oldest /tf message goes first)."""
        body = raw.data
        if not isinstance(body, bytes | FrameBuffer):
            body = bytes(body)  # a view into a shared-memory ring is only ours during this call
        callerid = raw.header.callerid or "no callerid"
        count = int.from_bytes(bytes(body[:4]), "little") if len(body) >= 4 else 0
        if count > MAX_TRANSFORMS:
            _peer_log.warning(
                "tf size", "a /tf message from %s claims %d transforms; at most %d", callerid, count, MAX_TRANSFORMS
            )
            return
        self._inbox.append((body, callerid, static))
        self._inbox_bytes += len(body)
        while self._inbox_bytes > INBOX_BYTES and len(self._inbox) > 1:
            oldest = next((i for i, item in enumerate(self._inbox) if not item[2]), None)
            if oldest is None:
                break  # only /tf_static waits: it is latched, sent once, never dropped
            dropped = self._inbox[oldest]
            del self._inbox[oldest]
            self._inbox_bytes -= len(dropped[0])
            self.dropped += 1
        self._inbox_ready.set()

    async def _store(self) -> None:
        loop_time = _time.monotonic
        while True:
            await self._inbox_ready.wait()
            self._inbox_ready.clear()
            slice_end = loop_time() + SLICE_S
            while self._inbox:
                body, callerid, static = self._inbox.popleft()
                self._inbox_bytes -= len(body)
                try:
                    msg = TFMessage.deserialize(body)
                except MrosError as exc:
                    _peer_log.warning("tf decode", "a /tf message from %s does not decode: %s", callerid, exc)
                    continue
                del body
                for i, t in enumerate(msg.transforms):
                    self.core.set_transform(
                        t.header.frame_id,
                        t.child_frame_id,
                        stamp_ns(t.header.stamp),
                        pose_of(t.transform),
                        authority=callerid,
                        static=static,
                    )
                    if i % 64 == 63 and loop_time() > slice_end:
                        slice_end = await self._next_slice()
                self._changed.set()
                if loop_time() > slice_end:
                    slice_end = await self._next_slice()

    async def _next_slice(self) -> float:
        """The slice is over: wake the waiters for what is stored so far, give the loop back, start the next."""
        self._changed.set()
        await asyncio.sleep(0)
        return _time.monotonic() + SLICE_S

    def _on_tf(self, raw: RawMessage) -> None:
        self._feed(raw, False)

    def _on_tf_static(self, raw: RawMessage) -> None:
        self._feed(raw, True)

    # --- questions -------------------------------------------------------------------------------

    def lookup_transform(self, target: str, source: str, time: Time | None = None) -> Any:
        pose, used = self.core.lookup(target, source, 0 if time is None else stamp_ns(time))
        return transform_stamped(target, source, used, pose)

    def can_transform(self, target: str, source: str, time: Time | None = None) -> bool:
        return self.core.can_transform(target, source, 0 if time is None else stamp_ns(time))

    async def wait_for_transform(self, target: str, source: str, time: Time | None = None, timeout: float = 5.0) -> Any:
        """``lookup_transform`` once it can answer; each new transform retries.

        Raises:
            TransformError: the lookup still fails after ``timeout`` seconds (tf2's error from the last try).
        """
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while True:
            self._changed.clear()
            try:
                return self.lookup_transform(target, source, time)
            except TransformError:
                remaining = deadline - loop.time()
                if remaining <= 0:
                    raise
                try:
                    async with backports.timeout(remaining):
                        await self._changed.wait()
                except TimeoutError:
                    pass

    def all_frames_as_yaml(self) -> str:
        return self.core.frames_as_yaml()

    def frames(self) -> dict[str, dict[str, Any]]:
        """Each child frame: parent, broadcaster, rate (Hz), most recent and oldest stamp (s), as tf2 reports."""
        out: dict[str, dict[str, Any]] = {}
        for name, cache in self.core.frames.items():
            if not cache.stamps:
                continue
            newest = 0 if cache.static else cache.stamps[-1]
            oldest = 0 if cache.static else cache.stamps[0]
            span = (newest - oldest) / 1e9
            out[name] = {
                "parent": cache.parents[-1],
                "broadcaster": cache.authority,
                "rate": len(cache.stamps) / max(span, 0.0001),
                "most_recent_transform": newest / 1e9,
                "oldest_transform": oldest / 1e9,
                "buffer_length": span,
                "static": cache.static,
            }
        return out


class TransformBroadcaster:
    """Publishes ``geometry_msgs/TransformStamped`` on /tf."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self._pub: Publisher | None = None

    async def start(self) -> TransformBroadcaster:
        self._pub = await self.node.advertise("/tf", TFMessage, queue_size=100)
        return self

    async def send_transform(self, *transforms: Any) -> None:
        if self._pub is None:
            await self.start()
        assert self._pub is not None
        await self._pub.publish(TFMessage(transforms=list(transforms)))

    async def aclose(self) -> None:
        if self._pub is not None:
            await self._pub.aclose()


class StaticTransformBroadcaster(TransformBroadcaster):
    """Publishes on /tf_static, latched; every transform sent so far is republished together (one per child
    frame, the last sent), as tf2_ros's StaticTransformBroadcaster does."""

    def __init__(self, node: Node) -> None:
        super().__init__(node)
        self._by_child: dict[str, Any] = {}

    async def start(self) -> StaticTransformBroadcaster:
        self._pub = await self.node.advertise("/tf_static", TFMessage, latch=True, queue_size=100)
        return self

    async def send_transform(self, *transforms: Any) -> None:
        if self._pub is None:
            await self.start()
        assert self._pub is not None
        for t in transforms:
            self._by_child[t.child_frame_id] = t
        await self._pub.publish(TFMessage(transforms=list(self._by_child.values())))
