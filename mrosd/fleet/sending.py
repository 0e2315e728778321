"""Local topics offered to the fleet (``send_topics``).

A local topic in ``send_topics`` is subscribed raw; once its type and md5 are known, a Zenoh publisher on the
bridge's data key is declared and the topic is announced (``pub``) every second. Bodies go to Zenoh only while
a remote subscriber matches (Zenoh's matching status): a topic nobody remote asked for costs no bandwidth. A
latched topic's last body also answers queries on its data key, so a late joiner gets it.
"""

from __future__ import annotations

import contextlib
import time
from typing import Any

from mrosd.errors import MrosError
from mrosd.fleet.keys import LATCHED_ATTACHMENT, ItemKind, data_key, discovery_key
from mrosd.fleet.link import FleetLink, SentTopic, ratelog
from mrosd.fleet.raw import FleetTypeError, message_class
from mrosd.tcpros.subscriber import AnyMsg, RawMessage


class Sender:
    """The sent topics of one ``FleetLink``."""

    def __init__(self, link: FleetLink) -> None:
        self.link = link

    async def reconcile(self, pubs: Any, types: dict[str, str]) -> None:
        """Offer the local topics in ``send_topics`` that have a publisher other than us; forget the rest."""
        link = self.link
        own = link.node.name
        want = {
            str(topic)
            for topic, nodes in pubs
            if topic in link.options.send_topics and topic not in link.received and any(n != own for n in nodes)
        }
        for topic in want - set(link.sent):
            await self._add(topic, types.get(topic, ""))
        for topic in set(link.sent) - want:
            await self.drop(link.sent.pop(topic))

    async def _add(self, topic: str, msg_type: str) -> None:
        link = self.link
        st = SentTopic(topic, link.options.limit_for(topic))
        link.sent[topic] = st
        try:
            st.subscriber = await link.node.subscribe(
                topic, AnyMsg, callback=lambda msg: self._local_message(st, msg), queue_size=link.options.queue_size
            )
        except MrosError as exc:
            ratelog.warning(f"sub {topic}", "fleet: cannot subscribe to %s: %s", topic, exc)
            link.sent.pop(topic, None)
            return
        # A known type is announced at once (a topic that publishes rarely is seen before its first message);
        # an unknown one when its first message tells the md5.
        if msg_type and msg_type != "*":
            with contextlib.suppress(FleetTypeError):
                cls = await message_class(msg_type)
                if st.publisher is None and link.sent.get(topic) is st:
                    self._declare(st, msg_type, str(cls._md5sum))

    def _local_message(self, st: SentTopic, msg: RawMessage) -> None:
        link = self.link
        msg_type, md5sum = msg.header.type or "", msg.header.md5sum or ""
        told = bool(msg_type) and md5sum not in ("", "*")
        if st.publisher is not None and told and (msg_type, md5sum) != (st.msg_type, st.md5sum):
            self._undeclare(st)  # the publisher's definition differs from ours: its own md5 is the key
        if st.publisher is None:
            if not told:
                return  # a publisher that does not say its type and md5 cannot be announced
            self._declare(st, msg_type, md5sum)
            if st.publisher is None:
                return
        body = bytes(msg.data)
        if msg.header.latching == "1":
            st.latched = body
            if st.latch_queryable is None:
                self._declare_latch_queryable(st)
        if not st.matched or link.outbox is None:
            return
        now = time.monotonic()
        if st.limit is not None and not st.limit.admit(now, len(body)):
            return
        st.meter.tick(now)
        st.sent += 1
        st.bytes_sent += len(body)
        link.outbox.put(st.key, st.publisher, body, LATCHED_ATTACHMENT if st.latched is not None else None)

    def _declare(self, st: SentTopic, msg_type: str, md5sum: str) -> None:
        link = self.link
        zenoh = link.zenoh
        st.msg_type, st.md5sum = msg_type, md5sum
        try:
            st.key = data_key(msg_type, md5sum, link.options.robot, st.topic)
        except ValueError as exc:
            ratelog.warning(f"key {st.topic}", "fleet: cannot send %s: %s", st.topic, exc)
            return
        st.publisher = link.session.declare_publisher(
            st.key,
            congestion_control=zenoh.CongestionControl.BLOCK,
            reliability=zenoh.Reliability.RELIABLE,
            allowed_destination=zenoh.Locality.REMOTE,
        )

        def matching(status: Any) -> None:
            st.matched = bool(status.matching)  # a plain store: read by the loop, written by Zenoh's thread

        st.matching = st.publisher.declare_matching_listener(matching)
        st.matched = bool(st.publisher.matching_status.matching)
        st.announced = discovery_key(ItemKind.PUBLISHER, msg_type, md5sum, link.options.robot, st.topic)
        link.announce()

    def _declare_latch_queryable(self, st: SentTopic) -> None:
        link = self.link
        key = st.key

        def answer(query: Any) -> None:
            # On Zenoh's thread: reads one reference, the loop replaces it whole.
            with query:
                body = st.latched
                if body is not None:
                    query.reply(key, body)

        st.latch_queryable = link.session.declare_queryable(key, answer, allowed_origin=link.zenoh.Locality.REMOTE)

    def _undeclare(self, st: SentTopic) -> None:
        link = self.link
        for entity in (st.latch_queryable, st.matching, st.publisher):
            link.undeclare(entity)
        st.publisher = st.latch_queryable = st.matching = None
        st.matched = False
        st.announced = ""
        if link.outbox is not None and st.key:
            link.outbox.forget(st.key)

    async def drop(self, st: SentTopic) -> None:
        self._undeclare(st)
        if st.subscriber is not None:
            with contextlib.suppress(MrosError, OSError):
                await st.subscriber.aclose()
