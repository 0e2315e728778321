"""tf2's BufferCore as plain data: per-frame time caches, interpolation, the tree walk and tf2's error texts.

No I/O here; ``mrosd.tf.buffer`` feeds it from /tf and /tf_static. The rules are tf2's (``time_cache.cpp``,
``buffer_core.cpp``, Debian's libtf2 0.7.6), restated: a frame's cache keeps ``cache_time`` seconds of
transforms behind its newest one; a lookup between two stored stamps interpolates the translation linearly
and the rotation by slerp on the shortest arc; time 0 means the latest time every frame on the path shares.
Times are integer nanoseconds throughout, as ros::Time compares them.
"""

from __future__ import annotations

import math
from bisect import bisect_left
from dataclasses import dataclass, field
from math import acos, sin, sqrt

from mrosd.errors import MrosError

#: tf2's default cache length (``BufferCore::DEFAULT_CACHE_TIME``).
DEFAULT_CACHE_TIME = 10.0
#: Frames a buffer holds; a peer inventing frame names cannot grow it further (tf2 has no bound).
MAX_FRAMES = 10_000
#: Entries one frame's cache holds whatever its time window (1 kHz for the default 10 s).
MAX_ENTRIES_PER_FRAME = 10_000
#: Entries of all frames together (about 180 bytes each: 45 MB). The two bounds above allow 10^8, which a
#: /tf publisher inventing frames and stamps fills at the rate the daemon decodes (+250 MiB in 15 s). Past
#: it, the frame being written keeps at most its fair share (this over the frames known), oldest out first:
#: 100 frames keep 2,500 entries each (250 Hz for 10 s), 10,000 frames 25 each.
MAX_TOTAL_ENTRIES = 250_000
#: tf2 ignores a transform whose rotation's squared norm is this far or further from 1
#: (``QUATERNION_NORMALIZATION_TOLERANCE``, TF_DENORMALIZED_QUATERNION)
QUATERNION_TOLERANCE = 10e-3
#: tf2's guard against loops in the tree (``MAX_GRAPH_DEPTH``).
MAX_GRAPH_DEPTH = 1000

#: translation (x, y, z) then rotation quaternion (x, y, z, w).
Pose = tuple[float, float, float, float, float, float, float]
IDENTITY: Pose = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)


class TransformError(MrosError):
    """Base of tf2's lookup errors (``tf2.TransformException``)."""


class FrameNotFoundError(TransformError):
    """A frame does not exist (tf2's LookupException)."""


class ConnectivityError(TransformError):
    """The two frames are in different trees."""


class ExtrapolationError(TransformError):
    """The time asked is outside the stored data."""


class InvalidArgumentError(TransformError):
    """A frame id is empty or starts with '/'."""


def format_time(ns: int) -> str:
    """ros::Time's text: ``secs.nsecs`` with nine digits."""
    sign = "-" if ns < 0 else ""
    secs, nsecs = divmod(abs(ns), 1_000_000_000)
    return f"{sign}{secs}.{nsecs:09d}"


# --- quaternion and transform algebra ------------------------------------------------------------


def compose(a: Pose, b: Pose) -> Pose:
    """``a * b``: first b, then a (both parent <- child)."""
    ax, ay, az, aqx, aqy, aqz, aqw = a
    bx, by, bz, bqx, bqy, bqz, bqw = b
    rx, ry, rz = rotate((aqx, aqy, aqz, aqw), (bx, by, bz))
    return (
        ax + rx,
        ay + ry,
        az + rz,
        aqw * bqx + aqx * bqw + aqy * bqz - aqz * bqy,
        aqw * bqy - aqx * bqz + aqy * bqw + aqz * bqx,
        aqw * bqz + aqx * bqy - aqy * bqx + aqz * bqw,
        aqw * bqw - aqx * bqx - aqy * bqy - aqz * bqz,
    )


