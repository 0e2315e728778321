"""rostopic's hz, bw and delay statistics over bounded windows (pure: the caller passes the times)."""

from __future__ import annotations

import math
from collections import deque

__all__ = ["BandwidthStats", "DelayStats", "RateStats"]


class RateStats:
    """rostopic hz's statistics over the inter-arrival times of a bounded window."""

    def __init__(self, window: int) -> None:
        self.deltas: deque[float] = deque(maxlen=max(window - 1, 1))
        self.last: float | None = None
        self.last_printed: float | None = None

    def on_message(self, now: float) -> None:
        """Record one arrival at wall time ``now``."""
        if self.last is not None and now >= self.last:
            self.deltas.append(now - self.last)
        elif self.last is not None:
            self.deltas.clear()
        self.last = now

    def report(self) -> str:
        """The two lines rostopic hz prints each second, or ``no new messages``."""
        if not self.deltas or self.last == self.last_printed:
            return "no new messages"
        self.last_printed = self.last
        n = len(self.deltas)
        mean = sum(self.deltas) / n
        rate = 1.0 / mean if mean > 0 else 0.0
        std = math.sqrt(sum((d - mean) ** 2 for d in self.deltas) / n)
        return (
            f"average rate: {rate:.3f}\n\tmin: {min(self.deltas):.3f}s max: {max(self.deltas):.3f}s "
            f"std dev: {std:.5f}s window: {n + 1}"
        )


class BandwidthStats:
    """rostopic bw's statistics over the sizes of the last messages."""

    def __init__(self, window: int) -> None:
        self.times: deque[float] = deque(maxlen=window)
        self.sizes: deque[int] = deque(maxlen=window)

    def on_message(self, now: float, size: int) -> None:
        """Record one message of ``size`` body bytes."""
        self.times.append(now)
        self.sizes.append(size)

    def report(self, now: float) -> str | None:
        """rostopic bw's two lines, or None until two messages arrived."""
        if len(self.times) < 2:
            return None
        n = len(self.times)
        total = sum(self.sizes)
        per_s = total / max(now - self.times[0], 1e-9)
        values = [per_s, total / n, min(self.sizes), max(self.sizes)]
        if per_s < 1000:
            bw, mean, low, high = [f"{v:.2f}B" for v in values]
        elif per_s < 1000000:
            bw, mean, low, high = [f"{v / 1000:.2f}KB" for v in values]
        else:
            bw, mean, low, high = [f"{v / 1000000:.2f}MB" for v in values]
        return f"average: {bw}/s\n\tmean: {mean} min: {low} max: {high} window: {n}"


class DelayStats:
    """rostopic delay's statistics: now minus ``header.stamp``, over the last messages.

    As rostopic, the first message only starts the clock (it is not counted), nothing is printed before a
    second one, and ``no new messages`` is printed when none arrived since the last report.
    """

    def __init__(self, window: int) -> None:
        self.delays: deque[float] = deque(maxlen=max(window - 1, 1))
        self.started: float | None = None
        self.last: float | None = None
        self.last_printed: float | None = None

    def on_message(self, now: float, stamp: float) -> None:
        """Record one message stamped ``stamp`` (seconds) received at ``now``."""
        if self.started is None or self.started > now:
            self.started = now
            self.delays.clear()
        else:
            self.delays.append(now - stamp)
        self.last = now

    def report(self) -> str | None:
        """rostopic delay's two lines, ``no new messages``, or None while nothing was measured."""
        if not self.delays:
            return None
        if self.last == self.last_printed:
            return "no new messages"
        self.last_printed = self.last
        n = len(self.delays)
        mean = sum(self.delays) / n
        std = math.sqrt(sum((d - mean) ** 2 for d in self.delays) / n)
        return (
            f"average delay: {mean:.3f}\n\tmin: {min(self.delays):.3f}s max: {max(self.delays):.3f}s "
            f"std dev: {std:.5f}s window: {n + 1}"
        )
