"""mrosd.tf against Debian's tf2_ros: the same transforms give the same lookups (1e-9) and the same errors;
``mros tf echo`` and examples/tf_listener.py print what a tf2_ros broadcaster sends (1e-6); tf2_ros reads what
mrosd's broadcasters send."""

from __future__ import annotations

import asyncio
import json
import math
import random
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

import mrosd
from mrosd.msg import Time
from mrosd.tf import BufferCore, StaticTransformBroadcaster, TransformBroadcaster, TransformError, transform_stamped
from mrosd.tf.core import Pose, compose
from tests.interop.cli.cliutil import mros_env
from tests.rosenv import PROJECT_ROOT, ROS_PYTHON, Processes, iter_lines_until, needs_ros, ros_env

DATA = Path(__file__).resolve().parents[2] / "data" / "tf"
S = 1_000_000_000


def has_tf2_ros() -> bool:
    probe = subprocess.run([ROS_PYTHON, "-c", "import tf2_ros"], capture_output=True, timeout=60, check=False)
    return probe.returncode == 0


pytestmark = [needs_ros, pytest.mark.skipif(not has_tf2_ros(), reason="python3-tf2-ros is not installed")]

#: tf2_ros's exception class -> ours
ERRORS = {
    "LookupException": "FrameNotFoundError",
    "ConnectivityException": "ConnectivityError",
    "ExtrapolationException": "ExtrapolationError",
    "InvalidArgumentException": "InvalidArgumentError",
}


def random_pose(rng: random.Random) -> Pose:
    q = [rng.gauss(0, 1) for _ in range(4)]
    n = math.sqrt(sum(c * c for c in q))
    return (rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-1, 1), *(c / n for c in q))  # type: ignore[return-value]


