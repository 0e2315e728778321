"""One attached shared-memory subscriber as its publisher holds it, and the leases it may be granted.

Owns what the publisher keeps per subscriber: its acknowledgement page (the next message it wants, the
leases it holds), the socket pair for wake-ups both ways, its counters, and the rule that shares the pool's
lease slots between subscribers (``grant_leases``). Must not know the ring, the backlog or how the
subscriber attached (``mrosd.shm.publisher`` and ``mrosd.shm.door``).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import os
import socket
from collections.abc import Iterable

from mrosd.ixm.channel import small_send_buffer
from mrosd.shm.channel import ControlChannel
from mrosd.shm.segment import MAX_LEASES, AckPage

__all__ = ["ShmSubscriberLink", "grant_leases"]

_ids = itertools.count(1)


class ShmSubscriberLink:
    """One attached subscriber, seen from the publisher."""

    def __init__(
        self,
        label: str,
        channel: ControlChannel,
        *,
        callerid: str,
        pid: int,
        first: int,
        loop: asyncio.AbstractEventLoop,
    ) -> None:
        self.channel = channel
        self._loop = loop
        self.callerid = callerid
        self.pid = pid
        self.id = next(_ids)
        self.messages_sent = 0
        self.bytes_sent = 0
        #: as last reported by the subscriber
        self.dropped = 0
        self.connected = True
        #: the subscriber's acknowledgement page: the number of the next message it wants
        self.ack = AckPage(label, first)
        #: wake-ups both ways: we send on ``wake`` to wake it, it sends on its end (``peer_end``, sent with
        #: Attached, then closed here) when it moves on while ``waiting`` is set. Only it holds its end, and a
        #: send here ignores the file's flags: it cannot make us block, read what we send, or steal its own
        #: wake-ups of us; flooding or shutting its end costs only itself.
        try:
            self.wake, self.peer_end = socket.socketpair(
                socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_NONBLOCK | socket.SOCK_CLOEXEC
            )
        except OSError:
            self.ack.close()
            raise
        small_send_buffer(self.wake)
        #: no longer waited for (it fell too far behind) until it catches up
        self.lagging = False
        #: leases honoured for it (granted at attach; what it writes in more lease words is ignored)
        self.grant = 0
        #: its uid (from the kernel): a foreign uid's subscribers share half of the lease slots
        self.uid = -1

    def acked(self, head: int) -> int:
        """The next message the subscriber wants, as it says, kept within 0..head + 1."""
        return min(self.ack.read(), head + 1)

    def leases(self) -> list[int]:
        """The messages it holds leases on (at most ``grant`` of them, whatever it wrote)."""
        return self.ack.leases(self.grant) if self.grant else []

    def close(self) -> None:
        if not self.connected:
            return
        self.connected = False
        loop = self._loop
        with contextlib.suppress(Exception):
            loop.remove_reader(self.channel.sock.fileno())
        with contextlib.suppress(Exception):
            loop.remove_reader(self.wake.fileno())
        self.channel.close()
        self.wake.close()
        self.peer_end.close()
        self.ack.close()


def grant_leases(links: Iterable[ShmSubscriberLink], lease_slots: int, uid: int, wanted: int) -> int:
    """Leases for a new subscriber of ``uid``: what it asks, at most ``MAX_LEASES``, within what the
    pool's lease slots have left; the subscribers of any other uid than ours and root's hold at most half
    of them together, so that one trusted foreign uid attaching again and again cannot take them all."""
    links = list(links)
    left = lease_slots - sum(lk.grant for lk in links)
    if uid not in (0, os.getuid()):
        left = min(left, lease_slots // 2 - sum(lk.grant for lk in links if lk.uid == uid))
    return max(0, min(wanted, MAX_LEASES, left))
