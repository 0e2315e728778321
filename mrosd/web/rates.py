"""``RateWindow``: a topic's message rate and bandwidth over the last few seconds, from running counts.

The hub counts every shared subscription's messages and bytes as they arrive (no decoding); the page's
topics table asks for rates, so the session samples those counts once a second and this turns the samples
into Hz and bytes/s over a sliding window. Pure data: the caller passes the time, tests need no clock.
"""

from __future__ import annotations

import collections

__all__ = ["RateWindow"]


class RateWindow:
    """Samples ``(t, messages, bytes)`` of one monotonically growing counter pair, kept for ``span`` seconds."""

    __slots__ = ("_samples", "span")

    def __init__(self, span: float = 5.0) -> None:
        if span <= 0:
            raise ValueError(f"span must be > 0, got {span}")
        self.span = span
        self._samples: collections.deque[tuple[float, int, int]] = collections.deque()

    def add(self, t: float, messages: int, nbytes: int) -> None:
        """One sample; a counter that went backwards (the subscription was reopened) restarts the window."""
        samples = self._samples
        if samples and (messages < samples[-1][1] or nbytes < samples[-1][2] or t < samples[-1][0]):
            samples.clear()
        samples.append((t, messages, nbytes))
        # keep one sample at or before t - span, so the window always covers the whole span once it can
        while len(samples) > 2 and samples[1][0] <= t - self.span:
            samples.popleft()

    def rate(self) -> tuple[float, float] | None:
        """``(messages/s, bytes/s)`` over the window, or None before two samples apart in time."""
        if len(self._samples) < 2:
            return None
        t0, m0, b0 = self._samples[0]
        t1, m1, b1 = self._samples[-1]
        if t1 <= t0:
            return None
        return (m1 - m0) / (t1 - t0), (b1 - b0) / (t1 - t0)
