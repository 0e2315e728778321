"""tf2's cache rules without a network: the time window, repeated and old data, bounds, slerp's short arc."""

from __future__ import annotations

import math

import pytest

from mrosd.tf.core import MAX_ENTRIES_PER_FRAME, BufferCore, FrameCache, FrameNotFoundError, slerp

S = 1_000_000_000
POSE = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)


def test_a_frame_keeps_ten_seconds_behind_its_newest_transform() -> None:
    core = BufferCore()
    for i in range(100 * 60):  # 100 Hz for 60 s
        core.set_transform("map", "base", i * S // 100, POSE, authority="a", static=False)
    cache = core.frames["base"]
    assert cache.stamps[-1] - cache.stamps[0] == 10 * S
    assert len(cache.stamps) == 1001


def test_old_and_repeated_data_is_ignored_as_tf2_ignores_it() -> None:
    cache = FrameCache()
    assert cache.insert(20 * S, "map", POSE, 10 * S)
    assert not cache.insert(20 * S, "map", POSE, 10 * S)  # TF_REPEATED_DATA
    assert not cache.insert(9 * S, "map", POSE, 10 * S)  # TF_OLD_DATA
    assert cache.insert(15 * S, "map", POSE, 10 * S)  # late but inside the window: kept, in order
    assert cache.stamps == [15 * S, 20 * S]


def test_entries_per_frame_are_bounded_whatever_the_rate() -> None:
    cache = FrameCache()
    for i in range(MAX_ENTRIES_PER_FRAME + 50):
        cache.insert(i, "map", POSE, 10 * S)  # 1 ns apart: all inside the window
    assert len(cache.stamps) == MAX_ENTRIES_PER_FRAME


def test_self_transforms_empty_ids_and_nan_are_rejected() -> None:
    core = BufferCore()
    assert not core.set_transform("a", "a", 1, POSE, authority="x", static=False)
    assert not core.set_transform("", "c", 1, POSE, authority="x", static=False)
    assert not core.set_transform("a", "b", 1, (math.nan, *POSE[1:]), authority="x", static=False)
    assert core.rejected == 3 and not core.frames


def test_slerp_takes_the_short_arc_between_a_quaternion_and_its_negation() -> None:
    q = (0.0, 0.0, math.sin(0.25), math.cos(0.25))
    neg = tuple(-c for c in q)
    mid = slerp(q, neg, 0.5)  # type: ignore[arg-type]
    assert max(abs(a - b) for a, b in zip(mid, q, strict=True)) < 1e-12


def test_a_denormalized_quaternion_is_ignored_as_tf2_ignores_it() -> None:
    """tf2 (TF_DENORMALIZED_QUATERNION) drops a transform whose |q|^2 is 0.01 or more away from 1: a broadcaster
    sending a zero quaternion must not make a lookup across it divide by zero (slerp divides by the norms)."""
    core = BufferCore()
    s = 1_000_000_000
    assert core.set_transform("world", "base", s, (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0), authority="a", static=False)
    assert core.set_transform("world", "base", 2 * s, (1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0), authority="a", static=False)
    for stamp in (s, 2 * s):  # a hostile broadcaster's frame: zero rotation at both stamps
        assert not core.set_transform("base", "evil", stamp, (0.0,) * 7, authority="evil", static=False)
    # tf2's own bounds: 1.004^2 = 1.008 is kept, 1.006^2 = 1.012 is not
    assert core.set_transform("base", "near", s, (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.004), authority="a", static=False)
    assert not core.set_transform("base", "far", s, (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.006), authority="a", static=False)
    assert core.rejected == 3
    with pytest.raises(FrameNotFoundError):
        core.lookup("world", "evil", s + s // 2)
    pose, _ = core.lookup("world", "base", s + s // 2)
    assert pose[0] == pytest.approx(0.5)