def scenario() -> dict[str, Any]:
    rng = random.Random(34)
    transforms: list[list[Any]] = [["world", "map", 0, list(random_pose(rng)), True, "/static_pub"]]
    for i in range(31):  # map -> base every 0.1 s from 100 s
        transforms.append(["map", "base", 100 * S + i * S // 10, list(random_pose(rng)), False, "/mover"])
    for i in range(16):  # base -> laser every 0.2 s, offset
        transforms.append(["base", "laser", 100 * S + S // 20 + i * S // 5, list(random_pose(rng)), False, "/laser"])
    pose = list(random_pose(rng))  # a quaternion and its negation: slerp must take the short arc
    transforms.append(["map", "arm", 100 * S, pose, False, "/arm"])
    transforms.append(["map", "arm", 101 * S, [*pose[:3], *(-c for c in pose[3:])], False, "/arm"])
    for i in range(51):  # odom -> fast every 0.5 s over 25 s: the 10 s window prunes the first 30
        transforms.append(["odom", "fast", i * S // 2, list(random_pose(rng)), False, "/fast"])
    transforms.append(["other", "x", 100 * S, list(random_pose(rng)), False, "/x"])
    queries: list[list[Any]] = []
    for _ in range(40):
        t = rng.randrange(100 * S + S // 20, 103 * S)
        queries += [["world", "laser", t], ["laser", "world", t], ["map", "base", t], ["laser", "map", t]]
    queries += [["world", "arm", 100 * S + S // 3], ["world", "base", 0], ["world", "laser", 0], ["base", "base", 0]]
    queries += [["world", "base", 104 * S], ["world", "base", 99 * S], ["world", "laser", 100 * S]]
    queries += [["odom", "fast", 12 * S], ["odom", "fast", 20 * S + 123], ["world", "x", 0], ["world", "nope", 0]]
    queries += [["nope", "world", 0], ["", "world", 0], ["/world", "base", 0], ["map", "map", 7 * S]]
    return {"transforms": transforms, "queries": queries}


def test_lookups_and_errors_agree_with_tf2_ros_buffer() -> None:
    spec = scenario()
    oracle = subprocess.run(
        [ROS_PYTHON, str(DATA / "tf2_oracle.py")],
        input=json.dumps(spec),
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    *expected, yaml = json.loads(oracle.stdout)
    core = BufferCore()
    for parent, child, stamp, pose, static, authority in spec["transforms"]:
        core.set_transform(parent, child, stamp, tuple(pose), authority=authority, static=static)
    errors = 0
    for (target, source, time), want in zip(spec["queries"], expected, strict=True):
        try:
            pose, stamp = core.lookup(target, source, time)
        except TransformError as exc:
            assert "error" in want, (target, source, time, exc)
            assert (type(exc).__name__, str(exc)) == (ERRORS[want["error"]], want["text"])
            errors += 1
            continue
        assert "pose" in want, (target, source, time, want)
        assert stamp == want["stamp"]
        assert max(abs(a - b) for a, b in zip(pose, want["pose"], strict=True)) < 1e-9, (target, source, time)
    assert errors == 9
    assert core.frames_as_yaml() == yaml["yaml"]


def pose_at(t: float) -> Pose:
    """tf2_broadcaster.py's moving frame at stamp ``t`` (seconds, mod 1000)."""
    yaw = 0.3 * t
    return (math.cos(t), math.sin(t), 0.5, 0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


STATIC: Pose = (1.0, 2.0, 0.0, 0.0, 0.0, 0.38268343236508984, 0.9238795325112868)


def expected_world_base(secs: int, nsecs: int) -> Pose:
    return compose(STATIC, pose_at(secs % 1000 + nsecs * 1e-9))


def numbers(text: str) -> list[float]:
    return [float(x) for x in re.findall(r"-?\d+\.\d+", text)]


async def test_mros_tf_echo_and_the_example_print_what_tf2_ros_broadcasts(procs: Processes, rosmaster: str) -> None:
    broadcaster = procs.start([ROS_PYTHON, str(DATA / "tf2_broadcaster.py")], ros_env(rosmaster, procs.tmp))
    await asyncio.to_thread(lambda: list(iter_lines_until(broadcaster, 1, 30.0)))
    echo = await asyncio.to_thread(
        subprocess.run,
        [sys.executable, "-m", "mros_cli.main", "tf", "echo", "world", "base", "-p", "9", "-n", "2", "-r", "5"],
        env=mros_env(rosmaster, procs.tmp),
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    block = echo.stdout.split("At time ")[-1]
    assert block.splitlines()[1].startswith("- Translation: ["), echo
    stamp, x, y, z, qx, qy, qz, qw = numbers(block)[:8]
    secs, nsecs = int(stamp), round((stamp - int(stamp)) * 1e9)
    want = expected_world_base(secs, nsecs)
    assert max(abs(a - b) for a, b in zip((x, y, z, qx, qy, qz, qw), want, strict=True)) < 1e-6, echo.stdout

    tree = await asyncio.to_thread(
        subprocess.run,
        [sys.executable, "-m", "mros_cli.main", "tf", "tree", "--listen", "1"],
        env=mros_env(rosmaster, procs.tmp),
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    lines = tree.stdout.splitlines()
    assert lines[0] == "world", tree
    assert lines[1] == "  map  broadcaster: /tf2_broadcaster  static", tree
    assert re.match(r"    base  broadcaster: /tf2_broadcaster  rate: \d+\.\d{3} Hz  most recent: ", lines[2]), tree

    listener = procs.start(
        [sys.executable, str(PROJECT_ROOT / "examples" / "tf_listener.py"), "world", "base"],
        mros_env(rosmaster, procs.tmp),
        stderr=subprocess.DEVNULL,
    )
    [line] = await asyncio.to_thread(lambda: list(iter_lines_until(listener, 1, 30.0)))
    m = re.match(r"(\d+)\.(\d{9}) translation \[(.*)\] rotation \[(.*)\]", line)
    assert m is not None, line
    got = [float(v) for v in (m[3] + ", " + m[4]).split(", ")]
    want = expected_world_base(int(m[1]), int(m[2]))
    assert max(abs(a - b) for a, b in zip(got, want, strict=True)) < 1e-6, line


LISTENER = """
import rospy, tf2_ros
rospy.init_node("tf2_listener")
buf = tf2_ros.Buffer()
tf2_ros.TransformListener(buf)
print("up", flush=True)
t = buf.lookup_transform("world", "base", rospy.Time(0), rospy.Duration(20))
v, q = t.transform.translation, t.transform.rotation
print(t.header.stamp.to_nsec(), v.x, v.y, v.z, q.x, q.y, q.z, q.w, flush=True)
"""


async def test_tf2_ros_reads_what_our_broadcasters_send(procs: Processes, rosmaster: str) -> None:
    listener = procs.python(LISTENER, ros_env(rosmaster, procs.tmp), stderr=subprocess.DEVNULL)
    await asyncio.to_thread(lambda: list(iter_lines_until(listener, 1, 30.0)))
    async with mrosd.Node("our_broadcaster", master_uri=rosmaster, argv=[], host="127.0.0.1") as node:
        static, moving = StaticTransformBroadcaster(node), TransformBroadcaster(node)
        await static.send_transform(transform_stamped("world", "map", 0, STATIC))
        line: list[str] = []
        sent: list[int] = []
        reader = asyncio.create_task(asyncio.to_thread(lambda: line.extend(iter_lines_until(listener, 1, 30.0))))
        while not reader.done():
            now = Time.now()
            sent.append(now.to_nsec())
            await moving.send_transform(
                transform_stamped("map", "base", now.to_nsec(), pose_at(now.secs % 1000 + now.nsecs * 1e-9))
            )
            await asyncio.sleep(0.05)
        await reader
        await static.aclose()
        await moving.aclose()
    first, *rest = line[0].split()
    # tf2_py hands stamps to Python through a double (0.24 us steps at today's epoch): take the stamp we sent
    got, stamp = [float(v) for v in rest], min(sent, key=lambda ns: abs(ns - int(first)))
    assert abs(stamp - int(first)) < 1000
    want = expected_world_base(stamp // S, stamp % S)
    assert max(abs(a - b) for a, b in zip(got, want, strict=True)) < 1e-9, line