def rotate(q: tuple[float, float, float, float], v: tuple[float, float, float]) -> tuple[float, float, float]:
    qx, qy, qz, qw = q
    vx, vy, vz = v
    # t = 2 q_vec x v ; v' = v + w t + q_vec x t
    tx = 2.0 * (qy * vz - qz * vy)
    ty = 2.0 * (qz * vx - qx * vz)
    tz = 2.0 * (qx * vy - qy * vx)
    return (
        vx + qw * tx + (qy * tz - qz * ty),
        vy + qw * ty + (qz * tx - qx * tz),
        vz + qw * tz + (qx * ty - qy * tx),
    )


def inverse(a: Pose) -> Pose:
    x, y, z, qx, qy, qz, qw = a
    ix, iy, iz = rotate((-qx, -qy, -qz, qw), (x, y, z))
    return (-ix, -iy, -iz, -qx, -qy, -qz, qw)


def slerp(
    q0: tuple[float, float, float, float], q1: tuple[float, float, float, float], t: float
) -> tuple[float, float, float, float]:
    """tf2's ``Quaternion::slerp``: the shortest arc, no renormalisation."""
    dot = q0[0] * q1[0] + q0[1] * q1[1] + q0[2] * q1[2] + q0[3] * q1[3]
    # plain left-to-right sums, as tf2's length2() and the walk's inlined copy: Python 3.12's sum() of floats
    # compensates its rounding, which would make the same lookup differ in its last bits between versions
    norm0 = q0[0] * q0[0] + q0[1] * q0[1] + q0[2] * q0[2] + q0[3] * q0[3]
    norm1 = q1[0] * q1[0] + q1[1] * q1[1] + q1[2] * q1[2] + q1[3] * q1[3]
    norms = math.sqrt(norm0 * norm1)
    theta = math.acos(max(-1.0, min(1.0, abs(dot) / norms)))  # half of angleShortestPath
    if theta == 0.0:
        return q0
    d = 1.0 / math.sin(theta)
    s0 = math.sin((1.0 - t) * theta)
    s1 = math.sin(t * theta)
    if dot < 0:
        s1 = -s1
    return (
        (q0[0] * s0 + q1[0] * s1) * d,
        (q0[1] * s0 + q1[1] * s1) * d,
        (q0[2] * s0 + q1[2] * s1) * d,
        (q0[3] * s0 + q1[3] * s1) * d,
    )


def interpolate(a: Pose, b: Pose, ratio: float) -> Pose:
    q = slerp(a[3:], b[3:], ratio)  # type: ignore[arg-type]
    return (
        a[0] + (b[0] - a[0]) * ratio,
        a[1] + (b[1] - a[1]) * ratio,
        a[2] + (b[2] - a[2]) * ratio,
        *q,
    )


# --- caches --------------------------------------------------------------------------------------


@dataclass(slots=True)
class FrameCache:
    """One child frame's transforms to its parent, oldest first (tf2 keeps newest first; same rules)."""

    static: bool = False
    stamps: list[int] = field(default_factory=list)
    parents: list[str] = field(default_factory=list)
    poses: list[Pose] = field(default_factory=list)
    authority: str = ""

    def insert(self, stamp: int, parent: str, pose: Pose, cache_ns: int) -> bool:
        """Store one transform; False when tf2 ignores it (older than the window, or a repeated stamp)."""
        if self.static:
            self.stamps, self.parents, self.poses = [stamp], [parent], [pose]
            return True
        stamps = self.stamps
        if stamps and stamps[-1] > stamp + cache_ns:
            return False  # TF_OLD_DATA
        i = bisect_left(stamps, stamp)
        if i < len(stamps) and stamps[i] == stamp:
            return False  # TF_REPEATED_DATA
        stamps.insert(i, stamp)
        self.parents.insert(i, parent)
        self.poses.insert(i, pose)
        latest = stamps[-1]
        cut = bisect_left(stamps, latest - cache_ns)  # keep stamp + cache >= latest
        cut = max(cut, len(stamps) - MAX_ENTRIES_PER_FRAME)
        if cut > 0:
            del stamps[:cut], self.parents[:cut], self.poses[:cut]
        return True

    def latest(self) -> tuple[int, str | None]:
        if not self.stamps:
            return 0, None
        if self.static:
            return 0, self.parents[0]
        return self.stamps[-1], self.parents[-1]

    def get(self, time: int) -> tuple[str, Pose] | str:
        """(parent, pose) at ``time``, or tf2's extrapolation text."""
        stamps = self.stamps
        if not stamps:
            return ""
        if self.static or time == 0:
            return self.parents[-1], self.poses[-1]
        if len(stamps) == 1:
            if stamps[0] == time:
                return self.parents[0], self.poses[0]
            return (
                f"Lookup would require extrapolation at time {format_time(time)}, but only time "
                f"{format_time(stamps[0])} is in the buffer"
            )
        earliest, latest = stamps[0], stamps[-1]
        if time > latest:
            return (
                f"Lookup would require extrapolation {format_time(time - latest)}s into the future.  Requested time "
                f"{format_time(time)} but the latest data is at time {format_time(latest)}"
            )
        if time < earliest:
            return (
                f"Lookup would require extrapolation {format_time(earliest - time)}s into the past.  Requested time "
                f"{format_time(time)} but the earliest data is at time {format_time(earliest)}"
            )
        i = bisect_left(stamps, time)
        if stamps[i] == time:
            return self.parents[i], self.poses[i]
        older, newer = i - 1, i
        if self.parents[older] != self.parents[newer]:
            return self.parents[older], self.poses[older]
        ratio = (time - stamps[older]) / (stamps[newer] - stamps[older])
        return self.parents[older], interpolate(self.poses[older], self.poses[newer], ratio)


