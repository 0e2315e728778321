"""The lookup's hot loop (``BufferCore._walk``, the interpolation and composition written out over floats) and
its latest common time give exactly what tf2's rules give step by step with the plain algebra (``FrameCache.get``
and ``latest``, ``compose``, ``inverse``): the same poses, stamps, error classes and texts, on a tree with every
kind of step."""

from __future__ import annotations

import math
import random

from mrosd.tf.core import (
    IDENTITY,
    MAX_GRAPH_DEPTH,
    BufferCore,
    ConnectivityError,
    ExtrapolationError,
    Pose,
    TransformError,
    compose,
    inverse,
)

S = 1_000_000_000


def latest_common_time(core: BufferCore, target: str, source: str) -> int:
    """tf2's getLatestCommonTime restated plainly, with ``FrameCache.latest``."""
    if source == target:
        return core.frames[source].latest()[0] if source in core.frames else 0

    def chain(frame: str, stop: str | None) -> list[str]:
        frames = [frame]
        while frame != stop and len(frames) <= MAX_GRAPH_DEPTH:
            parent = core.frames[frame].latest()[1] if frame in core.frames else None
            if parent is None:
                break
            frame = parent
            frames.append(frame)
        return frames

    up_source, up_target = chain(source, target), chain(target, None)
    common = next((f for f in up_source if f in up_target), None)
    if common is None:
        raise ConnectivityError(core._unconnected(target, source))
    stamps = [
        core.frames[f].latest()[0] for c in (up_source, up_target) for f in c[: c.index(common)] if f in core.frames
    ]
    return min((s for s in stamps if s), default=0)


def reference(core: BufferCore, target: str, source: str, time: int) -> tuple[Pose, int]:
    """tf2's lookup restated plainly: each frame's cache asked in turn, the steps composed one by one."""
    core._validate("lookupTransform", "target_frame", target)
    core._validate("lookupTransform", "source_frame", source)
    if time == 0:
        time = latest_common_time(core, target, source)
    if source == target:
        return IDENTITY, time

    def walk(frame: str, stop: str | None) -> tuple[list[str], Pose]:
        frames, pose = [frame], IDENTITY
        while frame != stop:
            cache = core.frames.get(frame)
            if cache is None:
                break
            got = cache.get(time)
            if isinstance(got, str):
                if not got:
                    break
                raise ExtrapolationError(f"{got}, when looking up transform from frame [{source}] to frame [{target}]")
            frame, step = got[0], got[1]
            pose = compose(step, pose)
            frames.append(frame)
            if len(frames) > MAX_GRAPH_DEPTH:
                raise ConnectivityError("The tf tree is invalid because it contains a loop.")
        return frames, pose

    up_source, to_source = walk(source, target)
    if up_source[-1] == target:
        return to_source, time
    up_target, to_target = walk(target, up_source[-1])
    if up_target[-1] != up_source[-1]:
        raise ConnectivityError(core._unconnected(target, source))
    return compose(inverse(to_target), to_source), time


def random_pose(rng: random.Random) -> Pose:
    q = [rng.gauss(0, 1) for _ in range(4)]
    n = math.sqrt(sum(c * c for c in q))
    return (rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-1, 1), *(c / n for c in q))  # type: ignore[return-value]


def tree() -> BufferCore:
    rng = random.Random(7)
    core = BufferCore()
    add = core.set_transform
    add("world", "map", 0, random_pose(rng), authority="s", static=True)  # static
    for i in range(21):  # a chain of moving frames at different rates
        add("map", "base", 100 * S + i * S // 10, random_pose(rng), authority="m", static=False)
        add("base", "arm", 100 * S + S // 20 + i * S // 10, random_pose(rng), authority="m", static=False)
        add("arm", "hand", 100 * S + i * S // 5, random_pose(rng), authority="m", static=False)
    q = random_pose(rng)  # a quaternion and its negation (the short arc), and twice the same one (theta 0)
    add("map", "flip", 100 * S, q, authority="m", static=False)
    add("map", "flip", 101 * S, (*q[:3], *(-c for c in q[3:])), authority="m", static=False)  # type: ignore[arg-type]
    add("map", "still", 100 * S, q, authority="m", static=False)
    add("map", "still", 102 * S, q, authority="m", static=False)
    add("base", "one", 100 * S + S // 2, random_pose(rng), authority="m", static=False)  # a single entry
    add("map", "hop", 100 * S, random_pose(rng), authority="m", static=False)  # changes parent: the older one holds
    add("base", "hop", 101 * S, random_pose(rng), authority="m", static=False)
    add("other", "island", 100 * S, random_pose(rng), authority="m", static=False)  # a second tree
    add("base", "conv", 100 * S, random_pose(rng), authority="m", static=False)  # moving, then static
    add("base", "conv", 101 * S, random_pose(rng), authority="m", static=False)
    add("base", "conv", 0, random_pose(rng), authority="s", static=True)
    add("base", "conv", 102 * S, random_pose(rng), authority="m", static=False)  # replaces: a static has one
    return core


def outcome(call: object) -> object:
    try:
        return call()  # type: ignore[operator]
    except TransformError as exc:
        return type(exc).__name__, str(exc)


def test_the_walk_answers_as_the_plain_algebra_does() -> None:
    core = tree()
    rng = random.Random(11)
    frames = [*core.known, "nope", "", "/map"]
    times = [0, 100 * S, 100 * S + S // 2, 101 * S, 102 * S, 99 * S, 103 * S]
    checked = errors = 0
    for _ in range(3000):
        target, source = rng.choice(frames), rng.choice(frames)
        when = rng.choice(times) if rng.random() < 0.3 else 100 * S + rng.randrange(2 * S + S // 5)
        ours = outcome(lambda: core.lookup(target, source, when))  # noqa: B023
        expected = outcome(lambda: reference(core, target, source, when))  # noqa: B023
        assert ours == expected, (target, source, when)  # == on floats: exact (0.0 and -0.0 are equal)
        checked += 1
        errors += isinstance(ours, tuple) and isinstance(ours[0], str)
    assert 300 < errors < checked - 300  # both answers and errors exercised
