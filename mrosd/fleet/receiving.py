"""Remote topics published here (``receive_topics``), every body checked against its type first.

A remote ``pub`` announcement whose local (renamed) name is in ``receive_topics`` makes a local publisher of
that name, once the type is found on the search path with the announced md5 (else the item is refused: a
body of a type this robot cannot check never reaches a subscriber). Its Zenoh subscription exists only while
a local subscriber is connected, and starts with a query for the latched body. Each body is decoded by the
type's checker (``mrosd.fleet.check``) before it is published; one that is not exactly one well-formed
message of the type is dropped and
counted, and the local subscribers' connections never see it (rospy drops a connection on a bad frame, and
the subscription then stays dead).
"""

from __future__ import annotations

import contextlib
import time
from typing import Any

from mrosd.errors import MrosError
from mrosd.fleet.frames import prefix_tf_frames, wants_tf_prefix
from mrosd.fleet.keys import LATCHED_ATTACHMENT, WILDCARD_NS, Item
from mrosd.fleet.limits import LINK_BYTES, MAX_BODY_BYTES
from mrosd.fleet.link import QUERY_TIMEOUT, FleetLink, ReceivedTopic, ratelog
from mrosd.fleet.raw import FleetTypeError, checker, message_class, raw_message_class

#: How a received body came: a plain sample, a sample of a latched topic, or the answer to the latched query.
LIVE, LIVE_LATCHED, CACHED = 0, 1, 2
#: ``(type, md5)`` pairs remembered as not checkable here, so a repeated announcement costs no new look-up.
MAX_UNCHECKABLE = 1024


def _how(sample: Any) -> int:
    """``LIVE_LATCHED`` when the sender marked the sample as a latched topic's (runs on Zenoh's thread)."""
    attachment = sample.attachment
    if attachment is not None and attachment.to_bytes() == LATCHED_ATTACHMENT:
        return LIVE_LATCHED
    return LIVE


