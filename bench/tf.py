"""TF: lookups per second of mrosd's ``BufferCore`` against Debian's ``tf2_ros.Buffer`` (C++ tf2 underneath,
under /usr/bin/python3 in a subprocess), in the same run, on the same tree and times; then the buffer's memory
with 200 frames at 100 Hz for 60 s of stamps. ``python -m bench tf [--lookups N] [--seconds S] [--repeat R]``.

The tree is a chain of 10 frames (``world -> f1 -> ... -> f10``), each moving at 100 Hz over 5 s of stamps;
each lookup asks ``world <- f10`` (or the reverse, every other one) at a time between two stamps, so every
step interpolates. Both sides time only the lookups, the best of ``--repeat`` passes (5) over the same
queries, as timeit does: on a shared machine one pass of either side can be slowed 2-3x by other load, which
swung the ratio between runs more than the code did. The first 200 answers are compared (1e-9).

Memory: the stamps are fed as fast as they can be (60 s of 100 Hz stamps, 1.2 million transforms), not in
wall time; the interpreter's allocated objects (``sys.getallocatedblocks``) and the process's RSS are read
every 5 s of stamps (tracemalloc would triple the feeding time). tf2's 10 s window
(``cache_time``) keeps each frame at 1 001 entries, so both must plateau once 10 s are stored.
"""

from __future__ import annotations

import json
import math
import random
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from mrosd.tf.core import BufferCore, Pose

ROS_PYTHON = "/usr/bin/python3"
S = 1_000_000_000
CHAIN = 10
RATE = 100
TREE_SECONDS = 5

ORACLE = r"""
import json, sys, time
import rospy, tf2_ros
from geometry_msgs.msg import TransformStamped
spec = json.load(sys.stdin)
buf = tf2_ros.Buffer(cache_time=rospy.Duration(10), debug=False)
for parent, child, stamp, pose in spec["transforms"]:
    m = TransformStamped()
    m.header.frame_id, m.child_frame_id = parent, child
    m.header.stamp = rospy.Time(0, stamp)
    t, r = m.transform.translation, m.transform.rotation
    t.x, t.y, t.z, r.x, r.y, r.z, r.w = pose
    buf.set_transform(m, "bench")
queries = [(target, source, rospy.Time(0, ns)) for target, source, ns in spec["queries"]]
lookup = buf.lookup_transform
elapsed = float("inf")
for _ in range(spec["repeat"]):
    start = time.perf_counter()
    for target, source, when in queries:
        lookup(target, source, when)
    elapsed = min(elapsed, time.perf_counter() - start)
first = []
for target, source, when in queries[:200]:
    res = lookup(target, source, when)
    t, r = res.transform.translation, res.transform.rotation
    first.append([t.x, t.y, t.z, r.x, r.y, r.z, r.w])
json.dump({"elapsed": elapsed, "first": first}, sys.stdout)
"""


def pose_at(rng: random.Random) -> Pose:
    q = [rng.gauss(0, 1) for _ in range(4)]
    n = math.sqrt(sum(c * c for c in q))
    return (rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-1, 1), *(c / n for c in q))  # type: ignore[return-value]


