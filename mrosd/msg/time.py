"""ROS ``time`` and ``duration``: two int32/uint32 pairs with ROS arithmetic.

They are msgspec Structs (``gc=False``) so that generated decoders build them positionally at C speed;
the constructor therefore does not normalise (``Time(1, 1_500_000_000)`` keeps its fields as given, and
serializing it fails the uint32 range check). Every arithmetic result and every ``from_*`` constructor is
normalised to ``0 <= nsecs < 1e9``, as genpy's ``canon()`` does; call ``canon()`` to normalise by hand.
"""

from __future__ import annotations

import math
import time as _time
from typing import Any

import msgspec

from mrosd.backports import Self

NSEC_PER_SEC = 1_000_000_000


def _split_nsec(total: int) -> tuple[int, int]:
    secs, nsecs = divmod(total, NSEC_PER_SEC)
    return secs, nsecs


def _sec_to_nsec(value: float) -> int:
    if math.isnan(value) or math.isinf(value):
        raise ValueError(f"cannot represent {value!r} seconds as ROS time")
    secs = math.floor(value)
    return secs * NSEC_PER_SEC + round((value - secs) * NSEC_PER_SEC)


class _SecsNsecs(msgspec.Struct, gc=False, order=True):
    """What Time and Duration share: the two wire fields and the conversions between units."""

    secs: int = 0
    nsecs: int = 0

    @classmethod
    def from_sec(cls, value: float) -> Self:
        """``value`` seconds (nanosecond-rounded; negative values get negative secs)."""
        return cls(*_split_nsec(_sec_to_nsec(value)))

    @classmethod
    def from_nsec(cls, value: int) -> Self:
        """``value`` nanoseconds."""
        return cls(*_split_nsec(int(value)))

    def to_sec(self) -> float:
        """Seconds as a float."""
        return self.secs + self.nsecs / NSEC_PER_SEC

    def to_nsec(self) -> int:
        """Nanoseconds as an int."""
        return self.secs * NSEC_PER_SEC + self.nsecs

    def is_zero(self) -> bool:
        """True for zero (for Time, ROS's "unset")."""
        return self.secs == 0 and self.nsecs == 0

    def canon(self) -> Self:
        """Normalise in place so that ``0 <= nsecs < 1e9``; returns self."""
        self.secs, self.nsecs = _split_nsec(self.to_nsec())
        return self

    def __bool__(self) -> bool:
        return not self.is_zero()


class Time(_SecsNsecs):
    """A point in time: ``secs`` (uint32 on the wire) and ``nsecs`` since the epoch."""

    @classmethod
    def now(cls) -> Time:
        """The wall-clock time (ROS simulated time is the node's business, not this class's)."""
        return cls.from_nsec(_time.time_ns())

    def __add__(self, other: Any) -> Time:
        if isinstance(other, Duration):
            return Time.from_nsec(self.to_nsec() + other.to_nsec())
        return NotImplemented

    __radd__ = __add__

    def __sub__(self, other: Any) -> Any:
        if isinstance(other, Time):
            return Duration.from_nsec(self.to_nsec() - other.to_nsec())
        if isinstance(other, Duration):
            return Time.from_nsec(self.to_nsec() - other.to_nsec())
        return NotImplemented

    def __hash__(self) -> int:
        return hash(("Time", self.to_nsec()))


class Duration(_SecsNsecs):
    """A signed span of time: ``secs`` (int32 on the wire) and ``nsecs``."""

    def __add__(self, other: Any) -> Any:
        if isinstance(other, Duration):
            return Duration.from_nsec(self.to_nsec() + other.to_nsec())
        if isinstance(other, Time):
            return Time.from_nsec(self.to_nsec() + other.to_nsec())
        return NotImplemented

    __radd__ = __add__

    def __sub__(self, other: Any) -> Duration:
        if isinstance(other, Duration):
            return Duration.from_nsec(self.to_nsec() - other.to_nsec())
        return NotImplemented

    def __neg__(self) -> Duration:
        return Duration.from_nsec(-self.to_nsec())

    def __abs__(self) -> Duration:
        return Duration.from_nsec(abs(self.to_nsec()))

    def __mul__(self, factor: Any) -> Duration:
        if isinstance(factor, int):
            return Duration.from_nsec(self.to_nsec() * factor)
        if isinstance(factor, float):
            return Duration.from_nsec(round(self.to_nsec() * factor))
        return NotImplemented

    __rmul__ = __mul__

    def __truediv__(self, other: Any) -> Any:
        if isinstance(other, Duration):
            return self.to_nsec() / other.to_nsec()
        if isinstance(other, int | float):
            return Duration.from_nsec(round(self.to_nsec() / other))
        return NotImplemented

    def __floordiv__(self, other: Any) -> Any:
        if isinstance(other, Duration):
            return self.to_nsec() // other.to_nsec()
        if isinstance(other, int):
            return Duration.from_nsec(self.to_nsec() // other)
        return NotImplemented

    def __hash__(self) -> int:
        return hash(("Duration", self.to_nsec()))
