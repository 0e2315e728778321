"""What rosbridge's ROS 1 publisher manager does beyond sharing a publisher, so a message a client publishes
right after ``advertise`` (and then leaves) reaches the subscribers.

- **Linger** (rosbridge's ``unregister_timeout``): when a client lets go of a topic (``unadvertise`` or
  disconnect), the publisher stays advertised for ``UNREGISTER_TIMEOUT`` seconds more, so subscribers still
  connecting get what it sent, and a client that comes back finds it. At most ``MAX_LINGERING`` publishers of a
  hub linger at once: beyond, a released one goes at once (a client that advertises and leaves in a loop holds
  no more than that).
- **Consistency** (rosbridge's ``PublisherConsistencyListener``): for ``CONSISTENCY_WINDOW`` seconds after a
  publisher is made, what rosbridge clients publish on it is kept (at most ``CONSISTENCY_MESSAGES`` messages and
  ``CONSISTENCY_BYTES``, dropping the oldest) and sent again to each TCPROS subscriber that connects within that
  window, right after its handshake, ahead of any later message. A subscriber that connects later gets nothing
  more, as with rosbridge. (A same-host mrosd subscriber on shared memory is not re-sent to.)
"""

from __future__ import annotations

import asyncio
import collections
import weakref
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mrosd.web.hub import WebHub

__all__ = ["CONSISTENCY_WINDOW", "UNREGISTER_TIMEOUT", "linger_release", "published", "watch_new"]

UNREGISTER_TIMEOUT = 10.0
MAX_LINGERING = 256
CONSISTENCY_WINDOW = 1.0
CONSISTENCY_MESSAGES = 100
CONSISTENCY_BYTES = 4 * 1024 * 1024


class _Lingering:
    """The releases a hub has put off (one timer per released ownership)."""

    def __init__(self) -> None:
        self.timers: set[asyncio.TimerHandle] = set()
        self.tasks: set[asyncio.Task[None]] = set()


_lingering: weakref.WeakKeyDictionary[WebHub, _Lingering] = weakref.WeakKeyDictionary()


async def linger_release(hub: WebHub, topic: str, timeout: float | None = None) -> None:
    """Give back one ownership of ``topic``'s shared publisher ``timeout`` seconds from now (now when the hub
    already holds ``MAX_LINGERING`` such releases)."""
    state = _lingering.setdefault(hub, _Lingering())
    timeout = UNREGISTER_TIMEOUT if timeout is None else timeout
    if timeout <= 0 or len(state.timers) >= MAX_LINGERING:
        await hub.release_publisher(topic)
        return
    loop = asyncio.get_running_loop()

    def release() -> None:
        state.timers.discard(handle)
        task = loop.create_task(hub.release_publisher(topic), name=f"rosbridge unregister {topic}")
        state.tasks.add(task)
        task.add_done_callback(state.tasks.discard)

    handle = loop.call_later(timeout, release)
    state.timers.add(handle)


class _Consistency:
    """The first second of one publisher's messages, sent again to subscribers that connect within it."""

    def __init__(self, pub: Any) -> None:
        loop = asyncio.get_running_loop()
        self.pub = pub
        self.until = loop.time() + CONSISTENCY_WINDOW
        self.frames: collections.deque[bytes] = collections.deque()
        self.size = 0
        self._accept = pub.accept
        pub.accept = self.accept  # the node's TCPROS server hands new subscribers to ``pub.accept``
        loop.call_later(CONSISTENCY_WINDOW, self.detach)

    def open(self) -> bool:
        return asyncio.get_running_loop().time() < self.until

    def detach(self) -> None:
        if self.pub.__dict__.get("accept") == self.accept:
            del self.pub.accept
        self.frames.clear()
        self.size = 0
        _consistency.pop(self.pub, None)

    def record(self, msg: Any) -> None:
        if not self.open():
            return
        body = bytes(msg.serialize())
        self.frames.append(len(body).to_bytes(4, "little") + body)
        self.size += len(self.frames[-1])
        while len(self.frames) > CONSISTENCY_MESSAGES or (self.size > CONSISTENCY_BYTES and len(self.frames) > 1):
            self.size -= len(self.frames.popleft())

    def accept(self, proto: Any, header: Any) -> None:
        self._accept(proto, header)
        link = getattr(proto, "link", None)
        if link is None or link not in self.pub.links or not self.open():
            return
        for frame in self.frames:  # the new link has had nothing yet: everything kept is news to it
            link.send(frame)


_consistency: weakref.WeakKeyDictionary[Any, _Consistency] = weakref.WeakKeyDictionary()


def watch_new(pub: Any) -> None:
    """Keep ``pub``'s first second for late subscribers, if it is new (it has published nothing yet)."""
    if pub.messages_published == 0 and pub not in _consistency and not pub.closed:
        _consistency[pub] = _Consistency(pub)


def published(pub: Any, msg: Any) -> None:
    """``msg`` was just published on ``pub`` by a rosbridge client."""
    watch = _consistency.get(pub)
    if watch is not None:
        watch.record(msg)