@dataclass
class BufferCore:
    """Frames by child name, each with its cache; lookups as tf2's BufferCore does them."""

    cache_time: float = DEFAULT_CACHE_TIME
    frames: dict[str, FrameCache] = field(default_factory=dict)
    #: every frame id seen, as child or parent, in first-seen order (tf2's frame ids)
    known: dict[str, None] = field(default_factory=dict)
    rejected: int = 0
    #: entries of every frame's cache (``MAX_TOTAL_ENTRIES``)
    entries: int = 0

    def set_transform(self, parent: str, child: str, stamp: int, pose: Pose, *, authority: str, static: bool) -> bool:
        """Store one transform (frame ids with a leading '/' stripped, as tf2 does); False when ignored."""
        parent, child = parent.lstrip("/"), child.lstrip("/")
        if not parent or not child or parent == child or not all(math.isfinite(v) for v in pose):
            self.rejected += 1
            return False
        qx, qy, qz, qw = pose[3:]
        if abs(qx * qx + qy * qy + qz * qz + qw * qw - 1.0) >= QUATERNION_TOLERANCE:
            self.rejected += 1  # tf2's TF_DENORMALIZED_QUATERNION (a zero one would divide by zero in slerp)
            return False
        cache = self.frames.get(child)
        if cache is None:
            if len(self.known) >= MAX_FRAMES and (child not in self.known or parent not in self.known):
                self.rejected += 1
                return False
            cache = self.frames[child] = FrameCache(static=static)
        elif static and not cache.static:
            self.entries -= len(cache.stamps)
            cache.static, cache.stamps, cache.parents, cache.poses = True, [], [], []
        self.known.setdefault(child)
        self.known.setdefault(parent)
        cache.authority = authority
        before = len(cache.stamps)
        ok = cache.insert(stamp, parent, pose, int(self.cache_time * 1e9))
        self.entries += len(cache.stamps) - before
        if self.entries > MAX_TOTAL_ENTRIES:
            cut = len(cache.stamps) - max(1, MAX_TOTAL_ENTRIES // len(self.frames))
            if cut > 0:
                del cache.stamps[:cut], cache.parents[:cut], cache.poses[:cut]
                self.entries -= cut
        if not ok:
            self.rejected += 1
        return ok

    def _validate(self, function: str, arg: str, frame: str) -> None:
        if not frame:
            raise InvalidArgumentError(
                f"Invalid argument passed to {function} argument {arg} in tf2 frame_ids cannot be empty"
            )
        if frame.startswith("/"):
            raise InvalidArgumentError(
                f'Invalid argument "{frame}" passed to {function} argument {arg} in tf2 frame_ids cannot start '
                "with a '/' like: "
            )
        if frame not in self.known:
            raise FrameNotFoundError(f'"{frame}" passed to {function} argument {arg} does not exist. ')

    def _chain(self, frame: str, stop: str | None) -> list[str]:
        """``frame`` and its ancestors at their latest parents, up to (not past) ``stop`` or the root."""
        frames = self.frames
        chain = [frame]
        while frame != stop and len(chain) <= MAX_GRAPH_DEPTH:
            cache = frames.get(frame)
            if cache is None or not cache.parents:  # FrameCache.latest()'s parent is None
                break
            frame = cache.parents[-1]
            chain.append(frame)
        return chain

    def latest_common_time(self, target: str, source: str) -> int:
        frames = self.frames
        if source == target:
            cache = frames.get(source)
            return cache.latest()[0] if cache is not None else 0
        up_source = self._chain(source, target)
        up_target = self._chain(target, None)
        on_target = set(up_target)
        common = next((f for f in up_source if f in on_target), None)
        if common is None:
            raise ConnectivityError(self._unconnected(target, source))
        stamps = []
        for chain in (up_source, up_target):
            for frame in chain[: chain.index(common)]:
                cache = frames.get(frame)
                if cache is not None and cache.stamps and not cache.static:  # FrameCache.latest()'s stamp
                    stamp = cache.stamps[-1]
                    if stamp:
                        stamps.append(stamp)
        return min(stamps) if stamps else 0

    @staticmethod
    def _unconnected(target: str, source: str) -> str:
        return (
            f"Could not find a connection between '{target}' and '{source}' because they are not part of the same "
            "tree.Tf has two or more unconnected trees."
        )

    def _walk(self, frame: str, stop: str | None, time: int, source: str, target: str) -> tuple[str, Pose | None]:
        """From ``frame`` up to ``stop`` (or the root) at ``time``: the last frame reached and root <- frame.

        The pose is None when no step was taken (the identity). This is the lookups' hot loop: each step's
        interpolation (``FrameCache.get`` and ``interpolate``) and its composition (``compose``) are written
        out over local floats, in the same operations in the same order, so the answers are theirs (bit for
        bit; ``tests/unit/tf/test_lookup_walk.py``). Only a time strictly after a frame's oldest stamp and at
        most its newest takes that path; the rest (time 0, no entry, a single one, as a static frame always
        has, a time outside the stored span) goes through ``FrameCache.get`` and its error texts.
        """
        frames = self.frames
        x = y = z = qx = qy = qz = 0.0
        qw = 1.0
        depth = 1
        while frame != stop:
            cache = frames.get(frame)
            if cache is None:
                break
            stamps = cache.stamps
            i = bisect_left(stamps, time) if time else 0
            if not 0 < i < len(stamps):  # stamps[i - 1] < time <= stamps[i] or not
                got = cache.get(time)
                if isinstance(got, str):
                    if not got:
                        break
                    raise ExtrapolationError(
                        f"{got}, when looking up transform from frame [{source}] to frame [{target}]"
                    )
                parent, (sx, sy, sz, sqx, sqy, sqz, sqw) = got
            else:
                parents = cache.parents
                if stamps[i] == time:
                    parent = parents[i]
                    sx, sy, sz, sqx, sqy, sqz, sqw = cache.poses[i]
                elif parents[i - 1] != parents[i]:
                    parent = parents[i - 1]
                    sx, sy, sz, sqx, sqy, sqz, sqw = cache.poses[i - 1]
                else:
                    parent = parents[i - 1]
                    older = stamps[i - 1]
                    ratio = (time - older) / (stamps[i] - older)
                    poses = cache.poses
                    ax, ay, az, aqx, aqy, aqz, aqw = poses[i - 1]
                    bx, by, bz, bqx, bqy, bqz, bqw = poses[i]
                    sx = ax + (bx - ax) * ratio
                    sy = ay + (by - ay) * ratio
                    sz = az + (bz - az) * ratio
                    # slerp(a, b, ratio), as ``slerp`` computes it
                    dot = aqx * bqx + aqy * bqy + aqz * bqz + aqw * bqw
                    norm_a = aqx * aqx + aqy * aqy + aqz * aqz + aqw * aqw
                    norm_b = bqx * bqx + bqy * bqy + bqz * bqz + bqw * bqw
                    cos = (dot if dot >= 0.0 else -dot) / sqrt(norm_a * norm_b)  # abs(dot)
                    theta = acos(cos if cos < 1.0 else 1.0)
                    if theta == 0.0:
                        sqx, sqy, sqz, sqw = aqx, aqy, aqz, aqw
                    else:
                        d = 1.0 / sin(theta)
                        s0 = sin((1.0 - ratio) * theta)
                        s1 = sin(ratio * theta)
                        if dot < 0:
                            s1 = -s1
                        sqx = (aqx * s0 + bqx * s1) * d
                        sqy = (aqy * s0 + bqy * s1) * d
                        sqz = (aqz * s0 + bqz * s1) * d
                        sqw = (aqw * s0 + bqw * s1) * d
            if depth == 1:  # the first step: root <- frame is the step itself
                x, y, z, qx, qy, qz, qw = sx, sy, sz, sqx, sqy, sqz, sqw
            else:
                # compose(step, pose): the step's rotation applied to the pose's translation, as ``rotate``
                tx = 2.0 * (sqy * z - sqz * y)
                ty = 2.0 * (sqz * x - sqx * z)
                tz = 2.0 * (sqx * y - sqy * x)
                x = sx + (x + sqw * tx + (sqy * tz - sqz * ty))
                y = sy + (y + sqw * ty + (sqz * tx - sqx * tz))
                z = sz + (z + sqw * tz + (sqx * ty - sqy * tx))
                rx = sqw * qx + sqx * qw + sqy * qz - sqz * qy
                ry = sqw * qy - sqx * qz + sqy * qw + sqz * qx
                rz = sqw * qz + sqx * qy - sqy * qx + sqz * qw
                qw = sqw * qw - sqx * qx - sqy * qy - sqz * qz
                qx, qy, qz = rx, ry, rz
            frame = parent
            depth += 1
            if depth > MAX_GRAPH_DEPTH:
                raise ConnectivityError("The tf tree is invalid because it contains a loop.")
        if depth == 1:
            return frame, None
        return frame, (x, y, z, qx, qy, qz, qw)

    def lookup(self, target: str, source: str, time: int, function: str = "lookupTransform") -> tuple[Pose, int]:
        """target <- source at ``time`` (0: the latest common time); returns (pose, the time used).

        Raises:
            InvalidArgumentError, FrameNotFoundError, ConnectivityError, ExtrapolationError: as tf2, with its texts.
        """
        known = self.known
        if target not in known or source not in known:  # known ids are never empty nor start with '/'
            self._validate(function, "target_frame", target)
            self._validate(function, "source_frame", source)
        if time == 0:
            time = self.latest_common_time(target, source)
        if source == target:
            return IDENTITY, time
        top, to_source = self._walk(source, target, time, source, target)
        if top == target:
            return to_source or IDENTITY, time
        reached, to_target = self._walk(target, top, time, source, target)
        if reached != top:
            raise ConnectivityError(self._unconnected(target, source))
        if to_target is None:
            return to_source or IDENTITY, time
        if to_source is None:
            return inverse(to_target), time
        return compose(inverse(to_target), to_source), time

    def can_transform(self, target: str, source: str, time: int) -> bool:
        try:
            self.lookup(target, source, time, "canTransform")
        except TransformError:
            return False
        return True

    def frames_as_yaml(self) -> str:
        """tf2's ``allFramesAsYAML``: each child frame's parent, broadcaster, rate and time span."""
        out = []
        for name, cache in self.frames.items():
            if not cache.stamps:
                continue
            newest = 0 if cache.static else cache.stamps[-1]
            oldest = 0 if cache.static else cache.stamps[0]
            span = (newest - oldest) / 1e9
            rate = len(cache.stamps) / max(span, 0.0001)
            out.append(
                f"{name}: \n  parent: '{cache.parents[-1]}'\n  broadcaster: '{cache.authority}'\n"
                f"  rate: {rate:.3f}\n  most_recent_transform: {newest / 1e9:.3f}\n"
                f"  oldest_transform: {oldest / 1e9:.3f}\n  buffer_length: {span:.3f}\n"
            )
        return "".join(out)
