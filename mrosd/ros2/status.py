"""What ``mros ros2 status`` shows: the bridge's rows, with rates, bounded (pure).

Rates are counts differenced between two reads of the ROS 1 graph (about a second apart), so they cost
nothing per message. The document is bounded: at most ``MAX_ROWS`` rows per section (the rest counted), so
a bridge in mode "all" on a large graph still answers in one small service response.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

__all__ = ["MAX_ROWS", "RateMeter", "inbound_rows", "outbound_rows", "status_document"]

#: rows per section of the status document; the rest are counted in ``<section>_more``
MAX_ROWS = 200


class RateMeter:
    """Messages per second of named counters, from the two latest samples."""

    def __init__(self) -> None:
        self._marks: dict[str, tuple[float, int]] = {}
        self.rates: dict[str, float] = {}

    def sample(self, now: float, counts: dict[str, int]) -> None:
        """Take one sample of every counter; counters not in ``counts`` are forgotten."""
        for name in set(self._marks) - set(counts):
            del self._marks[name]
            self.rates.pop(name, None)
        for name, count in counts.items():
            mark = self._marks.get(name)
            if mark is not None and now > mark[0]:
                self.rates[name] = max(0.0, (count - mark[1]) / (now - mark[0]))
            self._marks[name] = (now, count)

    def rate(self, name: str) -> float:
        return round(self.rates.get(name, 0.0), 1)


def _bounded(doc: dict[str, Any], section: str, rows: list[dict[str, Any]]) -> None:
    doc[section] = rows[:MAX_ROWS]
    if len(rows) > MAX_ROWS:
        doc[section + "_more"] = len(rows) - MAX_ROWS


def status_document(
    *,
    zid: str,
    domain_id: int,
    mode: str,
    distro: str,
    router: bool,
    to_ros2: list[dict[str, Any]],
    from_ros2: list[dict[str, Any]],
    services: list[dict[str, Any]],
) -> dict[str, Any]:
    """The JSON document ``~status`` answers."""
    doc: dict[str, Any] = {"zid": zid, "domain_id": domain_id, "mode": mode, "distro": distro, "router": router}
    _bounded(doc, "to_ros2", to_ros2)
    _bounded(doc, "from_ros2", from_ros2)
    _bounded(doc, "services", services)
    return doc


def outbound_rows(topics: Iterable[Any], rates: RateMeter, dropped: Callable[[str], int]) -> list[dict[str, Any]]:
    """One row per ROS 1 topic shown to ROS 2 (the bridge's ``BridgedTopic`` s): names, key, counts, any problem."""
    return [
        {
            "topic": bt.topic,
            "ros2_type": bt.mapping.ros2_type if bt.mapping else "",
            "key": bt.key,
            "sent": bt.rmw.sent if bt.rmw else 0,
            "rate": rates.rate("out:" + bt.topic),
            "dropped": dropped(bt.key) if bt.key else 0,
            "latched": bt.latched,
            "problem": bt.problem,
        }
        for bt in topics
    ]


def inbound_rows(topics: Iterable[Any], rates: RateMeter, dropped: Callable[[str], int]) -> list[dict[str, Any]]:
    """One row per ROS 2 topic republished on ROS 1 (``mrosd.ros2.inbound`` 's topics); ``dropped`` counts the
    inbox's drops of a topic's ``in:`` name."""
    return [
        {
            "topic": rt.topic,
            "ros2_type": rt.ros2_type,
            "key": rt.key,
            "received": rt.received,
            "rate": rates.rate("in:" + rt.topic),
            "dropped": dropped("in:" + rt.topic) + rt.dropped,
            "bad": rt.bad,
            "latched": rt.latched,
            "subscribed": rt.subscriber is not None,
        }
        for rt in topics
    ]
