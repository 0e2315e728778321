"""Remote items heard in announcements, forgotten after silence: pure (the caller passes the clock).

The bridge puts each item's discovery key once a second (and, ALOHA-style, only one of several announcers of
one key keeps doing so); a listener that has not heard a key for three periods forgets it. This table is that
rule and nothing else, so the I/O shell cannot disagree with the bridge about when something is gone.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from mrosd.fleet.keys import FORGET_AFTER, Item

#: Items remembered at most (a hostile or broken peer announcing names without end costs a bounded table).
MAX_ITEMS = 10_000


@dataclass
class Presence:
    """``heard(item, now)`` on every announcement; ``expire(now)`` returns what went silent."""

    forget_after: float = FORGET_AFTER
    max_items: int = MAX_ITEMS
    last_heard: dict[Item, float] = field(default_factory=dict)
    #: Announcements refused because the table was full.
    refused: int = 0

    def heard(self, item: Item, now: float) -> bool:
        """Record an announcement; True when the item is new (the caller then bridges it)."""
        new = item not in self.last_heard
        if new and len(self.last_heard) >= self.max_items:
            self.refused += 1
            return False
        self.last_heard[item] = now
        return new

    def expire(self, now: float) -> list[Item]:
        """Forget and return every item not heard for ``forget_after`` seconds."""
        gone = [item for item, t in self.last_heard.items() if now - t >= self.forget_after]
        for item in gone:
            del self.last_heard[item]
        return gone

    def __contains__(self, item: object) -> bool:
        return item in self.last_heard

    def items(self) -> list[Item]:
        return list(self.last_heard)