class Receiver:
    """The received topics of one ``FleetLink``."""

    def __init__(self, link: FleetLink) -> None:
        self.link = link
        self.uncheckable: set[tuple[str, str]] = set()

    def offer(self, item: Item, local: str) -> bool:
        """A remote publisher announced under ``local`` (already allowed by ``receive_topics``): publish it
        here unless it is known or its type cannot be checked. True when it is new here."""
        link = self.link
        if local in link.received or local in link.sent or (item.type, item.md5sum) in self.uncheckable:
            return False
        rt = link.received[local] = ReceivedTopic(local, item, tf_robot=self._tf_robot(item))
        link.spawn(self._add(rt))
        return True

    def _tf_robot(self, item: Item) -> str:
        options = self.link.options
        if not options.prefix_tf or not wants_tf_prefix(item.topic, item.type):
            return ""
        return options.rename.wildcard_robot if item.namespace == WILDCARD_NS else item.namespace

    async def _add(self, rt: ReceivedTopic) -> None:
        link = self.link
        try:
            rt.cls = await message_class(rt.item.type, rt.item.md5sum)
            rt.checker = await checker(rt.cls)
        except FleetTypeError as exc:
            link.counters.unchecked_types += 1
            if len(self.uncheckable) >= MAX_UNCHECKABLE:
                self.uncheckable.clear()
            self.uncheckable.add((rt.item.type, rt.item.md5sum))
            ratelog.warning("unchecked", "fleet: not receiving %s: %s", rt.local, exc)
            if link.received.get(rt.local) is rt:
                del link.received[rt.local]
            return
        if link.received.get(rt.local) is not rt or link.closed:
            return
        cls = raw_message_class(rt.item.type, rt.item.md5sum, str(rt.cls._full_text))
        try:
            rt.publisher = await link.node.advertise(
                rt.local, cls, queue_size=link.options.queue_size, max_queued_bytes=LINK_BYTES
            )
            link.touch()
        except MrosError as exc:
            ratelog.warning(f"adv {rt.local}", "fleet: cannot publish %s here: %s", rt.local, exc)
            link.received.pop(rt.local, None)

    def deliver(self, name: str, items: list[Any]) -> None:
        """Bodies that came for ``name`` (on the loop, from the inbox): checked, then published."""
        link = self.link
        rt = link.received.get(name)
        if rt is None or rt.publisher is None or (rt.publisher.closed and not rt.relatching):
            return
        for raw, how in items:
            why = rt.checker.check(raw)
            if why is not None:
                rt.refused += 1
                link.malformed("body", name, why)
                continue
            body = raw
            if rt.tf_robot:
                try:
                    body = prefix_tf_frames(raw, rt.tf_robot)
                except MrosError as exc:
                    rt.refused += 1
                    link.malformed("TFMessage", name, str(exc))
                    continue
            if how == CACHED and rt.received:
                continue  # live data already came: the cached body is older
            rt.latched_seen = rt.latched_seen or how != LIVE
            if rt.latched_seen and not rt.publisher.latch and rt.publisher.shm is None:
                # Latched at the sender: latched here too, so later local subscribers get the last body. TCPROS
                # reads the flag at each new connection (a shared-memory side, made later, takes it then too).
                rt.publisher.latch = True
            if rt.relatching or (rt.latched_seen and not rt.publisher.latch):
                # The publisher's shared-memory side took its latch when made: advertise it again, latched.
                rt.pending = body
                if not rt.relatching:
                    rt.relatching = True
                    link.spawn(self._relatch(rt))
                continue
            rt.received += 1
            rt.bytes_received += len(body)
            rt.meter.tick(time.monotonic())
            rt.publisher.publish_serialized(body)
        link.touch()

    async def _relatch(self, rt: ReceivedTopic) -> None:
        """Replace the local publisher of ``rt`` by a latched one and publish the last body on it.

        Its subscribers see the publisher leave and come back (publisherUpdate) and get the body on
        reconnecting, once; bodies that arrive meanwhile replace the pending one.
        """
        link = self.link
        old = rt.publisher
        try:
            if old is not None:
                with contextlib.suppress(MrosError, OSError):
                    await old.aclose()
            cls = raw_message_class(rt.item.type, rt.item.md5sum, str(rt.cls._full_text))
            pub = await link.node.advertise(
                rt.local, cls, latch=True, queue_size=link.options.queue_size, max_queued_bytes=LINK_BYTES
            )
        except MrosError as exc:
            ratelog.warning(f"adv {rt.local}", "fleet: cannot publish %s latched here: %s", rt.local, exc)
            return
        finally:
            rt.relatching = False
        if link.received.get(rt.local) is not rt:  # forgotten meanwhile
            await pub.aclose()
            return
        rt.publisher = pub
        if rt.pending is not None:
            body, rt.pending = rt.pending, None
            rt.received += 1
            rt.bytes_received += len(body)
            rt.meter.tick(time.monotonic())
            pub.publish_serialized(body)
        link.touch()

    async def drop(self, rt: ReceivedTopic) -> None:
        link = self.link
        link.undeclare(rt.subscriber)
        rt.subscriber = None
        if link.inbox is not None:
            link.inbox.forget(rt.local)
        if rt.publisher is not None:
            with contextlib.suppress(MrosError, OSError):
                await rt.publisher.aclose()

    async def expire(self, item: Item, local: str) -> None:
        """``item`` went silent: stop publishing it here."""
        rt = self.link.received.get(local)
        if rt is not None and rt.item == item:
            del self.link.received[local]
            await self.drop(rt)
            self.link.touch()

    def _subscribe(self, rt: ReceivedTopic) -> None:
        link = self.link
        zenoh = link.zenoh
        local = rt.local
        key = rt.item.data_key

        def take(payload: Any, how: int) -> None:  # on Zenoh's thread
            if len(payload) > MAX_BODY_BYTES:  # refused before it is copied out of Zenoh
                link.oversized(local, len(payload))
            else:
                link.inbox_put(local, (payload.to_bytes(), how))

        def reply(r: Any) -> None:
            if r.ok is not None:
                take(r.ok.payload, CACHED)

        # On Zenoh's own thread (``indirect=False``): zenoh-python's default hands each sample to a Python thread
        # through a queue with no bound, where a peer's bodies piled up while the GIL was busy.
        rt.subscriber = link.session.declare_subscriber(
            key,
            zenoh.handlers.Callback(lambda sample: take(sample.payload, _how(sample)), indirect=False),
            allowed_origin=zenoh.Locality.REMOTE,
        )
        # The latched body, if the sender holds one (a late joiner's first message).
        link.session.get(
            key,
            zenoh.handlers.Callback(reply, indirect=False),
            timeout=QUERY_TIMEOUT,
            allowed_destination=zenoh.Locality.REMOTE,
        )

    def follow_subscribers(self) -> bool:
        """Subscribe in Zenoh to the topics a local node subscribes to, and only those; True if any changed."""
        changed = False
        for rt in self.link.received.values():
            wanted = rt.publisher is not None and rt.publisher.get_num_connections() > 0
            if wanted and rt.subscriber is None:
                self._subscribe(rt)
                changed = True
            elif not wanted and rt.subscriber is not None:
                self.link.undeclare(rt.subscriber)
                rt.subscriber = None
                changed = True
        return changed
