"""Rate-limited logging for errors a peer can trigger at will.

A client that makes the daemon fail the same way ten thousand times a second (a refused accept, a malformed
frame) must not turn the journal into the attack's amplifier. ``RateLimitedLog`` lets the first
``burst`` records of a kind through per ``period`` seconds, counts the rest, and reports the count with the
next record that passes ("... (1234 similar suppressed)").
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any


class RateLimitedLog:
    """Per-key token bucket in front of a ``logging.Logger``.

    Args:
        logger: where records go.
        period: seconds after which a key's budget is full again.
        burst: records of one key let through per period.
        clock: monotonic clock (injectable for tests).
    """

    def __init__(
        self,
        logger: logging.Logger,
        period: float = 10.0,
        burst: int = 5,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.logger = logger
        self.period = period
        self.burst = burst
        self._clock = clock
        # key -> [window start, records let through in window, records suppressed since last report]
        self._state: dict[str, list[float]] = {}

    def log(self, level: int, key: str, msg: str, *args: Any) -> bool:
        """Log ``msg % args`` at ``level`` unless ``key`` is over budget; return whether it was logged."""
        if not self.logger.isEnabledFor(level):
            return False
        now = self._clock()
        state = self._state.get(key)
        if state is None:
            if len(self._state) >= 1024:  # keys are ours, but never let the table itself grow without bound
                self._state.clear()
            state = self._state[key] = [now, 0.0, 0.0]
        if now - state[0] >= self.period:
            state[0], state[1] = now, 0.0
        if state[1] >= self.burst:
            state[2] += 1
            return False
        state[1] += 1
        suppressed = int(state[2])
        state[2] = 0.0
        if suppressed:
            self.logger.log(level, msg + " (%d similar suppressed)", *args, suppressed)
        else:
            self.logger.log(level, msg, *args)
        return True

    def warning(self, key: str, msg: str, *args: Any) -> bool:
        return self.log(logging.WARNING, key, msg, *args)

    def error(self, key: str, msg: str, *args: Any) -> bool:
        return self.log(logging.ERROR, key, msg, *args)
