"""``mros ros2``: the daemon's ros2 part alone, against any master (rosmaster included).

``mros ros2 bridge`` runs the same ``mrosd.ros2.bridge.Ros2Bridge`` the daemon runs with ``[ros2] enabled``,
in the foreground until Ctrl-C: chosen ROS 1 topics appear to ROS 2 nodes that use rmw_zenoh.
"""

from __future__ import annotations

import asyncio
import json
from typing import Any

import click

from mros_cli.main import anonymous, fail, master_uri, run
from mrosd.errors import MrosError

#: the bridge node's status service (``Ros2Bridge``'s ``~status`` of node ``mrosd_ros2``)
STATUS_SERVICE = "/mrosd_ros2/status"


@click.group(name="ros2")
def group() -> None:
    """Show ROS 1 topics to ROS 2 (rmw_zenoh) without a ROS 2 install.

    \b
    Examples:
      mros ros2 bridge --to-ros2 /chatter --from-ros2 /cmd_vel
      mros ros2 bridge --to-ros2 '/camera/**' --connect tcp/laptop:7447 --domain-id 3
      mros ros2 bridge --router --listen tls/0.0.0.0:7447 --from-ros2 /cmd_vel \\
        --tls-root-ca ca.pem --tls-certificate robot.pem --tls-private-key robot.key
      mros ros2 status
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
@click.option(
    "--mode",
    type=click.Choice(["listed", "all", "demand"]),
    default="listed",
    show_default=True,
    help="listed: the globs; all: every ROS 1 topic; demand: only while the other side subscribes "
    "(from ROS 2, every mode takes only --from-ros2)",
)
@click.option("--distro", type=click.Choice(["jazzy", "humble"]), default="jazzy", show_default=True)
@click.option("--router", is_flag=True, help="Be the Zenoh router ROS 2 nodes connect to (listens on tcp/[::]:7447)")
@click.option("--service-timeout", type=click.FloatRange(0.1, 3600), default=10.0, show_default=True)
@click.option("--mapping-rules", multiple=True, help="ros1_bridge mapping-rule YAML (repeatable)")
@click.option("--ros2-share", multiple=True, help="ROS 2 share tree with <pkg>/msg/*.msg (repeatable)")
@click.option(
    "--tls-root-ca",
    type=click.Path(exists=True, dir_okay=False),
    help="PEM: the CA every peer's certificate must be signed by (tls/ endpoints)",
)
@click.option(
    "--tls-certificate",
    type=click.Path(exists=True, dir_okay=False),
    help="PEM: this end's certificate; with --tls-private-key, peers must show one of the CA (mutual TLS)",
)
@click.option("--tls-private-key", type=click.Path(exists=True, dir_okay=False), help="PEM: its key")
def bridge(
    *,
    to_ros2: tuple[str, ...],
    from_ros2: tuple[str, ...],
    connect: tuple[str, ...],
    listen: tuple[str, ...],
    domain_id: int,
    queue_size: int,
    mode: str,
    distro: str,
    router: bool,
    service_timeout: float,
    mapping_rules: tuple[str, ...],
    ros2_share: tuple[str, ...],
    tls_root_ca: str | None,
    tls_certificate: str | None,
    tls_private_key: str | None,
) -> None:
    """Put the chosen ROS 1 topics on Zenoh as an rmw_zenoh ROS 2 node publishes them, and back."""
    from mrosd.config import Ros2Config
    from mrosd.errors import ConfigError
    from mrosd.ros2.bridge import Ros2Bridge, ros2_options

    if not to_ros2 and not from_ros2 and mode == "listed":
        raise click.UsageError("name topics with --to-ros2 and/or --from-ros2 (or use --mode all or demand)")
    cfg = Ros2Config(
        enabled=True,
        domain_id=domain_id,
        listen=list(listen),
        to_ros2=list(to_ros2),
        from_ros2=list(from_ros2),
        queue_size=queue_size,
        mode=mode,  # type: ignore[arg-type]
        distro=distro,  # type: ignore[arg-type]
        router=router,
        connect=list(connect),
        service_timeout=service_timeout,
        mapping_rules=list(mapping_rules),
        ros2_share=list(ros2_share),
        tls_root_ca=tls_root_ca or "",
        tls_certificate=tls_certificate or "",
        tls_private_key=tls_private_key or "",
    )
    try:
        options = ros2_options(cfg)
    except ConfigError as exc:
        raise click.UsageError(str(exc)) from None

    async def serve() -> None:
        async with Ros2Bridge(options, master_uri()):
            click.echo(
                f"ros2: to ROS 2 {', '.join(to_ros2) or '-'}, from ROS 2 {', '.join(from_ros2) or '-'}; "
                f"Zenoh {'router on ' + ', '.join(options.listen) if router else ', '.join(options.connect)} "
                f"domain {options.domain_id}, mode {mode}, {distro} (master {master_uri()}); Ctrl-C to stop",
                err=True,
            )
            await asyncio.Event().wait()

    run(serve())


async def fetch_status(uri: str, timeout: float = 5.0) -> dict[str, Any]:
    """The bridge node's status.

    Raises:
        MrosError: no ros2 bridge runs on this master, or it does not answer.
    """
    from mrosd.msg import get_service_class
    from mrosd.tcpros.node import Node

    trigger = get_service_class("std_srvs/Trigger")
    async with Node(anonymous("ros2"), master_uri=uri, argv=[], rosout=False, logger_services=False) as node:
        resp = await node.service_proxy(STATUS_SERVICE, trigger).call(trigger._request_class(), timeout=timeout)
    status: dict[str, Any] = json.loads(resp.message)
    return status


def _more(st: dict[str, Any], section: str) -> list[str]:
    more = st.get(section + "_more", 0)
    return [f"  ... and {more} more"] if more else []


def format_status(st: dict[str, Any]) -> str:
    """One line per bridged topic and service, each direction, with rates (Hz), drops and type problems."""
    head = f"zenoh id {st['zid']}, domain {st['domain_id']}"
    if "mode" in st:
        head += f", mode {st['mode']}, {st['distro']}{', router' if st.get('router') else ''}"
    lines = [head, "to ROS 2:"]
    for row in st["to_ros2"]:
        what = row["problem"] or f"{row['ros2_type']}{' (latched)' if row.get('latched') else ''}"
        lines.append(
            f"  {row['topic']}  {what}  {row.get('rate', 0.0):g} Hz  sent {row['sent']}  dropped {row['dropped']}"
        )
    lines += _more(st, "to_ros2")
    lines.append("from ROS 2:")
    for row in st["from_ros2"]:
        lines.append(
            f"  {row['topic']}  {row['ros2_type']}{' (latched)' if row.get('latched') else ''}  "
            f"{row.get('rate', 0.0):g} Hz  received {row['received']}  "
            f"dropped {row['dropped']}  bad {row['bad']}"
        )
    lines += _more(st, "from_ros2")
    services = st.get("services", [])
    if services:
        lines.append("services:")
        for row in services:
            arrow = "->" if row["direction"] == "to_ros2" else "<-"
            what = row["problem"] or row["ros2_type"]
            lines.append(
                f"  {row['service']} {arrow} ROS 2  {what}  calls {row['calls']}  errors {row['errors']}  "
                f"refused {row['refused']}"
            )
        lines += _more(st, "services")
    return "\n".join(lines)


@group.command(name="status")
@click.option("--json", "as_json", is_flag=True, help="Print the status as JSON.")
def status(as_json: bool) -> None:
    """What the ros2 bridge on this master shows to ROS 2 and takes from it."""

    async def ask() -> dict[str, Any]:
        try:
            return await fetch_status(master_uri())
        except MrosError as exc:
            fail(f"no ros2 bridge answers on {master_uri()}: {exc}")

    st = run(ask())
    click.echo(json.dumps(st, indent=2, sort_keys=True) if as_json else format_status(st))