def tree_and_queries(lookups: int) -> dict[str, Any]:
    rng = random.Random(34)
    transforms = []
    for k in range(1, CHAIN + 1):
        parent = "world" if k == 1 else f"f{k - 1}"
        for i in range(TREE_SECONDS * RATE + 1):
            transforms.append([parent, f"f{k}", 100 * S + i * S // RATE, list(pose_at(rng))])
    queries = []
    for i in range(lookups):
        step = rng.randrange(TREE_SECONDS * RATE)
        when = 100 * S + step * S // RATE + rng.randrange(1, S // RATE)  # strictly between two stamps
        queries.append(["world", f"f{CHAIN}", when] if i % 2 == 0 else [f"f{CHAIN}", "world", when])
    return {"transforms": transforms, "queries": queries}


def bench_lookups(lookups: int, repeat: int) -> None:
    spec = tree_and_queries(lookups)
    spec["repeat"] = repeat
    core = BufferCore()
    for parent, child, stamp, pose in spec["transforms"]:
        core.set_transform(parent, child, stamp, tuple(pose), authority="bench", static=False)  # type: ignore[arg-type]
    queries = [tuple(q) for q in spec["queries"]]
    lookup = core.lookup
    elapsed = math.inf
    for _ in range(repeat):
        start = time.perf_counter()
        for target, source, when in queries:
            lookup(target, source, when)
        elapsed = min(elapsed, time.perf_counter() - start)
    ours = len(queries) / elapsed
    print(
        f"chain of {CHAIN} frames at {RATE} Hz, {len(queries)} lookups world <-> f{CHAIN} at interpolated times "
        f"(the best of {repeat} passes each)"
    )
    print(f"  mrosd BufferCore (CPython {sys.version.split()[0]}): {ours:,.0f} lookups/s")
    try:
        proc = subprocess.run(
            [ROS_PYTHON, "-c", ORACLE], input=json.dumps(spec), capture_output=True, text=True, timeout=120, check=True
        )
    except (OSError, subprocess.CalledProcessError, subprocess.TimeoutExpired) as exc:
        print(f"  tf2_ros.Buffer: not measured ({type(exc).__name__}: python3-tf2-ros under {ROS_PYTHON}?)")
        return
    result = json.loads(proc.stdout)
    theirs = len(queries) / result["elapsed"]
    worst = 0.0
    for (target, source, when), expected in zip(queries, result["first"], strict=False):
        got = lookup(target, source, when)[0]  # type: ignore[arg-type]
        worst = max(worst, *(abs(a - b) for a, b in zip(got, expected, strict=True)))
    print(f"  tf2_ros.Buffer (Debian, C++ tf2 underneath): {theirs:,.0f} lookups/s")
    print(f"  ratio mrosd / tf2_ros: {ours / theirs:.2f}; first 200 answers agree within {worst:.1e}")


def rss_mib() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def bench_memory(frames: int, seconds: int) -> None:
    print(f"memory: {frames} frames at {RATE} Hz, {seconds} s of stamps fed as fast as possible (10 s window)")
    core = BufferCore()
    names = [(f"p{i % 10}" if i >= 10 else "world", f"p{i}") for i in range(frames)]
    names[0] = ("world", "p0")
    base_blocks = sys.getallocatedblocks()
    base_rss = rss_mib()
    start = time.perf_counter()
    rows = []
    step = S // RATE
    for tick in range(seconds * RATE):
        stamp = tick * step
        for i, (parent, child) in enumerate(names):
            x = tick * 1e-3 + i  # a pose of its own per transform, as a decoded message gives one
            pose: Pose = (x, x + 0.5, 0.25 * x, 0.0, 0.0, math.sin(x), math.cos(x))
            core.set_transform(parent, child, stamp, pose, authority="bench", static=False)
        if (tick + 1) % (5 * RATE) == 0:
            rows.append(((tick + 1) // RATE, sys.getallocatedblocks() - base_blocks, rss_mib() - base_rss))
    elapsed = time.perf_counter() - start
    entries = sum(len(c.stamps) for c in core.frames.values())
    print("  stamps (s)  Python objects (+)  RSS growth (MiB)")
    for secs, blocks, rss in rows:
        print(f"  {secs:10d}  {blocks:18,d}  {rss:16.1f}")
    if len(rows) > 2:
        full = rows[1]  # 10 s of stamps: the window is full
        print(
            f"  {frames * seconds * RATE:,} transforms in {elapsed:.1f} s; {entries:,} entries held "
            f"({entries // frames} per frame), {full[2] * 2**20 / entries:.0f} bytes of RSS each; from 10 s to "
            f"{seconds} s of stamps: objects {rows[-1][1] - full[1]:+,d}, RSS {rows[-1][2] - full[2]:+.1f} MiB"
        )


def main(argv: list[str]) -> int:
    lookups, seconds, repeat = 20_000, 60, 5
    args = list(argv)
    while args:
        opt = args.pop(0)
        if opt == "--lookups":
            lookups = int(args.pop(0))
        elif opt == "--seconds":
            seconds = int(args.pop(0))
        elif opt == "--repeat":
            repeat = max(1, int(args.pop(0)))
        else:
            print(f"unknown option {opt}; use --lookups N --seconds S --repeat R", file=sys.stderr)
            return 2
    bench_lookups(lookups, repeat)
    bench_memory(200, seconds)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
