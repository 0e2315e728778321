"""``mros tf``: echo a transform as tf_echo prints it, and print the frame tree as view_frames reports it."""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from typing import Any

import click

from mros_cli.main import anonymous, master_client, run

#: How long ``tree`` listens before printing (view_frames listens 5 s).
TREE_LISTEN = 2.0


@click.group(name="tf")
def group() -> None:
    """Transforms on /tf and /tf_static (like tf_echo and view_frames).

    \b
    Examples:
      mros tf echo map base_link
      mros tf tree
    """


def rpy(qx: float, qy: float, qz: float, qw: float) -> tuple[float, float, float]:
    """Roll, pitch, yaw of a quaternion (tf's ``Matrix3x3::getRPY``, first solution)."""
    n = qx * qx + qy * qy + qz * qz + qw * qw
    s = 2.0 / n if n else 0.0
    m20 = s * (qx * qz - qw * qy)
    m21 = s * (qy * qz + qw * qx)
    m22 = 1.0 - s * (qx * qx + qy * qy)
    m10 = s * (qx * qy + qw * qz)
    m00 = 1.0 - s * (qy * qy + qz * qz)
    if abs(m20) >= 1.0:
        m01 = s * (qx * qy - qw * qz)
        m02 = s * (qx * qz + qw * qy)
        delta = math.atan2(m01, m02)
        if m20 < 0:
            return delta, math.pi / 2, 0.0
        return delta, -math.pi / 2, 0.0
    pitch = -math.asin(m20)
    c = math.cos(pitch)
    return math.atan2(m21 / c, m22 / c), pitch, math.atan2(m10 / c, m00 / c)


def echo_text(t: Any, precision: int = 3) -> str:
    """tf_echo's block for one ``TransformStamped``."""
    p = precision
    v, q = t.transform.translation, t.transform.rotation
    roll, pitch, yaw = rpy(q.x, q.y, q.z, q.w)
    stamp = t.header.stamp.secs + t.header.stamp.nsecs / 1e9
    d = 180.0 / math.pi
    return (
        f"At time {stamp:.{p}f}\n"
        f"- Translation: [{v.x:.{p}f}, {v.y:.{p}f}, {v.z:.{p}f}]\n"
        f"- Rotation: in Quaternion [{q.x:.{p}f}, {q.y:.{p}f}, {q.z:.{p}f}, {q.w:.{p}f}]\n"
        f"            in RPY (radian) [{roll:.{p}f}, {pitch:.{p}f}, {yaw:.{p}f}]\n"
        f"            in RPY (degree) [{roll * d:.{p}f}, {pitch * d:.{p}f}, {yaw * d:.{p}f}]"
    )


@group.command()
@click.argument("source")
@click.argument("target")
@click.option("-r", "--rate", type=float, default=1.0, show_default=True, help="Prints per second.")
@click.option("-p", "--precision", type=int, default=3, show_default=True, help="Digits after the point.")
@click.option("-n", "--count", type=int, default=0, help="Stop after this many prints (0: until Ctrl-C).")
def echo(source: str, target: str, rate: float, precision: int, count: int) -> None:
    """Print the transform of TARGET in SOURCE's frame, as tf_echo SOURCE TARGET does.

    \b
    Example:
      mros tf echo map base_link
    """
    from mrosd.msg import Time
    from mrosd.tcpros import Node
    from mrosd.tf import Buffer, TransformError

    if rate <= 0:
        raise click.BadParameter("must be > 0", param_hint="--rate")

    async def main() -> None:
        async with master_client() as master:
            uri = master.master_uri
        async with Node(anonymous("tf_echo"), master_uri=uri, argv=[]) as node, Buffer(node) as buffer:
            with contextlib.suppress(TransformError):  # tf_echo waits up to 1 s for the first transform
                await buffer.wait_for_transform(source, target, None, timeout=1.0)
            printed = 0
            while True:
                try:
                    text = echo_text(buffer.lookup_transform(source, target), precision)
                except TransformError as exc:
                    now = Time.now()
                    frames = "".join(
                        f"Frame {name} exists with parent {f['parent']}.\n" for name, f in buffer.frames().items()
                    )
                    text = (
                        f"Failure at {now.secs}.{now.nsecs:09d}\nException thrown:{exc}\n"
                        f"The current list of frames is:\n{frames}"
                    )
                click.echo(text)
                printed += 1
                if count and printed >= count:
                    return
                await asyncio.sleep(1.0 / rate)

    with contextlib.suppress(KeyboardInterrupt):
        run(main())


def tree_text(frames: dict[str, dict[str, Any]], now: float) -> str:
    """The frames as an indented tree, each with its broadcaster, rate, age and buffer length."""
    children: dict[str, list[str]] = {}
    for name, f in frames.items():
        children.setdefault(f["parent"], []).append(name)
    roots = sorted(p for p in children if p not in frames)
    lines: list[str] = []

    def walk(name: str, depth: int) -> None:
        f = frames.get(name)
        if f is None:
            lines.append(name)
        elif f["static"]:
            lines.append(f"{'  ' * depth}{name}  broadcaster: {f['broadcaster']}  static")
        else:
            age = now - f["most_recent_transform"]
            lines.append(
                f"{'  ' * depth}{name}  broadcaster: {f['broadcaster']}  rate: {f['rate']:.3f} Hz  "
                f"most recent: {f['most_recent_transform']:.3f} ({age:.3f} sec old)  "
                f"buffer: {f['buffer_length']:.3f} sec"
            )
        if depth < 1000:
            for child in sorted(children.get(name, [])):
                walk(child, depth + 1)

    for root in roots:
        walk(root, 0)
    return "\n".join(lines)


@group.command()
@click.option("--listen", type=float, default=TREE_LISTEN, show_default=True, help="Seconds to listen first.")
@click.option("--yaml", "as_yaml", is_flag=True, help="Print tf2's allFramesAsYAML text instead.")
def tree(listen: float, as_yaml: bool) -> None:
    """Print the frame tree: each frame's parent, broadcaster, rate, age and buffer length (as view_frames).

    \b
    Example:
      mros tf tree
    """
    from mrosd.tcpros import Node
    from mrosd.tf import Buffer

    async def main() -> str:
        async with master_client() as master:
            uri = master.master_uri
        async with Node(anonymous("tf_tree"), master_uri=uri, argv=[]) as node, Buffer(node) as buffer:
            await asyncio.sleep(listen)
            if as_yaml:
                return buffer.all_frames_as_yaml().rstrip("\n")
            return tree_text(buffer.frames(), time.time())

    text = run(main())
    if text:
        click.echo(text)
