"""``mros ros2``: the daemon's ros2 part alone, against any master (rosmaster included).

``mros ros2 bridge`` runs the same ``mrosd.ros2.bridge.Ros2Bridge`` the daemon runs with ``[ros2] enabled``,
in the foreground until Ctrl-C: chosen ROS 1 topics appear to ROS 2 nodes that use rmw_zenoh.
"""

from __future__ import annotations

import asyncio

import click

from mros_cli.main import master_uri, run


@click.group(name="ros2")
def group() -> None:
    """Show ROS 1 topics to ROS 2 (rmw_zenoh) without a ROS 2 install.

    \b
    Examples:
      mros ros2 bridge --to-ros2 /chatter --from-ros2 /cmd_vel
      mros ros2 bridge --to-ros2 '/camera/**' --connect tcp/laptop:7447 --domain-id 3
    """


@group.command(name="bridge")
@click.option("--to-ros2", "to_ros2", multiple=True, help="ROS 1 topic glob to show to ROS 2 (repeatable)")
@click.option("--from-ros2", "from_ros2", multiple=True, help="ROS 2 topic glob to republish on ROS 1 (repeatable)")
@click.option(
    "--connect",
    multiple=True,
    default=["tcp/localhost:7447"],
    show_default=True,
    help="Zenoh endpoint of the ROS 2 side's router (repeatable)",
)
@click.option("--listen", multiple=True, help="Zenoh endpoint to listen on (repeatable)")
@click.option(
    "--domain-id", type=click.IntRange(-1, 232), default=-1, show_default=True, help="-1: $ROS_DOMAIN_ID, else 0"
)
@click.option("--queue-size", type=click.IntRange(1, 10000), default=16, show_default=True)
def bridge(
    *,
    to_ros2: tuple[str, ...],
    from_ros2: tuple[str, ...],
    connect: tuple[str, ...],
    listen: tuple[str, ...],
    domain_id: int,
    queue_size: int,
) -> None:
    """Put the chosen ROS 1 topics on Zenoh as an rmw_zenoh ROS 2 node publishes them, and back."""
    from mrosd.config import Ros2Config
    from mrosd.errors import ConfigError
    from mrosd.ros2.bridge import Ros2Bridge, ros2_options

    if not to_ros2 and not from_ros2:
        raise click.UsageError("name topics with --to-ros2 and/or --from-ros2")
    cfg = Ros2Config(
        enabled=True,
        domain_id=domain_id,
        connect=list(connect),
        listen=list(listen),
        to_ros2=list(to_ros2),
        from_ros2=list(from_ros2),
        queue_size=queue_size,
    )
    try:
        options = ros2_options(cfg)
    except ConfigError as exc:
        raise click.UsageError(str(exc)) from None

    async def serve() -> None:
        async with Ros2Bridge(options, master_uri()):
            click.echo(
                f"ros2: to ROS 2 {', '.join(to_ros2) or '-'}, from ROS 2 {', '.join(from_ros2) or '-'}; "
                f"Zenoh {', '.join(connect)} domain {options.domain_id} (master {master_uri()}); Ctrl-C to stop",
                err=True,
            )
            await asyncio.Event().wait()

    run(serve())
