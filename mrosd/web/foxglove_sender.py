"""The sending half of a Foxglove session: time messages, control frames, then subscription data in a fair
order (``mrosd.web.fairsend``), and the drop reports.

The sender drains, in this order, the latest /clock time, control messages (JSON and binary replies, bounded
in ``ClientSession``) and then the subscriptions, deficit round robin by bytes: a small topic's backlog goes
out in the round in which a camera sends one frame, and a big topic's next frame waits, newest only, until the
link is clear. Small messages go through aiohttp's writer (deflated when the client negotiated
permessage-deflate); big and already compressed ones are written past it from the buffer TCPROS delivered
them in (``_send_message_data``).

Every ``REPORT_PERIOD`` a client whose subscriptions dropped messages gets a warning status per subscription,
and a client that asked for them (``x-mrosd.subscribeDelivery``: the page does) gets an ``x-mrosd.delivery``
op when they changed: per subscription, messages sent, dropped and bytes queued (the page shows the drops in
its topics table). Other clients never get it: Foxglove's own report an op they do not know as an error.
"""

from __future__ import annotations

import asyncio
import time
from typing import TYPE_CHECKING, Any

from mrosd.web import foxglove as fg
from mrosd.web.fairsend import (
    DEFLATE_MAX_BYTES,
    FairSender,
    delivery_counts,
    is_precompressed,
    settle_deflate_writes,
)
from mrosd.web.hub import PAUSE_BYTES
from mrosd.web.session import ClientSession

if TYPE_CHECKING:
    from aiohttp.abc import AbstractStreamWriter

__all__ = ["REPORT_PERIOD", "FoxgloveSender"]

#: Seconds between two drop reports (and delivery counts) of one client.
REPORT_PERIOD = 1.0
#: payloads from this size on are written after their frame head rather than copied behind it
_SEPARATE_WRITE_BYTES = 16 * 1024


class FoxgloveSender(ClientSession):
    """The sender task of a Foxglove session (``FoxgloveSession`` sets up what is declared here)."""

    _writer: AbstractStreamWriter
    _fair: FairSender[int, Any]
    _time_ns: int | None
    _throttle_timer: asyncio.TimerHandle | None
    sent_messages: int

    def _init_sender(self, writer: AbstractStreamWriter) -> None:
        #: the prepared response's stream: big messageData frames are written to its transport directly
        self._writer = writer
        self._fair = FairSender(self._wake.set)
        self._fair.transport = writer.transport
        self.sent_messages = 0
        #: the client asked for ``x-mrosd.delivery`` reports
        self.wants_delivery = False
        #: the latest /clock time not yet sent (a 1 kHz clock costs the client the rate it reads at)
        self._time_ns = None
        self._throttle_timer = None
        #: the client negotiated permessage-deflate (aiohttp then deflates what goes through it)
        self._deflate = bool(self.ws.compress)

    def _next_message(self) -> tuple[int, int, bytes | bytearray, bool] | None:
        """The next message to send: (subscription id, receipt ns, body, deflate it)."""
        now = time.monotonic_ns()

        def ready(sub: Any) -> bool:
            return not sub.period_ns or now >= sub.next_ns

        sub = self._fair.pick(self.subs, ready)
        if sub is None:
            waits = [s.next_ns - now for s in self.subs.values() if s.period_ns and len(s.queue) and now < s.next_ns]
            if waits and self._throttle_timer is None:
                self._throttle_timer = asyncio.get_running_loop().call_later(min(waits) / 1e9, self._throttle_due)
            return None
        if sub.period_ns:
            sub.next_ns = now + sub.period_ns
        receipt_ns, body = sub.queue.get()
        if self.backlog(sub.topic.name) < PAUSE_BYTES:
            self.hub.resume(sub.topic.name)
        deflate = self._deflate and len(body) < DEFLATE_MAX_BYTES and not is_precompressed(sub.topic.type)
        return sub.id, receipt_ns, body, deflate

    def _throttle_due(self) -> None:
        self._throttle_timer = None
        self._wake.set()

    async def _sender(self) -> None:
        ws = self.ws
        try:
            while not self._closed:
                await self._wake.wait()
                self._wake.clear()
                while not self._closed:
                    if self._time_ns is not None:
                        stamp, self._time_ns = self._time_ns, None
                        await ws.send_bytes(fg.time_message(stamp))
                        continue
                    if self._control:
                        text, data = self._control.pop()
                        if text:
                            await ws.send_str(data.decode())
                        else:
                            await ws.send_bytes(data)
                        continue
                    message = self._next_message()
                    if message is None:
                        break
                    await self._send_message_data(*message)
                    self.sent_messages += 1
        finally:
            self._fair.close()
            settle_deflate_writes(self.ws)

    async def _send_message_data(
        self, sub_id: int, receipt_ns: int, body: bytes | bytearray, deflate: bool = False
    ) -> None:
        """One messageData frame: through aiohttp's writer when it is to be deflated, else its payload written
        from the buffer TCPROS delivered it in.

        aiohttp's ``send_bytes`` takes a frame's whole payload as one buffer, which would mean copying every
        message behind its 13-byte prefix (a quarter of the bridge's CPU at 8 MB images). The frame is the
        same bytes written in two parts, with no await between them, so nothing aiohttp itself writes (pongs,
        the close frame) can come in between. Flow control: ``FairSender.must_drain``.
        """
        head = fg.message_data_head(sub_id, receipt_ns, len(body))
        if deflate:
            prefix = head[len(head) - _MESSAGE_DATA_PREFIX :]
            await self.ws.send_bytes(prefix + body)
            return
        transport = self._writer.transport
        if self.ws.closed or transport is None or transport.is_closing():
            raise ConnectionResetError("the client's connection is closing")
        if len(body) < _SEPARATE_WRITE_BYTES:
            transport.write(head + body)
        else:
            transport.write(head)
            transport.write(body)
        if self._fair.must_drain(len(body)):
            await self._writer.drain()

    async def _reporter(self) -> None:
        last: list[dict[str, Any]] = []
        while not self._closed:
            await asyncio.sleep(REPORT_PERIOD)
            for sub in list(self.subs.values()):
                dropped = sub.queue.take_unreported()
                if dropped:
                    self.status(
                        fg.STATUS_WARNING,
                        f"dropped {dropped} message(s) of {sub.topic.name} (subscription {sub.id}): this client "
                        f"reads slower than the topic is published; {sub.queue.dropped} dropped in all",
                        f"dropped:{sub.id}",
                    )
            counts = delivery_counts(self.subs, lambda s: s.topic.name)
            for sub_id, row in zip(self.subs, counts, strict=True):
                row["subscriptionId"] = sub_id
            if self.wants_delivery and counts != last:
                self._queue_control(True, fg.encode_json("x-mrosd.delivery", subscriptions=counts))
                last = counts

    if TYPE_CHECKING:

        def backlog(self, topic: str) -> int: ...

        def status(self, level: int, message: str, status_id: str | None = None) -> None: ...


#: the messageData prefix (op, subscription id, receipt time) that follows the frame head
_MESSAGE_DATA_PREFIX = 1 + 4 + 8
