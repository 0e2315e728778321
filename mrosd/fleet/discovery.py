"""What peers announce: which remote items cross, under which local names.

An announcement is parsed (``keys.parse_discovery_key``), remembered (``Presence``) and, when its local name
is one the configuration imports, handed to the receiving side. The local name is always the announcing
robot's prefix plus the remote name (``/robot1/odom``); an item announced under ``*`` (a plain bridge, or
anyone claiming to be one) gets one only from ``bridge_robot``, or with ``prefix = ""``, both explicit choices
of the configuration. So a peer can publish only into names the configuration imports (issue 31, case 3).
"""

from __future__ import annotations

import time

from mrosd.fleet.keys import FleetKeyError, Item, ItemKind, parse_discovery_key
from mrosd.fleet.link import FleetLink, ratelog
from mrosd.fleet.receiving import Receiver
from mrosd.fleet.services import Services


class Discovery:
    """Announcements in, received topics and services out."""

    def __init__(self, link: FleetLink, receiver: Receiver, services: Services) -> None:
        self.link = link
        self.receiver = receiver
        self.services = services

    def heard(self, keys: list[str]) -> None:
        """A batch of discovery keys from the inbox (on the loop)."""
        link = self.link
        now = time.monotonic()
        for key in dict.fromkeys(keys):
            try:
                item = parse_discovery_key(key)
            except FleetKeyError as exc:
                link.counters.bad_keys += 1
                ratelog.warning("badkey", "fleet: ignoring an announcement: %s", exc)
                continue
            if item.namespace == link.options.robot:
                continue
            link.presence.heard(item, now)
            if item not in link.presence:
                continue  # the table is full: not bridged, and not remembered either
            # Every announcement is checked, not only the first: an item refused while full gets in later.
            local = link.options.rename.local_name(item.namespace, item.topic)
            if local is None:
                continue
            if item.kind is ItemKind.PUBLISHER and local in link.options.receive_topics:
                if local not in link.received and local not in link.sent and self._room_for(item):
                    self.receiver.offer(item, local)
            elif (
                item.kind is ItemKind.SERVICE
                and local in link.options.receive_services
                and local not in link.received_services
                and local not in link.sent_services
                and self._room_for(item)
            ):
                self.services.offer(item, local)

    def _room_for(self, item: Item) -> bool:
        """True while fewer than ``max_received`` remote topics and services are published here."""
        link = self.link
        if len(link.received) + len(link.received_services) < link.options.max_received:
            return True
        link.counters.refused_items += 1
        ratelog.warning(
            "full",
            "fleet: %s from %s refused: max_received (%d) reached",
            item.topic,
            item.namespace,
            link.options.max_received,
        )
        return False

    async def expire(self) -> None:
        """Forget the items not heard for three announcement periods."""
        link = self.link
        for item in link.presence.expire(time.monotonic()):
            local = link.options.rename.local_name(item.namespace, item.topic)
            if local is None:
                continue
            if item.kind is ItemKind.PUBLISHER:
                await self.receiver.expire(item, local)
            elif item.kind is ItemKind.SERVICE:
                await self.services.expire(item, local)
